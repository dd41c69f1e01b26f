"""The probabilistic model, written once for NUTS, emcee and prediction (numpyro).

``heli_model(problem, y=None, mode=...)``:

* the sampling coordinates ``z`` of the model's free parameters with their physical
  priors (:mod:`heli_uq.probability.coordinates`), the common inertia scale drawn as
  ``scale_noise`` from its exact conditional prior;
* the initial state ``theta0, psi0, omega_theta0, omega_psi0``; in identifiable
  coordinates a free initial yaw rate is sampled as its angular momentum over the yaw
  ratios' inertia, ``p_psi0_ratio`` (below), and ``omega_psi0`` is deterministic;
* the error model: ``sigma_theta, sigma_psi``; for AR(1) ``tau_theta, tau_psi`` with
  ``rho = exp(-dt / tau)``; with a timing error ``timing_theta, timing_psi``
  (deterministic ``sigma``, ``tau``, ``rho``, ``timing`` per output);
* deterministic physical parameters by name.

``mode="fit"`` (default, ``y`` given): one simulation of the training window and the
log likelihood of :mod:`heli_uq.probability.likelihood` as the factor ``log_likelihood``.
``mode="params"`` stops before simulating: mapping draws to physical parameters costs no
ODE solve.  ``mode="predict"``: simulate the whole span and draw predictive angles
(``y_sim``, and ``y_pred`` with error-model noise).  A failed solve is a rejected
proposal (``-inf``), never an exception.

**The initial yaw rate as a momentum.**  In the identifiable coordinates
(:mod:`heli_uq.probability.coordinates`) a record whose yaw starts moving pins the initial
yaw rate only together with ``J_s / M11`` and the yaw ratios: the yaw the initial rate
carries before damping stops it is ``omega_psi0 M22(theta0) / D_psi``, and ``M22(theta0)``
is the yaw ratios' ``M22(theta_ref)`` times a factor that ``J_s`` sets.  The ridge bends
with the square of the rate (studies/notes/discovery.md, "Why the initial yaw rate mixes
slowly"): on a 131 s record the straight line of the Laplace covariance along
``omega_psi0`` rose 54 nats at 2 marginal sd where the posterior's profile rose 2, and NUTS
mixed that rate slowest of all (bulk ESS 13-184).  So the initial yaw angular momentum over
the same inertia, ``p_psi0_ratio = M22(theta0) omega_psi0 / M22(theta_ref)`` [rad/s]
(:meth:`~heli_uq.probability.coordinates.Coordinates.yaw_inertia_ratio`), is sampled
instead, along which that line rises 2.0 nats at 2 sd, a Gaussian's.  The prior stays the
user's prior on ``omega_psi0``, with the Jacobian ``M22(theta_ref) / M22(theta0)``.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpyro
import numpyro.distributions as dist
from numpyro.distributions import constraints

from heli_uq.errors import ParameterError
from heli_uq.model.tables import X0_NAMES
from heli_uq.probability.likelihood import log_likelihood
from heli_uq.probability.noise import ar1_noise
from heli_uq.probability.priors import OUTPUTS
from heli_uq.probability.problem import Problem

__all__ = ["heli_model", "MODES", "YAW_MOMENTUM_SITE"]

MODES = ("fit", "params", "predict")


def _scalar_site(name: str, prior, loc=None, scale=None):
    """A sampled scalar (normal or log-normal prior) or a deterministic fixed value.

    ``loc``, ``scale``: the normal prior's location and sd as array elements (``prior.a``,
    ``prior.b`` by default): values taken from the record then reach the compiled program
    as arguments, not as constants, so records of one length share compiled programs
    (:mod:`heli_uq._jax_config`).
    """
    if prior.kind == "fixed":
        return numpyro.deterministic(name, jnp.asarray(prior.a))
    if prior.kind == "normal":
        return numpyro.sample(name, dist.Normal(prior.a if loc is None else loc,
                                                prior.b if scale is None else scale))  # fmt: skip
    if prior.kind == "lognormal":
        return numpyro.sample(name, dist.LogNormal(jnp.log(prior.a), prior.b))
    raise ParameterError(f"{name}: prior {prior.describe()} is not supported here")


#: The sampled site of a free initial yaw rate in identifiable coordinates: the initial yaw
#: angular momentum ``M22(theta0) omega_psi0`` over ``M22(theta_ref)`` [rad/s].
YAW_MOMENTUM_SITE = "p_psi0_ratio"


def _initial_yaw_rate(coords, phys, theta0, loc, scale):
    """``omega_psi0`` [rad/s] from the sampled momentum ratio, with the prior
    ``normal(loc, scale)`` on ``omega_psi0`` and the Jacobian of ``omega = p / r``,
    ``r = M22(theta0) / M22(theta_ref)``."""
    ratio = coords.yaw_inertia_ratio(phys, theta0)
    momentum = numpyro.sample(YAW_MOMENTUM_SITE, dist.ImproperUniform(constraints.real, (), ()))
    omega = momentum / ratio
    numpyro.factor("omega_psi0_prior", dist.Normal(loc, scale).log_prob(omega) - jnp.log(ratio))
    return numpyro.deterministic("omega_psi0", omega)


def _per_output(problem: Problem, kind: str):
    """The error-model parameter ``kind`` (``sigma``, ``tau``, ``timing``) of each output,
    shape (2,): sites ``{kind}_theta, {kind}_psi``."""
    return jnp.stack([_scalar_site(f"{kind}_{o}", problem.priors.noise[f"{kind}_{o}"]) for o in OUTPUTS])


def heli_model(problem: Problem, y=None, mode: str = "fit"):
    """numpyro model of a record (module docstring)."""
    coords = problem.coords
    n_z = len(coords.sampled_names)
    z = numpyro.sample("z", dist.ImproperUniform(constraints.real_vector, (), (n_z,)))
    eps = numpyro.sample("scale_noise", dist.Normal(0.0, 1.0)) if coords.marginal_scale else None
    log_prior, z, phys = coords.prior_and_physical(z, eps)
    if coords.marginal_scale:
        numpyro.deterministic("log_J_pitch", z[0])
    numpyro.factor("prior", log_prior)
    for name in coords.free:
        numpyro.deterministic(name, phys[name])
    x0_priors = problem.x0_priors()
    x0_loc = jnp.asarray([p.a for p in x0_priors])
    x0_scale = jnp.asarray([p.b for p in x0_priors])
    x0 = []
    for i, (n, p) in enumerate(zip(X0_NAMES, x0_priors)):
        if n == "omega_psi0" and coords.samples_yaw_momentum(p):
            x0.append(_initial_yaw_rate(coords, phys, x0[0], x0_loc[i], x0_scale[i]))
        else:
            x0.append(_scalar_site(n, p, x0_loc[i], x0_scale[i]))
    x0 = jnp.stack(x0)
    sigma = numpyro.deterministic("sigma", _per_output(problem, "sigma"))
    rho = timing = None
    if problem.ar1:
        tau = numpyro.deterministic("tau", _per_output(problem, "tau"))
        rho = numpyro.deterministic("rho", jnp.exp(-problem.dt / tau))
    if problem.timing:
        timing = numpyro.deterministic("timing", _per_output(problem, "timing"))
    if mode == "params":
        return
    n = problem.n_train if mode == "fit" else None
    sol = problem.solve(phys, x0, n)
    ok = sol.ok
    # A failed solve is a rejected proposal: -inf log density, finite placeholders.
    numpyro.factor("solver_ok", jnp.where(ok, 0.0, -jnp.inf))
    sim = jnp.where(ok, sol.ys[:, :2], 0.0)
    rate = jnp.where(ok, sol.ys[:, 2:4], 0.0) if problem.timing else None
    if mode == "predict":
        noise = ar1_noise(numpyro.prng_key(), sim.shape[0], sigma, rho, timing, rate)
        numpyro.deterministic("y_pred", sim + noise)
        numpyro.deterministic("y_sim", sim)
        return
    numpyro.factor("log_likelihood", log_likelihood(sim, y, sigma, rho, timing, rate))
