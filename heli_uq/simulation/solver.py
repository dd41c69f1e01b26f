"""The simulator: exact zero-order-hold inputs, fixed-step RK4, discrete-adjoint gradients.

Inputs are voltages held constant on each sample interval ``[t_k, t_k + dt)``.  The
solver takes ``substeps`` classical Runge-Kutta steps inside every interval, so a
step never straddles a switch of the input: each switch is treated exactly, with no
smoothing and no adaptive step.  For the paper's model one RK4 step per interval of the
rig record (dt = 0.01 s) is accurate to well below 1e-6 rad; stiff effects (sharp
friction) need more substeps, see :func:`heli_uq.simulation.stiffness.default_substeps` and
:func:`heli_uq.simulation.reference_solve`.  Substeps are taken as rows of their own
(each sample's voltages repeated ``substeps`` times, the states kept at the samples), so
the loop body is one small RK4 step whatever their number: a body of several unrolled
steps ran 4-6x slower per step on the CPU.

Gradients use a hand-built *discrete adjoint* (a :func:`jax.custom_vjp`): the
forward pass stores only the states; the backward pass computes the sines and cosines of
the pitch angle at every Runge-Kutta stage once (vectorised over time: in float64 on the
CPU they are most of the cost), then all step Jacobians ``dy_{k+1}/dy_k`` at once
re-using them, runs the cheap linear adjoint recursion
``lam_k = c_k + A_k^T lam_{k+1}`` and gets the parameter and input cotangents from one
time-vectorised VJP; all of it in chunks of :data:`ADJOINT_CHUNK` steps, last first.
The result is the exact gradient of the discrete solution (checked against plain
reverse-mode autodiff to ~1e-13).
"""

from __future__ import annotations

import enum
from collections.abc import Mapping

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jax.custom_derivatives import SymbolicZero
from jax.flatten_util import ravel_pytree

from heli_uq.errors import ParameterError
from heli_uq.model.heli_model import HeliModel

__all__ = ["simulate", "solve", "Solution", "RESULTS", "MAX_ABS_STATE", "MAX_SAMPLES"]

#: A state component beyond this magnitude (rad or rad/s) counts as a blow-up.
MAX_ABS_STATE = 1.0e4
#: Largest number of solver steps (samples x substeps) one solve may take: 10 million
#: steps store 0.3 GB of states and trigonometry, several minutes of work.
MAX_SAMPLES = 10_000_000
#: Steps per chunk of the adjoint's backward pass.  A chunk's arrays then stay in the CPU
#: caches: on the rig record at 5 substeps (65,500 steps) the gradient took 26 ms in
#: chunks of 16,384 against 41 ms all at once; at 1 substep (one chunk) 4.7 ms either way.
ADJOINT_CHUNK = 16_384

class RESULTS(enum.IntEnum):
    """Outcome codes of :func:`solve` (``Solution.result``)."""

    successful = 0
    #: NaN or inf in the solution: the parameters make the ODE singular (e.g. M22 <= 0).
    nonfinite = 1
    #: A state left ``|y| < MAX_ABS_STATE``: the model blew up for these parameters.
    blow_up = 2


class Solution(eqx.Module):
    """A simulated trajectory on the sample grid.

    Attributes
    ----------
    ts : array, shape (N,)
        Sample times [s], ``ts[k] = k dt``.
    ys : array, shape (N, 4)
        States ``(theta, psi, omega_theta, omega_psi)`` [rad, rad, rad/s, rad/s] at ``ts``;
        ``ys[0] = x0``.
    result : int array, shape ()
        A :class:`RESULTS` code; check :attr:`ok` before using ``ys``.
    """

    ts: jnp.ndarray
    ys: jnp.ndarray
    result: jnp.ndarray

    @property
    def ok(self):
        """Boolean array: the solve succeeded (finite and bounded)."""
        return self.result == RESULTS.successful


@jax.custom_jvp
def _sincos(theta):
    """``(sin theta, cos theta)``, each computed once also under differentiation."""
    return jnp.sin(theta), jnp.cos(theta)


@_sincos.defjvp
def _sincos_jvp(primals, tangents):
    s, c = _sincos(primals[0])
    return (s, c), (c * tangents[0], -s * tangents[0])


@jax.custom_jvp
def _cached_sincos(theta, s, c):
    """``(sin theta, cos theta)`` taken from the forward pass, with the right derivative."""
    return s, c


@_cached_sincos.defjvp
def _cached_sincos_jvp(primals, tangents):
    _, s, c = primals
    dtheta = tangents[0]
    return (s, c), (c * dtheta, -s * dtheta)


