"""MAP estimation (multi-start L-BFGS) and the Laplace approximation, on the model's density.

Everything works on numpyro's *unconstrained* flat vector of the model
(:func:`log_density_setup`), the same space in which NUTS and emcee move, so the MAP
is a valid starting point for both and the Laplace covariance is a valid (dense)
inverse mass matrix for NUTS.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
import optax
from jax.flatten_util import ravel_pytree
from numpyro.infer import init_to_value
from numpyro.infer.util import initialize_model

from heli_uq.errors import ParameterError
from heli_uq.levenberg import masked_least_squares
from heli_uq.model import Problem, heli_model
from heli_uq.params import TABLE1, TABLE2
from heli_uq.priors import X0_ANGLE_SD, X0_RATE_SD
from heli_uq.simulate import simulate

__all__ = [
    "LogDensity", "batched_constrain", "constrain_draws", "log_density_setup", "MapResult", "find_map", "laplace", "least_squares_fit",
    "newton_polish", "start_parameters",
]  # fmt: skip

#: Residual scales [rad] (theta, psi) of the least-squares stage that precedes the MAP.
LSQ_SIGMA = (0.02, 0.1)

#: Relative step of the finite-difference Hessian (of the analytic gradient).
HESSIAN_STEP = 1e-5

#: Newton polish of :func:`find_map`: at most this many steps, stopping once the Newton
#: decrement ``g^T H^-1 g`` (twice the predicted decrease of ``-log p``) is below
#: :data:`NEWTON_TOL`.
NEWTON_STEPS = 20
NEWTON_TOL = 1e-15


@dataclasses.dataclass(frozen=True, eq=False)
class LogDensity:
    """The model's log density on a flat unconstrained vector.

    Attributes
    ----------
    potential : callable
        ``x (d,) -> -log p(x | y)`` (jit-able, differentiable).
    unravel : callable
        Flat vector -> dict of unconstrained sites.
    constrain : callable
        Dict of unconstrained sites -> dict of constrained sites (incl. deterministics).
    x_init : ndarray, shape (d,)
    """

    potential: object
    unravel: object
    constrain: object
    x_init: np.ndarray
    model_kwargs: dict

    @property
    def dim(self) -> int:
        return int(self.x_init.shape[0])

    # Compiled once per density and shared by find_map / laplace (a fresh ``jax.jit`` of a
    # new closure would recompile the simulator every call).  cached_property writes the
    # instance ``__dict__`` directly, which a frozen dataclass allows.
    @functools.cached_property
    def potential_jit(self):
        return jax.jit(self.potential)

    @functools.cached_property
    def grad_jit(self):
        return jax.jit(jax.grad(self.potential))


#: Draws per batch when mapping unconstrained draws to constrained sites.
CONSTRAIN_BATCH = 1024


@functools.lru_cache(maxsize=8)
def _vmapped_constrain(constrain, unravel):
    return jax.jit(jax.vmap(lambda x: constrain(unravel(x))))


def batched_constrain(density: LogDensity):
    """Jitted, vmapped ``x (n, d) ->`` dict of constrained sites (incl. deterministics),
    leading axis ``n``; cached per density, so repeated runs compile once."""
    return _vmapped_constrain(density.constrain, density.unravel)


def constrain_draws(density: LogDensity, x: np.ndarray) -> dict:
    """Constrained sites of the unconstrained draws ``x (n, d)``, in fixed-size batches."""
    constrain = batched_constrain(density)
    n = x.shape[0]
    parts = []
    for i in range(0, n, CONSTRAIN_BATCH):
        block = x[i : i + CONSTRAIN_BATCH]
        pad = CONSTRAIN_BATCH - block.shape[0]
        if pad:  # one compiled batch shape: pad with the last draw, drop afterwards
            block = np.concatenate([block, np.repeat(block[-1:], pad, axis=0)])
        out = constrain(jnp.asarray(block))
        parts.append({k: np.asarray(v)[: CONSTRAIN_BATCH - pad] for k, v in out.items()})
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def default_init_values(problem: Problem, params=None) -> dict:
    """Constrained initial values: parameters (default Table 1), first angles, at rest."""
    params = dict(TABLE1 if params is None else params)
    z = jnp.asarray(problem.coords.from_physical(params))
    values = {
        "z": z[1:] if problem.coords.marginal_scale else z,
        "theta0": jnp.asarray(problem.y[0, 0]),
        "psi0": jnp.asarray(problem.y[0, 1]),
        "omega_theta0": jnp.asarray(0.0),
        "omega_psi0": jnp.asarray(0.0),
        "sigma": jnp.array([0.05, 0.05]),
    }
    if problem.error == "ar1":
        values["tau"] = jnp.array([0.5, 0.5])
    if problem.coords.marginal_scale:
        _, mean, sd = problem.coords.scale_conditional(z[1:])
        values["scale_noise"] = (z[0] - mean) / sd
    return values


def log_density_setup(problem: Problem, init_values: dict | None = None, seed: int = 0):
    """Build the :class:`LogDensity` of ``heli_model`` conditioned on the training data."""
    kwargs = {"y": jnp.asarray(problem.y[: problem.n_train])}
    values = default_init_values(problem) if init_values is None else init_values
    info = initialize_model(
        jax.random.PRNGKey(seed), heli_model, model_args=(problem,), model_kwargs=kwargs,
        init_strategy=init_to_value(values=values), validate_grad=False,
    )  # fmt: skip
    # validate_grad=False: numpyro would otherwise run value-and-grad of the model op by
    # op (no jit), ~13 s for a 500-sample record; find_map checks finiteness anyway.
    x0, unravel = ravel_pytree(info.param_info.z)

    def potential(x):
        return info.potential_fn(unravel(x))

    def constrain(sites):
        return info.postprocess_fn(sites)

    return LogDensity(potential, unravel, constrain, np.asarray(x0), kwargs)


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


def least_squares_fit(problem: Problem, *, max_steps: int = 100):
    """Levenberg-Marquardt fit of coordinates ``z`` and initial state ``x0`` to the training
    angles (residuals scaled by :data:`LSQ_SIGMA`, plus the Gaussian prior residuals).

    This is the robust first stage of :func:`find_map`: a Gauss-Newton method handles the
    very different scales of the parameters in a few steps, where a quasi-Newton method
    on the full posterior stalls.  Returns a compiled function
    ``fit(z0, x0) -> (z, x0, cost)``, reused for every start.
    """
    coords = problem.coords
    n, d = problem.n_train, coords.dim
    u, y = jnp.asarray(problem.u[:n]), jnp.asarray(problem.y[:n])
    sigma = jnp.asarray(LSQ_SIGMA)
    mu = jnp.asarray([coords.priors[k].coordinate_mean for k in coords.free])
    sd = jnp.asarray([coords.priors[k].b for k in coords.free])
    x0_mu = jnp.concatenate([jnp.asarray(problem.y[0]), jnp.zeros(2)])
    x0_sd = jnp.asarray([X0_ANGLE_SD, X0_ANGLE_SD, X0_RATE_SD, X0_RATE_SD])

    def residuals(v):
        z, x_init = v[:d], v[d:]
        phys = coords.to_physical(z)
        ys = simulate(phys, x_init, u, problem.dt, gradients="autodiff")
        r = ((ys[:, :2] - y) / sigma).ravel()
        r = jnp.where(jnp.isfinite(r), r, 1e6)
        w = jnp.stack([coords.priors[k].to_coordinate(phys[k]) for k in coords.free])
        return jnp.concatenate([r, (w - mu) / sd, (x_init - x0_mu) / x0_sd])

    free = jnp.zeros(d + 4, dtype=bool)

    @jax.jit
    def fit(z0, x0):
        v0 = jnp.concatenate([jnp.asarray(z0), jnp.asarray(x0)])
        v, cost = masked_least_squares(residuals, v0, free, v0, max_steps)
        return v[:d], v[d:], cost

    return fit


def find_map(density: LogDensity, starts: list[np.ndarray], *, maxiter: int = 200,
             gtol: float = 1e-4, newton_steps: int = NEWTON_STEPS) -> MapResult:  # fmt: skip
    """Minimise ``density.potential`` from every start; return the best finite optimum.

    Every start runs at most ``maxiter`` L-BFGS steps (none if ``maxiter <= 0``), then
    damped Newton steps on the finite-difference Hessian (:func:`newton_polish`); the
    best polished optimum wins.
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
    for x in starts:
        xs, v, k = run(jnp.asarray(x))
        xs, v = np.asarray(xs), float(v)
        ok = np.isfinite(v) and np.all(np.isfinite(xs))
        polish = (float("nan"), float("nan"), 0)
        if ok and newton_steps > 0:
            xs, v, *polish = newton_polish(density, xs, newton_steps)
        ok = ok and np.isfinite(v) and np.all(np.isfinite(xs))
        results.append((v if ok else np.inf, xs, int(k), polish))
    best = min(results, key=lambda r: r[0])
    return MapResult(x=np.asarray(best[1]), value=best[0],
                     start_values=tuple(r[0] for r in results),
                     n_iterations=tuple(r[2] for r in results), grad_max=best[3][0],
                     newton_decrement=best[3][1], newton_steps=best[3][2])  # fmt: skip


