"""The SBC rank histograms (one panel per ranked coordinate, with the 99 % band of
uniform ranks)."""

from __future__ import annotations

import numpy as np
from scipy import stats

from heli_uq.calibration.ranks import RANK_BINS, pooled_rank_counts
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
        Histogram bins over ranks ``0..L`` (fewer when a replicate ranks among fewer
        draws: :func:`~heli_uq.calibration.ranks.pooled_rank_counts`).

    Returns
    -------
    pathlib.Path
        The written figure.
    """
    import pathlib

    names = reps[0]["names"]
    ls = sorted({r["L"] for r in reps})
    n = len(reps)
    tail = (1 - BAND) / 2
    cols = 4
    rows = -(-len(names) // cols)
    fig = new_figure((3.2 * cols, 2.4 * rows))
    axes = fig.subplots(rows, cols, squeeze=False)
    for ax, name in zip(axes.flat, names):
        # each replicate's rank binned on its own 0..L, as the chi-square test does
        counts, expected = pooled_rank_counts(reps, name, bins)
        x = (np.arange(counts.size) + 0.5) / counts.size
        lo, hi = stats.binom.ppf(np.array([[tail], [1 - tail]]), n, expected / n)
        ax.bar(x, hi - lo, bottom=lo, width=1.0 / counts.size, color="0.85",
               label=f"{BAND:.0%} band (uniform)")  # fmt: skip
        ax.step(np.r_[0.0, x + 0.5 / counts.size], np.r_[expected[0], expected], color="0.5", lw=0.8)
        ax.bar(x, counts, width=0.9 / counts.size, color="C0", label="rank of truth")
        ax.set_title(name, fontsize=9)
        ax.set_xlim(0.0, 1.0)
        ax.set_xlabel("rank / (L + 1)" + (f", L = {ls[0]}" if len(ls) == 1 else f", L = {ls[0]}..{ls[-1]}"))
        ax.set_ylabel("replicates")
        cov = float(np.mean([r["covered90"][name] for r in reps]))
        ax.text(0.02, 0.95, f"90% cov {cov:.0%}", transform=ax.transAxes, fontsize=8, va="top", zorder=5,
                bbox={"facecolor": "white", "alpha": 0.8, "linewidth": 0})  # fmt: skip
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
