"""The paper's torque model (Sec. 2.5): linear motor gains and viscous damping.

``F = K u - D v`` with ``K = [[K_theta_theta, -K_theta_psi], [K_psi_theta, -K_psi_psi]]``
[N m/V] and ``D = diag(D_theta, D_psi)`` [N m s/rad].
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from heli_uq.model.parameter import Parameter
from heli_uq.model.prior import Prior
from heli_uq.model.terms.base import AbstractTorque
from heli_uq.model.terms.rigid_body import DEFAULT_LOG_SIGMA

__all__ = ["LinearTorque", "LINEAR_TORQUE_PARAMETERS", "motor_torques"]


def _gain(name, unit, nominal, fitted, axis, text, source=None) -> Parameter:
    return Parameter(name, unit, nominal, Prior("lognormal", nominal, DEFAULT_LOG_SIGMA),
                     "nonnegative", True, axis, text, fitted, input=source)  # fmt: skip


#: Paper Table 2 (default) and Table 1 (start) values.
LINEAR_TORQUE_PARAMETERS: tuple[Parameter, ...] = (
    _gain("K_theta_theta", "N m/V", 0.055, 0.105, "pitch", "pitch torque per pitch-motor volt",
          (0, 1.0)),
    _gain("K_theta_psi", "N m/V", 0.005, 0.0017, "pitch",
          "pitch torque per yaw-motor volt (enters with minus sign)", (1, -1.0)),
    _gain("K_psi_theta", "N m/V", 0.15, 0.03, "yaw", "yaw torque per pitch-motor volt", (0, 1.0)),
    _gain("K_psi_psi", "N m/V", 0.20, 0.043, "yaw",
          "yaw torque per yaw-motor volt (enters with minus sign)", (1, -1.0)),
    _gain("D_theta", "N m s/rad", 0.01, 0.014, "pitch", "viscous friction in pitch"),
    _gain("D_psi", "N m s/rad", 0.08, 0.11, "yaw", "viscous friction in yaw"),
)  # fmt: skip


def motor_torques(p, u):
    """The motors' torques ``K u`` [N m], a pair ``(T_theta, T_psi)`` of scalars, from the
    gains in ``p`` and the voltages ``u = (u_theta, u_psi)`` [V] (other terms that modify
    them, e.g. :mod:`~heli_uq.model.terms.thrust_tilt`, read them here)."""
    return (p["K_theta_theta"] * u[0] - p["K_theta_psi"] * u[1],
            p["K_psi_theta"] * u[0] - p["K_psi_psi"] * u[1])  # fmt: skip


class LinearTorque(AbstractTorque):
    """``F = K u - D v`` (paper Sec. 2.5), returning ``(T_theta, T_psi)`` [N m]."""

    kind: ClassVar[str] = "linear"
    input_only: ClassVar[bool] = False

    def parameters(self) -> tuple[Parameter, ...]:
        return LINEAR_TORQUE_PARAMETERS

    def __call__(self, p, x, v, u):
        t_theta, t_psi = motor_torques(p, u)
        return t_theta - p["D_theta"] * v[0], t_psi - p["D_psi"] * v[1]

    def decay_rates(self, p, inertia):
        """The viscous decays ``D / M`` [1/s] of the two axes: 2.3 (pitch) and 1.2 /s (yaw)
        at the rig's fit, but a fit that imitates a hidden friction by heavy damping on a
        light body reaches RK4's limit (``D_theta / M11`` = 278 /s, ``r h`` = 2.78 at one
        substep, blew up 125 s into a record)."""
        return {"pitch": np.asarray(p["D_theta"], dtype=float) / np.asarray(inertia[0], dtype=float),
                "yaw": np.asarray(p["D_psi"], dtype=float) / np.asarray(inertia[1], dtype=float)}
