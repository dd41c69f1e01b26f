"""Where the base model fails: by axis, by input segment, and by state.

From the base model's Laplace predictive over the fitting and held-out windows:

* per axis, RMSE and the share of samples outside the 90 % band on each window; the
  *worst axis* is the one with the larger held-out RMSE relative to the data's noise
  scale there, estimated from the residuals' successive differences (:func:`noise_scale`).
  A fitted error scale would not do: it absorbs the model's misfit (on a record with a
  hidden pitch friction the pitch scale was fitted at 6.7 mrad for 3 mrad of noise, and the
  pitch looked no worse than the yaw);
* per input segment (runs of constant voltages), the share outside the band;
* per candidate feature (the voltages, the rates, whether the axis is still, the angles),
  the share outside the band in quantile bins: structure against a feature points at the
  effects that act through it (e.g. misses concentrated where yaw is still point at
  friction, misses that follow ``u_psi`` at a gain or dead band);
* per axis, whether the residuals are white noise on every window
  (:func:`~heli_uq.discovery.screen.white_axes`): nothing left there for a torque;
* whether the fit damps an axis as hard as the solver allows
  (:func:`~heli_uq.simulation.stiffness.damping_edge`, ``solver_edge``): it imitates a
  missing torque there by damping.

Writes ``residuals.png`` (time, segments, features) and returns a JSON-able dict.
"""

from __future__ import annotations

import numpy as np

from heli_uq.data.rates import measured_rates
from heli_uq.discovery.score import input_blocks
from heli_uq.discovery.screen import white_axes
from heli_uq.errors import ParameterError
from heli_uq.figure import new_figure, save_figure

__all__ = ["locate", "noise_scale", "failed_draws", "STILL_RATE", "N_BINS"]

#: An axis counts as still below this rate [rad/s] (smoothed measured angle).
STILL_RATE = 0.02
#: Quantile bins per feature.
N_BINS = 6
_SMOOTH_S = 0.5
_AXES = ("theta", "psi")
#: Colours of the samples outside the 90 % band, pitch and yaw: darker than the residual
#: lines (``C0``, ``C1``) so that the misses show on top of them.
OUTSIDE_COLORS = ("navy", "saddlebrown")


def _features(y, u, dt) -> dict:
    v = measured_rates(y, dt, _SMOOTH_S)
    return {"u_theta [V]": u[:, 0], "u_psi [V]": u[:, 1], "omega_theta [rad/s]": v[:, 0],
            "omega_psi [rad/s]": v[:, 1], "theta [rad]": y[:, 0], "psi [rad]": y[:, 1],
            "psi still (|omega_psi| < 0.02)": (np.abs(v[:, 1]) < STILL_RATE).astype(float)}  # fmt: skip


def noise_scale(resid) -> np.ndarray:
    """The white-noise scale [rad] of residuals ``resid`` (n, 2), per column, from their
    successive differences: ``sqrt(mean(diff^2) / 2)`` (Rice 1984).  A smooth misfit
    (a missing torque's, integrated twice) barely enters the differences; white noise of
    scale ``s`` gives ``s``."""
    d = np.diff(np.asarray(resid, dtype=float), axis=0)
    return np.sqrt(0.5 * np.mean(d * d, axis=0))


def _binned(feature, outside) -> list[dict]:
    values = np.unique(feature)
    if values.size <= 2:
        edges = [(v, v) for v in values]
    else:
        q = np.unique(np.quantile(feature, np.linspace(0, 1, N_BINS + 1)))
        edges = list(zip(q[:-1], q[1:]))
    out = []
    for i, (lo, hi) in enumerate(edges):
        m = (feature >= lo) & ((feature <= hi) if i == len(edges) - 1 else (feature < hi))
        if lo == hi:
            m = feature == lo
        if m.any():
            out.append({"low": float(lo), "high": float(hi), "n": int(m.sum()),
                        "outside90": float(outside[m].mean())})  # fmt: skip
    return out


def failed_draws(fitted) -> int:
    """How many of the base fit's predictive draws fail to simulate (NaN) over the fitting
    and held-out windows.

    Raises
    ------
    ParameterError
        If every draw fails: there is no band to locate misses in and nothing to compare
        candidates with (the misses had read 0 %, as if the model were perfect).
    """
    y_pred = np.asarray(fitted.y_pred)
    failed = int(np.isnan(y_pred).any(axis=(1, 2)).sum())
    if failed == y_pred.shape[0]:
        problem = fitted.start.problem
        t = problem.t
        raise ParameterError(
            f"{problem.source}: the base model fitted on {t[0]:g}:{t[problem.n_train - 1] + problem.dt:g} s "
            f"cannot be simulated to {t[-1] + problem.dt:g} s (all {failed} of its predictive draws "
            "fail), so there is no gap to locate or close; try a longer fitting window, other "
            "--base-effects, or --cold-starts 1")  # fmt: skip
    return failed