def _rk4_step(model, prepared, y, u, h, trig=None):
    """One classical RK4 step of ``x' = v, v' = a(x, v, u)`` with ``u`` held.

    ``u`` (2,) [V], or (4,): the voltages and the model's input-only torques at them
    [N m] (:func:`held_inputs`).

    Returns the new state (4,) and ``(sin, cos)`` of the pitch angle at the four stages,
    shape (4, 2); ``trig`` (4, 2) replaces their computation when given.
    """
    x, v = y[:2], y[2:]

    held = None if u.shape[0] == 2 else u[2:]  # the input-only torques, held with u

    def acc(i, xi, vi):
        if trig is None:
            sc = _sincos(xi[0])
        else:
            sc = _cached_sincos(xi[0], trig[i, 0], trig[i, 1])
        return model.acceleration(prepared, xi, vi, u[:2], sc, held), jnp.stack(sc)

    a1, t1 = acc(0, x, v)
    v2 = v + 0.5 * h * a1
    a2, t2 = acc(1, x + 0.5 * h * v, v2)
    v3 = v + 0.5 * h * a2
    a3, t3 = acc(2, x + 0.5 * h * v2, v3)
    v4 = v + h * a3
    a4, t4 = acc(3, x + h * v3, v4)
    y_new = jnp.concatenate([x + (h / 6.0) * (v + 2.0 * v2 + 2.0 * v3 + v4),
                             v + (h / 6.0) * (a1 + 2.0 * a2 + 2.0 * a3 + a4)])  # fmt: skip
    return y_new, jnp.stack([t1, t2, t3, t4])


def _make_trajectory(static_model, unravel):
    """Build ``trajectory(args, us, y0) -> ys`` (one RK4 step per row of ``us``) with a
    discrete-adjoint VJP.

    ``args`` is the flat float64 vector of ``(dynamic model leaves, prepared parameters,
    step)`` (``unravel`` restores the pytree): one loop-invariant buffer instead of dozens
    of scalars keeps the per-step kernel count, and so the run time, low.
    ``us`` (N, 2), or (N, 4) with the held torques (:func:`held_inputs`); ``y0`` (4,).
    ``ys[k]`` is the state before step ``k``.
    """

    def step_tree(args_tree, y, u, trig=None):
        dyn_model, prepared, h = args_tree
        return _rk4_step(eqx.combine(dyn_model, static_model), prepared, y, u, h, trig)

    # The scan bodies unravel the flat ``args`` themselves: closing over the unravelled
    # leaves instead makes every step read dozens of scalar buffers (2-3x slower).
    def forward(args, us, y0):
        def body(y, u):
            return step_tree(unravel(args), y, u)[0], y

        return lax.scan(body, y0, us)[1]

    @jax.custom_vjp
    def trajectory(args, us, y0):
        return forward(args, us, y0)

    def fwd(args, us, y0):
        # symbolic_zeros: the wrappers say which inputs are differentiated (``perturbed``).
        ys = forward(args.value, us.value, y0.value)
        return ys, (args.value, us.value, ys, us.perturbed)

    def chunk_vjp(tree, lam, y_prev, u_prev, ct_prev, with_u):
        """The adjoint over consecutive steps ``y_prev -> y_prev[1:], ...`` ending in the
        cotangent ``lam`` of the state after the last one: ``(lam of the first state,
        parameter cotangent (flat), input cotangents or None)``."""
        # The stage sines and cosines of every step in one vectorised pass; the Jacobians
        # and the VJP below re-use them.  Recomputing them inside each differentiated pass
        # costs several times more: in float64 on the CPU they are most of the work.
        trig = jax.vmap(lambda y, u: step_tree(tree, y, u)[1])(y_prev, u_prev)

        def batched(a_tree, y, u):
            return jax.vmap(lambda a, y1, u1, t1: step_tree(a, y1, u1, t1)[0],
                            in_axes=(None, 0, 0, 0))(a_tree, y, u, trig)  # fmt: skip

        # One linearisation of the batched step over (args, states, inputs) serves both
        # the state Jacobians and the parameter/input cotangents below.
        _, lin = jax.linearize(batched, tree, y_prev, u_prev)
        zero_tree = jax.tree_util.tree_map(jnp.zeros_like, tree)
        zero_y, zero_u = jnp.zeros_like(y_prev), jnp.zeros_like(u_prev)
        # A_k = d y_{k+1} / d y_k for all k at once: columns from the 4 unit tangents.
        unit = jnp.eye(4, dtype=y_prev.dtype)
        columns = jax.vmap(lambda e: lin(zero_tree, jnp.broadcast_to(e, y_prev.shape), zero_u))(unit)
        jac = jnp.transpose(columns, (1, 2, 0))  # (n, 4 out, 4 in)

        def adjoint(lam_k1, inp):
            a_k, c_k = inp
            return c_k + a_k.T @ lam_k1, lam_k1

        lam_first, lam_next = lax.scan(adjoint, lam, (jac, ct_prev), reverse=True)
        # Parameter (and input) cotangents: sum_k (d y_{k+1} / d args)^T lam_{k+1}.
        if with_u:
            d_tree, d_u = jax.linear_transpose(lambda a, u: lin(a, zero_y, u), tree, u_prev)(lam_next)
        else:
            (d_tree,) = jax.linear_transpose(lambda a: lin(a, zero_y, zero_u), tree)(lam_next)
            d_u = None
        return lam_first, ravel_pytree(d_tree)[0], d_u

    def bwd(res, ct):
        args, us, ys, us_perturbed = res
        if isinstance(ct, SymbolicZero):  # the states do not enter the differentiated output
            ct = jnp.zeros_like(ys)
        tree = unravel(args)
        y_prev, u_prev, ct_prev = ys[:-1], us[:-1], ct[:-1]
        # The steps are taken in chunks of ADJOINT_CHUNK, the last chunk first.
        n = y_prev.shape[0]
        n_chunks, head = divmod(n, ADJOINT_CHUNK)
        lam, d_args, d_u_parts = ct[-1], jnp.zeros_like(args), []
        if n_chunks:
            def body(carry, chunk):
                lam_c, acc = carry
                lam_c, d, d_u = chunk_vjp(tree, lam_c, *chunk, us_perturbed)
                return (lam_c, acc + d), d_u

            tail = [a[head:].reshape(n_chunks, ADJOINT_CHUNK, *a.shape[1:])
                    for a in (y_prev, u_prev, ct_prev)]  # fmt: skip
            (lam, d_args), d_u = lax.scan(body, (lam, d_args), tail, reverse=True)
            if us_perturbed:
                d_u_parts.append(d_u.reshape(n_chunks * ADJOINT_CHUNK, -1))
        if head:
            lam, d, d_u = chunk_vjp(tree, lam, y_prev[:head], u_prev[:head], ct_prev[:head],
                                    us_perturbed)  # fmt: skip
            d_args = d_args + d
            d_u_parts.insert(0, d_u)
        if us_perturbed:
            d_us = jnp.concatenate([*d_u_parts, jnp.zeros_like(us[-1:])], axis=0)
        else:
            d_us = jnp.zeros_like(us)
        return d_args, d_us, lam

    trajectory.defvjp(fwd, bwd, symbolic_zeros=True)
    return trajectory, forward


