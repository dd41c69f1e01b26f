"""Figures of the identifiability report (PNG, Agg canvas, no pyplot state).

:func:`write_report_figures` writes ``singular_values.png``, ``fim_correlation.png``,
``profiles.png``, ``contraction.png`` and ``posterior_pairs.png`` and returns their paths.
Coordinates of positive parameters are natural logs, the others in their SI unit; initial
angles in rad and rates in rad/s.
"""

from __future__ import annotations

import pathlib

import numpy as np
from matplotlib.figure import Figure

from heli_uq.figure import new_figure, save_figure
from heli_uq.identifiability.profiles import THRESHOLD_95

__all__ = ["write_report_figures", "axis_label"]

#: How many of the most correlated pairs the pair plot shows.
N_PAIRS = 4


def axis_label(pv, name: str) -> str:
    """Axis label of a coordinate of ``w`` (a ParameterVector's) with its unit."""
    if name in ("theta0", "psi0"):
        return f"{name} [rad]"
    if name.startswith("omega"):
        return f"{name} [rad/s]"
    unit = pv.model.parameter(name).unit
    return f"log {name} [log {unit}]" if pv.is_log(name) else f"{name} [{unit}]"


def _figure(figsize):
    return new_figure(figsize)


def plot_singular_values(st) -> Figure:
    fig = _figure((7, 4))
    ax = fig.subplots()
    rel = st.singular_values / st.singular_values[:, :1]
    k = np.arange(1, rel.shape[1] + 1)
    for i, s in enumerate(rel):
        ax.semilogy(k, np.maximum(s, 1e-300), "o-", ms=4, alpha=0.8,
                    label="fit" if i == 0 else f"random point {i}")  # fmt: skip
    ax.axhline(st.rtol, color="k", ls="--", lw=1, label=f"rank tolerance {st.rtol:g}")
    ax.set_ylim(max(np.min(rel[rel > 0]) / 10, 1e-20), 2)
    ax.set_xlabel("singular value index")
    ax.set_ylabel("singular value / largest")
    ax.set_title(f"Output sensitivities d(theta, psi)/dw: rank {st.rank} of {st.n_parameters}")
    ax.legend(fontsize="small", loc="lower left")
    ax.grid(True, alpha=0.4)
    fig.tight_layout()
    return fig


def plot_correlation(names, corr, title) -> Figure:
    fig = _figure((7.5, 6.5))
    ax = fig.subplots()
    im = ax.imshow(np.ma.masked_invalid(corr), vmin=-1, vmax=1, cmap="RdBu_r")
    ax.set_xticks(range(len(names)), names, rotation=90, fontsize=8)
    ax.set_yticks(range(len(names)), names, fontsize=8)
    fig.colorbar(im, ax=ax, label="correlation")
    ax.set_title(title, fontsize=10)
    fig.tight_layout()
    return fig


