"""The SBC rank histograms (one panel per ranked coordinate, with the 99 % band of
uniform ranks)."""

from __future__ import annotations

import numpy as np
from scipy import stats

from heli_uq.calibration.ranks import RANK_BINS, rank_bins
from heli_uq.figure import new_figure, save_figure

__all__ = ["plot_ranks"]

#: Two-sided probability of the grey band of each histogram bin under uniform ranks.
BAND = 0.99


def plot_ranks(reps: list[dict], path, bins: int = RANK_BINS):
    """Rank histograms of SBC replicates, written as a PNG to ``path``.

    Parameters
    ----------
    reps : list of dict
        Replicates (:func:`heli_uq.calibration.sbc.run_replicate`), same ``names``.
    path : path
        Destination ``.png`` (its directory is created).
    bins : int
        Histogram bins over ranks ``0..L``.

    Returns
    -------
    pathlib.Path
        The written figure.
    """
    import pathlib

    names = reps[0]["names"]
    big_l = min(r["L"] for r in reps)
    n = len(reps)
    edges, prob = rank_bins(big_l, bins)
    tail = (1 - BAND) / 2
    lo, hi = stats.binom.ppf([tail, 1 - tail], n, prob.mean())
    cols = 4
    rows = -(-len(names) // cols)
    fig = new_figure((3.2 * cols, 2.4 * rows))
    axes = fig.subplots(rows, cols, squeeze=False)
    for ax, name in zip(axes.flat, names):
        ranks = np.array([min(r["ranks"][name], big_l) for r in reps])
        ax.axhspan(lo, hi, color="0.85", label=f"{BAND:.0%} band (uniform)")
        ax.axhline(n * prob.mean(), color="0.5", lw=0.8)
        ax.hist(ranks, bins=edges, color="C0", edgecolor="white", label="rank of truth")
        ax.set_title(name, fontsize=9)
        ax.set_xlabel(f"rank among {big_l} draws")
        ax.set_ylabel("replicates")
        cov = float(np.mean([r["covered90"][name] for r in reps]))
        ax.text(0.02, 0.95, f"90% cov {cov:.0%}", transform=ax.transAxes, fontsize=8, va="top")
    spare = list(axes.flat)[len(names):]
    for ax in spare:
        ax.axis("off")
    handles, labels = axes.flat[0].get_legend_handles_labels()
    if spare:
        spare[0].legend(handles, labels, fontsize=8, loc="center")
    else:
        axes.flat[0].legend(fontsize=7, loc="lower left")
    st = reps[0].get("settings") or {}
    fig.suptitle(f"SBC: ranks of the true coordinates, {n} synthetic {st.get('duration', '?')} s "
                 f"records (x0 prior: {st.get('x0_prior', 'data')}; grey: {BAND:.0%} band of "
                 f"uniform ranks)", fontsize=11)  # fmt: skip
    fig.tight_layout()
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    return save_figure(fig, path)
