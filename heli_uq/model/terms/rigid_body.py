"""The rigid-body mechanics of the helicopter (paper Sec. 2): parameters, closed-form
equations of motion (Sec. 2.7), momentum/DAE form (Sec. 2.6) and energy.

Derivation (App. A).  With ``c = cos theta``, ``s = sin theta`` the Lagrangian is
``L = 1/2 M11 w_theta^2 + 1/2 M22(theta) w_psi^2 - m g (r_c s + h c)`` where
``M11 = J_bc + m r_c^2 + m h^2`` and ``M22 = J_bc c^2 + m (r_c c - h s)^2 + J_s``.
Differentiating,

``dM22/dtheta = -2 [J_bc c s + m (r_c c - h s)(r_c s + h c)]
             = -2 [(J_bc + m (r_c^2 - h^2)) c s + m r_c h (c^2 - s^2)] =: -2 a(theta)``

so ``dL/dtheta = -w_psi^2 a(theta) - m g (r_c c - h s)`` and
``(dp/dx v)_psi = -2 a(theta) w_theta w_psi``.  The equations of motion are

``M11 dw_theta/dt = -w_psi^2 a(theta) - m g (r_c c - h s) + T_theta``
``M22 dw_psi/dt   = 2 w_theta w_psi a(theta) + T_psi``.

**Printed-term error in the paper.**  Sec. 2.7 and App. A.2 print the ``h``-term of
``dL/dtheta`` as ``- r_c h (c^2 - s^2)``.  The derivation above (and App. A.2's own
``dp_psi/dtheta``) gives ``+ m r_c h (c^2 - s^2)``: the sign is flipped and the mass
``m`` is missing.  This package uses the derived term; ``tests/test_dynamics.py``
checks it against autodiff of the Lagrangian (:mod:`heli_uq.model.lagrangian`).  For
``h = 0`` both agree and reduce to Sec. 2.8.

Parameters are passed as a dict ``p`` of values by name (SI units).
"""

from __future__ import annotations

import abc
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from heli_uq.model.lagrangian import euler_lagrange_acceleration, helicopter_lagrangian
from heli_uq.model.parameter import Parameter
from heli_uq.model.prior import Prior
from heli_uq.model.terms.base import AbstractTerm

__all__ = [
    "MECHANICS_PARAMETERS",
    "DEFAULT_LOG_SIGMA",
    "MechanicsCoefficients",
    "AbstractMechanics",
    "ClosedFormMechanics",
    "LagrangianMechanics",
    "pitch_inertia",
    "yaw_inertia",
    "GRAVITY_PARAMETERS",
    "weight",
    "centre_of_mass",
    "centre_of_mass_radius",
    "mass_matrix",
    "dl_dx",
    "closed_form_acceleration",
    "total_energy",
    "BODY_COORDINATES",
    "BODY_PARAMETERS",
    "body_coordinates",
    "body_to_ratios",
    "body_from_ratios",
    "body_log_jacobian",
    "identifiable_combinations",
    "ratio_coordinates_allowed",
    "mechanics_null_directions",
]

#: sigma of the log of the default log-normal priors (a least-squares fit moves gains by up
#: to ~15x, e.g. K_psi_theta 0.009 vs 0.15: 1.4 sigma; Table 1 lies within 1 sigma).
DEFAULT_LOG_SIGMA = 2.0


def _lognormal(median: float) -> Prior:
    return Prior("lognormal", median, DEFAULT_LOG_SIGMA)


#: Paper Table 2 (default = nominal value) and Table 1 (start = the paper's fit).
MECHANICS_PARAMETERS: tuple[Parameter, ...] = (
    Parameter("r_c", "m", 0.015, _lognormal(0.015), "positive", False, None,
              "distance from pivot to centre of mass along the body axis", 0.022),
    Parameter("h", "m", 0.0, Prior("normal", 0.0, 0.01), "real", False, None,
              "elevation of the body axis above the pivot", 0.001),
    Parameter("m", "kg", 0.5, _lognormal(0.5), "positive", True, None,
              "mass of the helicopter body", 0.72),
    Parameter("J_bc", "kg m^2", 0.015, _lognormal(0.015), "positive", True, None,
              "moment of inertia of the body about its centre of mass", 0.01),
    Parameter("J_s", "kg m^2", 0.005, _lognormal(0.005), "positive", True, "pitch",
              "moment of inertia of the yaw shaft", 0.0017),
    Parameter("g", "m/s^2", 9.81, Prior("fixed", 9.81), "positive", False, None,
              "acceleration of gravity", 9.81),
)  # fmt: skip


