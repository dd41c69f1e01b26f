"""The Bayesian view of the identifiability report: a posterior's draws in the report's
coordinates ``w`` and their contraction from the prior, per coordinate and along the
structural null directions (:func:`heli_uq.identifiability.report.identifiability_report`,
step 4)."""

from __future__ import annotations

import numpy as np

from heli_uq.errors import ParameterError
from heli_uq.identifiability.structural import ParameterVector

__all__ = ["draws_in_w", "contraction", "sampled_prior_cov", "MIN_PRIOR_DRAWS"]

#: Fewest finite prior draws whose covariance measures a posterior's contraction (the
#: variance of 200 draws has a relative error of 0.1, against CONTRACTION_WIDER's 0.25).
MIN_PRIOR_DRAWS = 200


def draws_in_w(posterior, pv: ParameterVector, source: str = "posterior") -> np.ndarray:
    """Draws of ``w`` from a posterior group (xarray Dataset), shape (S, P).

    Raises
    ------
    ParameterError
        If the posterior lacks a coordinate of ``w``.
    """
    for n in pv.names:
        if n not in posterior:
            raise ParameterError(f"{source}: posterior has no variable {n!r} (free here); rerun "
                                 f"with free parameters matching the posterior's")  # fmt: skip
    return _columns(posterior, pv, pv.names)


def _columns(group, pv: ParameterVector, names) -> np.ndarray:
    """Draws of the coordinates ``names`` of ``w`` (their ``log`` where ``w`` takes it), (S, len)."""
    cols = []
    for n in names:
        v = np.asarray(group[n], dtype=float).reshape(-1)
        with np.errstate(divide="ignore", invalid="ignore"):  # a draw at 0: -inf, dropped by callers
            cols.append(np.log(v) if pv.is_log(n) else v)
    return np.column_stack(cols)


def contraction(cov_post: np.ndarray, prior_sd: np.ndarray, directions=(), *,
                prior_cov: np.ndarray | None = None) -> tuple:  # fmt: skip
    """Per-coordinate ``1 - var_post / var_prior`` and the same along unit ``directions``.

    ``prior_cov`` (P, P): the prior's covariance in ``w``, e.g. of a posterior file's prior
    draws (the joint prior its sampler used); default ``diag(prior_sd**2)``, the declared
    priors taken one by one."""
    prior_cov = np.diag(prior_sd**2) if prior_cov is None else np.asarray(prior_cov)
    per = 1.0 - np.diag(cov_post) / np.diag(prior_cov)
    along = [1.0 - float(v @ cov_post @ v) / float(v @ prior_cov @ v) for v in directions]
    return per, along


def sampled_prior_cov(prior_group, pv: ParameterVector, prior_sd: np.ndarray):
    """The prior covariance (P, P) in ``w`` that a posterior file was sampled under, or None.

    The model parameters' block is the covariance of the file's ``prior`` group; the
    coordinates that group lacks (the initial state, whose prior is not drawn there) keep
    their declared variances ``prior_sd**2`` (P,), uncorrelated with the rest.  None when
    the group holds none of the coordinates, or fewer than :data:`MIN_PRIOR_DRAWS` finite
    draws of them.

    The sampler's prior is not the declared priors taken one by one: the common scale of
    the inertia-scaled parameters has its own prior, as wide as one parameter's, and the
    scaled parameters' priors are taken at its mean (README, "Posterior"), so an effect
    level's SI prior is far wider in ``log`` than its declaration.  A posterior's
    contraction is measured against the prior it was sampled under."""
    have = [j for j, n in enumerate(pv.names) if n in prior_group]
    if not have:
        return None
    draws = _columns(prior_group, pv, [pv.names[j] for j in have])
    draws = draws[np.all(np.isfinite(draws), axis=1)]
    if draws.shape[0] < MIN_PRIOR_DRAWS:
        return None
    cov = np.diag(np.asarray(prior_sd, dtype=float) ** 2)
    cov[np.ix_(have, have)] = np.atleast_2d(np.cov(draws, rowvar=False))
    return cov
