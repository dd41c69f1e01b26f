"""Which effects the implied torque asks for: sparse regression with pysindy.

The implied torque of both axes (each divided by its spread) is one target; every
candidate effect contributes its feature columns (:func:`~heli_uq.discovery.implied.effect_features`)
on both axes.  The base model's own columns are projected out first (a refit of the base
model could absorb those directions).  pysindy's ``EnsembleOptimizer`` over ``STLSQ``
(bagged, :data:`N_MODELS` fits, threshold :data:`THRESHOLD` in standardized units) gives
each column an *inclusion probability*; a candidate's is its largest column's.

For each candidate alone, the least-squares coefficients of its columns are its implied
parameter values (used as start values of its parametric fit) and the fraction of the
projected target it explains.  Candidates are ranked by inclusion probability, then by
that fraction.  This ranking only orders and seeds the parametric fits of
:mod:`heli_uq.discovery.candidates`; it decides nothing: features of different effects
can be nearly collinear on a record (a dead band on a voltage that never falls below it
acts like an offset), which only a fit of the trajectories separates.
"""

from __future__ import annotations

import warnings

import numpy as np
import pysindy as ps

__all__ = ["rank_effects", "THRESHOLD", "N_MODELS", "STRIDE"]

#: STLSQ threshold on coefficients of standardized columns (target scaled to unit spread).
THRESHOLD = 0.02
#: Ridge weight of STLSQ.
ALPHA = 1e-3
#: Bagged fits of the ensemble.
N_MODELS = 40
#: Rows kept: every STRIDE-th sample (the smoothed signals are strongly correlated).
STRIDE = 5
#: Relative singular-value cut of the base columns' span.
_RANK_TOL = 1e-8


def _stack(cols: np.ndarray, scale: np.ndarray, rows) -> np.ndarray:
    """(N, 2, k) -> (2 n_rows, k): both axes, each divided by its spread."""
    c = cols[rows] / scale[None, :, None]
    return np.concatenate([c[:, 0, :], c[:, 1, :]], axis=0)


def _orthonormal_span(a: np.ndarray) -> np.ndarray:
    u, s, _ = np.linalg.svd(a, full_matrices=False)
    return u[:, s > _RANK_TOL * (s[0] if s.size else 1.0)]


def rank_effects(residual: np.ndarray, base_cols: np.ndarray, candidates: dict, *,
                 seed: int = 0) -> list[dict]:  # fmt: skip
    """Rank candidate effects by how the implied torque asks for them (module docstring).

    Parameters
    ----------
    residual : array, shape (N, 2)
        Residual acceleration ``a - a_model`` [rad/s^2] (:class:`~heli_uq.discovery.implied.ImpliedTorque`).
    base_cols : array, shape (N, 2, n_base)
        The base model's parameter columns.
    candidates : dict
        ``{"axis:kind": (param_names, columns (N, 2, k))}``.
    seed : int
        Seed of the bagging.

    Returns
    -------
    list of dict
        ``{"effect", "inclusion", "explained", "implied": {param: value}}``, best first.
    """
    tau = residual
    rows = np.arange(0, tau.shape[0], STRIDE)
    scale = np.maximum(np.std(tau[rows], axis=0), 1e-12)
    y = np.concatenate([tau[rows, 0] / scale[0], tau[rows, 1] / scale[1]])
    q = _orthonormal_span(_stack(base_cols, scale, rows))
    y = y - q @ (q.T @ y)
    y = y / max(np.std(y), 1e-300)
    keys, blocks, owner = list(candidates), [], []
    for i, key in enumerate(keys):
        c = _stack(candidates[key][1], scale, rows)
        blocks.append(c - q @ (q.T @ c))
        owner += [i] * c.shape[1]
    x = np.concatenate(blocks, axis=1)
    norms = np.sqrt(np.mean(x**2, axis=0))
    usable = norms > 1e-9 * max(norms.max(initial=0.0), 1e-300)
    xs = np.where(usable, x / np.where(usable, norms, 1.0), 0.0)
    # pysindy's bagging draws from numpy's global generator: seed it, then restore it
    state = np.random.get_state()  # noqa: NPY002
    np.random.seed(seed)  # noqa: NPY002
    try:
        with warnings.catch_warnings():
            # every coefficient thresholded away is an answer here ("nothing"), not a problem
            warnings.filterwarnings("ignore", message="Sparsity parameter is too big")
            opt = ps.EnsembleOptimizer(opt=ps.STLSQ(threshold=THRESHOLD, alpha=ALPHA), bagging=True,
                                       n_models=N_MODELS).fit(xs[:, usable], y[:, None])  # fmt: skip
    finally:
        np.random.set_state(state)  # noqa: NPY002
    inclusion = np.zeros(x.shape[1])
    inclusion[usable] = np.mean(np.abs(np.asarray(opt.coef_list)[:, 0, :]) > 0, axis=0)
    owner = np.asarray(owner)
    out = []
    for i, key in enumerate(keys):
        cols = blocks[i]
        coef, *_ = np.linalg.lstsq(cols, y, rcond=None)
        resid = y - cols @ coef
        names = candidates[key][0]
        # coefficients of the unit-spread target back in physical units of each parameter
        implied = _physical_coefficients(candidates[key][1], tau, base_cols, scale, rows)
        out.append({"effect": key, "inclusion": float(inclusion[owner == i].max(initial=0.0)),
                    "explained": float(1.0 - np.mean(resid**2) / np.mean(y**2)),
                    "implied": dict(zip(names, implied))})  # fmt: skip
    out.sort(key=lambda r: (-r["inclusion"], -r["explained"]))
    return out


def _physical_coefficients(cols, tau, base_cols, scale, rows) -> list[float]:
    """Least-squares coefficients [parameter units] of one candidate's columns for the
    implied torque, jointly with the base columns."""
    a = np.concatenate([_stack(cols, scale, rows), _stack(base_cols, scale, rows)], axis=1)
    b = np.concatenate([tau[rows, 0] / scale[0], tau[rows, 1] / scale[1]])
    coef, *_ = np.linalg.lstsq(a, b, rcond=None)
    return [float(c) for c in coef[: cols.shape[2]]]