def held_inputs(model: HeliModel, p, u):
    """The voltages ``u`` (N, 2) [V] with the model's input-only torques at each sample
    appended, shape (N, 4) (``u`` itself if the model has none).

    The voltages are held on each sample interval, so a torque of the voltages alone
    (a network of ``u``, a quadratic thrust, a feature torque) is constant there: it is
    evaluated once per sample instead of at every Runge-Kutta stage, and, when ``u`` is
    concrete, once per distinct voltage pair (a record holds a few dozen).  ``p``: the
    prepared parameter values (:meth:`HeliModel.prepare`).
    """
    if not model.holds_torque:
        return u
    torque = jax.vmap(lambda uk: model.held_torque(p, uk))
    if isinstance(u, jax.core.Tracer):
        held = torque(u)
    else:
        pairs, inverse = np.unique(np.asarray(u), axis=0, return_inverse=True)
        held = torque(jnp.asarray(pairs))[jnp.asarray(inverse.reshape(-1))]
    return jnp.concatenate([u, held], axis=1)


def _check_inputs(x0, u, substeps, gradients):
    if gradients not in ("adjoint", "autodiff"):
        raise ParameterError(f"gradients: expected 'adjoint' or 'autodiff', found {gradients!r}")
    x0 = jnp.asarray(x0, dtype=jnp.float64)
    u = jnp.asarray(u, dtype=jnp.float64)
    if x0.shape != (4,):
        raise ParameterError(
            f"x0: expected 4 values (theta, psi, omega_theta, omega_psi), found shape {x0.shape}"
        )
    if u.ndim != 2 or u.shape[1] != 2 or u.shape[0] < 1:
        raise ParameterError(f"u: expected shape (N, 2) volts with N >= 1, found {u.shape}")
    if isinstance(substeps, bool) or not isinstance(substeps, int) or substeps < 1:
        raise ParameterError(f"substeps: expected a positive integer, found {substeps!r}")
    if u.shape[0] * substeps > MAX_SAMPLES:
        raise ParameterError(f"u: {u.shape[0]} samples x {substeps} substeps exceed the limit of "
                             f"{MAX_SAMPLES:,} solver steps per solve (shorten the record or "
                             "raise the sample time)")  # fmt: skip
    return x0, u


