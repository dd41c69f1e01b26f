"""MAP estimation (L-BFGS then a damped Newton polish) and the Laplace approximation.

Everything works on numpyro's *unconstrained* flat vector of the model
(:func:`heli_uq.inference.density.log_density_setup`), the same space in which NUTS and
emcee move, so the MAP is a valid starting point for both and the Laplace covariance
whitens the posterior for NUTS.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import optax

from heli_uq.errors import ParameterError
from heli_uq.inference.density import LogDensity

__all__ = ["MapResult", "find_map", "newton_polish", "laplace", "leave_saddles", "HESSIAN_STEP",
           "NEWTON_STEPS", "NEWTON_TOL", "VALUE_RESOLUTION", "NEWTON_STALL_STEPS", "NEWTON_STALL_FACTOR",
           "NEWTON_EXTEND", "NEWTON_SCOUT_STEPS", "EIGEN_FLOOR"]  # fmt: skip

#: Relative step of the finite-difference Hessian (of the analytic gradient).
HESSIAN_STEP = 1e-5
#: Where a perturbed gradient is not finite, the step shrinks by this factor, up to
#: :data:`HESSIAN_RETRIES` steps in all (the first is :data:`HESSIAN_STEP`).
HESSIAN_STEP_SHRINK = 0.1
HESSIAN_RETRIES = 3

#: Newton polish of :func:`find_map`: at most this many steps, stopping once the Newton
#: decrement ``g^T H^-1 g`` (twice the predicted decrease of ``-log p``) is below
#: :data:`NEWTON_TOL` (or stalls below the value's resolution, :data:`NEWTON_STALL_STEPS`).  From a good
#: start it converges in 3-10 steps; from a poor one (a least-squares start near a saddle: a
#: 21 s record with a yaw torque offset needed 101 steps and gained 2700 nats over the 20th)
#: it needs many, so the cap is generous and a converged polish stops early.
NEWTON_STEPS = 200
#: With several starts, each gets this many Newton steps; only the best continues.
NEWTON_SCOUT_STEPS = 20
NEWTON_TOL = 1e-15
#: Relative resolution of ``-log p`` (1000 float64 epsilons): a sum of ~1e4 likelihood
#: terms carries rounding of about this size.  Below it Newton steps still improve ``x``
#: while the gradient is clean (the decrement keeps falling fast), but with rounding in the
#: gradient the decrement stalls: a polish at -log p = -71423 (a stiff friction refit)
#: spent all 200 steps and 125 s with the decrement at 1e-14 and the value unchanged.  So
#: the polish stops after :data:`NEWTON_STALL_STEPS` steps in a row below this floor
#: whose decrement fell by less than :data:`NEWTON_STALL_FACTOR`.
VALUE_RESOLUTION = 1e3 * float(np.finfo(float).eps)
NEWTON_STALL_STEPS = 3
NEWTON_STALL_FACTOR = 0.1
#: Eigenvalues of a Hessian below this fraction of its largest magnitude are raised to it
#: (:func:`_positive_curvature`): the finite-difference Hessian does not resolve them.
#: It was 1e-10 until 2026-11-27, and on long records that floor cut real curvature: on
#: a 92 s record the Hessian's eigenvalues span 0.43 to 6.8e10 (the pitch gain-gravity
#: balance against the prior-only inertia split), the two smallest were raised to 6.84,
#: and the Laplace sd of the prior-dominated coordinates came out 0.38 where the exact
#: Hessian and the NUTS posterior give 0.66 and 1.5 (``scale_noise``,
#: ``logit_body_fraction``).  There the differences resolve 6e-12 of the largest (they
#: match ``jax.jvp`` of the gradient to 8 digits); at a hybrid model's saddle the
#: differences gave -6e-13 and 1.4e-12, unchecked, and 1e-13 let them widen the
#: Laplace draws' network directions (tests/test_hybrid_posterior.py).
EIGEN_FLOOR = 1e-12
#: At most this many doublings of an accepted full Newton step (:func:`_extend`).
NEWTON_EXTEND = 6


@dataclasses.dataclass(frozen=True)
class MapResult:
    """Result of :func:`find_map`: ``x`` (flat unconstrained), ``value`` (= -log p) and
    the values reached from every start (``start_values``, ``inf`` for a failed start)."""

    x: np.ndarray
    value: float
    start_values: tuple
    n_iterations: tuple
    #: ``max |grad|`` and Newton decrement ``g^T H^-1 g`` at ``x`` after the Newton polish
    #: (``nan`` if not computed).  The gradient alone is no convergence measure here: the
    #: Hessian's condition number is ~1e9, so ``max |grad|`` ~ 10 can sit 1e-4 nats and
    #: 0.03 posterior sd from the optimum; the decrement is scale-free.
    grad_max: float = float("nan")
    newton_decrement: float = float("nan")
    newton_steps: int = 0


def _lbfgs(potential, x0, maxiter: int, gtol: float):
    opt = optax.lbfgs()
    value_and_grad = optax.value_and_grad_from_state(potential)

    def cond(carry):
        _, state, k = carry
        grad = optax.tree.get(state, "grad")
        return (k < maxiter) & (jnp.max(jnp.abs(grad)) > gtol) | (k == 0)

    def body(carry):
        x, state, k = carry
        value, grad = value_and_grad(x, state=state)
        updates, state = opt.update(grad, state, x, value=value, grad=grad, value_fn=potential)
        return optax.apply_updates(x, updates), state, k + 1

    x, _, k = jax.lax.while_loop(cond, body, (x0, opt.init(x0), 0))
    return x, potential(x), k


def find_map(density: LogDensity, starts: list[np.ndarray], *, maxiter: int = 200,
             gtol: float = 1e-4, newton_steps: int = NEWTON_STEPS,
             polish_best: int | None = None) -> MapResult:  # fmt: skip
    """Minimise ``density.potential`` from every start; return the best finite optimum.

    ``polish_best``: Newton-polish only this many of the starts, those with the lowest
    ``-log p`` after L-BFGS (default all).

    Every start runs at most ``maxiter`` L-BFGS steps (none if ``maxiter <= 0``), then
    damped Newton steps on the finite-difference Hessian (:func:`newton_polish`): with
    several polished starts, :data:`NEWTON_SCOUT_STEPS` each, then the best continues to
    ``newton_steps`` in all (or convergence); the best polished optimum wins.
    L-BFGS alone does not converge on short records (1000 steps leave ``max |grad|`` ~ 10):
    the posterior has one direction (pitch input gain vs. gravity ratio) with curvature
    ~1e9 next to others ~1, a condition number a quasi-Newton method cannot resolve.
    Newton converges from the L-BFGS point in 1-8 steps, so L-BFGS only needs to get
    into the basin.
    """
    if maxiter > 0:
        run = jax.jit(lambda x: _lbfgs(density.potential, x, maxiter, gtol))
    else:  # Newton only: no L-BFGS loop to compile

        def run(x):
            return x, density.potential_jit(x), 0

    results = []
    first = [(np.asarray(xs), float(v), int(k)) for xs, v, k in (run(jnp.asarray(x)) for x in starts)]
    order = np.argsort([v if np.isfinite(v) else np.inf for _, v, _ in first], kind="stable")
    chosen = set(order[: len(first) if polish_best is None else polish_best].tolist())
    scout = min(newton_steps, NEWTON_SCOUT_STEPS) if len(chosen) > 1 else newton_steps
    for i, (xs, v, k) in enumerate(first):
        ok = np.isfinite(v) and np.all(np.isfinite(xs))
        polish = (float("nan"), float("nan"), 0)
        if ok and newton_steps > 0 and i in chosen:
            xs, v, *polish = newton_polish(density, xs, scout)
        ok = ok and np.isfinite(v) and np.all(np.isfinite(xs))
        results.append((v if ok else np.inf, xs, int(k), polish))
    i_best = min(range(len(results)), key=lambda i: results[i][0])
    best = results[i_best]
    if scout < newton_steps and np.isfinite(best[0]) and not best[3][1] < NEWTON_TOL:
        xs, v, *polish = newton_polish(density, best[1], newton_steps - scout)
        polish[2] += best[3][2]
        if np.isfinite(v) and np.all(np.isfinite(xs)):
            results[i_best] = best = (v, xs, best[2], polish)
    return MapResult(x=np.asarray(best[1]), value=best[0],
                     start_values=tuple(r[0] for r in results),
                     n_iterations=tuple(r[2] for r in results), grad_max=best[3][0],
                     newton_decrement=best[3][1], newton_steps=best[3][2])  # fmt: skip


def _fd_column(grad, x: np.ndarray, j: int, g0: np.ndarray) -> np.ndarray:
    """Column ``j`` of the Hessian: central differences of the exact gradient, falling back
    to one-sided differences and smaller steps where a perturbed solve is not finite (a
    stiff or diverging model next to the optimum)."""
    base = HESSIAN_STEP * max(1.0, abs(x[j]))
    for eps in base * HESSIAN_STEP_SHRINK ** np.arange(HESSIAN_RETRIES):
        e = np.zeros(x.size)
        e[j] = eps
        up, down = np.asarray(grad(x + e)), np.asarray(grad(x - e))
        ok_up, ok_down = np.all(np.isfinite(up)), np.all(np.isfinite(down))
        if ok_up and ok_down:
            return (up - down) / (2 * eps)
        if ok_up:
            return (up - g0) / eps
        if ok_down:
            return (g0 - down) / eps
    return np.full(x.size, np.nan)


def _fd_hessian(grad, x: np.ndarray) -> np.ndarray:
    """Symmetrised central differences of the exact gradient (relative step; see
    :func:`_fd_column` for the fallback where a perturbed gradient is not finite)."""
    g0 = np.asarray(grad(x))
    if not np.all(np.isfinite(g0)):
        return np.full((x.size, x.size), np.nan)
    h = np.stack([_fd_column(grad, x, j, g0) for j in range(x.size)], axis=1)
    return 0.5 * (h + h.T)


def _positive_curvature(h: np.ndarray):
    """Eigen-decomposition ``(w, v)`` of the symmetric ``h`` with each eigenvalue replaced by
    its magnitude, floored at :data:`EIGEN_FLOOR` times the largest (and at least that
    fraction of 1): ``(v / w) @ v.T`` is then a positive-definite inverse that keeps every
    resolved curvature, and a Newton step with it descends."""
    w, v = np.linalg.eigh(h)
    w = np.abs(w)
    return np.maximum(w, max(w.max(), 1.0) * EIGEN_FLOOR), v


def newton_polish(density: LogDensity, x: np.ndarray, steps: int = NEWTON_STEPS):
    """Damped Newton iterations on ``density.potential`` from ``x``.

    The Hessian is :func:`_fd_hessian` with eigenvalues replaced by their absolute values
    (floored), so every step is a descent direction; a backtracking line search accepts
    only steps that decrease ``-log p``.  Stops when the Newton decrement is below
    :data:`NEWTON_TOL`, when it stalls below the value's resolution
    (:data:`VALUE_RESOLUTION`, :data:`NEWTON_STALL_STEPS`) or a step fails.

    Returns ``(x, value, max |grad|, newton decrement, steps taken)``.
    """
    f, grad = density.potential_jit, density.grad_jit
    x = np.asarray(x, dtype=float)
    value = float(f(x))
    taken = stalled = 0
    decrement = previous = float("nan")
    for _ in range(steps + 1):
        g = np.asarray(grad(x))
        h = _fd_hessian(grad, x)
        if not (np.all(np.isfinite(g)) and np.all(np.isfinite(h))):
            break
        w, v = _positive_curvature(h)
        step = -(v / w) @ (v.T @ g)
        decrement = float(-g @ step)
        below = decrement < VALUE_RESOLUTION * abs(value)
        stalled = stalled + 1 if below and not decrement < NEWTON_STALL_FACTOR * previous else 0
        if decrement < NEWTON_TOL or stalled >= NEWTON_STALL_STEPS or taken == steps:
            break
        previous = decrement
        t = 1.0
        for _ in range(30):
            new = float(f(x + t * step))
            if np.isfinite(new) and new <= value - 1e-4 * t * decrement:
                break
            t *= 0.5
        else:
            break
        if t == 1.0:  # full step accepted: extend it while -log p keeps falling
            t, new = _extend(f, x, step, new)
        x, value, taken = x + t * step, new, taken + 1
    g = np.asarray(grad(x))
    return x, value, float(np.max(np.abs(g))), decrement, taken


def _extend(f, x: np.ndarray, step: np.ndarray, value: float):
    """Double an accepted full Newton step while ``f`` keeps decreasing (at most
    :data:`NEWTON_EXTEND` doublings); returns the best ``(t, f(x + t step))``.

    Newton creeps on a one-sided exponential wall (a rate identified only from above): from
    the steep side each step covers ~1/curvature, so convergence is linear (the decrement
    fell by 12 % per step on the synthetic default record, 20 steps left 0.008 nats).
    """
    t = 1.0
    for _ in range(NEWTON_EXTEND):
        new = float(f(x + 2 * t * step))
        if not (np.isfinite(new) and new < value):
            break
        t, value = 2 * t, new
    return t, value


#: Rounds of :func:`leave_saddles`, and the Newton steps after each escape.
SADDLE_ROUNDS = 4
SADDLE_POLISH_STEPS = 20


def leave_saddles(density: LogDensity, x: np.ndarray, rounds: int = SADDLE_ROUNDS,
                  polish_steps: int = SADDLE_POLISH_STEPS):  # fmt: skip
    """From a stationary point with negative curvature to a local minimum of ``-log p``.

    :func:`newton_polish` replaces negative Hessian eigenvalues by their absolute values, so
    it converges to saddles as well as to minima; a neural term's posterior has them (two
    hidden units that do the same thing).  While the Hessian has a negative eigenvalue
    ``lam`` (eigenvector ``v``), step to whichever of ``x +- t v`` is lower, with ``t`` from
    ``1 / sqrt(|lam|)`` halving until ``-log p`` falls, and polish again.

    Returns ``(x, value, max |grad|, newton decrement, escapes)``; with no escape (a
    minimum already, or no lower point along the direction) ``x`` is unchanged and the
    gradient and decrement are NaN (not computed).
    """
    f = density.potential_jit
    x = np.asarray(x, dtype=float)
    value, grad_max, decrement = float(f(x)), float("nan"), float("nan")
    for k in range(rounds):
        h = _fd_hessian(density.grad_jit, x)
        if not np.all(np.isfinite(h)):
            return x, value, grad_max, decrement, k
        w, v = np.linalg.eigh(h)
        if w[0] >= 0:
            return x, value, grad_max, decrement, k
        best = None
        t = 1.0 / np.sqrt(-w[0])
        for _ in range(20):
            for sign in (1.0, -1.0):
                trial = x + sign * t * v[:, 0]
                new = float(f(trial))
                if np.isfinite(new) and new < value and (best is None or new < best[1]):
                    best = (trial, new)
            if best is not None:
                break
            t *= 0.5
        if best is None:
            return x, value, grad_max, decrement, k
        x, value, grad_max, decrement, _ = newton_polish(density, best[0], polish_steps)
    return x, value, grad_max, decrement, rounds  # still a saddle after every round


def laplace(density: LogDensity, x: np.ndarray):
    """Hessian of ``-log p`` at ``x`` (central differences of the exact gradient) and the
    covariance ``H^-1``, positive definite (:func:`_positive_curvature`: a negative
    eigenvalue counts by its magnitude, none below :data:`EIGEN_FLOOR` of the largest).

    Returns
    -------
    hessian, covariance : ndarrays, shape (d, d)
    """
    h = _fd_hessian(density.grad_jit, np.asarray(x, dtype=float))
    if not np.all(np.isfinite(h)):
        raise ParameterError(
            "the Hessian of the log density at the MAP is not finite: the model diverges "
            "next to the optimum (try a shorter window or tighter priors)"
        )
    w, v = _positive_curvature(h)
    return h, (v / w) @ v.T
