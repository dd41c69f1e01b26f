"""The Gaussian-process torque's posterior at its voltage pairs.

:func:`gp_torques` evaluates every draw's :class:`~heli_uq.model.terms.gp_torque.GPTorque`
torque ``T(u)`` [N m] (after the projection off the gains) at the term's reference pairs:
the training window's pairs, then the pairs only the test window holds.  The InferenceData
stores it as ``gp_torque_<axis>`` on the dimension ``gp_pair_<axis>`` with the pairs'
voltages and whether the training window holds them as coordinates
(:func:`heli_uq.output.inference_data.to_inference_data`), beside the networks'
``nn_torque_<axis>``: the curve a user plots and the quantity whose R-hat means something.

Layer 7 (output).
"""

from __future__ import annotations

import numpy as np

from heli_uq.model.terms.gp_torque import GPTorque
from heli_uq.output.network import draw_torques

__all__ = ["gp_torques"]


def gp_torques(problem, samples: dict) -> dict:
    """Every draw's GP torque at the reference pairs of each ``gp_torque`` term.

    Parameters
    ----------
    problem : Problem
        With the model adapted to its record (the terms hold their pairs).
    samples : dict
        Posterior draws by site name, shape (chain, draw) for scalars.

    Returns
    -------
    dict
        ``{axis: (torque (chain, draw, J) [N m], points, fitted)}``: ``points`` the pairs'
        ``{"u_theta", "u_psi"}`` (J,) [V], ``fitted`` (J,) True where the training window
        holds the pair; empty without a GP term.
    """
    out = {}
    for term in problem.model.torques:
        if isinstance(term, GPTorque) and term.n_pairs:
            pairs = np.asarray(term.reference)
            points = {"u_theta": pairs[:, 0], "u_psi": pairs[:, 1]}
            fitted = np.arange(term.n_pairs) < term.n_fitted
            out[term.axis] = (draw_torques(problem, term, samples, points), points, fitted)
    return out
