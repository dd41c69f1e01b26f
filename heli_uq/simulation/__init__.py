"""Simulation: the fixed-step RK4 solver with exact zero-order hold and a discrete adjoint,
an adaptive stiff reference solve (diffrax), and seeded synthetic records.

Layer 3 (imports :mod:`heli_uq.data` and :mod:`heli_uq.model`).
"""

from heli_uq.simulation.physical import PITCH_LIMIT as PITCH_LIMIT
from heli_uq.simulation.physical import physical_range as physical_range
from heli_uq.simulation.reference import reference_solve as reference_solve
from heli_uq.simulation.solver import MAX_ABS_STATE as MAX_ABS_STATE
from heli_uq.simulation.solver import RESULTS as RESULTS
from heli_uq.simulation.solver import Solution as Solution
from heli_uq.simulation.solver import simulate as simulate
from heli_uq.simulation.solver import solve as solve
from heli_uq.simulation.stiffness import default_substeps as default_substeps
from heli_uq.simulation.synthetic import SYNTHETIC_PARAMS as SYNTHETIC_PARAMS
from heli_uq.simulation.synthetic import SYNTHETIC_X0 as SYNTHETIC_X0
from heli_uq.simulation.synthetic import synthetic_experiment as synthetic_experiment

__all__ = ["PITCH_LIMIT", "physical_range", "reference_solve", "MAX_ABS_STATE", "RESULTS",
           "Solution", "default_substeps", "simulate", "solve", "SYNTHETIC_PARAMS", "SYNTHETIC_X0",
           "synthetic_experiment"]  # fmt: skip
