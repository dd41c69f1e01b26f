"""An equation from a network posterior: pysindy on every draw of the network's torque.

The paper ran SINDy once on the trained network's output (Sec. 4.3).  With a posterior
over the network there is one output per draw, so the sparse regression runs per draw and
each library feature gets an *inclusion probability* (the fraction of draws whose sparse
fit keeps it) and a coefficient distribution.

For a network of the voltages (``inputs="u"``, the torque ``nn_torque_<axis>`` at the
training window's distinct voltage pairs, :mod:`heli_uq.output.network`):

1. The library (:data:`LIBRARY`, names from
   :data:`heli_uq.model.terms.feature_torque.FEATURES`) is evaluated at the pairs and,
   like the network, projected orthogonal to what the physics owns (``u``: the span of
   ``u_theta, u_psi``; ``1,u``: also the constant), weighted by the samples held at each
   pair; each column is scaled to unit weighted RMS, so a coefficient is the torque the
   feature adds [N m].
2. pysindy's stepwise sparse regression (``SSR``, criterion ``model_residual``: each step
   drops the feature whose removal raises the residual least) gives each draw a path of
   ever sparser fits; the draw's model is the one of least BIC on that path
   (``k log(RSS / k) + m log k`` over the ``k`` pairs, ``m`` features).  The library's
   smooth functions of one voltage are nearly collinear over the rig's range (``u_psi^3``
   is close to a mix of ``u_psi^2`` and ``sin u_psi``), so a thresholded least squares
   (STLSQ) keeps large cancelling coefficients; the stepwise path does not.
3. Features with inclusion probability >= :data:`INCLUDE` form the recovered expression;
   :func:`equation_model` replaces the network by a
   :class:`~heli_uq.model.terms.FeatureTorque` of them, for a NUTS refit.

A network of the states (``u,x,v``) is named by the effects table instead
(:mod:`heli_uq.discovery.network_effects`).

Layer 8 (discovery).
"""

from __future__ import annotations

import warnings

import numpy as np
import pysindy as ps

from heli_uq.errors import ParameterError
from heli_uq.model.spec import with_effects
from heli_uq.model.terms import EFFECTS
from heli_uq.model.terms.base import residual_projector
from heli_uq.model.terms.feature_torque import FEATURES

__all__ = ["recover_equation", "equation_model", "bic_path_fit", "LIBRARY", "INCLUDE"]

#: Default library: the paper's kind (polynomials and trigonometric functions of u), with
#: features that duplicate others on the rig's positive voltages (|u|u = u^2) left out.
LIBRARY = ("1", "u_theta^2", "u_psi^2", "u_theta*u_psi", "u_theta^3", "u_psi^3",
           "cos(u_psi)", "sin(u_psi)")  # fmt: skip
#: Ridge weight of the stepwise regression (on unit-RMS columns): only guards singular fits.
ALPHA = 1e-10
#: Inclusion probability from which a feature enters the recovered expression.
INCLUDE = 0.5