def _fd_hessian(grad, x: np.ndarray) -> np.ndarray:
    """Symmetrised central differences of the exact gradient (relative step)."""
    d = x.size
    h = np.empty((d, d))
    for j in range(d):
        eps = HESSIAN_STEP * max(1.0, abs(x[j]))
        e = np.zeros(d)
        e[j] = eps
        h[:, j] = (np.asarray(grad(x + e)) - np.asarray(grad(x - e))) / (2 * eps)
    return 0.5 * (h + h.T)


def newton_polish(density: LogDensity, x: np.ndarray, steps: int = NEWTON_STEPS):
    """Damped Newton iterations on ``density.potential`` from ``x``.

    The Hessian is :func:`_fd_hessian` with eigenvalues replaced by their absolute values
    (floored), so every step is a descent direction; a backtracking line search accepts
    only steps that decrease ``-log p``.  Stops when the Newton decrement is below
    :data:`NEWTON_TOL` or a step fails.

    Returns ``(x, value, max |grad|, newton decrement, steps taken)``.
    """
    f, grad = density.potential_jit, density.grad_jit
    x = np.asarray(x, dtype=float)
    value = float(f(x))
    taken = 0
    decrement = float("nan")
    for _ in range(steps + 1):
        g = np.asarray(grad(x))
        h = _fd_hessian(grad, x)
        if not (np.all(np.isfinite(g)) and np.all(np.isfinite(h))):
            break
        w, v = np.linalg.eigh(h)
        w = np.maximum(np.abs(w), max(np.abs(w).max(), 1.0) * 1e-10)
        step = -(v / w) @ (v.T @ g)
        decrement = float(-g @ step)
        if decrement < NEWTON_TOL or taken == steps:
            break
        t = 1.0
        for _ in range(30):
            new = float(f(x + t * step))
            if np.isfinite(new) and new <= value - 1e-4 * t * decrement:
                break
            t *= 0.5
        else:
            break
        x, value, taken = x + t * step, new, taken + 1
    g = np.asarray(grad(x))
    return x, value, float(np.max(np.abs(g))), decrement, taken


