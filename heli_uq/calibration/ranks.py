"""Rank statistics of SBC replicates: the expected rank-bin probabilities, the chi-square
test of uniform ranks, and the 90 % coverage per coordinate and by noise level.

Layer 8 (imports only numpy, scipy and the noise-level constant of the priors).
"""

from __future__ import annotations

import numpy as np
from scipy import stats

from heli_uq.probability.priors import X0_ANGLE_SD

__all__ = ["rank_bins", "summarise", "RANK_BINS"]

#: Bins of the rank histograms (chi-square test and figure).
RANK_BINS = 10


def rank_bins(big_l: int, bins: int = RANK_BINS) -> tuple[np.ndarray, np.ndarray]:
    """Histogram edges of ranks ``0..big_l`` and the probability of each bin under uniform
    ranks (exact also when ``big_l + 1`` is not a multiple of ``bins``).

    Returns
    -------
    edges : ndarray, shape (bins + 1,)
    prob : ndarray, shape (bins,)
        Sums to 1.
    """
    bins = min(bins, big_l + 1)
    edges = np.linspace(0, big_l + 1, bins + 1)
    prob = np.histogram(np.arange(big_l + 1), edges)[0] / (big_l + 1)
    return edges, prob


def summarise(reps: list[dict], bins: int = RANK_BINS) -> dict:
    """Coverage and rank uniformity of SBC replicates.

    Parameters
    ----------
    reps : list of dict
        Replicates (:func:`run_replicate`), all with the same ``names``.
    bins : int
        Rank histogram bins of the chi-square test.

    Returns
    -------
    dict
        ``replicates``, ``L`` (smallest of the replicates; larger ranks are clipped to it),
        ``quantities``: name -> ``coverage90`` (fraction of replicates whose central 90 %
        interval covers the truth) and ``chi2_pvalue`` (chi-square test of uniform ranks
        over ``bins`` bins), the coverage averaged over the quantities overall
        (``coverage90_mean_over_quantities``) and split by the noise level
        (``coverage90_sigma_below_x0_sd`` / ``..._above_...``: replicates with
        ``sigma < X0_ANGLE_SD`` or not), and sampler statistics (``divergences_total``,
        ``mean_steps``, ``wall_s_mean`` [s], ``step_size_mean``, ``map_grad_max_max``).
    """
    if not reps:
        raise ParameterError("summarise: no replicates")
    names = reps[0]["names"]
    big_l = min(r["L"] for r in reps)
    n = len(reps)
    edges, prob = rank_bins(big_l, bins)
    summary = {"replicates": n, "L": big_l, "quantities": {}}
    for name in names:
        ranks = np.array([min(r["ranks"][name], big_l) for r in reps])
        counts = np.histogram(ranks, edges)[0]
        p = stats.chisquare(counts, n * prob).pvalue
        cov = float(np.mean([r["covered90"][name] for r in reps]))
        summary["quantities"][name] = {"coverage90": cov, "chi2_pvalue": float(p)}

    def mean_cov(group):
        return float(np.mean([[r["covered90"][q] for q in names] for r in group])) if group else None

    # Split by noise level: with x0_prior="data" the model centres the initial-angle prior
    # on the first (noisy) measurement and the generator does not, so the two priors differ
    # when sigma is not small next to X0_ANGLE_SD.
    low = [r for r in reps if r["sigma"] < X0_ANGLE_SD]
    high = [r for r in reps if r["sigma"] >= X0_ANGLE_SD]
    for label, group in (("sigma_below_x0_sd", low), ("sigma_above_x0_sd", high)):
        summary[f"coverage90_{label}"] = {"replicates": len(group), "mean_over_quantities": mean_cov(group)}
    summary["coverage90_mean_over_quantities"] = mean_cov(reps)
    summary["divergences_total"] = int(sum(r["divergences"] for r in reps))
    summary["mean_steps"] = float(np.mean([r["mean_steps"] for r in reps]))
    summary["wall_s_mean"] = float(np.mean([r["wall_s"] for r in reps]))
    summary["step_size_mean"] = float(np.mean([np.mean(r.get("step_size", np.nan)) for r in reps]))
    summary["map_grad_max_max"] = float(max(r.get("map_grad_max", np.nan) for r in reps))
    summary["settings"] = reps[0].get("settings")
    return summary
