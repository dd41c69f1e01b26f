"""The model: rigid-body mechanics, torque terms, named effects and their parameters.

Layer 2 (imports :mod:`heli_uq.data` and the base modules).  A
:class:`HeliModel` gathers the :class:`Parameter` declarations of its terms; the
effects vocabulary is :data:`EFFECTS` (one file per effect in ``model/terms/``).
"""

from heli_uq.model.heli_model import HeliModel as HeliModel
from heli_uq.model.heli_model import momentum_vector_field as momentum_vector_field
from heli_uq.model.parameter import AXES as AXES
from heli_uq.model.parameter import Parameter as Parameter
from heli_uq.model.prior import Prior as Prior
from heli_uq.model.spec import build_model as build_model
from heli_uq.model.spec import load_model_file as load_model_file
from heli_uq.model.spec import model_from_description as model_from_description
from heli_uq.model.spec import parse_effects as parse_effects
from heli_uq.model.spec import with_effects as with_effects
from heli_uq.model.tables import RIG_FIT as RIG_FIT
from heli_uq.model.tables import RIG_FIT_X0 as RIG_FIT_X0
from heli_uq.model.tables import STATE_NAMES as STATE_NAMES
from heli_uq.model.tables import TABLE1 as TABLE1
from heli_uq.model.tables import TABLE2 as TABLE2
from heli_uq.model.tables import TABLE3_X0 as TABLE3_X0
from heli_uq.model.tables import X0_NAMES as X0_NAMES
from heli_uq.model.tables import load_params_json as load_params_json
from heli_uq.model.tables import parse_x0 as parse_x0
from heli_uq.model.terms import EFFECTS as EFFECTS
from heli_uq.model.terms import ClosedFormMechanics as ClosedFormMechanics
from heli_uq.model.terms import CoulombFriction as CoulombFriction
from heli_uq.model.terms import DeadBand as DeadBand
from heli_uq.model.terms import LagrangianMechanics as LagrangianMechanics
from heli_uq.model.terms import LinearTorque as LinearTorque
from heli_uq.model.terms import QuadraticDrag as QuadraticDrag
from heli_uq.model.terms import QuadraticThrust as QuadraticThrust
from heli_uq.model.terms import TorqueOffset as TorqueOffset
from heli_uq.model.terms import TorsionalSpring as TorsionalSpring
from heli_uq.model.terms.rigid_body import total_energy as total_energy

__all__ = [
    "HeliModel", "momentum_vector_field", "AXES", "Parameter", "Prior", "build_model",
    "load_model_file", "model_from_description", "parse_effects", "with_effects", "STATE_NAMES", "TABLE1",
    "TABLE2", "TABLE3_X0", "RIG_FIT", "RIG_FIT_X0", "X0_NAMES", "load_params_json", "parse_x0", "EFFECTS",
    "ClosedFormMechanics", "CoulombFriction", "DeadBand", "LagrangianMechanics", "LinearTorque",
    "QuadraticDrag", "QuadraticThrust", "TorqueOffset", "TorsionalSpring", "total_energy",
]  # fmt: skip
