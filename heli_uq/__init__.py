"""heli_uq: Bayesian uncertainty quantification of a 2-DOF laboratory helicopter.

The public API is re-exported here; submodules are one concept each
(``params``, ``torques``, ``lagrangian``, ``dynamics``, ``simulate``, ``data``, ...).
"""

from heli_uq import _jax_config  # noqa: F401  (float64 before any array exists)
from heli_uq.dynamics import (
    AbstractHeliModel as AbstractHeliModel,
)
from heli_uq.dynamics import (
    HelicopterModel as HelicopterModel,
)
from heli_uq.dynamics import (
    LagrangianModel as LagrangianModel,
)
from heli_uq.dynamics import (
    MechanicsCoefficients as MechanicsCoefficients,
)
from heli_uq.dynamics import (
    momentum_vector_field as momentum_vector_field,
)
from heli_uq.dynamics import (
    total_energy as total_energy,
)
from heli_uq.errors import (
    DataFormatError as DataFormatError,
)
from heli_uq.errors import (
    HeliUQError as HeliUQError,
)
from heli_uq.errors import (
    ParameterError as ParameterError,
)
from heli_uq.objectives import loss_v as loss_v
from heli_uq.params import (
    PARAM_NAMES as PARAM_NAMES,
)
from heli_uq.params import (
    STATE_NAMES as STATE_NAMES,
)
from heli_uq.params import (
    TABLE1 as TABLE1,
)
from heli_uq.params import (
    TABLE2 as TABLE2,
)
from heli_uq.params import (
    TABLE3_X0 as TABLE3_X0,
)
from heli_uq.params import (
    HeliParams as HeliParams,
)
from heli_uq.simulate import (
    RESULTS as RESULTS,
)
from heli_uq.simulate import (
    Solution as Solution,
)
from heli_uq.simulate import (
    simulate as simulate,
)
from heli_uq.simulate import (
    solve as solve,
)
from heli_uq.torques import (
    AbstractTorque as AbstractTorque,
)
from heli_uq.torques import (
    LinearTorque as LinearTorque,
)
from heli_uq.torques import (
    SumTorque as SumTorque,
)

__all__ = [
    "AbstractHeliModel", "HelicopterModel", "LagrangianModel", "MechanicsCoefficients",
    "momentum_vector_field", "total_energy",
    "DataFormatError", "HeliUQError", "ParameterError",
    "loss_v",
    "PARAM_NAMES", "STATE_NAMES", "TABLE1", "TABLE2", "TABLE3_X0", "HeliParams",
    "RESULTS", "Solution", "simulate", "solve",
    "AbstractTorque", "LinearTorque", "SumTorque",
]  # fmt: skip
__version__ = "0.1.0"
