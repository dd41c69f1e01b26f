"""Model terms: the mechanics, the paper's linear torque, and the named effects.

One file per term.  :data:`EFFECTS` is the effects vocabulary (names are part of the
contract: ``--effects yaw:coulomb_friction`` and model files use them).  A new term is
one new file with one :class:`~heli_uq.model.terms.base.AbstractEffect` subclass (its
contract is in that class's docstring) plus its import here and one entry in
:data:`TERMS`, or in :data:`EFFECTS` to make it a discovery candidate on both axes
(README, "Adding a term").
"""

from heli_uq.model.terms.axis_tilt import AxisTilt as AxisTilt
from heli_uq.model.terms.base import AbstractEffect as AbstractEffect
from heli_uq.model.terms.base import AbstractInputMap as AbstractInputMap
from heli_uq.model.terms.base import AbstractTerm as AbstractTerm
from heli_uq.model.terms.base import AbstractTorque as AbstractTorque
from heli_uq.model.terms.coulomb_friction import CoulombFriction as CoulombFriction
from heli_uq.model.terms.cross_damping import CrossDamping as CrossDamping
from heli_uq.model.terms.deadband import DeadBand as DeadBand
from heli_uq.model.terms.feature_torque import FeatureTorque as FeatureTorque
from heli_uq.model.terms.gp_torque import GPTorque as GPTorque
from heli_uq.model.terms.input_delay import InputDelay as InputDelay
from heli_uq.model.terms.linear_torque import LinearTorque as LinearTorque
from heli_uq.model.terms.motor_lag import MotorLag as MotorLag
from heli_uq.model.terms.neural_torque import NeuralTorque as NeuralTorque
from heli_uq.model.terms.quadratic_drag import QuadraticDrag as QuadraticDrag
from heli_uq.model.terms.quadratic_thrust import QuadraticThrust as QuadraticThrust
from heli_uq.model.terms.rigid_body import AbstractMechanics as AbstractMechanics
from heli_uq.model.terms.rigid_body import ClosedFormMechanics as ClosedFormMechanics
from heli_uq.model.terms.rigid_body import LagrangianMechanics as LagrangianMechanics
from heli_uq.model.terms.stiction import Stiction as Stiction
from heli_uq.model.terms.thrust_tilt import ThrustTilt as ThrustTilt
from heli_uq.model.terms.torque_offset import TorqueOffset as TorqueOffset
from heli_uq.model.terms.torsional_spring import TorsionalSpring as TorsionalSpring

#: The named effects, by their contract names.
EFFECTS = {cls.kind: cls for cls in (DeadBand, CoulombFriction, QuadraticDrag, TorsionalSpring,
                                     QuadraticThrust, TorqueOffset)}  # fmt: skip
#: Every term a model file or ``--effects`` may name: the vocabulary plus the stiction
#: variant of friction (breakaway above the sliding level; outside the effects table), the
#: yaw torques' ``cos theta`` tilt with pitch (a correction of the paper's torque), the
#: first-order lag of a motor's voltage (a motor's dynamics), a motor's dead time, the
#: torque of one axis' rate on the other (cross damping), gravity on a tilted yaw axis
#: (axis tilt), the neural torque of the hybrid model, the feature torque of an equation
#: recovered from it and the Gaussian-process torque of the voltages (model discrepancy).
#: Only the vocabulary's effects are discovery candidates.
TERMS = {**EFFECTS, Stiction.kind: Stiction, ThrustTilt.kind: ThrustTilt,
         MotorLag.kind: MotorLag, InputDelay.kind: InputDelay, CrossDamping.kind: CrossDamping,
         AxisTilt.kind: AxisTilt,
         NeuralTorque.kind: NeuralTorque, FeatureTorque.kind: FeatureTorque, GPTorque.kind: GPTorque}

__all__ = [
    "AbstractEffect", "AbstractInputMap", "AbstractTerm", "AbstractTorque", "AbstractMechanics",
    "ClosedFormMechanics", "LagrangianMechanics", "LinearTorque", "CoulombFriction", "DeadBand",
    "QuadraticDrag", "QuadraticThrust", "TorqueOffset", "TorsionalSpring", "NeuralTorque",
    "FeatureTorque", "GPTorque", "Stiction", "ThrustTilt", "MotorLag", "InputDelay", "CrossDamping",
    "AxisTilt",
    "EFFECTS", "TERMS",
]  # fmt: skip
