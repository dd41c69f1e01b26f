"""The MAP's start for the error model's parameters, from the residuals of a least-squares
fit: the residual scale, the AR(1) correlation time and the timing error
(:mod:`heli_uq.probability.noise`)."""

from __future__ import annotations

import numpy as np

__all__ = ["error_start", "timing_start", "residual_rms", "TIMING_GRID", "SIGMA_FRACTIONS"]

#: Grids of the timing error's start [s] and of the residual scale's, as fractions of the
#: residual RMS (:func:`timing_start`).
TIMING_GRID = np.geomspace(0.01, 4.0, 25)
SIGMA_FRACTIONS = np.geomspace(0.01, 1.0, 41)
#: Smallest residual scale of a start [rad].
MIN_SIGMA = 1e-4
#: Range of the residuals' lag-1 autocorrelation that sets the AR(1) start.
LAG1_RANGE = (0.01, 0.9999)


def residual_rms(resid):
    """RMS of ``resid`` (N, 2) [rad] per output, at least :data:`MIN_SIGMA`."""
    return np.maximum(np.sqrt(np.mean(resid**2, axis=0)), MIN_SIGMA)


def error_start(resid, rate, dt: float, timing: bool):
    """``(sigma, tau, timing)`` (2,) each: the starts of the residual scale [rad] (the RMS
    of ``resid`` (N, 2) [rad]), the AR(1) correlation time [s] (from the lag-1
    autocorrelation at sample time ``dt`` [s]) and, if ``timing``, the timing error [s]
    with the scale that goes with it (:func:`timing_start`, from the simulated rates
    ``rate`` (N, 2) [rad/s]; else the prior's median 0.2 s)."""
    sigma = residual_rms(resid)
    lag1 = np.sum(resid[1:] * resid[:-1], axis=0) / np.sum(resid**2, axis=0)
    tau = -dt / np.log(np.clip(lag1, *LAG1_RANGE))
    if not timing:
        return sigma, tau, np.full(2, 0.2)
    sigma, timing_sd = timing_start(resid, rate)
    return sigma, tau, timing_sd


def timing_start(resid, rate):
    """``(sigma, timing)`` (2,) each: the residual scale [rad] and timing error [s] that
    maximise the independent-error likelihood of ``resid`` (N, 2) [rad] with the simulated
    rates ``rate`` (N, 2) [rad/s] over :data:`TIMING_GRID` x :data:`SIGMA_FRACTIONS`."""
    rms = residual_rms(resid)
    sigma, timing = rms.copy(), np.full(2, TIMING_GRID[0])
    for j in range(2):
        s_grid = rms[j] * SIGMA_FRACTIONS
        var = s_grid[:, None, None] ** 2 + (TIMING_GRID[None, :, None] * rate[None, None, :, j]) ** 2
        nll = 0.5 * np.sum(resid[None, None, :, j] ** 2 / var + np.log(var), axis=-1)
        a, b = np.unravel_index(np.argmin(nll), nll.shape)
        sigma[j], timing[j] = s_grid[a], TIMING_GRID[b]
    return sigma, timing
