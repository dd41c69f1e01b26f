"""The model's log density on numpyro's flat unconstrained vector, shared by every sampler.

:func:`log_density_setup` conditions :func:`heli_uq.probability.heli_model` on the
training angles; the MAP, the Laplace approximation, NUTS and emcee all move in the same
flat vector ``x``.  :func:`constrain_draws` maps draws of ``x`` to named sites (physical
parameters, initial state, error model) *without simulating*: the model runs in its
``"params"`` mode, so no ODE is solved for bookkeeping.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree
from numpyro.infer import init_to_value
from numpyro.infer.util import constrain_fn, initialize_model

from heli_uq.errors import ParameterError
from heli_uq.model.tables import X0_NAMES
from heli_uq.probability.numpyro_model import YAW_MOMENTUM_SITE, heli_model
from heli_uq.probability.priors import OUTPUTS
from heli_uq.probability.problem import Problem

__all__ = ["LogDensity", "log_density_setup", "init_sites", "constrain_draws", "coordinate_names",
           "CONSTRAIN_BATCH"]  # fmt: skip

#: Draws per batch when mapping unconstrained draws to constrained sites.
CONSTRAIN_BATCH = 1024


@dataclasses.dataclass(frozen=True, eq=False)
class LogDensity:
    """The model's log density on a flat unconstrained vector.

    Attributes
    ----------
    problem : Problem
    potential : callable
        ``x (d,) -> -log p(x | y)`` (jit-able, differentiable).
    unravel : callable
        Flat vector -> dict of unconstrained sites.
    x_init : ndarray, shape (d,)
    """

    problem: Problem
    potential: object
    unravel: object
    x_init: np.ndarray

    @property
    def dim(self) -> int:
        return int(self.x_init.shape[0])

    # Compiled once per density and shared by the MAP, Laplace and samplers (a fresh
    # ``jax.jit`` of a new closure would recompile the simulator every call).
    @functools.cached_property
    def potential_jit(self):
        return jax.jit(self.potential)

    @functools.cached_property
    def grad_jit(self):
        return jax.jit(jax.grad(self.potential))

    @functools.cached_property
    def _constrain_batched(self):
        problem = self.problem

        def one(x):
            return constrain_fn(heli_model, (problem,), {"mode": "params"}, self.unravel(x),
                                return_deterministic=True)  # fmt: skip

        return jax.jit(jax.vmap(one))

    def ravel(self, sites: dict) -> np.ndarray:
        """Flat vector of a dict of unconstrained sites (inverse of ``unravel``)."""
        template = self.unravel(jnp.asarray(self.x_init))
        return np.asarray(ravel_pytree({k: jnp.asarray(sites[k]) for k in template})[0])


def init_sites(problem: Problem, params: dict, x0, sigma=(0.05, 0.05), tau=(0.5, 0.5),
               timing=(0.2, 0.2)) -> dict:  # fmt: skip
    """Constrained site values for ``init_to_value``: coordinates of ``params``, the
    initial state ``x0`` (4,), residual scales [rad], correlation times [s] and timing
    errors [s] (2,) each."""
    coords = problem.coords
    z = jnp.asarray(coords.from_physical(params))
    values = {"z": z[1:] if coords.marginal_scale else z}
    if coords.marginal_scale:
        values["scale_noise"] = jnp.asarray(coords.scale_noise(z))
    for name, v, prior in zip(X0_NAMES, x0, problem.x0_priors()):
        if name == "omega_psi0" and coords.samples_yaw_momentum(prior):
            # the sampled site is the rate's momentum ratio (heli_model), of the parameters
            # as the coordinates map them (fixed ones at their priors' values)
            ratio = coords.yaw_inertia_ratio(coords.to_physical(z), jnp.asarray(float(x0[0])))
            values[YAW_MOMENTUM_SITE] = jnp.asarray(float(v) * float(ratio))
        elif prior.free:
            values[name] = jnp.asarray(float(v))
    for i, o in enumerate(OUTPUTS):
        if problem.priors.noise[f"sigma_{o}"].free:
            values[f"sigma_{o}"] = jnp.asarray(float(sigma[i]))
        if problem.ar1 and problem.priors.noise[f"tau_{o}"].free:
            values[f"tau_{o}"] = jnp.asarray(float(tau[i]))
        if problem.timing and problem.priors.noise[f"timing_{o}"].free:
            values[f"timing_{o}"] = jnp.asarray(float(timing[i]))
    return values


def log_density_setup(problem: Problem, init_values: dict | None = None, seed: int = 0) -> LogDensity:
    """The :class:`LogDensity` of ``heli_model`` conditioned on the training angles."""
    kwargs = {"y": jnp.asarray(problem.y[: problem.n_train])}
    if init_values is None:
        x0 = np.concatenate([problem.y[0], np.zeros(2)])
        init_values = init_sites(problem, problem.model.start_values(), x0)
    try:
        info = initialize_model(
            jax.random.PRNGKey(seed), heli_model, model_args=(problem,), model_kwargs=kwargs,
            init_strategy=init_to_value(values=init_values), validate_grad=False,
        )  # fmt: skip
    except RuntimeError as err:  # numpyro: the log density is not finite at the values
        if "Cannot find valid initial parameters" not in str(err):
            raise
        u = np.asarray(problem.u)
        raise ParameterError(
            f"{problem.source}: the log density is not finite at the model's start values (its "
            "simulation from them blows up or turns the pitch over); check the record's units "
            f"(voltages {u.min():.3g} to {u.max():.3g} V, angles in rad) or start from values "
            "near the data (guesses; on the command line --init)") from None  # fmt: skip
    # validate_grad=False: numpyro would otherwise run value-and-grad of the model op by
    # op (no jit), ~13 s for a 500-sample record; the MAP checks finiteness anyway.
    x_init, unravel = ravel_pytree(info.param_info.z)

    def potential(x):
        return info.potential_fn(unravel(x))

    return LogDensity(problem, potential, unravel, np.asarray(x_init))


def constrain_draws(density: LogDensity, x: np.ndarray) -> dict:
    """Named constrained sites of unconstrained draws ``x`` (n, d), in fixed-size batches.

    Returns a dict of arrays with leading axis ``n``: the sampled sites and the
    deterministic ones (physical parameters by name, ``sigma``, ``rho``, ...).  No ODE is
    solved.
    """
    constrain = density._constrain_batched
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


def coordinate_names(density: LogDensity) -> list[str]:
    """Names of the entries of the flat unconstrained vector (``z[3]``, ``sigma_psi``, ...).

    The entries of ``z`` are named by their coordinate (``z[log_F_c_yaw_ratio]``).
    """
    sampled = density.problem.coords.sampled_names
    leaves, _ = jax.tree_util.tree_flatten_with_path(density.unravel(density.x_init))
    names = []
    for path, leaf in leaves:
        base = "".join(str(getattr(k, "key", k)) for k in path)
        if np.ndim(leaf) == 0:
            names.append(base)
        else:
            labels = sampled if base == "z" else range(int(np.size(leaf)))
            names += [f"{base}[{lab}]" for lab in labels]
    return names
