"""heli_uq: Bayesian uncertainty quantification of a 2-DOF laboratory helicopter.

The package is laid out by stage; data flows one way and every subpackage imports only
from the ones before it (``tests/test_layout.py`` checks this)::

    errors, io, figure      base utilities (provenance: which code made a result)
    data/                   rig records (Experiment, the published CSV, the real record)
    model/                  mechanics, torque terms, named effects, parameters, priors
    model/terms/            one file per term (a new effect: one file there, one line in its __init__)
    simulation/             fixed-step RK4 with discrete adjoint, diffrax reference, synthetic records
    probability/            priors, sampling coordinates, error models, the likelihood, numpyro model
    inference/              MAP, Laplace, NUTS, emcee, checkpoints
    identifiability/        structural, practical and Bayesian identifiability report
    output/                 InferenceData, diagnostics, figures, the posterior study
    discovery/              the missing named effect of a record (``heli-uq discover``)
    design/                 informative voltage staircases (``heli-uq design``)
    cli/                    the ``heli-uq`` command

**JAX configuration.**  Importing :mod:`heli_uq` (any submodule) enables float64 in JAX
(``jax_enable_x64``) and, if JAX is not imported yet, has jitted functions take the
arrays they close over (a record) as arguments instead of constants, so that records of
one length share compiled programs (:mod:`heli_uq._jax_config`).  These are the
package's only global settings.  The ``heli-uq`` commands that sample also give XLA one
host device per chain, before JAX starts.
"""

from heli_uq import _jax_config  # noqa: F401  (float64 before any array exists)
from heli_uq.data import Experiment as Experiment
from heli_uq.data import load_data as load_data
from heli_uq.errors import DataFormatError as DataFormatError
from heli_uq.errors import HeliUQError as HeliUQError
from heli_uq.errors import ParameterError as ParameterError
from heli_uq.model import EFFECTS as EFFECTS
from heli_uq.model import STATE_NAMES as STATE_NAMES
from heli_uq.model import TABLE1 as TABLE1
from heli_uq.model import TABLE2 as TABLE2
from heli_uq.model import TABLE3_X0 as TABLE3_X0
from heli_uq.model import HeliModel as HeliModel
from heli_uq.model import Parameter as Parameter
from heli_uq.model import Prior as Prior
from heli_uq.model import build_model as build_model
from heli_uq.model import parse_effects as parse_effects
from heli_uq.probability import PriorSet as PriorSet
from heli_uq.probability import loss_v as loss_v
from heli_uq.probability import make_problem as make_problem
from heli_uq.simulation import RESULTS as RESULTS
from heli_uq.simulation import Solution as Solution
from heli_uq.simulation import reference_solve as reference_solve
from heli_uq.simulation import simulate as simulate
from heli_uq.simulation import solve as solve
from heli_uq.simulation import synthetic_experiment as synthetic_experiment

__all__ = [
    "Experiment", "load_data", "DataFormatError", "HeliUQError", "ParameterError", "EFFECTS",
    "STATE_NAMES", "TABLE1", "TABLE2", "TABLE3_X0", "HeliModel", "Parameter", "Prior",
    "build_model", "parse_effects", "PriorSet", "loss_v", "make_problem", "RESULTS", "Solution",
    "reference_solve", "simulate", "solve", "synthetic_experiment",
]  # fmt: skip
__version__ = "0.2.0"
