"""The torque the data imply given a fitted model, and each candidate effect's feature.

**Implied torque.**  The angles are smoothed and differentiated (Savitzky-Golay, window
:data:`SMOOTH_WINDOW_S`), giving rates ``v`` and accelerations ``a`` at every sample.  The
fitted model predicts ``a_model(x, v, u)``; the generalized force it misses is

    ``tau = M(theta) (a - a_model)``  [N m], shape (N, 2),

(``M`` the mass matrix: the equations of motion are linear in the force, so this is exactly
the torque that, added to the model, reproduces the measured accelerations).

**Features.**  A candidate effect's feature is the derivative of the model's generalized
force with respect to each of the effect's parameters, at the measured states and the
effect's probe values (its start values, e.g. ``F_c = 0.005`` N m, ``delta = 0.1`` V), by
forward-mode autodiff.  For the effects linear in their parameter (offset, friction,
drag, quadratic thrust) this is the effect's torque per unit parameter, e.g.
``-tanh(omega / omega_s)`` for Coulomb friction; a dead band gives ``-K_{.m} sign(u_m)`` on
both axes where the motor voltage exceeds the band.  Nothing here names an effect: a new
effect in the vocabulary gets its feature from its own equations.  The base model's own
parameters give the *base* columns, the directions a refit of the base model could
absorb; they are projected out before the sparse regression
(:mod:`heli_uq.discovery.sindy`).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from heli_uq.data.rates import smoothed_derivatives
from heli_uq.model import HeliModel, build_model
from heli_uq.model.terms.rigid_body import mass_matrix

__all__ = ["ImpliedTorque", "implied_torque", "effect_features", "base_features",
           "SMOOTH_WINDOW_S"]  # fmt: skip

#: Savitzky-Golay window [s] (cubic, :func:`heli_uq.data.rates.smoothed_derivatives`) for the
#: rates and accelerations of the measured angles: twice the rates' window, since a second
#: derivative amplifies the noise more.
SMOOTH_WINDOW_S = 0.5


@dataclasses.dataclass(frozen=True)
class ImpliedTorque:
    """Smoothed states and the torque the fitted model misses.

    Attributes
    ----------
    x, v, a : ndarray, shape (N, 2)
        Angles [rad], rates [rad/s], accelerations [rad/s^2] from the smoothed record.
    u : ndarray, shape (N, 2)
        Voltages [V] as recorded (a model's lag acts on them in :meth:`acting_voltages`).
    dt : float
        Sample time [s].
    residual : ndarray, shape (N, 2)
        ``a - a_model`` [rad/s^2]: what the regression explains.
    tau : ndarray, shape (N, 2)
        ``M(theta) (a - a_model)`` [N m] per axis.
    """

    x: np.ndarray
    v: np.ndarray
    a: np.ndarray
    u: np.ndarray
    dt: float
    residual: np.ndarray
    tau: np.ndarray

    def acting_voltages(self, model: HeliModel, p):
        """The voltages (N, 2) [V] the torques of ``model`` see at parameters ``p``: the
        recorded ones after the model's sequence maps (a motor's lag; else themselves)."""
        return model.filtered_voltages(p, jnp.asarray(self.u), self.dt)


def implied_torque(model: HeliModel, params: dict, y, u, dt: float, *,
                   window_s: float = SMOOTH_WINDOW_S) -> ImpliedTorque:  # fmt: skip
    """The torque the data imply beyond the fitted ``model`` (module docstring).

    Parameters
    ----------
    model : HeliModel
    params : dict
        Physical parameter values of ``model`` (e.g. its MAP).
    y : array, shape (N, 2)
        Measured angles [rad].
    u : array, shape (N, 2)
        Voltages [V].
    dt : float
        Sample time [s].
    """
    y = np.asarray(y, dtype=float)
    x, v, a = smoothed_derivatives(y, dt, window_s)
    p = _complete(model, params)
    data = ImpliedTorque(x=x, v=v, a=a, u=np.asarray(u, dtype=float), dt=float(dt),
                         residual=np.zeros_like(a), tau=np.zeros_like(a))  # fmt: skip
    resid = a - np.asarray(_accelerations(model, data)(p))
    mass = np.asarray(jax.vmap(lambda th: jnp.diagonal(mass_matrix(p, th)))(jnp.asarray(x[:, 0])))
    return dataclasses.replace(data, residual=resid, tau=mass * resid)  # M is diagonal (Sec. 2.3)


def _accelerations(model: HeliModel, data: ImpliedTorque):
    """``p -> a_model`` (N, 2) [rad/s^2] at the smoothed states of ``data`` and the voltages
    the model's torques see there (after a lag, which reads the whole sequence)."""
    x, v = jnp.asarray(data.x), jnp.asarray(data.v)

    def a_model(p):
        prepared = model.prepare(p)
        u = data.acting_voltages(model, p)
        return jax.vmap(lambda xi, vi, ui: model.acceleration(prepared, xi, vi, ui))(x, v, u)

    return jax.jit(a_model)


def _jacobian_columns(model: HeliModel, p: dict, names, data: ImpliedTorque) -> np.ndarray:
    """d a_model / d p[name] at every sample, shape (N, 2, len(names)) [rad/s^2 per unit].

    In acceleration space the common inertia scale is a null direction, as it is for the
    angles (in torque space the residual is homogeneous in the scaled parameters, so the
    base columns would span the residual itself).
    """
    names = list(names)
    a_model = _accelerations(model, data)
    theta0 = jnp.asarray([p[n] for n in names])
    jac = jax.jit(jax.jacfwd(lambda theta: a_model({**p, **dict(zip(names, theta))})))
    return np.asarray(jac(theta0))


def effect_features(base: HeliModel, params: dict, effect: str, data: ImpliedTorque):
    """Feature columns of adding ``effect`` (``"axis:kind"``) to ``base`` at ``params``.

    Returns ``(names, columns)``: the effect's parameter names and an array (N, 2, k)
    [rad/s^2 per unit of each parameter], evaluated at the effect's probe (start) values.
    """
    model = build_model([*_effect_specs(base), effect])
    extra = [par for par in model.parameters() if par.name not in base.names]
    p = _complete(model, {**params, **{par.name: par.start_value() for par in extra}})
    names = [par.name for par in extra]
    return names, _jacobian_columns(model, p, names, data)


def base_features(model: HeliModel, params: dict, data: ImpliedTorque) -> np.ndarray:
    """Columns (N, 2, n_params) of the model's own parameters (what a refit could absorb)."""
    p = _complete(model, params)
    return _jacobian_columns(model, p, model.names, data)


def _complete(model: HeliModel, params: dict) -> dict:
    """The model's parameters from ``params`` (other entries, e.g. the initial state, ignored)."""
    return model.complete({k: float(v) for k, v in params.items() if k in model.names})


def _effect_specs(model: HeliModel) -> list[dict]:
    return model.describe()["effects"]