def bic_path_fit(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Coefficients (m,) of the least-BIC model on pysindy's stepwise path of ``y ~ x``."""
    k = x.shape[0]
    opt = ps.SSR(alpha=ALPHA, criteria="model_residual", max_iter=x.shape[1])
    opt.fit(x, y[:, None])
    best, best_bic = np.zeros(x.shape[1]), np.inf
    for coef in opt.history_:
        c = np.asarray(coef, dtype=float).reshape(-1)
        rss = float(np.sum((y - x @ c) ** 2))
        bic = k * np.log(max(rss, 1e-300) / k) + np.count_nonzero(c) * np.log(k)
        if bic < best_bic:
            best, best_bic = c, bic
    return best


def recover_equation(torque, points: dict, weights=None, *, project: str = "u", library=LIBRARY,
                     include: float = INCLUDE) -> dict:  # fmt: skip
    """Sparse regression of each draw's network torque on a named library.

    Parameters
    ----------
    torque : array, shape (S, k)
        Network torque [N m] of ``S`` posterior draws at ``k`` voltage pairs.
    points : dict
        ``{"u_theta": (k,), "u_psi": (k,)}`` [V].
    weights : array, shape (k,), optional
        Samples held at each pair (default: equal).
    project : {"u", "1,u", "none"}
        The span the network was made orthogonal to (its ``project`` option).
    library : sequence of str
        Feature names; those inside the projected span are dropped.

    Returns
    -------
    dict
        ``features`` (the library used), ``inclusion`` (name -> probability),
        ``selected`` (names with inclusion >= ``include``), ``coefficients`` (selected
        name -> ``{mean, ci95}`` of its coefficient [N m per feature unit] when the
        selected expression is fitted to each draw by least squares), ``r2`` (weighted R^2
        of the selected features' least-squares fit to the posterior-mean torque) and ``draws``.
    """
    torque = np.atleast_2d(np.asarray(torque, dtype=float))
    u = np.stack([np.asarray(points["u_theta"], float), np.asarray(points["u_psi"], float)])
    k = u.shape[1]
    if torque.shape[1] != k or k < 2:
        raise ParameterError(f"recover_equation: torque must be (draws, {k}) at >= 2 voltage pairs, "
                             f"found {torque.shape}")  # fmt: skip
    w = np.ones(k) if weights is None else np.asarray(weights, dtype=float)
    w = w / w.sum()
    owned = {"u": ("u_theta", "u_psi"), "1,u": ("1", "u_theta", "u_psi"), "none": ()}[project]
    basis = np.column_stack([np.asarray(FEATURES[f][0](u)) * np.ones(k) for f in owned]) if owned \
        else np.zeros((k, 0))
    proj = residual_projector(basis, w)
    names = [f for f in library if f not in owned]
    cols = proj @ np.column_stack([np.asarray(FEATURES[f][0](u)) * np.ones(k) for f in names])
    rms = np.sqrt(w @ cols**2)
    keep = rms > 1e-9 * max(rms.max(), 1e-300)  # features the projection leaves nothing of
    names, cols, rms = [n for n, kp in zip(names, keep) if kp], cols[:, keep], rms[keep]
    x = cols / rms * np.sqrt(w)[:, None]
    y = (torque @ proj.T) * np.sqrt(w)[None, :]
    coefs = np.zeros((torque.shape[0], len(names)))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for s in range(torque.shape[0]):
            coefs[s] = bic_path_fit(x, y[s])
    kept = coefs != 0
    inclusion = {n: float(kept[:, i].mean()) for i, n in enumerate(names)}
    selected = [n for n in names if inclusion[n] >= include]
    coefficients, r2 = {}, float("nan")
    if selected:  # the selected expression refitted to every draw (least squares)
        cols_sel = [names.index(n) for n in selected]
        xs = x[:, cols_sel]
        fits = np.linalg.lstsq(xs, y.T, rcond=None)[0].T / rms[cols_sel][None, :]
        for j, n in enumerate(selected):
            coefficients[n] = {"mean": float(fits[:, j].mean()),
                               "ci95": [float(np.quantile(fits[:, j], 0.025)),
                                        float(np.quantile(fits[:, j], 0.975))]}  # fmt: skip
        target = y.mean(0)
        fit = xs @ np.linalg.lstsq(xs, target, rcond=None)[0]
        r2 = float(1 - np.sum((target - fit) ** 2) / max(np.sum(target**2), 1e-300))
    return {"features": names, "inclusion": inclusion, "coefficients": coefficients,
            "selected": selected, "r2": r2, "draws": int(torque.shape[0])}


def equation_model(model, axis: str, selected) -> object:
    """``model`` with its neural term on ``axis`` replaced by what was recovered from it:
    named effects of the vocabulary (kinds from
    :func:`heli_uq.discovery.network_effects.name_network_effects`) on ``axis``, and a
    feature torque of the selected voltage features (:func:`recover_equation`); the model
    without the network when nothing was selected."""
    named = [s for s in selected if s in EFFECTS]
    features = [s for s in selected if s not in EFFECTS]
    add = [{"effect": kind, "axis": axis} for kind in named]
    add += [{"effect": "feature_torque", "axis": axis, "features": features}] if features else []
    return with_effects(model, lambda e: not (e["effect"] == "neural_torque" and e["axis"] == axis),
                        add, where="equation_model")  # fmt: skip
