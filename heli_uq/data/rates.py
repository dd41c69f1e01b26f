"""Rates of a record's measured angles, smoothed (the data give angles only).

A rate by plain finite differences of encoder angles is mostly noise: 8 mrad of yaw noise
at 0.01 s gives about 0.6 rad/s of rate noise, the size of the rig's yaw swings.  A
Savitzky-Golay derivative (a local cubic fitted over :data:`WINDOW_S`) keeps the swings
and drops that noise; it is what a term's input scaling and reference points, and the grid
a network torque is reported on, use (at :func:`evenly_spaced` samples of a window).
:func:`initial_rates` tells whether a record starts still and estimates the rates at its
first sample, for the initial state's prior.
"""

from __future__ import annotations

import numpy as np
from scipy.signal import savgol_filter

__all__ = ["measured_rates", "smoothed_derivatives", "evenly_spaced", "initial_rates", "WINDOW_S", "ORDER",
           "START_WINDOW_S", "START_ORDER", "STILL_Z"]

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


#: Longest stretch [s] at the start of a record from which its initial rates are estimated
#: (:func:`initial_rates`): long against the encoder's noise, short against the rig's swings.
START_WINDOW_S = 1.0
#: Degree of the polynomial fitted there.
START_ORDER = 2
#: An angle counts as still at the start when its fitted slope and curvature are both
#: within this many standard errors of 0.
STILL_Z = 3.0


def initial_rates(y, dt: float, u=None, window_s: float = START_WINDOW_S):
    """Whether each angle starts still, and its rate at the first sample with its error.

    A polynomial of degree :data:`START_ORDER` is fitted by least squares to the first
    ``window_s`` of each angle, ended at the first change of the voltages ``u`` (where the
    motion is smooth); its slope at the first sample is the rate, with the standard error
    from the fit's residual variance.  The angle is *still* when the slope and the
    curvature are both within :data:`STILL_Z` standard errors of 0.  For an angle that
    moves the slope is not a trustworthy rate: a record that starts accelerating (at rest,
    then a voltage step) bends the polynomial, and on a 4 s synthetic record started at
    rest it read 0.15 rad/s at a standard error of 0.007.

    Parameters
    ----------
    y : array_like, shape (N, 2)
        Angles (theta, psi) [rad] on a uniform grid.
    dt : float
        Sample time [s], > 0.
    u : array_like, shape (N, 2), optional
        Voltages [V]; the fit stops before the first sample whose voltages differ from the
        first one's.
    window_s : float
        Longest stretch used [s].

    Returns
    -------
    still : ndarray of bool, shape (2,)
    rates, se : ndarray, shape (2,) each
        [rad/s].  With fewer than ``START_ORDER + 3`` samples in the stretch nothing is
        still, the rates are 0 and the errors infinite (the record says nothing).
    """
    y = np.asarray(y, dtype=float)
    n = min(len(y), int(round(window_s / dt)) + 1)
    if u is not None:
        u = np.asarray(u, dtype=float)
        changed = np.flatnonzero(np.any(u[1:n] != u[0], axis=1))
        n = min(n, int(changed[0]) + 1) if changed.size else n
    if n < START_ORDER + 3:
        return np.zeros(2, bool), np.zeros(2), np.full(2, np.inf)
    t = np.arange(n) * float(dt)
    design = np.vander(t, START_ORDER + 1, increasing=True)  # 1, t, t^2
    coef, _, _, _ = np.linalg.lstsq(design, y[:n], rcond=None)
    resid = y[:n] - design @ coef
    var = np.sum(resid * resid, axis=0) / (n - START_ORDER - 1)
    se = np.sqrt(np.outer(np.diag(np.linalg.inv(design.T @ design)), var))  # (order + 1, 2)
    still = np.all(np.abs(coef[1:]) <= STILL_Z * se[1:], axis=0)
    return still, coef[1], se[1]
