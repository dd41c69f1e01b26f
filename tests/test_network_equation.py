"""Equations from a network posterior: pysindy's stepwise path on draws of a known
expression recovers its features and coefficients; the feature torque that the expression
becomes matches its formula; the recovered model replaces the network."""

import jax.numpy as jnp
import numpy as np
import pytest

from heli_uq.discovery.network_equation import equation_model, recover_equation
from heli_uq.errors import ParameterError
from heli_uq.model import build_model

#: The known expression on yaw: a u_theta * u_psi + b u_psi^3 [N m].
TRUE_A, TRUE_B = 0.03, -0.02
#: Spread of the "posterior draws" around it [N m].
DRAW_NOISE = 2e-4
#: A true feature is kept in at least this fraction of the draws, a false one in at most
#: INCLUDE (it is not selected).
TRUE_INCLUSION = 0.9
#: Fraction of the posterior-mean torque the recovered expression must explain.
R2_MIN = 0.99
#: Agreement of the feature torque with its formula.
EXACT = 1e-14


def _grid(seed=0, k=31):
    rng = np.random.default_rng(seed)
    u_theta, u_psi = rng.uniform(1.22, 1.47, k), rng.uniform(0.45, 1.6, k)
    return u_theta, u_psi, rng.integers(100, 1400, k).astype(float)


def _projected(values, u_theta, u_psi, w):
    """``values`` minus their weighted least-squares fit on (u_theta, u_psi), as the
    network's projection does."""
    basis = np.column_stack([u_theta, u_psi])
    ww = w / w.sum()
    beta = np.linalg.solve(basis.T @ (basis * ww[:, None]), basis.T @ (ww * values))
    return values - basis @ beta


def _draws(seed=0):
    u_theta, u_psi, w = _grid(seed)
    truth = _projected(TRUE_A * u_theta * u_psi + TRUE_B * u_psi**3, u_theta, u_psi, w)
    rng = np.random.default_rng(seed + 1)
    return truth[None, :] + DRAW_NOISE * rng.standard_normal((200, truth.size)), truth, \
        {"u_theta": u_theta, "u_psi": u_psi}, w


def test_a_known_expression_is_recovered_from_draws_of_a_network_torque():
    """A library whose features are distinguishable over the voltage ranges: the true
    features are selected, the others not, and the coefficients' intervals hold the truth."""
    draws, _, points, w = _draws()
    library = ("1", "u_theta*u_psi", "u_psi^3")
    out = recover_equation(draws, points, w, project="u", library=library)
    assert out["selected"] == ["u_theta*u_psi", "u_psi^3"]
    assert min(out["inclusion"]["u_theta*u_psi"], out["inclusion"]["u_psi^3"]) >= TRUE_INCLUSION
    for name, true in (("u_theta*u_psi", TRUE_A), ("u_psi^3", TRUE_B)):
        lo, hi = out["coefficients"][name]["ci95"]
        assert lo <= true <= hi, (name, lo, hi)


def test_the_default_library_recovers_the_function_if_not_the_features():
    """Smooth functions of one voltage are nearly collinear over the rig's range (u_psi^3 is
    close to a mix of 1, u_psi^2 and u_psi): the features chosen may differ from the truth's,
    the torque they give at the pairs must not."""
    draws, truth, points, w = _draws()
    out = recover_equation(draws, points, w, project="u")
    assert "u_theta" not in out["features"] and "u_psi" not in out["features"]  # owned by K
    assert "u_theta*u_psi" in out["selected"]
    assert out["r2"] >= R2_MIN


def test_pure_noise_selects_no_expression():
    u_theta, u_psi, w = _grid(2)
    rng = np.random.default_rng(3)
    draws = np.stack([_projected(DRAW_NOISE * rng.standard_normal(u_theta.size), u_theta, u_psi, w)
                      for _ in range(100)])  # fmt: skip
    assert recover_equation(draws, {"u_theta": u_theta, "u_psi": u_psi}, w)["selected"] == []


def test_feature_torque_is_its_formula_and_replaces_the_network():
    model = build_model([{"effect": "neural_torque", "axis": "yaw", "hidden": 2}, "pitch:torque_offset"])
    refit = equation_model(model, "yaw", ["u_psi^2", "cos(u_psi)"])
    assert refit.label == "mechanistic + torque_offset(pitch) + feature_torque(yaw)"
    term = refit.effects[-1]
    p = refit.complete({"c_u_psi_sq_yaw": 0.0078, "c_cos_u_psi_yaw": -0.0136})
    for u_psi in (0.45, 1.0, 1.6):
        got = term(p, jnp.zeros(2), jnp.zeros(2), jnp.array([1.3, u_psi]))
        assert float(got[1]) == pytest.approx(0.0078 * u_psi**2 - 0.0136 * np.cos(u_psi), abs=EXACT)
        assert float(got[0]) == 0.0
    assert equation_model(model, "yaw", []).label == "mechanistic + torque_offset(pitch)"
    with pytest.raises(ParameterError, match="unknown feature"):
        build_model([{"effect": "feature_torque", "axis": "yaw", "features": ["u_psi^9"]}])
