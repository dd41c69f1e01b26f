"""An adaptive, stiff reference solve of any model (diffrax), to check the fixed-step solver.

The fixed-step RK4 solver (:mod:`heli_uq.simulation.solver`) is fast and differentiable
but its accuracy depends on the number of substeps, which stiff effects (sharp
friction) raise.  :func:`reference_solve` integrates the same vector field
(``model(t, y, (p, u))``) with an L-stable implicit Runge-Kutta method (diffrax
``Kvaerno5``) under a PID step-size controller, with every switch of the held voltages
given as a jump time, so each constant-input stretch is integrated on its own: the
independent form against which :func:`solver_error` measures the fixed-step solution.
A motor's lag (:mod:`heli_uq.model.terms.motor_lag`), which the fixed-step solver
applies exactly to the held voltages of each step, is integrated here as two more states,
and a motor's dead time (:mod:`heli_uq.model.terms.input_delay`), which it applies as step
means, as the voltage read ``d`` late, with the delayed switches as jump times.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping

import diffrax
import jax
import jax.numpy as jnp
import numpy as np

from heli_uq.errors import ParameterError
from heli_uq.model.heli_model import HeliModel
from heli_uq.model.terms.input_delay import InputDelay
from heli_uq.model.terms.motor_lag import TAU_FLOOR, MotorLag
from heli_uq.simulation.solver import solve

__all__ = ["reference_solve", "solver_error", "REFERENCE_RTOL", "REFERENCE_ATOL"]

#: Tolerances of the reference solve (angles in rad, rates in rad/s).
REFERENCE_RTOL = 1e-10
REFERENCE_ATOL = 1e-10
#: Step budget of one reference solve (a stiff stuck phase takes many small steps).
MAX_STEPS = 2_000_000


def _switch_times(u: np.ndarray, dt: float) -> np.ndarray:
    change = np.flatnonzero(np.any(u[1:] != u[:-1], axis=1)) + 1
    return change * dt


#: A delayed voltage is read at ``t - d +`` this [s], so that a step that starts just after a
#: delayed switch (diffrax starts it at ``nextafter``) reads the new voltage despite rounding.
READ_AFTER = 1e-9


@functools.partial(jax.jit, static_argnames=("model", "lagged", "t1", "dt0", "rtol", "atol"))
def _adaptive_solve(y0, p, taus, delays, levels, switch_ts, jump_ts, ts, *, model, lagged, t1, dt0,
                    rtol, atol):  # fmt: skip
    """The diffrax solve of :func:`reference_solve` (``switch_ts``: the switch times of
    ``levels``, maybe none; ``jump_ts``: those and the delayed ones).  Motor ``i`` reads its
    voltage ``delays[i]`` [s] late.  With a motor's lag (``lagged``, a pair of bools, not
    both False) ``y`` (6,) ends with the lagged voltages, ``tau du'/dt = u - u'`` on the
    lagged axes (``taus`` (2,) [s] their time constants), which the model's torques see;
    else ``y`` is the state (4,)."""
    mask = jnp.asarray(lagged)

    def field(t, y, args):
        p, taus, delays, levels, switch_ts = args
        at = jnp.searchsorted(switch_ts, t - delays + jnp.where(delays > 0, READ_AFTER, 0.0),
                              side="right")  # fmt: skip
        held = levels[at, jnp.arange(2)]
        if not any(lagged):
            return model(t, y, (p, held))
        acting = jnp.where(mask, y[4:], held)
        rate = jnp.where(mask, (held - y[4:]) / jnp.where(mask, taus, 1.0), 0.0)
        return jnp.concatenate([model(t, y[:4], (p, acting)), rate])

    controller = diffrax.PIDController(rtol=rtol, atol=atol,
                                       jump_ts=jump_ts if jump_ts.shape[0] else None)  # fmt: skip
    return diffrax.diffeqsolve(
        diffrax.ODETerm(field), diffrax.Kvaerno5(), t0=0.0, t1=t1, dt0=dt0, y0=y0,
        args=(p, taus, delays, levels, switch_ts), saveat=diffrax.SaveAt(ts=ts),
        stepsize_controller=controller, max_steps=MAX_STEPS, throw=False)  # fmt: skip


def _motor_dynamics(model: HeliModel, p) -> tuple[tuple[bool, bool], np.ndarray, np.ndarray]:
    """Which motors lag (time constant above the floor), their time constants [s] and
    every motor's dead time [s] (0 without one).

    Raises
    ------
    ParameterError
        A sequence map of the voltages with no continuous form here.
    """
    taus, delays = np.ones(2), np.zeros(2)
    lagged = [False, False]
    for term in model.inputs:
        if isinstance(term, MotorLag):
            i, tau = term.time_constant(p)
            if float(tau) > TAU_FLOOR:
                lagged[i], taus[i] = True, float(tau)
        elif isinstance(term, InputDelay):
            i, d = term.delay(p)
            delays[i] = max(float(d), 0.0)
        elif term.filters_sequence:
            raise ParameterError(f"reference solve: {term.label} acts on the voltage sequence and "
                                 "has no continuous form here")  # fmt: skip
    return tuple(lagged), taus, delays


def reference_solve(params: Mapping | None, x0, u, dt: float, *, model: HeliModel | None = None,
                    rtol: float = REFERENCE_RTOL, atol: float = REFERENCE_ATOL) -> np.ndarray:  # fmt: skip
    """States on the sample grid, shape (N, 4), by an adaptive stiff solver.

    Parameters
    ----------
    params, x0, u, dt, model
        As for :func:`heli_uq.simulation.solve`.
    rtol, atol : float
        Tolerances of the PID controller.

    Raises
    ------
    ParameterError
        If the adaptive solve fails (step budget exhausted or non-finite states).
    """
    model = HeliModel() if model is None else model
    u = np.asarray(u, dtype=float)
    dt = float(dt)
    p = model.complete(params)
    n = u.shape[0]
    ts = np.arange(n) * dt
    jumps = _switch_times(u, dt)
    # The voltage held at time t: the sample of the last switch at or before t.  diffrax
    # ends a step at prevbefore(jump) and starts the next at nextafter(jump), so every
    # stage of a step sees one constant voltage.
    starts = np.concatenate([[0], np.flatnonzero(np.any(u[1:] != u[:-1], axis=1)) + 1])
    # parameters, levels and switch times are arguments of one compiled solve per model,
    # record shape and tolerances (closed over, each parameter set compiled anew)
    lagged, taus, delays = _motor_dynamics(model, p)
    p = {k: jnp.asarray(v, dtype=jnp.float64) for k, v in p.items()}
    span = {"model": model, "t1": float(ts[-1]) if n > 1 else dt, "dt0": dt / 4, "rtol": rtol,
            "atol": atol}
    shifted = np.unique(np.concatenate([jumps + d for d in set(delays.tolist())]))  # with d = 0
    shifted = shifted[shifted < span["t1"]]
    levels, ts = jnp.asarray(u[starts]), jnp.asarray(ts)
    y0 = jnp.asarray(x0, dtype=jnp.float64)
    if any(lagged):  # the lagged voltages start at the first held voltage
        y0 = jnp.concatenate([y0, levels[0]])
    sol = _adaptive_solve(y0, p, jnp.asarray(taus), jnp.asarray(delays), levels, jnp.asarray(jumps),
                          jnp.asarray(shifted), ts, lagged=lagged, **span)  # fmt: skip
    ys = np.asarray(sol.ys)[:, :4]
    if not (sol.result == diffrax.RESULTS.successful) or not np.all(np.isfinite(ys)):
        raise ParameterError(f"reference solve failed ({sol.result}); the parameters make the "
                             "model singular or too stiff for the step budget")  # fmt: skip
    return ys


def solver_error(params: Mapping | None, x0, u, dt: float, *, model: HeliModel | None = None,
                 substeps: int = 1, reference=None) -> float:  # fmt: skip
    """Largest angle error [rad] of the fixed-step solver against :func:`reference_solve`.

    ``reference``: precomputed reference states (N, 4), to compare several substep counts.
    """
    ref = reference_solve(params, x0, u, dt, model=model) if reference is None else reference
    ys = np.asarray(solve(params, x0, u, dt, model=model, substeps=substeps).ys)
    return float(np.max(np.abs(ys[:, :2] - np.asarray(ref)[:, :2])))
