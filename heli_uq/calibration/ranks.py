"""Rank statistics of SBC replicates: the expected rank-bin probabilities, the chi-square
test of uniform ranks, and the 90 % coverage per coordinate and by noise level.

Layer 8 (imports only numpy, scipy and the noise-level constant of the priors).
"""

from __future__ import annotations

import numpy as np
from numpyro.diagnostics import effective_sample_size
from scipy import stats

from heli_uq.errors import ParameterError
from heli_uq.probability.priors import X0_ANGLE_SD

__all__ = ["rank_bins", "pooled_rank_counts", "thinned_ranks", "rank_covered", "expected_rank_coverage",
           "expected_interval_coverage", "summarise", "RANK_BINS"]  # fmt: skip

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


def pooled_rank_counts(reps: list[dict], name: str, bins: int = RANK_BINS) -> tuple[np.ndarray, np.ndarray]:
    """``(counts, expected)`` of the truth's rank of ``name`` over the replicates, each
    replicate's rank binned on its own ``0..L`` (``L`` varies when draws are thinned to
    their ESS) into ``min(bins, smallest L + 1)`` bins; ``expected``: the counts of
    uniform ranks.  The chi-square test and the figure use both."""
    bins = min([bins] + [r["L"] + 1 for r in reps])
    counts, expected = np.zeros(bins), np.zeros(bins)
    for r in reps:
        edges, prob = rank_bins(r["L"], bins)
        counts += np.histogram([r["ranks"][name]], edges)[0]
        expected += prob
    return counts, expected


