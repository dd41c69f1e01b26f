"""``candidates.png`` of a discovery run: each candidate's held-out score against the
current model, per held-out sample, with its uncertainty and the decision margin, and
beside it the CRPS gain (:func:`heli_uq.discovery.score.block_crps`; reported, it does not
decide), so a candidate the two proper scores disagree on stands out."""

from __future__ import annotations

import numpy as np

from heli_uq.discovery.score import MARGIN_PER_SAMPLE
from heli_uq.figure import new_figure

__all__ = ["candidates_figure"]


def candidates_figure(cands: list[dict], n_scored: int):
    """Held-out score per sample of each candidate against the current model, ± 2 SE;
    scores far below zero are cut at the left edge (hatched, value written).

    ``cands``: the ``candidates`` rows of ``discovery.json`` (``score``, ``score_se`` [nats],
    ``step``, ``effect``, ``axis``, ``passes``, ``supported``, ``tied``, ``chosen_by``, and
    ``crps_gain``, ``crps_gain_se`` [rad] where stored); ``n_scored``: held-out samples.
    Returns the matplotlib figure (a second panel for the CRPS gain when any row has one).
    """
    ok = [c for c in cands if c.get("score") is not None and np.isfinite(c["score"])]
    with_crps = any(c.get("crps_gain") is not None for c in ok)
    fig = new_figure((14.0 if with_crps else 10.0, 1.5 + 0.3 * max(len(ok), 1)))
    if with_crps:
        ax, ax_crps = fig.subplots(1, 2, sharey=True, gridspec_kw={"width_ratios": (3, 2)})
    else:
        ax = fig.add_subplot(1, 1, 1)
    def label(c):
        tags = [t for t, on in (("tied", c.get("tied")), ("chosen by the fit window", c.get("chosen_by")))
                if on]  # fmt: skip
        return f"step {c['step']}: {c['effect']} ({c['axis']})" + (f" [{', '.join(tags)}]" if tags else "")

    labels = [label(c) for c in ok][::-1]
    x = np.asarray([c["score"] for c in ok][::-1]) / n_scored
    err = 2 * np.asarray([c["score_se"] for c in ok][::-1]) / n_scored
    # the right edge from the bars shown whole (a cut bar's huge SE once stretched it to
    # +13 nats per sample and hid every bar near the margin)
    right = max(float(np.max((x + err)[x > -1.0], initial=0.0)), 5 * MARGIN_PER_SAMPLE)
    left = -max(right, 1.0)
    shown = np.clip(x, left, None)
    y = np.arange(len(ok))
    colors = ["C2" if c.get("passes") and c.get("supported", True) else "C1" if c.get("passes") else "0.6"
              for c in ok][::-1]
    bars = ax.barh(y, shown, color=colors)
    ax.errorbar(np.clip(x, left, None), y, xerr=np.where(x > left, err, 0), fmt="none", ecolor="k",
                capsize=2)  # fmt: skip
    for bar, value, cut in zip(bars, x, x < left):
        if cut:
            bar.set_hatch("//")
            ax.text(left, bar.get_y() + bar.get_height() / 2, f" {value:.3g}", va="center",
                    fontsize="x-small")  # fmt: skip
    ax.set_yticks(y, labels, fontsize="small")
    ax.axvline(0, color="k", lw=0.8)
    ax.axvline(MARGIN_PER_SAMPLE, color="C3", ls="--", lw=0.8,
               label=f"margin {MARGIN_PER_SAMPLE} nats/sample")  # fmt: skip
    ax.set_xlim(left * 1.05, right * 1.05)
    ax.set_xlabel("held-out log predictive density minus the current model's,\nper sample [nats] "
                  "(± 2 SE)")  # fmt: skip
    ax.set_title("Candidate effects (green: passes the margin and the fitting window supports it;\n"
                 "orange: passes, not supported; grey: does not pass; hatched: cut at the left edge)",
                 loc="left", fontsize="medium")
    ax.legend(loc="lower right", fontsize="small")
    ax.grid(True, axis="x", alpha=0.4)
    if with_crps:
        _crps_panel(ax_crps, ok[::-1], n_scored, y)
    fig.tight_layout()
    return fig


def _crps_panel(ax, rows: list[dict], n_scored: int, y: np.ndarray) -> None:
    """The CRPS gain per sample of ``rows`` (in plotting order) at heights ``y``, ± 2 SE;
    a row without one (a fit stored before the CRPS was kept) is marked "–"."""
    has = np.asarray([r.get("crps_gain") is not None for r in rows])
    gain = np.asarray([r["crps_gain"] if h else 0.0 for r, h in zip(rows, has)]) / n_scored
    err = 2 * np.asarray([r["crps_gain_se"] if h else 0.0 for r, h in zip(rows, has)]) / n_scored
    ax.barh(y[has], gain[has], color="C0", alpha=0.8)
    ax.errorbar(gain[has], y[has], xerr=err[has], fmt="none", ecolor="k", capsize=2)
    for yi in y[~has]:
        ax.text(0, yi, " –", va="center", fontsize="x-small")
    ax.axvline(0, color="k", lw=0.8)
    ax.set_xlabel("held-out CRPS of the current model minus the candidate's,\nper sample [rad] (± 2 SE)")
    ax.set_title("CRPS gain (a second proper score;\nreported, does not decide)", loc="left",
                 fontsize="medium")  # fmt: skip
    ax.grid(True, axis="x", alpha=0.4)
