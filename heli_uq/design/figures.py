"""The figure of ``heli-uq design``: the designed voltages, the predicted angles and what the
experiment identifies."""

from __future__ import annotations

import numpy as np

from heli_uq.figure import new_figure

__all__ = ["plot_design"]


def plot_design(dt: float, u, u_published, curves: dict, summary: dict):
    """Three panels: voltages [V] (design and published profile), predicted angles [rad]
    (one curve per model), and the shrinkage per whitened direction (information) or the
    criterion against the baselines (discrimination).

    Parameters
    ----------
    dt : float
    u, u_published : arrays, shape (N, 2), or None for the published profile
    curves : dict of str to array (N, 2)
        Predicted (theta, psi) by label.
    summary : dict
        The content of ``design.json``.
    """
    t = np.arange(len(u)) * dt
    fig = new_figure((11, 9))
    ax_u, ax_y, ax_c = fig.subplots(3, 1)
    for j, (name, color) in enumerate((("u_theta", "C0"), ("u_psi", "C1"))):
        ax_u.plot(t, u[:, j], color=color, lw=1.6, label=f"{name}, design")
        if u_published is not None:
            ax_u.plot(t, u_published[:, j], color=color, lw=0.9, ls="--", alpha=0.7,
                      label=f"{name}, published profile")  # fmt: skip
    ax_u.set(xlabel="time [s]", ylabel="voltage [V]", title="Designed input")
    ax_u.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.01, 0.5))
    styles = ("-", "--", ":")
    for i, (label, y) in enumerate(curves.items()):
        ax_y.plot(t, y[:, 0], color="C0", ls=styles[i % 3], label=f"pitch theta, {label}")
        ax_y.plot(t, y[:, 1], color="C1", ls=styles[i % 3], label=f"yaw psi, {label}")
    ax_y.set(xlabel="time [s]", ylabel="angle [rad]", title="Predicted response")
    ax_y.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.01, 0.5))
    if "shrinkage" in summary:
        _plot_shrinkage(ax_c, summary["shrinkage"])
    else:
        _plot_values(ax_c, summary)
    crit = summary["criterion"]["name"]
    gain = summary["gain_over_published"]
    more = "" if gain is None else f"; {gain:+.3g} {summary['unit']} over the published profile"
    fig.suptitle(f"Experiment design ({crit}): {summary['value']:.4g} {summary['unit']}{more}",
                 fontsize=10)  # fmt: skip
    fig.tight_layout()
    return fig


def _plot_shrinkage(ax, shrinkage: dict) -> None:
    for label, values in shrinkage.items():
        ax.semilogy(np.arange(1, len(values) + 1), values, "o-" if label == "design" else "s--",
                    label=label)  # fmt: skip
    ax.axhline(1.0, color="grey", lw=0.8)
    ax.set(xlabel="whitened direction (most to least informed)",
           ylabel="posterior sd / prior sd", title="What the experiment identifies (lower is better)")
    ax.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.01, 0.5))


def _plot_values(ax, summary: dict) -> None:
    base = summary["baselines"]
    labels = ["design", "random (median)", "random (best)"]
    values = [summary["value"], base["random"]["median"], base["random"]["best"]]
    if base["published"]["value"] is not None:
        labels.append("published profile")
        values.append(base["published"]["value"])
    ax.bar(labels, values, color=["C2", "C7", "C7", "C3"][: len(values)])
    ax.set(ylabel=f"criterion [{summary['unit']}]", title="Criterion: design and baselines")
