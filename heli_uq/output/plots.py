"""Figures in the style of the paper: simulated trajectories (Figs. 4-6), records (Figs. 9-10).

Every plotting function takes arrays (or an :class:`~heli_uq.data.Experiment`) and returns
a :class:`matplotlib.figure.Figure`.  Figures are built without :mod:`matplotlib.pyplot`
and rendered with the Agg canvas, so importing this module never changes the user's
backend (it works headless, in scripts and in notebooks).  Write a figure with
:func:`heli_uq.figure.save_figure`.

Angles are shown in degrees; everything else in SI units.
"""

from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from heli_uq.figure import new_figure, save_figure

__all__ = ["plot_simulation", "plot_experiment", "plot_bands", "save_figure"]

#: Characters of a figure title per inch of figure width: the default 12 pt title font
#: averages about 12 per inch (a 150-character title overflowed an 11 inch figure a
#: little); the margin covers wide glyphs.
TITLE_CHARS_PER_INCH = 10.0
_THETA_COLOR = "C0"
_PSI_COLOR = "C1"


def _new_figure(nrows: int, figsize: tuple[float, float]):
    fig = new_figure(figsize)
    axes = fig.subplots(nrows, 1, sharex=True, squeeze=False)[:, 0]
    return fig, axes


def _legend(ax) -> None:
    # Outside the axes on the right: never hides data, and avoids loc="best", which is
    # slow (and warns) for long records.
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0, fontsize="small")


def _wrap_title(fig, title: str) -> str:
    """``title`` with each line broken at spaces to fit the figure's width (a model label
    and a file name can be longer than the figure)."""
    width = max(int(fig.get_figwidth() * TITLE_CHARS_PER_INCH), 20)
    return "\n".join(textwrap.fill(line, width, break_on_hyphens=False) for line in title.split("\n"))


def _finish(fig, axes, title: str | None) -> None:
    for ax in axes:
        ax.grid(True, alpha=0.4)
    axes[-1].set_xlabel("time $t$ [s]")
    if title:
        fig.suptitle(_wrap_title(fig, title))
    fig.tight_layout()


def _pair_panel(ax, t, values, labels, ylabel: str, title: str, **style) -> None:
    """Plot the pitch (column 0) and yaw (column 1) series of ``values`` on one axis."""
    for j, (label, color) in enumerate(zip(labels, (_THETA_COLOR, _PSI_COLOR), strict=True)):
        ax.plot(t, values[:, j], color=color, label=label, **style)
    ax.set_ylabel(ylabel)
    ax.set_title(title, loc="left", fontsize="medium")


def _as_2col(name: str, arr, n: int) -> np.ndarray:
    arr = np.asarray(arr, dtype=float)
    if arr.ndim != 2 or arr.shape[0] != n or arr.shape[1] < 2:
        raise ValueError(f"{name}: expected shape ({n}, 2) or ({n}, 4), found {arr.shape}")
    return arr


#: An angle axis is clipped when what is drawn goes beyond the data's range widened by this
#: fraction of it on either side (a blow-up, not a model that drifts off the data)...
CLIP_TRIGGER = 1.0
#: ...and then shows the data's range widened by this fraction of it on each side.
CLIP_MARGIN = 0.25


def _keep_data_readable(ax, data_deg, drawn_deg, note: str = "") -> bool:
    """Clip ``ax``'s y range to the data (``data_deg``, any shape) widened by
    :data:`CLIP_MARGIN` when what is drawn (``drawn_deg``) leaves the data's range widened
    by :data:`CLIP_TRIGGER`, and say so in the axes (with ``note``).  Returns whether it
    clipped."""
    data = np.asarray(data_deg, dtype=float)
    data = data[np.isfinite(data)]
    drawn = np.asarray(drawn_deg, dtype=float)
    drawn = drawn[np.isfinite(drawn)]
    if data.size == 0 or drawn.size == 0:
        return False
    lo, hi = float(data.min()), float(data.max())
    span = max(hi - lo, 1.0)
    if drawn.min() >= lo - CLIP_TRIGGER * span and drawn.max() <= hi + CLIP_TRIGGER * span:
        return False
    ax.set_ylim(lo - CLIP_MARGIN * span, hi + CLIP_MARGIN * span)
    text = "axis clipped to the data's range; the model leaves it" + (f" ({note})" if note else "")
    ax.text(0.01, 0.02, text, transform=ax.transAxes, fontsize="small", color="firebrick",
            bbox={"facecolor": "white", "alpha": 0.8, "linewidth": 0})
    return True