def _sinusoid_minimum(a, b, angles):
    """``min_j (a cos x_j - b sin x_j)`` over the angles ``x`` [rad] (any shape), for each
    of the (broadcast) ``a``, ``b``.  The sinusoid is ``R cos(x + phi)``, lowest where
    ``x + phi = pi (mod 2 pi)`` and falling with the circular distance from there, so its
    minimum over a set is at one of the two sorted neighbours of that point: O(log m) per
    draw instead of O(m).  Angles that are not finite are left out; with none left, the
    minimum over every angle, ``-hypot(a, b)``."""
    x = np.ravel(angles)
    x = np.unique(np.mod(x[np.isfinite(x)], 2.0 * np.pi))
    a, b = np.broadcast_arrays(np.asarray(a, dtype=float), np.asarray(b, dtype=float))
    if x.size == 0:
        return -np.hypot(a, b)
    target = np.mod(np.pi - np.arctan2(b, a), 2.0 * np.pi)
    right = np.searchsorted(x, target) % x.size
    nearest = np.stack([x[right], x[right - 1]])  # index -1 wraps to the largest angle
    return np.min(a * np.cos(nearest) - b * np.sin(nearest), axis=0)


def pitch_inertia(p):
    """``M11 = J_bc + m r_c^2 + m h^2`` [kg m^2]."""
    return p["J_bc"] + p["m"] * (p["r_c"] ** 2 + p["h"] ** 2)


def yaw_inertia(p, theta):
    """``M22(theta) = J_bc cos^2 + m (r_c cos - h sin)^2 + J_s`` [kg m^2] (numpy or jax)."""
    c, s = jnp.cos(theta), jnp.sin(theta)
    return p["J_bc"] * c**2 + p["m"] * (p["r_c"] * c - p["h"] * s) ** 2 + p["J_s"]


#: The parameters of the body's weight and centre of mass (:func:`centre_of_mass`,
#: :func:`weight`), which a term of gravity (a tilted yaw axis) reads.
GRAVITY_PARAMETERS = ("m", "g", "r_c", "h")


def weight(p):
    """``m g`` [N] (numpy or jax)."""
    return p["m"] * p["g"]


def centre_of_mass(p, theta):
    """The body's centre of mass at pitch ``theta``: its distance from the yaw axis along
    the arm and its height above the pivot [m], ``(r_c cos - h sin, r_c sin + h cos)``
    (the distance in ``M22``, the height in the paper's potential; numpy or jax)."""
    c, s = jnp.cos(theta), jnp.sin(theta)
    return p["r_c"] * c - p["h"] * s, p["r_c"] * s + p["h"] * c


def centre_of_mass_radius(p):
    """``sqrt(r_c^2 + h^2)`` [m]: the centre of mass's distance from the pivot, the largest
    of its distances from the yaw axis over all pitch angles (numpy)."""
    return np.hypot(np.asarray(p["r_c"], dtype=float), np.asarray(p["h"], dtype=float))


#: Coordinates of the body parameters (r_c, m, J_bc, h) in which the common inertia scale
#: is one axis: log M11 [kg m^2], log(m g r_c / M11) [1/s^2], logit(m (r_c^2 + h^2) / M11),
#: h / r_c.  Used by :class:`heli_uq.probability.Coordinates`.
BODY_COORDINATES = ("log_J_pitch", "log_gravity_ratio", "logit_body_fraction", "h_over_r_c")


def body_to_ratios(p) -> tuple:
    """``(M11, m g r_c / M11, m (r_c^2 + h^2) / M11, h / r_c)`` of concrete values."""
    m11 = float(pitch_inertia(p))
    body = float(p["m"]) * (float(p["r_c"]) ** 2 + float(p["h"]) ** 2)
    return (m11, float(p["m"]) * float(p["g"]) * float(p["r_c"]) / m11, body / m11,
            float(p["h"]) / float(p["r_c"]))  # fmt: skip


