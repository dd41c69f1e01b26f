"""``feature_torque``: a torque linear in named features of the voltages.

    T(u) = sum_k c_k f_k(u)        [N m], any sign,

with the features ``f_k`` chosen by name from :data:`FEATURES` (polynomials, ``|u|u``
and trigonometric functions of the two voltages after any dead band).  This is how an
equation recovered from a network (:mod:`heli_uq.discovery.network_equation`, pysindy on
posterior draws of the network's torque) becomes a parametric term that NUTS refits:
``{"effect": "feature_torque", "axis": "yaw", "features": ["u_psi^2", "cos(u_psi)"]}``.
Parameters are named ``c_<feature>_<axis>`` (e.g. ``c_u_psi_sq_yaw`` for ``u_psi^2``;
see :func:`coefficient_name`).  Each has
a ``normal(0, 0.05 N m / typical |f|)`` prior.  Inputs are held on each sample interval:
no stiffness.
"""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp

from heli_uq.errors import ParameterError
from heli_uq.model.parameter import Parameter
from heli_uq.model.prior import Prior
from heli_uq.model.terms.base import AbstractEffect, AbstractTorque, on_axis

__all__ = ["FeatureTorque", "FEATURES", "coefficient_name"]

#: The feature vocabulary: name -> (function of the voltages u (2,) [V], typical size on
#: the rig's voltage ranges, which scales the coefficient's prior, the coefficient's name
#: without the ``c_`` prefix).
FEATURES = {
    "1": (lambda u: jnp.ones_like(u[0]), 1.0, "one"),
    "u_theta": (lambda u: u[0], 1.4, "u_theta"),
    "u_psi": (lambda u: u[1], 1.0, "u_psi"),
    "u_theta^2": (lambda u: u[0] ** 2, 2.0, "u_theta_sq"),
    "u_psi^2": (lambda u: u[1] ** 2, 1.0, "u_psi_sq"),
    "u_theta*u_psi": (lambda u: u[0] * u[1], 1.4, "u_theta_u_psi"),
    "u_theta^3": (lambda u: u[0] ** 3, 2.8, "u_theta_cube"),
    "u_psi^3": (lambda u: u[1] ** 3, 1.0, "u_psi_cube"),
    "|u_theta|u_theta": (lambda u: jnp.abs(u[0]) * u[0], 2.0, "abs_u_theta_u_theta"),
    "|u_psi|u_psi": (lambda u: jnp.abs(u[1]) * u[1], 1.0, "abs_u_psi_u_psi"),
    "cos(u_theta)": (lambda u: jnp.cos(u[0]), 0.2, "cos_u_theta"),
    "sin(u_theta)": (lambda u: jnp.sin(u[0]), 1.0, "sin_u_theta"),
    "cos(u_psi)": (lambda u: jnp.cos(u[1]), 0.6, "cos_u_psi"),
    "sin(u_psi)": (lambda u: jnp.sin(u[1]), 0.8, "sin_u_psi"),
}
#: Prior sd of the torque one feature may add at its typical size [N m].
TORQUE_PRIOR_SD = 0.05


def coefficient_name(feature: str) -> str:
    """The bare parameter name of ``feature``'s coefficient, e.g. ``"c_u_psi_sq"`` for
    ``"u_psi^2"``."""
    return "c_" + FEATURES[feature][2]


def _features(value) -> tuple[str, ...]:
    if isinstance(value, str):
        value = [v for v in value.split(",") if v.strip()]
    return tuple(str(v).strip() for v in value)


class FeatureTorque(AbstractEffect, AbstractTorque):
    """``sum_k c_k f_k(u)`` on ``axis`` (module docstring).

    Parameters
    ----------
    axis : {"pitch", "yaw"}
    features : tuple of str
        Names from :data:`FEATURES`, at least one, no repeats.
    """

    kind: ClassVar[str] = "feature_torque"
    summary: ClassVar[str] = (
        "an equation recovered from a network: a sum of named features of the voltages with fitted "
        "coefficients (option features in a model file)")
    input_only: ClassVar[bool] = True
    axis: str = eqx.field(static=True, default="yaw")
    features: tuple = eqx.field(static=True, default=("1",), converter=_features)

    def __check_init__(self):
        unknown = [f for f in self.features if f not in FEATURES]
        if unknown or not self.features:
            raise ParameterError(f"feature_torque: unknown feature(s) {unknown or '(none given)'}; "
                                 f"expected some of {', '.join(FEATURES)}")  # fmt: skip
        if len(set(self.features)) < len(self.features):
            raise ParameterError(f"feature_torque: repeated feature in {list(self.features)}")

    def _declare(self):
        return tuple(Parameter(coefficient_name(f), "N m", 0.0,
                               Prior("normal", 0.0, TORQUE_PRIOR_SD / FEATURES[f][1]), "real", True,
                               None, f"coefficient of {f}", 0.0)  # fmt: skip
                     for f in self.features)

    def __call__(self, p, x, v, u):
        torque = sum(p[self.name(coefficient_name(f))] * FEATURES[f][0](u) for f in self.features)
        return on_axis(self.axis, torque)

    def describe(self) -> dict:
        return {"effect": self.kind, "axis": self.axis, "features": list(self.features)}