def plot_simulation(ts, ys, momenta, *, title: str | None = None, data=None,
                    note: str = "") -> Figure:  # fmt: skip
    """Simulated trajectory in three panels (paper Figs. 4-6).

    Parameters
    ----------
    ts : array_like, shape (N,)
        Sample times [s].
    ys : array_like, shape (N, 4)
        States ``(theta, psi, omega_theta, omega_psi)`` [rad, rad, rad/s, rad/s].
    momenta : array_like, shape (N, 2)
        Generalized momenta ``(p_theta, p_psi)`` [kg m^2/s].
    title : str, optional
        Figure title.
    data : Experiment, optional
        A measured record; its angles are drawn on panel (a) as thin grey/black lines,
        and panel (a) is clipped to their range if the simulation leaves it.
    note : str, optional
        Said on panel (a) when it is clipped (e.g. how far pitch goes).

    Returns
    -------
    matplotlib.figure.Figure
        Panels (a) angles [deg], (b) angular velocities [rad/s], (c) momenta [kg m^2/s].
    """
    ts = np.asarray(ts, dtype=float).reshape(-1)
    n = ts.shape[0]
    ys = _as_2col("ys", ys, n)
    if ys.shape[1] != 4:
        raise ValueError(f"ys: expected shape ({n}, 4), found {ys.shape}")
    momenta = _as_2col("momenta", momenta, n)

    fig, (ax_a, ax_b, ax_c) = _new_figure(3, (9.0, 9.0))
    if data is not None:
        y_deg = np.degrees(np.asarray(data.y, dtype=float))
        t_d = np.asarray(data.t, dtype=float)
        ax_a.plot(t_d, y_deg[:, 0], color="black", lw=0.8, alpha=0.8,
                  label=r"$\theta$ measured")
        ax_a.plot(t_d, y_deg[:, 1], color="0.55", lw=0.8, alpha=0.9,
                  label=r"$\psi$ measured")
    _pair_panel(ax_a, ts, np.degrees(ys[:, :2]), (r"$\theta$ (pitch)", r"$\psi$ (yaw)"),
                "angle [deg]", "(a) angles", lw=1.5)
    _pair_panel(ax_b, ts, ys[:, 2:], (r"$\omega_\theta$", r"$\omega_\psi$"),
                "angular velocity [rad/s]", "(b) angular velocities", lw=1.5)
    _pair_panel(ax_c, ts, momenta, (r"$p_\theta$", r"$p_\psi$"),
                "momentum [kg m$^2$/s]", "(c) generalized momenta", lw=1.5)

    if data is not None:
        _keep_data_readable(ax_a, np.degrees(np.asarray(data.y, dtype=float)),
                            np.degrees(ys[:, :2]), note)  # fmt: skip
    for ax in (ax_a, ax_b, ax_c):
        _legend(ax)
    _finish(fig, (ax_a, ax_b, ax_c), title)
    return fig


def plot_experiment(exp) -> Figure:
    """A rig record in two panels (paper Figs. 9-10): input voltages and measured angles.

    Parameters
    ----------
    exp : Experiment
        The record; ``exp.t`` [s], ``exp.u`` [V] (zero-order held, drawn as steps),
        ``exp.y`` [rad] (drawn in degrees).

    Returns
    -------
    matplotlib.figure.Figure
    """
    t = np.asarray(exp.t, dtype=float)
    u = np.asarray(exp.u, dtype=float)
    y_deg = np.degrees(np.asarray(exp.y, dtype=float))
    # Show the last input held for its full interval [t_{N-1}, t_{N-1} + dt).
    t_u = np.append(t, t[-1] + float(exp.dt))
    u_ext = np.vstack([u, u[-1:]])

    fig, (ax_u, ax_y) = _new_figure(2, (9.0, 6.0))
    _pair_panel(ax_u, t_u, u_ext, (r"$u_\theta$ (pitch motor)", r"$u_\psi$ (yaw motor)"),
                "voltage [V]", "(a) input voltages", lw=1.2, drawstyle="steps-post")
    _pair_panel(ax_y, t, y_deg, (r"$\theta$ (pitch)", r"$\psi$ (yaw)"),
                "angle [deg]", "(b) measured angles", lw=1.2)

    for ax in (ax_u, ax_y):
        _legend(ax)
    name = Path(str(exp.source)).name if exp.source else "record"
    _finish(fig, (ax_u, ax_y), f"{name}: {exp.n} samples, dt = {exp.dt:g} s")
    return fig