#: The body parameters that :data:`BODY_COORDINATES` replace.
BODY_PARAMETERS = ("r_c", "m", "J_bc", "h")


def body_coordinates(priors) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """``(coordinate names, unidentified ones)`` of the body under ``priors``: without
    ``h_over_r_c`` when h is fixed (at 0), and then ``logit_body_fraction`` is unidentified."""
    if priors["h"].free:
        return BODY_COORDINATES, ("log_J_pitch",)
    return BODY_COORDINATES[:3], ("log_J_pitch", "logit_body_fraction")


def body_from_ratios(m11, gravity_ratio, body_fraction, h_over_r_c, fixed) -> dict:
    """Inverse of :func:`body_to_ratios`: ``{r_c, m, h, J_bc}`` (jax-traceable); ``fixed``
    holds the fixed parameters (gravity ``g``)."""
    m_r_c = gravity_ratio * m11 / fixed["g"]
    r_c = body_fraction * m11 / ((1.0 + h_over_r_c**2) * m_r_c)
    return {"r_c": r_c, "m": m_r_c / r_c, "h": h_over_r_c * r_c, "J_bc": m11 * (1.0 - body_fraction)}


def body_log_jacobian(body, with_h: bool):
    """``log |det dw/dz|`` of the body block: ``w`` = (log r_c, log m, log J_bc[, h]),
    the prior coordinates that :func:`ratio_coordinates_allowed` demands, and ``z`` =
    :data:`BODY_COORDINATES` (without ``h_over_r_c`` when h is fixed).  The determinant is
    ``-r_c`` with ``h`` (from ``dh / d(h/r_c) = r_c``) and ``-1`` without it (derived
    symbolically; tests check it against the autodiff Jacobian).  ``body``: the
    parameters, e.g. ``{"r_c": ..., ...}`` (jax-traceable)."""
    return jnp.log(body["r_c"]) if with_h else jnp.zeros(())


def ratio_coordinates_allowed(priors) -> bool:
    """Whether priors allow :data:`BODY_COORDINATES`: log-normal ``r_c, m, J_bc``, ``g``
    fixed, ``h`` normal or fixed at 0 (so that ``h / r_c`` is 0 or sampled)."""
    h = priors["h"]
    h_ok = h.kind == "normal" or (h.kind == "fixed" and h.a == 0.0)
    return all(priors[n].kind == "lognormal" for n in ("r_c", "m", "J_bc")) and not priors["g"].free and h_ok


def mechanics_null_directions(p) -> list[tuple[str, dict, str]]:
    """Null directions the mechanics add to the common scaling, in log coordinates.

    With ``h = 0`` the parameters enter only through ``M11 = J_bc + m r_c^2``, ``m r_c``
    (gravity) and ``M22 = J_s + (J_bc + m r_c^2) s^2``, so a change of ``(r_c, m, J_bc)``
    keeping ``m r_c`` and ``J_bc + m r_c^2`` fixed is invisible: ``d log m = -d log r_c =
    a`` gives ``d(m r_c^2) = -a m r_c^2``, compensated by ``d log J_bc = a m r_c^2 / J_bc``.
    With ``h != 0`` the ``m (r_c s + h c)^2`` term of ``M22`` breaks it (the caller checks
    which candidates lie in the computed null space).

    Returns ``(key, {name: loading}, description)`` per candidate.
    """
    ratio = float(p["m"] * p["r_c"] ** 2 / p["J_bc"])
    return [("rc_m_Jbc_trade", {"r_c": -1.0, "m": 1.0, "J_bc": ratio},
             "r_c down, m up and J_bc up at fixed m r_c and J_bc + m r_c^2 (the gravity "
             "moment and the pitch inertia); invisible when h = 0")]  # fmt: skip


def identifiable_combinations() -> dict:
    """The mechanics' ratios the angles depend on: ``{label: f(p)}`` (see the structural
    identifiability derivation); torque-type parameters add ``X / M11`` each."""
    return {
        "m g r_c / M11 [1/s^2]": lambda p: p["m"] * p["g"] * p["r_c"] / pitch_inertia(p),
        "m (r_c^2 + h^2) / M11": lambda p: p["m"] * (p["r_c"] ** 2 + p["h"] ** 2) / pitch_inertia(p),
        "h / r_c": lambda p: p["h"] / p["r_c"],
        "J_s / M11": lambda p: p["J_s"] / pitch_inertia(p),
    }


