"""The probabilistic model, written once for NUTS, emcee and prediction (numpyro).

``heli_model(problem, y=None)``: coordinates ``z`` (see :mod:`heli_uq.reparam`) with the
physical priors, the initial state, the error model, one simulation over the whole
window, and the observation site ``y`` on the training samples.  With ``y=None`` the
same function draws predictive angles (simulation + error-model noise) on the whole
window, so prior/posterior prediction use exactly the likelihood's assumptions.
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np
import numpyro
import numpyro.distributions as dist
from numpyro.distributions import constraints

from heli_uq.data import Experiment
from heli_uq.errors import ParameterError
from heli_uq.noise import ERROR_MODELS, ar1_noise, conditional_moments
from heli_uq.params import STATE_NAMES
from heli_uq.priors import SIGMA_PRIOR, TAU_PRIOR, X0_ANGLE_SD, X0_RATE_SD, default_priors
from heli_uq.reparam import Coordinates
from heli_uq.simulate import solve

__all__ = ["Problem", "heli_model", "make_problem"]


@dataclasses.dataclass(frozen=True, eq=False)
class Problem:
    """Everything the model needs: inputs, data, priors, coordinates, error model.

    Attributes
    ----------
    u : ndarray, shape (N, 2)
        Voltages [V] over the whole simulated span (training window, then up to the end
        of the test window).
    y : ndarray, shape (N, 2)
        Measured angles [rad] over the same span.
    t : ndarray, shape (N,)
        Sample times [s] (absolute, as in the record).
    dt : float
        Sample time [s].
    n_train : int
        The likelihood uses samples ``[0, n_train)``.
    test : tuple of int or None
        ``(start, stop)`` sample indices of the held-out test window, if any.
    coords : Coordinates
    error : {"iid", "ar1"}
    source : str
    """

    u: np.ndarray
    y: np.ndarray
    t: np.ndarray
    dt: float
    n_train: int
    test: tuple[int, int] | None
    coords: Coordinates
    error: str = "ar1"
    source: str = ""

    @property
    def x0_center(self) -> np.ndarray:
        return self.y[0]

    def windows(self) -> dict[str, tuple[int, int]]:
        """``{"train": (0, n_train), "test": (start, stop)}`` sample-index ranges."""
        out = {"train": (0, self.n_train)}
        if self.test is not None:
            out["test"] = self.test
        return out


def make_problem(record: Experiment, train=None, test=None, *, priors=None,
                 error: str = "ar1", strategy: str = "auto") -> Problem:  # fmt: skip
    """Build a :class:`Problem` from a record and optional train/test windows [s].

    Parameters
    ----------
    record : Experiment
    train, test : (float, float), optional
        ``(start, stop)`` in seconds; ``train`` defaults to the whole record.  The test
        window must start at or after the end of the training window.  The model
        simulates from the start of ``train`` to the end of ``test`` with the record's
        inputs and scores only ``train``.

    Raises
    ------
    ParameterError
        Unknown error model, or overlapping windows.
    """
    if error not in ERROR_MODELS:
        raise ParameterError(f"--error: expected one of {ERROR_MODELS}, found {error!r}")
    priors = default_priors() if priors is None else dict(priors)
    t0 = float(record.t[0])
    a, b = train if train is not None else (t0, t0 + record.duration)
    tr = record.window(a, b)
    coords = Coordinates(priors, strategy, yaw_theta_ref=float(np.median(tr.y[:, 0])))
    if test is None:
        span, test_idx = tr, None
    else:
        c, d = test
        if c < b - 0.5 * record.dt:
            raise ParameterError(
                f"test window {c:g}:{d:g} s overlaps the training window {a:g}:{b:g} s"
            )
        te = record.window(c, d)
        span = record.window(a, float(te.t[-1]) + 0.5 * record.dt)
        start = int(round((te.t[0] - span.t[0]) / record.dt))
        test_idx = (start, start + te.n)
    return Problem(u=np.asarray(span.u), y=np.asarray(span.y), t=np.asarray(span.t),
                   dt=float(record.dt), n_train=int(tr.n), test=test_idx, coords=coords,
                   error=error, source=str(record.source))  # fmt: skip


def heli_model(problem: Problem, y=None):
    """numpyro model of the rig record (see module docstring).

    Sites: ``z`` (the sampled coordinates ``coords.sampled_names``, improper flat; the
    prior enters as the factor ``prior``), ``scale_noise`` (standard normal; the common
    scale ``log_J_pitch`` is its exact conditional prior, see :mod:`heli_uq.reparam`),
    ``theta0, psi0, omega_theta0, omega_psi0``, ``sigma`` (2,), ``tau`` (2,) and the
    deterministic ``rho = exp(-dt / tau)`` (2,)
    for AR(1), deterministic physical parameters by Table 2 name, and ``y`` (observed,
    (n_train, 2)) or ``y_pred`` ((N, 2), when ``y`` is None).
    """
    coords = problem.coords
    n_z = len(coords.sampled_names)
    z = numpyro.sample("z", dist.ImproperUniform(constraints.real_vector, (), (n_z,)))
    if coords.marginal_scale:
        log_marginal, mean, sd = coords.scale_conditional(z)
        numpyro.factor("prior", log_marginal)
        noise = numpyro.sample("scale_noise", dist.Normal(0.0, 1.0))
        log_m11 = numpyro.deterministic("log_J_pitch", mean + sd * noise)
        z = jnp.concatenate([log_m11[None], z])
    else:
        numpyro.factor("prior", coords.log_prior(z))
    phys = coords.to_physical(z)
    for name in coords.free:
        numpyro.deterministic(name, phys[name])
    c = problem.x0_center
    x0 = jnp.stack([
        numpyro.sample(STATE_NAMES[0] + "0", dist.Normal(c[0], X0_ANGLE_SD)),
        numpyro.sample(STATE_NAMES[1] + "0", dist.Normal(c[1], X0_ANGLE_SD)),
        numpyro.sample(STATE_NAMES[2] + "0", dist.Normal(0.0, X0_RATE_SD)),
        numpyro.sample(STATE_NAMES[3] + "0", dist.Normal(0.0, X0_RATE_SD)),
    ])  # fmt: skip
    sigma = numpyro.sample(
        "sigma", dist.LogNormal(jnp.log(SIGMA_PRIOR[0]), SIGMA_PRIOR[1]).expand([2]).to_event(1)
    )
    rho = None
    if problem.error == "ar1":
        tau = numpyro.sample(
            "tau", dist.LogNormal(jnp.log(TAU_PRIOR[0]), TAU_PRIOR[1]).expand([2]).to_event(1)
        )
        rho = numpyro.deterministic("rho", jnp.exp(-problem.dt / tau))
    sol = solve(phys, x0, problem.u, problem.dt)
    ok = sol.ok
    # A failed solve is a rejected proposal: -inf log density, finite placeholders.
    numpyro.factor("solver_ok", jnp.where(ok, 0.0, -jnp.inf))
    sim = jnp.where(ok, sol.ys[:, :2], 0.0)
    if y is None:
        noise = ar1_noise(numpyro.prng_key(), sim.shape[0], sigma, rho)
        numpyro.deterministic("y_pred", sim + noise)
        numpyro.deterministic("y_sim", sim)
        return
    n = problem.n_train
    loc, scale = conditional_moments(sim[:n], y, sigma, rho)
    numpyro.sample("y", dist.Normal(loc, scale).to_event(0), obs=y)
