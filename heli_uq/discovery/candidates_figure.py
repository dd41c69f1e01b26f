"""``candidates.png`` of a discovery run: each candidate's held-out score against the
current model, per held-out sample, with its uncertainty and the decision margin (a
candidate the white-residual screen left out listed below, without a bar), and
beside it the CRPS gain (:func:`heli_uq.discovery.score.block_crps`), so a candidate the
two proper scores disagree on stands out.  The panel of the score that decided
(``discover(score=...)``) carries the pass colours."""

from __future__ import annotations

import numpy as np

from heli_uq.discovery.score import MARGIN_CRPS_FRACTION, MARGIN_PER_SAMPLE
from heli_uq.figure import new_figure

__all__ = ["candidates_figure"]

#: The pass colours' key (the deciding panel's title).
KEY = ("green: passes the margin and the fitting window supports it;\n"
       "orange: passes, not supported; grey: does not pass")


def candidates_figure(cands: list[dict], n_scored: int, criterion: str = "log"):
    """Held-out score per sample of each candidate against the current model, ± 2 SE;
    scores far below zero are cut at the left edge (hatched, value written).

    ``cands``: the ``candidates`` rows of ``discovery.json`` (``score``, ``score_se`` [nats],
    ``step``, ``effect``, ``axis``, ``passes``, ``supported``, ``tied``, ``chosen_by``, and
    ``crps_gain``, ``crps_gain_se`` [rad], ``crps_gain_fraction`` where stored);
    ``n_scored``: held-out samples; ``criterion``: the score that decided (``"log"`` or
    ``"crps"``), whose panel is coloured by ``passes``.  Returns the matplotlib figure (a
    second panel for the CRPS gain when any row has one).
    """
    ok = [c for c in cands if c.get("score") is not None and np.isfinite(c["score"])]
    skipped = [c for c in cands if c.get("skipped")]  # listed at the bottom, without a bar
    with_crps = any(c.get("crps_gain") is not None for c in ok)
    fig = new_figure((14.0 if with_crps else 10.0, 1.5 + 0.3 * max(len(ok) + len(skipped), 1)))
    if with_crps:
        ax, ax_crps = fig.subplots(1, 2, sharey=True, gridspec_kw={"width_ratios": (3, 2)})
    else:
        ax = fig.add_subplot(1, 1, 1)
    def label(c):
        tags = [t for t, on in (("tied", c.get("tied")),
                                ("chosen by evidence", c.get("chosen_by"))) if on]
        return f"step {c['step']}: {c['effect']} ({c['axis']})" + (f" [{', '.join(tags)}]" if tags else "")

    labels = [label(c) for c in ok][::-1]
    x = np.asarray([c["score"] for c in ok][::-1]) / n_scored
    err = 2 * np.asarray([c["score_se"] for c in ok][::-1]) / n_scored
    # the right edge from the bars shown whole (a cut bar's huge SE once stretched it to
    # +13 nats per sample and hid every bar near the margin)
    right = max(float(np.max((x + err)[x > -1.0], initial=0.0)), 5 * MARGIN_PER_SAMPLE)
    left = -max(right, 1.0)
    shown = np.clip(x, left, None)
    y = np.arange(len(ok)) + len(skipped)
    colors = ["C2" if c.get("passes") and c.get("supported", True) else "C1" if c.get("passes") else "0.6"
              for c in ok][::-1]
    by_crps = criterion == "crps" and with_crps
    bars = ax.barh(y, shown, color="C0" if by_crps else colors, alpha=0.8 if by_crps else 1.0)
    ax.errorbar(np.clip(x, left, None), y, xerr=np.where(x > left, err, 0), fmt="none", ecolor="k",
                capsize=2)  # fmt: skip
    for bar, value, cut in zip(bars, x, x < left):
        if cut:
            bar.set_hatch("//")
            ax.text(left, bar.get_y() + bar.get_height() / 2, f" {value:.3g}", va="center",
                    fontsize="x-small")  # fmt: skip
    for yi, c in enumerate(skipped[::-1]):
        ax.text(left, yi, " not fitted: the base model's residuals are white on its axes",
                va="center", fontsize="x-small", color="0.4")  # fmt: skip
    ax.set_yticks(np.arange(len(skipped) + len(ok)), [label(c) for c in skipped[::-1]] + labels,
                  fontsize="small")  # fmt: skip
    ax.set_ylim(-0.6, len(skipped) + len(ok) - 0.4)
    ax.axvline(0, color="k", lw=0.8)
    ax.axvline(MARGIN_PER_SAMPLE, color="C3", ls="--", lw=0.8,
               label=f"margin {MARGIN_PER_SAMPLE} nats/sample")  # fmt: skip
    ax.set_xlim(left * 1.05, right * 1.05)
    ax.set_xlabel("held-out log predictive density minus the current model's,\nper sample [nats] "
                  "(± 2 SE)")  # fmt: skip
    if by_crps:
        ax.set_title("Candidate effects, log density (reported; the CRPS decides);\nhatched: cut at the left "
                     "edge", loc="left", fontsize="medium")  # fmt: skip
    else:
        ax.set_title(f"Candidate effects ({KEY};\nhatched: cut at the left edge)", loc="left",
                     fontsize="medium")  # fmt: skip
    ax.legend(loc="lower right", fontsize="small")
    ax.grid(True, axis="x", alpha=0.4)
    if with_crps:
        _crps_panel(ax_crps, ok[::-1], n_scored, y, colors if by_crps else None)
    fig.tight_layout()
    return fig


