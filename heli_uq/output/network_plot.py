"""Figure of a hybrid posterior's network torque: median and 90 % interval per grid point.

For a network of the voltages the grid points are the training window's voltage pairs
(x axis: ``u_psi`` [V], colour: ``u_theta`` [V]), and, as open squares with red bars, the
pairs of the span it never holds (a test window's); for a network of states they are
samples of the training window (x axis: time [s]).  Built without :mod:`matplotlib.pyplot`
(see :mod:`heli_uq.output.plots`).
"""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from heli_uq.figure import new_figure, save_figure
from heli_uq.output.network import UNSEEN

__all__ = ["plot_network_torque"]


def plot_network_torque(idata, axis: str, path=None, *, truth=None) -> Figure:
    """The posterior of ``nn_torque_<axis>`` (:mod:`heli_uq.output.network`).

    Parameters
    ----------
    idata : InferenceData
        A hybrid posterior.
    axis : {"pitch", "yaw"}
    path : path, optional
        Also write the figure there (PNG).
    truth : array, shape (k,), optional
        A known torque at the grid points [N m] (synthetic records), drawn as crosses.
    """
    dim = f"nn_point_{axis}"
    torque = np.asarray(idata.posterior[f"nn_torque_{axis}"])
    torque = torque.reshape(-1, torque.shape[-1])
    lo, med, hi = np.quantile(torque, [0.05, 0.5, 0.95], axis=0)
    post = idata.posterior
    by_time = f"{dim}_time" in post.coords
    fig = new_figure((7.5, 4.8))
    ax = fig.subplots()
    if by_time:
        x = np.asarray(post[f"{dim}_time"])
        ax.fill_between(x, lo, hi, color="C1", alpha=0.3, label="90 % interval")
        ax.plot(x, med, color="C1", label="posterior median")
        ax.set_xlabel("time of the training-window sample [s]")
    else:
        x, colour = np.asarray(post[f"{dim}_u_psi"]), np.asarray(post[f"{dim}_u_theta"])
        ax.errorbar(x, med, yerr=[med - lo, hi - med], fmt="none", ecolor="0.6", elinewidth=1,
                    capsize=2, label="90 % interval", zorder=1)  # fmt: skip
        sc = ax.scatter(x, med, c=colour, cmap="viridis", s=18, zorder=2,
                        label="posterior median (training pairs)")  # fmt: skip
        fig.colorbar(sc, ax=ax, label="u_theta [V]")
        _unseen_pairs(ax, post, axis, sc)
        ax.set_xlabel("u_psi [V] (voltage pairs of the record)")
    if truth is not None:
        ax.scatter(x, truth, marker="x", color="k", s=22, zorder=3, label="truth")
    ax.axhline(0.0, color="0.3", lw=0.6)
    ax.set_ylabel(f"network torque on {axis} [N m]")
    ax.set_title(f"Hybrid posterior: the network's torque on {axis} "
                 f"({torque.shape[0]} draws; projected off the linear gains)", fontsize="medium")  # fmt: skip
    # below the axes: over them it hid a cluster of pairs whatever the corner
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.15), ncol=2, fontsize="small", frameon=False)
    fig.subplots_adjust(bottom=0.27)
    if path is not None:
        save_figure(fig, path)
    return fig


def _unseen_pairs(ax, post, axis: str, colours) -> None:
    """The torque at the voltage pairs the training window never holds: open squares,
    red interval bars (absent when the span has none)."""
    var, dim = f"nn_torque_{axis}{UNSEEN}", f"nn_point_{axis}{UNSEEN}"
    if var not in post:
        return
    torque = np.asarray(post[var]).reshape(-1, post[var].shape[-1])
    lo, med, hi = np.quantile(torque, [0.05, 0.5, 0.95], axis=0)
    x = np.asarray(post[f"{dim}_u_psi"])
    edges = colours.cmap(colours.norm(np.asarray(post[f"{dim}_u_theta"])))
    where = "pairs not in the training window"
    ax.errorbar(x, med, yerr=[med - lo, hi - med], fmt="none", ecolor="C3", elinewidth=1,
                capsize=2, label=f"90 % interval ({where})", zorder=1)  # fmt: skip
    ax.scatter(x, med, facecolors="none", edgecolors=edges, marker="s", s=30, zorder=2,
               label=f"posterior median ({where})")  # fmt: skip
