"""Practical identifiability at the fit: whitened residuals, likelihood fit, Fisher information.

The likelihood is the package's one likelihood (:mod:`heli_uq.probability.likelihood`) with its noise
parameters (``sigma`` per output and, for AR(1), ``rho``) held at their values estimated
from the residuals of the fit, so the negative log likelihood of ``w``
(:class:`~heli_uq.identifiability.structural.ParameterVector`) is half the sum of squares of
*whitened* residuals plus a constant.  The Gauss-Newton Fisher information is then
``F = J^T J`` with ``J`` the Jacobian of the whitened residuals; it is computed from the
singular value decomposition of ``J`` (``F``'s eigenvalues are the squared singular
values) so null directions are not lost to the squaring.
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from heli_uq.errors import ParameterError
from heli_uq.identifiability.structural import RANK_RTOL, ParameterVector
from heli_uq.inference.levenberg import masked_least_squares
from heli_uq.probability.likelihood import loss_v, whitened_residuals
from heli_uq.probability.noise import ERROR_MODELS, error_parts

__all__ = ["precision_draws", "WhitenedResiduals", "estimate_noise", "masked_least_squares", "LikelihoodFit",
           "fit_likelihood", "FisherResult", "fisher_information"]  # fmt: skip

#: The error models of the Fisher information: a constant scale (its Gauss-Newton form
#: needs residual scales that do not depend on the parameters, which a timing error's do).
FISHER_ERROR_MODELS = tuple(e for e in ERROR_MODELS if not error_parts(e)[1])

#: Residual scales [rad] (theta, psi) of the first least-squares stage, before the noise is estimated.
INITIAL_SIGMA = (0.02, 0.1)

#: Largest AR(1) coefficient estimated from residuals (keeps the whitening finite).
RHO_MAX = 0.9999

#: Whitened residual used for samples of a failed simulation (a large, finite penalty).
FAILED_RESIDUAL = 1e6


class WhitenedResiduals(eqx.Module):
    """``w -> (y - E[y_k | y_{k-1}]) / sd_k``, shape (2N,), under the fixed error model.

    Parameters
    ----------
    pv : ParameterVector
    u, y : arrays, shape (N, 2)
        Voltages [V] and measured angles [rad].
    dt : float
    sigma : array, shape (2,)
        Marginal residual sd per output [rad].
    rho : array, shape (2,), optional
        AR(1) coefficients; ``None`` for independent errors.
    x0 : array, shape (4,), optional
        Initial state when ``pv`` does not include it.
    """

    pv: ParameterVector = eqx.field(static=True)
    u: jax.Array
    y: jax.Array
    dt: float = eqx.field(static=True)
    sigma: jax.Array
    rho: jax.Array | None = None
    x0: jax.Array | None = None

    def __init__(self, pv, u, y, dt, sigma, rho=None, x0=None):
        self.pv, self.dt = pv, float(dt)
        self.u, self.y = jnp.asarray(u, dtype=float), jnp.asarray(y, dtype=float)
        self.sigma = jnp.asarray(sigma, dtype=float)
        self.rho = None if rho is None else jnp.asarray(rho, dtype=float)
        self.x0 = None if x0 is None else jnp.asarray(x0, dtype=float)

    def simulate(self, w):
        sol = self.pv.solve(w, self.u, self.dt, self.x0)
        return sol.ys[:, :2], sol.ok

    def __call__(self, w):
        sim, ok = self.simulate(w)
        r = whitened_residuals(sim, self.y, self.sigma, self.rho).ravel()
        return jnp.where(ok & jnp.isfinite(r), r, FAILED_RESIDUAL)

    def log_scale_sum(self) -> float:
        """``sum log sd_k``: the constant part of the negative log likelihood."""
        n = self.y.shape[0]
        sigma = np.asarray(self.sigma)
        if self.rho is None:
            return float(n * np.sum(np.log(sigma)))
        inner = np.log(sigma * np.sqrt(1 - np.asarray(self.rho) ** 2))
        return float(np.sum(np.log(sigma)) + (n - 1) * np.sum(inner))


def estimate_noise(resid: np.ndarray, error: str):
    """``(sigma, rho)`` of residuals of shape (N, 2): RMS and, for AR(1), lag-1 correlation."""
    if error not in FISHER_ERROR_MODELS:
        raise ParameterError(f"error: expected one of {FISHER_ERROR_MODELS}, found {error!r}")
    sigma = np.maximum(np.sqrt(np.mean(resid**2, axis=0)), 1e-6)
    if error == "iid":
        return sigma, None
    lag1 = np.sum(resid[1:] * resid[:-1], axis=0) / np.maximum(np.sum(resid**2, axis=0), 1e-300)
    return sigma, np.clip(lag1, 0.0, RHO_MAX)


@dataclasses.dataclass(frozen=True, eq=False)
class LikelihoodFit:
    """Result of :func:`fit_likelihood`.

    ``w`` (P,), ``cost`` = 0.5 |whitened residuals|^2 at ``w``, ``residuals`` (the
    :class:`WhitenedResiduals` with the estimated noise), ``loss_v`` = paper's V at ``w``.
    """

    w: np.ndarray
    cost: float
    residuals: WhitenedResiduals
    loss_v: float
    start_costs: tuple


def fit_likelihood(pv: ParameterVector, u, y, dt: float, starts, *, error: str = "ar1",
                   x0=None, rounds: int = 2) -> LikelihoodFit:  # fmt: skip
    """Maximum-likelihood ``w`` from several starts, then the noise, alternating ``rounds`` times.

    Stage 1 fits every start with iid residual scales :data:`INITIAL_SIGMA`; the best is
    kept.  Then ``rounds`` times: estimate the noise (:func:`estimate_noise`) from the
    residuals and refit under that error model.
    """
    u, y = np.asarray(u, dtype=float), np.asarray(y, dtype=float)
    res = WhitenedResiduals(pv, u, y, dt, np.asarray(INITIAL_SIGMA), None, x0)
    mask = jnp.zeros(pv.dim, dtype=bool)
    costs, best = [], None
    for w0 in starts:
        w, c = masked_least_squares(res, jnp.asarray(w0, dtype=float), mask, jnp.zeros(pv.dim))
        c = float(c)
        costs.append(c if np.isfinite(c) else np.inf)
        if np.isfinite(c) and (best is None or c < best[1]):
            best = (np.asarray(w), c)
    if best is None:
        raise ParameterError("identifiability: the likelihood fit failed from every start")
    w = best[0]
    for _ in range(rounds):
        sim, _ = res.simulate(jnp.asarray(w))
        sigma, rho = estimate_noise(y - np.asarray(sim), error)
        res = WhitenedResiduals(pv, u, y, dt, sigma, rho, x0)
        w, c = (np.asarray(a) for a in masked_least_squares(res, jnp.asarray(w), mask,
                                                            jnp.zeros(pv.dim)))  # fmt: skip
    sim, _ = res.simulate(jnp.asarray(w))
    v = float(loss_v(sim, y))
    return LikelihoodFit(w=w, cost=float(c), residuals=res, loss_v=v,
                         start_costs=tuple(costs))  # fmt: skip


@dataclasses.dataclass(frozen=True)
class FisherResult:
    """Gauss-Newton Fisher information at ``w`` under the fixed error model.

    Attributes
    ----------
    eigenvalues : ndarray, shape (P,)
        Of ``F``, descending (squared singular values of the whitened Jacobian).
    eigenvectors : ndarray, shape (P, P)
        Columns, matching ``eigenvalues``.
    condition_number : float
        ``lambda_max / lambda_min`` (``inf`` when ``lambda_min`` is 0).
    rank : int
        Eigenvalues above ``RANK_RTOL**2 * lambda_max``.
    standard_errors : ndarray, shape (P,)
        Cramér-Rao standard errors ``sqrt((F^+)_jj)``, ``inf`` for coordinates with a
        loading on the null space of ``F`` (not estimable).
    correlation : ndarray, shape (P, P)
        Correlation matrix of ``F^+`` (NaN rows for non-estimable coordinates).
    """

    eigenvalues: np.ndarray
    eigenvectors: np.ndarray
    condition_number: float
    rank: int
    standard_errors: np.ndarray
    correlation: np.ndarray
    covariance: np.ndarray


#: A coordinate whose unit vector has more than this projection on the null space of F is not estimable.
ESTIMABLE_TOL = 1e-6


def fisher_information(residuals: WhitenedResiduals, w) -> FisherResult:
    """Fisher information of ``w`` from the Jacobian of the whitened residuals."""
    jac = np.asarray(jax.jacfwd(residuals)(jnp.asarray(w, dtype=float)))
    _, s, vt = np.linalg.svd(jac, full_matrices=False)
    lam = s**2
    keep = s >= RANK_RTOL * s[0]
    rank = int(keep.sum())
    v = vt.T
    cov = (v[:, keep] / lam[keep]) @ v[:, keep].T
    null = v[:, ~keep]
    leak = np.linalg.norm(null, axis=1) if null.size else np.zeros(len(w))
    se = np.where(leak > ESTIMABLE_TOL, np.inf, np.sqrt(np.maximum(np.diag(cov), 0.0)))
    ok = np.isfinite(se) & (se > 0)
    corr = np.full_like(cov, np.nan)
    corr[np.ix_(ok, ok)] = cov[np.ix_(ok, ok)] / np.outer(se[ok], se[ok])
    cond = float(lam[0] / lam[-1]) if lam[-1] > 0 else float("inf")
    return FisherResult(eigenvalues=lam, eigenvectors=v, condition_number=cond, rank=rank,
                        standard_errors=se, correlation=corr, covariance=cov)  # fmt: skip


def precision_draws(mean: np.ndarray, precision: np.ndarray, n: int, seed: int) -> np.ndarray:
    """``n`` draws (n, d) of ``N(mean, precision^-1)`` from the eigendecomposition of the
    precision, which is never inverted: inverting ``F + prior precision`` of a network
    model (condition ~1e16) gave a covariance that was not positive semi-definite."""
    lam, vec = np.linalg.eigh(0.5 * (precision + precision.T))
    lam = np.maximum(lam, np.finfo(float).eps * lam.max())  # round-off below 0: a direction barely held
    z = np.random.default_rng(seed).standard_normal((n, mean.size))
    return mean + (z / np.sqrt(lam)) @ vec.T