def plot_profiles(profiles, labels) -> Figure:
    n = len(profiles)
    cols = 4
    rows = -(-n // cols)
    fig = _figure((3.3 * cols, 2.5 * rows))
    axes = np.atleast_1d(fig.subplots(rows, cols, squeeze=False)).ravel()
    for ax, p in zip(axes, profiles):
        d = np.where(np.isfinite(p.delta), p.delta, np.nan)
        ax.plot(p.values, np.minimum(d, 3 * THRESHOLD_95 * 1.5), "o-", ms=3, color="C0")
        ax.axhline(THRESHOLD_95, color="C3", ls="--", lw=1, label="95 % threshold")
        ax.axvspan(*p.bounds, color="0.93", zorder=-1, label="prior range")
        for c in (p.lower, p.upper):
            if c is not None:
                ax.axvline(c, color="C2", lw=0.8)
        ax.set_ylim(-0.1 * THRESHOLD_95, 3 * THRESHOLD_95)
        ax.set_xlabel(labels[p.name], fontsize=8)
        ax.set_ylabel("increase of -log L", fontsize=8)
        ax.set_title(f"{p.name}: {p.classification.replace('_', ' ')}", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(True, alpha=0.3)
    for ax in axes[n:]:
        ax.axis("off")
    axes[0].legend(fontsize=6, loc="upper center")
    fig.suptitle("Profile likelihoods (all other coordinates re-optimised; clipped at 3x the threshold)",
                 fontsize=10)  # fmt: skip
    fig.tight_layout()
    return fig


def plot_contraction(names, per, source) -> Figure:
    fig = _figure((8, 3.8))
    ax = fig.subplots()
    ax.bar(range(len(names)), per, color=["C0" if c >= 0.5 else "C1" for c in per])
    ax.set_xticks(range(len(names)), names, rotation=60, fontsize=8, ha="right")
    ax.set_ylim(min(-0.05, float(np.min(per)) - 0.05), 1.05)
    ax.axhline(0, color="k", lw=0.8)
    ax.set_ylabel("1 - var_post / var_prior")
    ax.set_title(f"Prior-to-posterior contraction ({source}); orange: below 0.5", fontsize=9)
    ax.grid(True, axis="y", alpha=0.4)
    fig.tight_layout()
    return fig


def plot_pairs(names, draws, corr, w_hat, labels) -> Figure:
    p = len(names)
    iu = [(i, j) for i in range(p) for j in range(i + 1, p) if np.isfinite(corr[i, j])]
    iu.sort(key=lambda ij: -abs(corr[ij]))
    pairs = iu[:N_PAIRS]
    fig = _figure((3.4 * max(len(pairs), 1), 3.2))
    axes = np.atleast_1d(fig.subplots(1, max(len(pairs), 1), squeeze=False)).ravel()
    for ax, (i, j) in zip(axes, pairs):
        ax.plot(draws[:, i], draws[:, j], ".", ms=2, alpha=0.3, color="C0", label="draws")
        ax.plot(w_hat[i], w_hat[j], "x", color="C3", ms=8, label="fit")
        ax.set_xlabel(labels[names[i]], fontsize=8)
        ax.set_ylabel(labels[names[j]], fontsize=8)
        ax.set_title(f"correlation {corr[i, j]:+.3f}", fontsize=9)
        ax.tick_params(labelsize=7)
    axes[0].legend(fontsize=7)
    fig.suptitle("Most correlated pairs of the posterior", fontsize=10)
    fig.tight_layout()
    return fig


def write_report_figures(out: pathlib.Path, pv, st, fim, profiles, draws, corr_post, per,
                         source: str, w_hat) -> list[pathlib.Path]:  # fmt: skip
    """Render every figure of the report into ``out``; returns the written paths.

    ``pv``: the :class:`~heli_uq.identifiability.structural.ParameterVector`;
    ``st``: :class:`~heli_uq.identifiability.structural.StructuralResult`; ``fim``:
    :class:`~heli_uq.identifiability.fisher.FisherResult`; ``profiles``: list of
    :class:`~heli_uq.identifiability.profiles.Profile`; ``draws`` (S, P) posterior draws of ``w`` with
    correlation ``corr_post`` (P, P); ``per`` (P,) contractions; ``source`` names where
    the draws come from; ``w_hat`` (P,) the fit.
    """
    names = pv.names
    labels = {n: axis_label(pv, n) for n in names}
    figures = {
        "singular_values.png": plot_singular_values(st),
        "fim_correlation.png": plot_correlation(
            names, fim.correlation,
            "Correlation from the Fisher information at the fit\n(blank: not estimable, "
            "on a null direction)"),
        "profiles.png": plot_profiles(profiles, labels),
        "contraction.png": plot_contraction(names, per, source),
        "posterior_pairs.png": plot_pairs(names, draws, corr_post, w_hat, labels),
    }  # fmt: skip
    paths = []
    for name, fig in figures.items():
        paths.append(save_figure(fig, out / name))
    return paths
