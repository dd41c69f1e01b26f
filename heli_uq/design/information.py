"""Expected information gain of an experiment: Bayesian D-optimality on the whitened Fisher information.

For a prior ``w ~ N(m, S)`` on the free parameters in their coordinates (log of each positive
parameter, see :class:`~heli_uq.identifiability.ParameterVector`) and iid Gaussian errors of sd
``sigma`` per angle, the linearised information an input ``u`` brings is

    EIG(u; w) = 1/2 log det(I + L^T F(u; w) L),   F = J^T J,   S = L L^T,

with ``J`` the Jacobian of the *whitened* simulated angles ``(theta, psi) / sigma`` with
respect to ``w`` (forward-mode autodiff through the simulator).  It is the log ratio of
prior to posterior volume, so directions the experiment cannot identify (the common inertia
scale, a fixed gain ratio) add nothing and need no special handling: the prior keeps the
determinant finite and only identifiable combinations count.  The criterion is averaged
over draws of the current posterior (pseudo-Bayesian design); an input whose simulation
fails or leaves the pitch envelope at any draw is infeasible.
"""

from __future__ import annotations

import dataclasses
import json

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from heli_uq.errors import DataFormatError, ParameterError
from heli_uq.identifiability.parameter_vector import ParameterVector
from heli_uq.model.heli_model import HeliModel
from heli_uq.model.tables import RIG_FIT, RIG_FIT_X0
from heli_uq.probability.priors import OUTPUTS, PriorSet, fixed_values
from heli_uq.simulation.physical import PITCH_LIMIT
from heli_uq.simulation.stiffness import default_substeps

__all__ = ["DesignPrior", "InformationGain", "DEFAULT_NOISE", "DESIGN_X0", "PRIOR_SAMPLES", "check_noise"]

#: Measurement noise [rad] (theta, psi) assumed without a posterior: the rig's encoders and
#: the size of the noise on the acceptance records (about 3 and 8 mrad).
DEFAULT_NOISE = (0.003, 0.008)
#: Initial state of a designed experiment: at rest, pitch at the rig record's start [rad].
DESIGN_X0 = (round(RIG_FIT_X0[0], 3), 0.0, 0.0, 0.0)
#: Prior draws used to compute the coordinate variance of a prior without closed form.
PRIOR_SAMPLES = 20000
#: Relative ridge added to an empirical posterior covariance (keeps its Cholesky factor).
COV_RIDGE = 1e-9


@dataclasses.dataclass(frozen=True, eq=False)
class DesignPrior:
    """What is known before the experiment.

    Attributes
    ----------
    pv : ParameterVector
        The model, its free parameters (``w``) and the values of the fixed ones.
    draws : ndarray, shape (K, P)
        Linearisation points ``w`` (posterior draws, or the centre alone).
    chol : ndarray, shape (P, P)
        Lower Cholesky factor ``L`` of the prior covariance of ``w``.
    sigma : ndarray, shape (2,)
        Noise sd of (theta, psi) [rad].
    x0 : ndarray, shape (4,)
        Initial state of the experiment.
    source : str
        Where the prior comes from (for reports).
    """

    pv: ParameterVector
    draws: np.ndarray
    chol: np.ndarray
    sigma: np.ndarray
    x0: np.ndarray
    source: str

    @property
    def center(self) -> np.ndarray:
        """Mean of the draws, shape (P,)."""
        return self.draws.mean(axis=0)

    def params(self, w) -> dict:
        """Physical values of all model parameters at ``w``."""
        params, _ = self.pv.to_model(jnp.asarray(w), self.x0)
        return {k: float(v) for k, v in params.items()}

    @classmethod
    def default(cls, model: HeliModel | None = None, *, priors: PriorSet | None = None,
                center=None, sigma=DEFAULT_NOISE, x0=DESIGN_X0, dt: float = 0.01,
                seed: int = 0) -> DesignPrior:  # fmt: skip
        """The package's priors, linearised at ``center`` (default: a fit of the rig record,
        ``RIG_FIT``, with each effect at its start value).  A term not yet set up from a
        record (a network's input scaling, a Gaussian process's voltage pairs:
        :attr:`~heli_uq.model.terms.base.AbstractTerm.awaits_record`) is refused: design from
        a posterior of the fitted model (:meth:`from_posterior`)."""
        model = HeliModel() if model is None else model
        waiting = [t.label for t in model.effects if t.awaits_record]
        if waiting:
            raise ParameterError(f"model: {', '.join(waiting)} is set up from a record (its inputs' scaling "
                                 "or voltage pairs) and has none here; design from a posterior of the "
                                 "fitted model (posterior=..., --posterior)")  # fmt: skip
        priors = PriorSet.default(model) if priors is None else priors
        free = [n for n in model.names if priors.params[n].free]
        base = model.start_values()
        base.update({k: v for k, v in RIG_FIT.items() if k in base})
        base.update({n: p.a for n, p in priors.params.items() if not p.free})
        base.update(center or {})
        pv = _vector(model, free, base, dt)
        rng = np.random.default_rng(seed)
        sd = []
        for n in pv.free:
            x = np.asarray(priors.params[n].sample(rng, PRIOR_SAMPLES), dtype=float)
            sd.append(np.std(np.log(x[x > 0]) if pv.is_log(n) else x))
        w = pv.from_model(base)
        return cls(pv, w[None, :], np.diag(sd), np.asarray(sigma, float), np.asarray(x0, float),
                   "the package's default priors, linearised at a fit of the rig record")

    @classmethod
    def from_posterior(cls, path, *, draws: int = 4, sigma=None, x0=DESIGN_X0, dt: float = 0.01,
                       seed: int = 0) -> DesignPrior:  # fmt: skip
        """The posterior of a ``heli-uq sample`` run (``posterior.nc``) as the prior: its
        covariance in ``w`` and ``draws`` of its draws as linearisation points; ``sigma``
        defaults to the posterior mean of the noise sd."""
        from heli_uq.output.inference_data import load_posterior

        idata, model = load_posterior(path)
        post = idata.posterior
        free = [n for n in post.attrs.get("free_parameters", "").split(",") if n in model.names]
        if not free:
            raise DataFormatError(f"{path}: the posterior names no free model parameters")
        values = {n: np.asarray(post[n]).reshape(-1) for n in free}
        base = model.start_values()
        fixed = fixed_values(json.loads(post.attrs.get("priors", "{}")))
        base.update({n: v for n, v in fixed.items() if n in base})
        base.update({n: float(np.mean(v)) for n, v in values.items()})
        pv = _vector(model, free, base, dt)
        w = np.column_stack([np.log(values[n]) if pv.is_log(n) else values[n] for n in pv.free])
        cov = np.atleast_2d(np.cov(w, rowvar=False))
        cov += COV_RIDGE * np.trace(cov) / len(cov) * np.eye(len(cov))
        rng = np.random.default_rng(seed)
        pick = rng.choice(len(w), size=min(draws, len(w)), replace=False)
        if sigma is None:
            sigma = np.asarray(post["sigma"]).reshape(-1, len(OUTPUTS)).mean(axis=0)
        return cls(pv, w[pick], np.linalg.cholesky(cov), np.asarray(sigma, float),
                   np.asarray(x0, float), f"the posterior in {path} ({len(w)} draws)")