def plot_bands(t, y_pred, y_obs, *, train_mask, test_mask=None, coverage=None,
               title: str | None = None, health: str = "", band: str = "predictive",
               examples=None) -> Figure:
    """Posterior-predictive 50 % and 90 % bands for pitch and yaw, translucent over the data.

    Parameters
    ----------
    t : array, shape (N,)
        Time [s].
    y_pred : array, shape (S, N, 2)
        Predictive draws of (theta, psi) [rad].
    y_obs : array, shape (N, 2)
        Measured angles [rad].
    train_mask, test_mask : bool arrays, shape (N,)
        The training window is shaded white, the test window light grey and labelled.
    coverage : dict, optional
        ``{window: {"theta": c90, "psi": c90}}``, shown in the panel titles.
    health : str, optional
        A failed health check, e.g. ``"UNCONVERGED"`` or ``"UNCONVERGED, unphysical"``:
        it leads the title and replaces the coverage claim.  Bands that leave the data's
        range are clipped to it (and the panel says so).
    band : str, optional
        What the bands are, in the legend (e.g. ``"prior predictive"``).
    examples : array, shape (K, N, 2), optional
        Single draws (e.g. simulated angles [rad]) drawn as thin lines over the bands:
        where the bands span everything, they show what one draw does.
    """
    t = np.asarray(t, dtype=float)
    y_pred = np.asarray(y_pred, dtype=float)
    solved = ~np.isnan(y_pred).any(axis=(1, 2))  # a failed solve is NaN throughout
    failed_note = (f"{np.sum(~solved)} of {solved.size} draws failed to simulate: bands of the others"
                   if not solved.all() else None)  # fmt: skip
    q = np.degrees(np.quantile(y_pred[solved] if solved.any() else y_pred,
                               [0.05, 0.25, 0.5, 0.75, 0.95], axis=0))  # fmt: skip
    obs = np.degrees(np.asarray(y_obs, dtype=float))
    fig, axes = _new_figure(2, (11.0, 6.5))
    for j, (ax, name, sym, color) in enumerate(zip(
            axes, ("pitch", "yaw"), (r"\theta", r"\psi"), (_THETA_COLOR, _PSI_COLOR))):  # fmt: skip
        # The translucent bands go over the data: a model that fits at the noise has a band
        # as narrow as the data's line (13,100 samples), which would hide it underneath.
        ax.plot(t, obs[:, j], color="k", lw=0.6, label="measured")
        ax.fill_between(t, q[0, :, j], q[4, :, j], color=color, alpha=0.3, lw=0, zorder=3,
                        label=f"90 % {band} band")
        ax.fill_between(t, q[1, :, j], q[3, :, j], color=color, alpha=0.4, lw=0, zorder=3,
                        label=f"50 % {band} band")
        ax.plot(t, q[2, :, j], color=color, lw=1.0, label=f"{band} median", zorder=4)
        if examples is not None:
            ex = np.degrees(np.asarray(examples))[:, :, j]
            ax.plot(t, ex.T, color="0.35", lw=0.5, alpha=0.7, zorder=4)
            ax.plot([], [], color="0.35", lw=0.5, label=f"{len(ex)} single draws")
        if failed_note:
            ax.plot([], [], " ", label=failed_note if solved.any() else "no draw simulates: no band")
        if test_mask is not None and np.any(test_mask):
            t_test = t[np.asarray(test_mask, bool)]
            ax.axvspan(t_test[0], t_test[-1], color="0.85", zorder=-1, label="test window")
            ax.axvline(t_test[0], color="0.3", ls="--", lw=0.8)
        if health:
            ax.set_title(f"{name} ${sym}$ - {health}: no coverage claimed (see summary.json "
                         "'health')", loc="left", fontsize="medium", color="firebrick")  # fmt: skip
        elif coverage:
            text = ", ".join(f"{100 * c[('theta', 'psi')[j]]:.0f} % of the "
                             + ("window" if w == "window" else f"{w} window")
                             for w, c in coverage.items())  # fmt: skip
            ax.set_title(f"{name} ${sym}$ - the 90 % band covers {text}", loc="left", fontsize="medium")
        _keep_data_readable(ax, obs[:, j], q[:, :, j])
        ax.set_ylabel(f"${sym}$ [deg]")
        _legend(ax)
    if health:
        title = f"{health} (see summary.json)\n{title}" if title else health
    _finish(fig, axes, title)
    return fig