def _a(p, c, s):
    """a(theta) = (J_bc + m (r_c^2 - h^2)) c s + m r_c h (c^2 - s^2)  [kg m^2]."""
    m, r, h = p["m"], p["r_c"], p["h"]
    return (p["J_bc"] + m * (r * r - h * h)) * c * s + m * r * h * (c * c - s * s)


def mass_matrix(p, theta):
    """M(theta), shape (2, 2) [kg m^2] (Sec. 2.3)."""
    m11 = pitch_inertia(p)
    m22 = yaw_inertia(p, theta)
    zero = jnp.zeros_like(m11 * m22)
    return jnp.stack([jnp.stack([m11 + zero, zero]), jnp.stack([zero, m22 + zero])])


def dl_dx(p, x, v):
    """dL/dx = (dL/dtheta, dL/dpsi), shape (2,) [N m], with the corrected h-term."""
    c, s = jnp.cos(x[0]), jnp.sin(x[0])
    dl_dtheta = -v[1] ** 2 * _a(p, c, s) - p["m"] * p["g"] * (p["r_c"] * c - p["h"] * s)
    return jnp.stack([dl_dtheta, jnp.zeros_like(dl_dtheta)])


def closed_form_acceleration(p, x, v, force):
    """Sec. 2.7 ODE solved for (dw_theta/dt, dw_psi/dt), shape (2,) [rad/s^2].

    Written term by term as in the paper (with the corrected ``+ m r_c h`` term); the
    simulator uses the algebraically equivalent :class:`MechanicsCoefficients`.
    """
    c, s = jnp.cos(x[0]), jnp.sin(x[0])
    a = _a(p, c, s)
    mm = mass_matrix(p, x[0])
    dw_theta = -v[1] ** 2 * a - p["m"] * p["g"] * (p["r_c"] * c - p["h"] * s) + force[0]
    dw_psi = 2.0 * v[0] * v[1] * a + force[1]
    return jnp.stack([dw_theta / mm[0, 0], dw_psi / mm[1, 1]])


def total_energy(p, y):
    """K + P [J] for states ``y`` of shape (..., 4) (Sec. 2.3-2.4)."""
    from heli_uq.model.lagrangian import kinetic_energy, potential_energy

    y = jnp.asarray(y)
    x, v = jnp.moveaxis(y[..., :2], -1, 0), jnp.moveaxis(y[..., 2:], -1, 0)
    return kinetic_energy(p, x, v) + potential_energy(p, x)


class MechanicsCoefficients(eqx.Module):
    """Parameter combinations the mechanics depend on, precomputed once per parameter set.

    Using ``sin 2theta = 2 s c`` and ``cos 2theta = c^2 - s^2``:
    ``a = k_a sin2 + k_b cos2``, ``M22 = k_0 + k_a cos2 - k_b sin2``, with
    ``k_a = (J_bc + m r_c^2 - m h^2)/2``, ``k_b = m r_c h``,
    ``k_0 = J_s + (J_bc + m r_c^2 + m h^2)/2``; gravity ``m g r_c``, ``m g h``.
    This is the fast path of the simulator (one sin/cos per stage).
    """

    inv_m11: jnp.ndarray
    k_0: jnp.ndarray
    k_a: jnp.ndarray
    k_b: jnp.ndarray
    grav_c: jnp.ndarray
    grav_s: jnp.ndarray

    @classmethod
    def from_params(cls, p) -> MechanicsCoefficients:
        m, r, h, j = p["m"], p["r_c"], p["h"], p["J_bc"]
        m11 = pitch_inertia(p)
        return cls(inv_m11=1.0 / m11, k_0=p["J_s"] + 0.5 * m11, k_a=0.5 * (j + m * r * r - m * h * h),
                   k_b=m * r * h, grav_c=m * p["g"] * r, grav_s=m * p["g"] * h)  # fmt: skip

    def acceleration(self, sc, v, force):
        """(dw_theta/dt, dw_psi/dt), shape (2,), for ``sc = (sin theta, cos theta)``."""
        s, c = sc
        s2, c2 = 2.0 * s * c, c * c - s * s
        a = self.k_a * s2 + self.k_b * c2
        m22 = self.k_0 + self.k_a * c2 - self.k_b * s2
        dw_theta = (-v[1] * v[1] * a - self.grav_c * c + self.grav_s * s + force[0]) * self.inv_m11
        dw_psi = (2.0 * v[0] * v[1] * a + force[1]) / m22
        return jnp.stack([dw_theta, dw_psi])


