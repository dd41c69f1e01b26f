"""Figures without pyplot state: a new Agg figure, and an atomic PNG writer.

Figures are built without :mod:`matplotlib.pyplot` and rendered with the Agg canvas, so
the package never changes the user's backend (it works headless, in scripts and in
notebooks).
"""

from __future__ import annotations

import io
import os
import sys
from pathlib import Path

__all__ = ["new_figure", "save_figure", "DPI"]

#: Resolution of PNG files written by :func:`save_figure` [dots per inch].
DPI = 150


def new_figure(figsize):
    """A :class:`matplotlib.figure.Figure` with an Agg canvas attached."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize)
    FigureCanvasAgg(fig)
    return fig


def save_figure(fig, path: str | os.PathLike) -> Path:
    """Write *fig* as a PNG at :data:`DPI`, atomically, then close it.

    The image is rendered in memory and written with
    :func:`heli_uq.io.atomic_write_bytes`, so *path* is never left half-written.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
    path : str or path-like
        Destination ``.png`` file; its directory must exist.

    Returns
    -------
    pathlib.Path
        The written path.
    """
    from heli_uq.io import atomic_write_bytes

    buf = io.BytesIO()
    try:
        fig.savefig(buf, format="png", dpi=DPI)
    finally:
        _close(fig)
    return atomic_write_bytes(path, buf.getvalue())


def _close(fig) -> None:
    # Figures made here are not registered with pyplot; if the caller's figure is, let
    # pyplot forget it (without importing pyplot, which would pick a backend).
    plt = sys.modules.get("matplotlib.pyplot")
    if plt is not None:
        plt.close(fig)