def thinned_ranks(draws: np.ndarray, truth: np.ndarray, max_ranks: int, *, thin_to_ess: bool = True):
    """Ranks of the truth among (thinned) posterior draws.

    Parameters
    ----------
    draws : ndarray, shape (chains, n, d)
    truth : ndarray, shape (d,)
    max_ranks : int
        Most draws ranked among.
    thin_to_ess : bool
        Keep every ``ceil(chains n / min ESS)``-th draw (Talts et al. 2018): ranks among
        autocorrelated draws are not uniform even for a calibrated posterior.

    Returns
    -------
    ranks : ndarray of int, shape (d,)
        Number of kept draws below the truth, ``0..L``.
    big_l : int
        Draws ranked among.
    thin : int
    ess : ndarray, shape (d,)
        Effective sample size of each coordinate's draws (numpyro's estimate; the number
        of draws where that estimate is not positive).
    """
    draws = np.asarray(draws, dtype=float)
    flat = draws.reshape(-1, draws.shape[-1])
    ess = np.asarray(effective_sample_size(draws), dtype=float).reshape(-1)
    # numpyro's estimate turns negative for strongly anti-correlated draws (the summed
    # autocorrelations go below -1/2): they need no thinning, so count them as independent
    ess = np.where(np.isfinite(ess) & (ess > 0), ess, float(flat.shape[0]))
    thin = max(1, flat.shape[0] // max_ranks)
    if thin_to_ess:
        thin = max(thin, int(np.ceil(flat.shape[0] / max(float(np.min(ess)), 1.0))))
    kept = flat[::thin][:max_ranks]
    return np.sum(kept < np.asarray(truth)[None], axis=0), int(kept.shape[0]), thin, ess


def rank_covered(rank: int, big_l: int, level: float = 0.9) -> bool:
    """Whether the truth's rank among ``big_l`` draws lies in the central ``level`` of the
    ``big_l + 1`` possible ranks: ``k <= rank <= big_l - k`` with
    ``k = floor((big_l + 1) (1 - level) / 2)``.

    For a calibrated posterior with independent draws the rank is uniform, so this holds
    with probability ``(big_l + 1 - 2 k) / (big_l + 1)`` (exactly ``level`` when
    ``(big_l + 1) (1 - level) / 2`` is an integer, e.g. 99 draws at 90 %), whatever the
    number of draws.  The empirical quantile interval of the draws covers less
    (:func:`expected_interval_coverage`).
    """
    k = int(np.floor((big_l + 1) * (1 - level) / 2 + 1e-9))
    return bool(k <= rank <= big_l - k)


def expected_rank_coverage(big_l: int, level: float = 0.9) -> float:
    """Probability that :func:`rank_covered` holds for a uniform rank on ``0..big_l``:
    ``(big_l + 1 - 2 k) / (big_l + 1)``, ``level`` or more (1 for ``big_l < 19`` at 0.9,
    where no rank is outside the central 90 %)."""
    k = int(np.floor((big_l + 1) * (1 - level) / 2 + 1e-9))
    return (big_l + 1 - 2 * k) / (big_l + 1)


def expected_interval_coverage(n: int, level: float = 0.9) -> float:
    """Expected coverage of the interval between the ``(1 -+ level) / 2`` empirical
    quantiles (``numpy.quantile``, linear interpolation) of ``n`` independent posterior
    draws, for a calibrated posterior: ``(n - 1) level / (n + 1)``.

    (The quantile at ``p`` sits at order statistic ``1 + (n - 1) p``, and ``E F(X_(k)) =
    k / (n + 1)``.)  100 draws give 0.882 at level 0.9, not 0.9; autocorrelated draws
    give less still.
    """
    return (n - 1) * level / (n + 1)


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
        interval of the draws covers the truth), ``coverage90_rank`` (fraction whose rank
        lies in the central 90 % of ranks, :func:`rank_covered`; exactly 90 % for a
        calibrated posterior when every ``L + 1`` is a multiple of 20, more otherwise:
        ``coverage90_rank_expected`` is its expectation over the replicates' ``L``,
        :func:`expected_rank_coverage`), ``chi2_pvalue`` (chi-square test of uniform ranks over ``bins`` bins;
        each replicate's rank binned on its own ``0..L``) and, when recorded,
        ``ess_median``; the coverage averaged over the quantities overall
        (``coverage90_mean_over_quantities``) and split by the noise level
        (``coverage90_sigma_below_x0_sd`` / ``..._above_...``: replicates with
        ``sigma < X0_ANGLE_SD`` or not; interval and rank coverage),
        ``coverage90_interval_expected_iid`` (:func:`expected_interval_coverage` for the
        draws of one replicate, when the settings are recorded), and sampler statistics
        (``divergences_total``,
        ``mean_steps``, ``wall_s_mean`` [s], ``step_size_mean``, ``map_grad_max_max``).
    """
    if not reps:
        raise ParameterError("summarise: no replicates")
    names = reps[0]["names"]
    n = len(reps)
    summary = {"replicates": n, "L": min(r["L"] for r in reps), "quantities": {},
               "coverage90_rank_expected": float(np.mean([expected_rank_coverage(r["L"]) for r in reps]))}
    for name in names:
        counts, expected = pooled_rank_counts(reps, name, bins)
        entry = {"coverage90": float(np.mean([r["covered90"][name] for r in reps])),
                 "coverage90_rank": float(np.mean([rank_covered(r["ranks"][name], r["L"]) for r in reps])),
                 "chi2_pvalue": float(stats.chisquare(counts, expected).pvalue)}  # fmt: skip
        if all("ess" in r for r in reps):
            entry["ess_median"] = float(np.median([r["ess"][name] for r in reps]))
        summary["quantities"][name] = entry

    def mean_cov(group, rank=False):
        if not group:
            return None
        if rank:
            return float(np.mean([[rank_covered(r["ranks"][q], r["L"]) for q in names] for r in group]))
        return float(np.mean([[r["covered90"][q] for q in names] for r in group]))

    # Split by noise level: with x0_prior="data" the model centres the initial-angle prior
    # on the first (noisy) measurement and the generator does not, so the two priors differ
    # when sigma is not small next to X0_ANGLE_SD.
    low = [r for r in reps if r["sigma"] < X0_ANGLE_SD]
    high = [r for r in reps if r["sigma"] >= X0_ANGLE_SD]
    for label, group in (("sigma_below_x0_sd", low), ("sigma_above_x0_sd", high)):
        summary[f"coverage90_{label}"] = {
            "replicates": len(group), "mean_over_quantities": mean_cov(group),
            "rank_mean_over_quantities": mean_cov(group, rank=True)}  # fmt: skip
    summary["coverage90_mean_over_quantities"] = mean_cov(reps)
    summary["coverage90_rank_mean_over_quantities"] = mean_cov(reps, rank=True)
    settings = reps[0].get("settings") or {}
    if "chains" in settings and "draws" in settings:
        summary["coverage90_interval_expected_iid"] = expected_interval_coverage(
            settings["chains"] * settings["draws"])
    summary["divergences_total"] = int(sum(r["divergences"] for r in reps))
    summary["mean_steps"] = float(np.mean([r["mean_steps"] for r in reps]))
    summary["wall_s_mean"] = float(np.mean([r["wall_s"] for r in reps]))
    summary["step_size_mean"] = float(np.mean([np.mean(r.get("step_size", np.nan)) for r in reps]))
    summary["map_grad_max_max"] = float(max(r.get("map_grad_max", np.nan) for r in reps))
    summary["settings"] = reps[0].get("settings")
    return summary