class AbstractMechanics(AbstractTerm):
    """Rigid-body mechanics: ``M(x) dv/dt = dL/dx - (dp/dx) v + F``.

    Declares the Table 2 body parameters (:data:`MECHANICS_PARAMETERS`).  Final classes
    implement :meth:`prepare` (parameter-only work, once per solve) and
    :meth:`acceleration`.
    """

    #: Whether the body parameters may be sampled in :data:`BODY_COORDINATES`.
    ratio_coordinates: eqx.AbstractClassVar[bool]

    def parameters(self) -> tuple[Parameter, ...]:
        return MECHANICS_PARAMETERS

    @abc.abstractmethod
    def prepare(self, p):
        """Parameter-only precomputation; a pytree passed to :meth:`acceleration`."""

    @abc.abstractmethod
    def acceleration(self, prepared, x, v, force, sc=None):
        """Generalized accelerations (2,) [rad/s^2] for the force ``(T_theta, T_psi)`` [N m]
        (a pair of scalars or a (2,) array).

        ``sc``: ``(sin theta, cos theta)`` if the caller has them (the simulator caches
        them between its forward and backward pass), else computed here.
        """

    def inertia_bounds(self, p, thetas=None) -> tuple:
        """``(M11, smallest M22)`` [kg m^2] of concrete values, for stiffness estimates.

        ``p``: values by name, scalars or arrays of one shape (e.g. ``(n,)`` posterior
        draws); the bounds then have that shape (floats for scalars).  ``thetas``: pitch
        angles [rad] to take the smallest ``M22`` over (e.g. those of a record); default
        every angle.
        """
        p = {k: np.asarray(p[k], dtype=float) for k in ("J_bc", "m", "r_c", "h", "J_s")}
        m11 = pitch_inertia(p)
        # M22 = k_0 + k_a cos 2theta - k_b sin 2theta = k_0 + R cos(2 theta + phi)
        k_a = 0.5 * (p["J_bc"] + p["m"] * (p["r_c"] ** 2 - p["h"] ** 2))
        k_b = p["m"] * p["r_c"] * p["h"]
        low = (-np.hypot(k_a, k_b) if thetas is None
               else _sinusoid_minimum(k_a, k_b, 2.0 * np.asarray(thetas, dtype=float)))  # fmt: skip
        m22 = p["J_s"] + 0.5 * m11 + low
        return (float(m11), float(m22)) if np.ndim(m11) == 0 and np.ndim(m22) == 0 else (m11, m22)


class ClosedFormMechanics(AbstractMechanics):
    """The paper's equations of motion in closed form (corrected h-term): the fast path."""

    kind: ClassVar[str] = "closed_form"
    #: The body parameters may be sampled in :data:`BODY_COORDINATES`.
    ratio_coordinates: ClassVar[bool] = True

    def prepare(self, p):
        return MechanicsCoefficients.from_params(p)

    def acceleration(self, prepared, x, v, force, sc=None):
        sc = (jnp.sin(x[0]), jnp.cos(x[0])) if sc is None else sc
        return prepared.acceleration(sc, v, force)


class LagrangianMechanics(AbstractMechanics):
    """Equations of motion derived by autodiff from a Lagrangian ``L(x, v, p)`` [J].

    The default is the helicopter's (:func:`heli_uq.model.lagrangian.helicopter_lagrangian`);
    pass another with the same parameter names to study another mechanism without
    writing its equations of motion (paper challenge 3a).  Slower than
    :class:`ClosedFormMechanics`; the independent reference in the tests.
    """

    kind: ClassVar[str] = "lagrangian"
    ratio_coordinates: ClassVar[bool] = False
    lagrangian: object = eqx.field(static=True, default=helicopter_lagrangian)

    def prepare(self, p):
        return p

    def acceleration(self, prepared, x, v, force, sc=None):
        force = jnp.stack([jnp.asarray(f, dtype=jnp.float64) for f in force])
        return euler_lagrange_acceleration(self.lagrangian, x, v, prepared, force)
