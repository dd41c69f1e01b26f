"""An independent reference simulator: numpy vector field + scipy DOP853, restarted at switches.

Written from the paper's equations (with the corrected h-term) without importing any
heli_uq code, so agreement with :func:`heli_uq.simulate` is a real check.
"""

import math

import numpy as np
from scipy.integrate import solve_ivp


def vector_field(t, y, p, u):
    th, _, wt, wp = y
    c, s = math.cos(th), math.sin(th)
    m, r, h = p["m"], p["r_c"], p["h"]
    a = (p["J_bc"] + m * (r * r - h * h)) * c * s + m * r * h * (c * c - s * s)
    m11 = p["J_bc"] + m * r * r + m * h * h
    m22 = p["J_bc"] * c * c + m * (r * c - h * s) ** 2 + p["J_s"]
    t_th = p["K_theta_theta"] * u[0] - p["K_theta_psi"] * u[1] - p["D_theta"] * wt
    t_ps = p["K_psi_theta"] * u[0] - p["K_psi_psi"] * u[1] - p["D_psi"] * wp
    return [wt, wp, (-wp * wp * a - m * p["g"] * (r * c - h * s) + t_th) / m11,
            (2 * wp * wt * a + t_ps) / m22]  # fmt: skip


def reference_solution(params, x0, u, dt, rtol=1e-11, atol=1e-12):
    """States at t_k = k dt, shape (N, 4), integrating each constant-input run separately."""
    u = np.asarray(u, dtype=float)
    n = len(u)
    out = np.empty((n, 4))
    y = np.asarray(x0, dtype=float)
    start = 0
    while start < n:
        stop = start + 1
        while stop < n and np.array_equal(u[stop], u[start]):
            stop += 1
        # run [start, stop): input u[start] held on [t_start, t_stop)
        t_eval = np.arange(start, stop + 1) * dt if stop < n else np.arange(start, stop) * dt
        t_end = stop * dt if stop < n else (stop - 1) * dt
        if t_end > start * dt:
            sol = solve_ivp(vector_field, (start * dt, t_end), y, method="DOP853",
                            t_eval=t_eval, rtol=rtol, atol=atol, args=(params, u[start]))  # fmt: skip
            out[start:stop] = sol.y.T[: stop - start]
            y = sol.y[:, -1]
        else:
            out[start] = y
        start = stop
    return out
