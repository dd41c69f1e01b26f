"""Rates of a record's measured angles, smoothed (the data give angles only).

A rate by plain finite differences of encoder angles is mostly noise: 8 mrad of yaw noise
at 0.01 s gives about 0.6 rad/s of rate noise, the size of the rig's yaw swings.  A
Savitzky-Golay derivative (a local cubic fitted over :data:`WINDOW_S`) keeps the swings
and drops that noise; it is what a term's input scaling and reference points, and the grid
a network torque is reported on, use (at :func:`evenly_spaced` samples of a window).
"""

from __future__ import annotations

import numpy as np
from scipy.signal import savgol_filter

__all__ = ["measured_rates", "smoothed_derivatives", "evenly_spaced", "WINDOW_S", "ORDER"]

#: Smoothing window [s] (short against the rig's 1-10 s swings, long against the noise).
WINDOW_S = 0.25
#: Degree of the local polynomial.
ORDER = 3


def measured_rates(y, dt: float, window_s: float = WINDOW_S) -> np.ndarray:
    """Rates [rad/s] of measured angles.

    Parameters
    ----------
    y : array_like, shape (N, 2)
        Angles (theta, psi) [rad] on a uniform grid.
    dt : float
        Sample time [s], > 0.
    window_s : float
        Smoothing window [s]; clipped to the record (at least ``ORDER + 2`` samples).

    Returns
    -------
    ndarray, shape (N, 2)
        The Savitzky-Golay derivative (:data:`ORDER`) of each angle; plain central
        differences for records shorter than ``ORDER + 2`` samples, zeros for one sample.
    """
    y = np.asarray(y, dtype=float)
    n = len(y)
    if n < 2:
        return np.zeros_like(y)
    if n < ORDER + 2:
        return np.gradient(y, float(dt), axis=0)
    return smoothed_derivatives(y, dt, window_s, orders=(1,))[0]


def smoothed_derivatives(y, dt: float, window_s: float = WINDOW_S, orders=(0, 1, 2)) -> tuple:
    """The Savitzky-Golay smoothed angles and their derivatives.

    Parameters
    ----------
    y : array_like, shape (N, 2)
        Angles [rad] on a uniform grid, ``N >= ORDER + 2``.
    dt : float
        Sample time [s], > 0.
    window_s : float
        Smoothing window [s]; at least ``ORDER + 2`` samples, clipped to the record.
    orders : sequence of int
        Derivative orders (0: the smoothed angles).

    Returns
    -------
    tuple of ndarray, each shape (N, 2)
        Per order: [rad], [rad/s], [rad/s^2], ...
    """
    y = np.asarray(y, dtype=float)
    n = len(y)
    width = max(int(round(window_s / dt)) | 1, (ORDER + 2) | 1)
    width = min(width, n if n % 2 else n - 1)
    return tuple(savgol_filter(y, width, ORDER, deriv=d, delta=float(dt), axis=0) for d in orders)


def evenly_spaced(n: int, k: int) -> np.ndarray:
    """Indices (at most ``k``, sorted, distinct, first and last included) of ``n`` samples."""
    return np.unique(np.linspace(0, n - 1, min(n, k)).round().astype(int))