def start_parameters(free, base, n: int, seed: int = 0) -> list[dict]:
    """Parameter guesses of a multi-start fit (shared by the MAP and the identifiability fit).

    ``base``, then ``base`` with Table 2 values for the ``free`` names, then ``n - 2``
    log-normal (sd 0.3) perturbations of ``base``'s free parameters other than ``h``; the
    other names keep their ``base`` values.  Returns ``n`` dicts.
    """
    rng = np.random.default_rng(seed)
    out = [dict(base), {p: (TABLE2[p] if p in free else v) for p, v in base.items()}]
    while len(out) < n:
        out.append({p: v * (float(np.exp(rng.normal(0, 0.3))) if p in free and p != "h" else 1.0)
                    for p, v in base.items()})  # fmt: skip
    return out[:n]


def map_starts(problem: Problem, density: LogDensity, n: int, seed: int = 0) -> list:
    """Starting points for :func:`find_map`, each refined by :func:`least_squares_fit`.

    Parameter guesses: Table 1, Table 2 and ``n - 2`` log-normal (sd 0.3) perturbations of
    Table 1 (fixed parameters keep their values).  After the least-squares stage the
    residual scale ``sigma`` is set to the residual RMS and ``tau`` to the correlation time
    of the residuals' lag-1 autocorrelation, so the MAP search starts close to its optimum.
    """
    coords = problem.coords
    n_train = problem.n_train
    out = []
    fit = least_squares_fit(problem)
    u_train = jnp.asarray(problem.u[:n_train])
    sim = jax.jit(lambda z, x0: simulate(coords.to_physical(z), x0, u_train, problem.dt))
    base = {p: (coords.priors[p].a if not coords.priors[p].free else v) for p, v in TABLE1.items()}
    for params in start_parameters(coords.free, base, n, seed):
        values = default_init_values(problem, params)
        x0 = np.array([values[s] for s in ("theta0", "psi0", "omega_theta0", "omega_psi0")])
        z_full = coords.from_physical(params)
        z, x0, _ = (np.asarray(a) for a in fit(z_full, x0))
        ys = np.asarray(sim(jnp.asarray(z), jnp.asarray(x0)))
        resid = ys[:, :2] - problem.y[:n_train]
        if not np.all(np.isfinite(resid)):
            continue
        sites = {"z": jnp.asarray(z[1:] if coords.marginal_scale else z), "theta0": x0[0],
                 "psi0": x0[1], "omega_theta0": x0[2],
                 "omega_psi0": x0[3],
                 "sigma": jnp.log(jnp.maximum(jnp.sqrt(jnp.mean(resid**2, axis=0)), 1e-4))}  # fmt: skip
        if coords.marginal_scale:
            _, mean, sd = coords.scale_conditional(jnp.asarray(z[1:]))
            sites["scale_noise"] = (z[0] - mean) / sd
        if problem.error == "ar1":
            lag1 = np.sum(resid[1:] * resid[:-1], axis=0) / np.sum(resid**2, axis=0)
            rho = np.clip(lag1, 0.01, 0.9999)
            sites["tau"] = jnp.log(-problem.dt / np.log(rho))
        sites = {name: jnp.asarray(sites[name]) for name in density.unravel(density.x_init)}
        out.append(np.asarray(ravel_pytree(sites)[0]))
    return out


def laplace(density: LogDensity, x: np.ndarray):
    """Hessian of ``-log p`` at ``x`` (central differences of the exact gradient) and the
    covariance ``H^-1`` with eigenvalues floored so it is positive definite.

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
    w, v = np.linalg.eigh(h)
    floor = max(w.max(), 1.0) * 1e-10
    w = np.maximum(w, floor)
    return h, (v / w) @ v.T
