"""Which axes the base model already fits to white noise, and the candidates not worth fitting.

A missing physical effect is a missing torque; the angles integrate it twice, so it leaves
a smooth residual that stays correlated for seconds.  Where the base model's residuals on
an axis are white on the fitting window *and* on the held-out window (the Ljung-Box test
of their autocorrelations up to :data:`LAG_SECONDS`, ``p >=`` :data:`P_WHITE` on each),
nothing is left there for a torque to explain, and a candidate that acts on that axis alone
(:meth:`~heli_uq.model.terms.base.AbstractEffect.acts_on`) is not fitted.  An effect on a
motor's voltage acts on both axes and is fitted unless both are white.

Why: the candidates that cannot help are the slow ones.  On a record with a hidden pitch
friction (2026-12-06, quick budget) the five yaw torque candidates took 541 s of the
workers' time, fitting stiff values to a yaw already at its noise.  The autocorrelations
are not computed about the residuals' mean, so a constant offset counts as structure.

The test is far more sensitive than the decision's margin.  Measured on the base fits of
131 s synthetic records (2026-12-06, noise 3 / 8 mrad, quantised, base jitter 0.1-0.2):
the weakest hidden effect discovery names (a pitch quadratic thrust, 0.0155 nats per held-out
sample against the margin's 0.009) left the pitch residuals at ``p = 1e-22`` (fit) and
``1e-37`` (held out); of 15 null records 14 were white on both axes (lowest p 0.007), and
one base fit extrapolated its yaw with a smooth error (held-out p 5e-9).  A test that
fails on a record without a hidden effect (that one, coloured noise, a simulator that
differs) only costs time: those candidates are fitted, as without the screen.

The statistic is written out here (a few lines of numpy and ``scipy.stats.chi2``) rather
than taken from statsmodels' ``acorr_ljungbox``, which is not a dependency; the test
checks its null distribution and its power independently.
"""

from __future__ import annotations

import numpy as np
from scipy import stats

from heli_uq.model import AXES, build_model

__all__ = ["ljung_box", "white_axes", "screened", "screen_text", "LAG_SECONDS", "P_WHITE"]

#: Longest lag [s] of the autocorrelations tested (100 lags at 0.01 s): a missing torque's
#: residual stays correlated for seconds; more lags tested at once add power against it (on
#: the record above, 0.5 s of lags gave pitch ``p = 1e-11`` on the fitting window, 1 s ``1e-22``).
LAG_SECONDS = 1.0
#: An axis is white on a window if the Ljung-Box p-value there is at least this.
P_WHITE = 1e-3


def ljung_box(resid, lags: int) -> tuple[float, float]:
    """Ljung-Box statistic ``Q = n (n + 2) sum_k r_k^2 / (n - k)``, ``k = 1..lags``, of the
    residuals ``resid`` (n,) and its p-value under white noise (``Q ~ chi2(lags)``; Ljung &
    Box 1978).  ``r_k`` are the autocorrelations about zero, not about the mean (a model's
    residuals should have mean zero; an offset is structure)."""
    r = np.asarray(resid, dtype=float)
    n = r.size
    if n <= lags + 1 or not np.all(np.isfinite(r)):
        return float("nan"), float("nan")
    power = float(np.dot(r, r))
    if power <= 0.0:
        return 0.0, 1.0
    k = np.arange(1, lags + 1)
    ac = np.array([np.dot(r[:-j], r[j:]) for j in k]) / power
    q = float(n * (n + 2) * np.sum(ac**2 / (n - k)))
    return q, float(stats.chi2.sf(q, lags))


def white_axes(resid, windows: dict, dt: float, lag_seconds: float = LAG_SECONDS,
               p_white: float = P_WHITE) -> dict:  # fmt: skip
    """Per axis, whether the residuals ``resid`` (N, 2) [rad] (measured less simulated,
    pitch and yaw) are white on every window of ``windows`` (``{name: (start, stop)}``
    sample indices), sampled every ``dt`` [s].

    Returns
    -------
    dict
        ``{axis: {"white": bool, "p": {window: p-value}}}`` for ``axis`` in
        ``("pitch", "yaw")``, plus ``"lags"`` (int) and ``"p_white"``.  A window too short
        for the lags, or with a non-finite residual, gives ``p`` None and the axis is not
        white.
    """
    lags = max(1, int(round(lag_seconds / dt)))
    out = {"lags": lags, "p_white": p_white}
    for j, axis in enumerate(AXES):
        p = {w: ljung_box(np.asarray(resid)[a:b, j], lags)[1] for w, (a, b) in windows.items()}
        p = {w: (None if np.isnan(v) else v) for w, v in p.items()}
        out[axis] = {"white": all(v is not None and v >= p_white for v in p.values()), "p": p}
    return out


def screened(effects, white: dict) -> dict:
    """The effects of ``effects`` (``"axis:kind"``) that act only on axes ``white``
    (:func:`white_axes`) calls white, each with the sentence that says why it is not fitted."""
    out = {}
    for effect in effects:
        axes = build_model([effect]).effects[0].acts_on()
        if all(white[a]["white"] for a in axes):
            out[effect] = (f"not fitted: it acts on {' and '.join(axes)}, where the base model's residuals "
                           f"are white ({screen_text(white, axes)})")  # fmt: skip
    return out


def screen_text(white: dict, axes=AXES) -> str:
    """``"Ljung-Box p over lags to 1 s: pitch 0.41 (train), 0.2 (test); ..."`` for ``axes``."""
    parts = []
    for axis in axes:
        ps = ", ".join(f"{_p_text(v)} ({w})" for w, v in white[axis]["p"].items())
        parts.append(f"{axis} {ps}")
    return f"Ljung-Box p over {white['lags']} lags: " + "; ".join(parts)


def _p_text(p) -> str:
    """A p-value as read: two digits, ``<1e-300`` where the chi-square tail underflows."""
    if p is None:
        return "–"
    return "<1e-300" if p < 1e-300 else f"{p:.2g}"