def solve(
    params: Mapping | None,
    x0,
    u,
    dt,
    *,
    model: HeliModel | None = None,
    substeps: int = 1,
    gradients: str = "adjoint",
) -> Solution:
    """Simulate and report success: the entry point for code that must not fail.

    Parameters
    ----------
    params : mapping
        Parameter values by name [SI]; missing names take the model's defaults (Table 2
        for the mechanics, "no effect" for effects).  Values may be traced (``jit``,
        ``grad``, ``vmap``).
    x0 : array, shape (4,)
        Initial state (theta, psi, omega_theta, omega_psi) [rad, rad, rad/s, rad/s].
    u : array, shape (N, 2)
        Voltages (u_theta, u_psi) [V]; ``u[k]`` is held on ``[t_k, t_k + dt)``.
    dt : float
        Sample time [s].
    model : HeliModel, optional
        Default: the paper's model (closed-form mechanics, ``F = K u - D v``).
    substeps : int
        RK4 steps per sample interval (default 1; see :func:`~heli_uq.simulation.stiffness.default_substeps`).
    gradients : {"adjoint", "autodiff"}
        ``"adjoint"`` (default): reverse mode (``jax.grad``, ``jax.vjp``, ``jax.jacrev``)
        through the fast discrete adjoint.  ``"autodiff"``: plain JAX differentiation of
        the time loop, which also supports forward mode (``jax.jvp``, ``jax.jacfwd``).

    Returns
    -------
    Solution
        ``ys`` of shape (N, 4) and a :class:`RESULTS` code.  Failure never raises and
        never hangs (fixed number of steps), so a sampler can reject the proposal.

    Raises
    ------
    ParameterError
        Bad shapes, unknown parameter names, values outside their support, or more than
        :data:`MAX_SAMPLES` solver steps.
    """
    x0, u = _check_inputs(x0, u, substeps, gradients)
    model = HeliModel() if model is None else model
    p = model.complete(params)
    dyn_model, static_model = eqx.partition(model, eqx.is_array)
    prepared = model.prepare(p)
    dt = jnp.asarray(dt, dtype=jnp.float64)
    args, unravel = ravel_pytree((dyn_model, prepared, dt / substeps))
    adjoint, plain = _make_trajectory(static_model, unravel)
    if model.filters_voltages:  # a lag acts on each solver step's voltage, then the held torques
        rows = jnp.repeat(u, substeps, axis=0) if substeps > 1 else u
        us = held_inputs(model, prepared[1], model.filtered_voltages(prepared[1], rows, dt / substeps))
    else:
        us = held_inputs(model, prepared[1], u)
        if substeps > 1:  # one RK4 step per row of the inputs, each sample's held `substeps` times
            us = jnp.repeat(us, substeps, axis=0)
    ys = (adjoint if gradients == "adjoint" else plain)(args, us, x0)[::substeps]
    finite = jnp.all(jnp.isfinite(ys))
    bounded = jnp.all(jnp.abs(jnp.where(finite, ys, 0.0)) < MAX_ABS_STATE)
    result = jnp.where(
        finite, jnp.where(bounded, RESULTS.successful, RESULTS.blow_up), RESULTS.nonfinite
    )
    ts = jnp.arange(u.shape[0]) * dt
    return Solution(ts=ts, ys=ys, result=result)


def simulate(params: Mapping | None, x0, u, dt, *, model: HeliModel | None = None,
             substeps: int = 1, gradients: str = "adjoint"):  # fmt: skip
    """States on the sample grid, shape (N, 4); differentiable and jit-able.

    Same arguments as :func:`solve`; returns ``solve(...).ys``.  Use :func:`solve`
    when you need to know whether the solve failed (NaN or blow-up).

    Examples
    --------
    >>> import heli_uq, jax, jax.numpy as jnp
    >>> u = jnp.ones((100, 2))
    >>> ys = heli_uq.simulate(heli_uq.TABLE1, [0.0, 0.0, 0.0, 0.0], u, 0.01)
    >>> ys.shape
    (100, 4)
    """
    return solve(params, x0, u, dt, model=model, substeps=substeps, gradients=gradients).ys