def locate(fitted, out_dir=None) -> dict:
    """Where the base model's 90 % band misses the data (module docstring).

    Parameters
    ----------
    fitted : heli_uq.discovery.candidates.Fitted
        The base model's fit with its predictive over fitting + held-out window.
    out_dir : path, optional
        Where ``residuals.png`` is written.
    """
    problem = fitted.start.problem
    y, u, t, dt = problem.y, problem.u, problem.t, problem.dt
    lo, hi = np.nanquantile(fitted.y_pred, [0.05, 0.95], axis=0)
    mean = np.nanmean(fitted.y_sim, axis=0)
    outside = (y < lo) | (y > hi)
    resid = y - mean
    windows = problem.windows()
    per_window = {}
    for w, (a, b) in windows.items():
        per_window[w] = {f"{k}_{ax}": float(v) for ax, j in zip(_AXES, (0, 1))
                         for k, v in (("rmse", np.sqrt(np.mean(resid[a:b, j] ** 2))),
                                      ("outside90", outside[a:b, j].mean()))}  # fmt: skip
    c, d = windows["test"]
    noise = noise_scale(resid[c:d])
    ratio = np.sqrt(np.mean(resid[c:d] ** 2, axis=0)) / np.maximum(noise, np.finfo(float).tiny)
    axis = "pitch" if ratio[0] > ratio[1] else "yaw"
    segments = [{"t0": float(t[a]), "t1": float(t[b - 1] + dt), "u_theta": float(u[a, 0]),
                 "u_psi": float(u[a, 1]),
                 **{f"outside90_{ax}": float(outside[a:b, j].mean()) for j, ax in enumerate(_AXES)}}
                for a, b in input_blocks(u, dt, min_block_s=0.0)]  # fmt: skip
    feats = _features(y, u, dt)
    j = 0 if axis == "pitch" else 1
    by_feature = {name: _binned(f, outside[:, j]) for name, f in feats.items()}
    spread = {name: max(b["outside90"] for b in bins) - min(b["outside90"] for b in bins)
              for name, bins in by_feature.items() if bins}  # fmt: skip
    result = {"axis": axis, "error_ratio": {"theta": float(ratio[0]), "psi": float(ratio[1])},
              "noise": {"theta": float(noise[0]), "psi": float(noise[1])},
              "windows": per_window, "segments": segments, "by_feature": by_feature,
              "strongest_features": sorted(spread, key=lambda k: -spread[k])[:3],
              "white": white_axes(resid, windows, dt), "solver_edge": fitted.start.solver_edge}  # fmt: skip
    if out_dir is not None:
        fig = _figure(t, resid, outside, segments, by_feature, axis, windows)
        save_figure(fig, f"{out_dir}/residuals.png")
    return result


def _figure(t, resid, outside, segments, by_feature, axis, windows):
    fig = new_figure((12.0, 10.0))
    grid = fig.add_gridspec(3, 4, height_ratios=[1.2, 1.0, 1.1])
    ax_t = fig.add_subplot(grid[0, :])
    c, d = windows["test"]
    order = (1, 0) if axis == "pitch" else (0, 1)  # the worst axis drawn last, on top
    for j in order:
        name = ("pitch", "yaw")[j]
        ax_t.plot(t, np.degrees(resid[:, j]), color=f"C{j}", lw=0.7, alpha=0.5, label=f"{name} residual")
        ax_t.plot(t[outside[:, j]], np.degrees(resid[outside[:, j], j]), ".", ms=2.5,
                  color=OUTSIDE_COLORS[j], label=f"{name} outside the 90 % band")  # fmt: skip
    ax_t.axvspan(t[c], t[d - 1], color="0.85", zorder=0, label="held out")
    ax_t.set_ylabel("measured - mean simulation [deg]")
    ax_t.set_xlabel("time $t$ [s]")
    ax_t.set_title("Residuals of the base model (dark dots: outside the 90 % band)", loc="left")
    ax_t.legend(loc="upper left", fontsize="small")
    ax_s = fig.add_subplot(grid[1, :])
    mids = [0.5 * (s["t0"] + s["t1"]) for s in segments]
    widths = [s["t1"] - s["t0"] for s in segments]
    for j, (ax_name, color, off) in enumerate((("theta", "C0", -0.25), ("psi", "C1", 0.25))):
        ax_s.bar(np.asarray(mids) + off * np.asarray(widths) * 0.5,
                 [100 * s[f"outside90_{ax_name}"] for s in segments], width=np.asarray(widths) * 0.45,
                 color=color, label=f"{'pitch' if j == 0 else 'yaw'}")  # fmt: skip
    ax_s.axhline(10, color="k", lw=0.8, ls="--", label="10 % (a calibrated band)")
    ax_s.set_ylabel("outside 90 % band [%]")
    ax_s.set_xlabel("input segment (time [s])")
    ax_s.set_title("Misses by input segment", loc="left")
    ax_s.legend(loc="upper left", fontsize="small")
    own = ("u_psi [V]", "omega_psi [rad/s]", "psi [rad]", "u_theta [V]") if axis == "yaw" else \
        ("u_theta [V]", "omega_theta [rad/s]", "theta [rad]", "u_psi [V]")
    for k, name in enumerate(own):
        bins = by_feature[name]
        ax = fig.add_subplot(grid[2, k])
        x = [0.5 * (b["low"] + b["high"]) for b in bins]
        ax.plot(x, [100 * b["outside90"] for b in bins], "o-", color="C1" if axis == "yaw" else "C0")
        ax.axhline(10, color="k", lw=0.8, ls="--")
        ax.set_xlabel(name)
        ax.set_ylabel(f"{axis} outside 90 % [%]" if k == 0 else "")
        ax.grid(True, alpha=0.4)
    fig.suptitle(f"Where the base model fails (worst axis: {axis})")
    fig.tight_layout()
    return fig