def _vector(model, free, base, dt) -> ParameterVector:
    base = {k: float(v) for k, v in model.complete(base).items()}
    substeps = default_substeps(model, base, dt, margin=2.0)
    return ParameterVector(model, tuple(free), base, include_x0=False, substeps=substeps)


class InformationGain(eqx.Module):
    """``u -> (EIG per draw (K,), feasible)``: the criterion of :mod:`heli_uq.design`.

    Call with voltages ``u`` of shape (N, 2) [V]; jit-compiled once per ``N``.  ``pitch``
    ``(low, high)`` [rad] is the envelope the simulated pitch must keep at every draw
    (default: the physical range, +-90 deg).
    """

    prior: DesignPrior = eqx.field(static=True)
    dt: float = eqx.field(static=True)
    pitch: tuple = eqx.field(static=True, default=(-PITCH_LIMIT, PITCH_LIMIT),
                             converter=lambda p: tuple(float(v) for v in p))

    def angles(self, w, u):
        """Simulated (theta, psi), shape (N, 2) [rad], and whether pitch stays in ``pitch``."""
        sol = self.prior.pv.solve(w, u, self.dt, jnp.asarray(self.prior.x0), gradients="autodiff")
        ys = sol.ys[:, :2]
        return ys, sol.ok & jnp.all((ys[:, 0] >= self.pitch[0]) & (ys[:, 0] <= self.pitch[1]))

    def fisher(self, w, u):
        """Whitened Fisher information ``F`` (P, P) at ``w`` and feasibility."""
        jac, ok = jax.jacfwd(self.angles, has_aux=True)(w, u)
        jw = (jac / jnp.asarray(self.prior.sigma)[None, :, None]).reshape(-1, w.shape[0])
        return jw.T @ jw, ok

    def gain(self, w, u):
        fisher, ok = self.fisher(w, u)
        chol = jnp.asarray(self.prior.chol)
        m = jnp.eye(chol.shape[0]) + chol.T @ fisher @ chol
        _, logdet = jnp.linalg.slogdet(m)
        ok = ok & jnp.isfinite(logdet)
        return jnp.where(ok, 0.5 * logdet, -jnp.inf), ok

    @eqx.filter_jit
    def __call__(self, u):
        u = jnp.asarray(u, dtype=jnp.float64)
        gains, ok = jax.lax.map(lambda w: self.gain(w, u), jnp.asarray(self.prior.draws))
        return gains, jnp.all(ok)

    def value(self, u) -> float:
        """Mean EIG over the draws [nats]; ``-inf`` when infeasible."""
        gains, ok = self(u)
        return float(jnp.mean(gains)) if bool(ok) else -np.inf

    def shrinkage(self, u) -> np.ndarray:
        """Posterior sd / prior sd along each whitened direction at the centre, ascending, (P,).

        The eigenvalues ``lambda`` of ``L^T F L`` give ``1 / sqrt(1 + lambda)``: well below 1
        for the combinations ``u`` identifies, 1 for the directions it cannot."""
        fisher, _ = self.fisher(jnp.asarray(self.prior.center), jnp.asarray(u, dtype=jnp.float64))
        chol = np.asarray(self.prior.chol)
        lam = np.linalg.eigvalsh(chol.T @ np.asarray(fisher) @ chol)
        return np.sort(1.0 / np.sqrt(1.0 + np.maximum(lam, 0.0)))


def check_noise(sigma) -> np.ndarray:
    """``sigma`` as a (2,) array of positive sds [rad], else :class:`ParameterError`."""
    sigma = np.asarray(sigma, dtype=float)
    if sigma.shape != (2,) or not np.all(np.isfinite(sigma) & (sigma > 0)):
        raise ParameterError(f"noise: expected two numbers > 0 [rad] (theta, psi), found {sigma.tolist()}")
    return sigma