def _crps_panel(ax, rows: list[dict], n_scored: int, y: np.ndarray, colors=None) -> None:
    """The CRPS gain per sample of ``rows`` (in plotting order) at heights ``y``, ± 2 SE,
    each row's margin (:data:`MARGIN_CRPS_FRACTION` of its current model's CRPS) a red
    tick; a row without one (a fit stored before the CRPS was kept) is marked "–".
    ``colors``: the bars' pass colours when the CRPS decided."""
    has = np.asarray([r.get("crps_gain") is not None for r in rows])
    gain = np.asarray([r["crps_gain"] if h else 0.0 for r, h in zip(rows, has)]) / n_scored
    err = 2 * np.asarray([r["crps_gain_se"] if h else 0.0 for r, h in zip(rows, has)]) / n_scored
    # the reference's CRPS per sample is the gain over its fraction
    fraction = np.asarray([r.get("crps_gain_fraction") or 0.0 if h else 0.0 for r, h in zip(rows, has)])
    known = has & (fraction != 0)
    margin = MARGIN_CRPS_FRACTION * gain[known] / fraction[known]
    scale, unit = _readable_unit(np.concatenate([np.abs(gain) + np.abs(err), np.abs(margin)]))
    gain, err, margin = gain * scale, err * scale, margin * scale
    shade = "C0" if colors is None else np.asarray(colors, dtype=object)[has].tolist()
    ax.barh(y[has], gain[has], color=shade, alpha=0.8 if colors is None else 1.0)
    ax.errorbar(gain[has], y[has], xerr=err[has], fmt="none", ecolor="k", capsize=2)
    if known.any():
        ax.plot(margin, y[known], "|", color="C3", ms=10, mew=1.5, label="margin")
    for yi in y[~has]:
        ax.text(0, yi, " –", va="center", fontsize="x-small")
    ax.axvline(0, color="k", lw=0.8)
    ax.set_xlabel("held-out CRPS of the current model minus\nthe candidate's, per sample "
                  f"[{unit}] (± 2 SE);\n"
                  f"red ticks: the margin, {MARGIN_CRPS_FRACTION:.1%} of the current CRPS")
    if colors is None:
        ax.set_title("CRPS gain (a second proper score;\nreported, does not decide)", loc="left",
                     fontsize="medium")  # fmt: skip
    else:
        ax.set_title(f"CRPS gain, which decides\n({KEY})", loc="left", fontsize="small")
    from matplotlib.ticker import MaxNLocator

    ax.xaxis.set_major_locator(MaxNLocator(nbins=4))  # the panel is narrow: 5-digit labels overlap
    ax.grid(True, axis="x", alpha=0.4)


#: Units the CRPS panel may be drawn in, as (factor from rad, name).
_ANGLE_UNITS = ((1.0, "rad"), (1e3, "mrad"), (1e6, "µrad"))


def _readable_unit(extent: np.ndarray) -> tuple[float, str]:
    """The largest of :data:`_ANGLE_UNITS` in which the panel's largest extent [rad] is at
    least 0.1, so its tick labels need no offset or exponent (a "1e-5" over the axis
    collided with the panel's label)."""
    top = float(np.max(extent, initial=0.0))
    return next((u for u in _ANGLE_UNITS if top * u[0] >= 0.1), _ANGLE_UNITS[-1])
