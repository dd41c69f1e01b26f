"""The cross damping term: the power balance of a general damping matrix, the conservation
of its skew (gyroscopic) part, the solver against the adaptive reference, and the paper's
model at zero."""

import jax.numpy as jnp
import numpy as np
import pytest
from conftest import assert_solver_follows_the_reference

from heli_uq.model import TABLE1, build_model, model_from_description, total_energy
from heli_uq.simulation import simulate

#: Relative agreement of the energy lost with the integrated power (trapezoid on 5 ms).
POWER_RTOL = 2e-3
#: Relative drift of the energy allowed when the damping does no work.
CONSERVATION_RTOL = 1e-8
MODEL = ("pitch:cross_damping", "yaw:cross_damping")


def _run(d_pitch, d_yaw, substeps):
    """A free swing (u = 0, no diagonal damping) with cross damping on both axes: the
    states (N, 4) and the total energy (N,) [J]."""
    model = build_model(list(MODEL))
    p = model.complete({**TABLE1, "D_theta": 0.0, "D_psi": 0.0, "h": 0.01,
                        "D_x_pitch": d_pitch, "D_x_yaw": d_yaw})  # fmt: skip
    x0 = jnp.array([0.6, 0.0, -0.3, 1.2])
    ys = np.asarray(simulate(p, x0, jnp.zeros((1201, 2)), 0.005, model=model, substeps=substeps))
    return ys, np.asarray(total_energy(p, ys))


def test_the_energy_lost_is_the_power_of_the_damping_matrix():
    """``dE/dt = -v^T D_offdiag v = -(D_x_pitch + D_x_yaw) omega_theta omega_psi``: the
    energy lost over a free swing equals that power integrated along it."""
    d_pitch, d_yaw = 0.004, 0.006
    ys, energy = _run(d_pitch, d_yaw, substeps=8)
    power = -(d_pitch + d_yaw) * ys[:, 2] * ys[:, 3]
    dt = 0.005
    dissipated = np.concatenate([[0.0], np.cumsum(0.5 * (power[1:] + power[:-1]) * dt)])
    drop = energy - energy[0]
    assert np.max(np.abs(drop)) > 0.01 * abs(energy[0])  # the term does work on this run
    np.testing.assert_allclose(drop, dissipated, atol=POWER_RTOL * np.max(np.abs(drop)))


def test_a_skew_damping_matrix_does_no_work():
    """``D_x_pitch = -D_x_yaw`` is a gyroscopic coupling: the angles change, the energy
    does not."""
    ys, energy = _run(0.01, -0.01, substeps=4)
    still, _ = _run(0.0, 0.0, substeps=4)
    assert np.max(np.abs(ys[:, :2] - still[:, :2])) > 0.05  # rad: the coupling acts
    assert np.max(np.abs(energy - energy[0])) < CONSERVATION_RTOL * abs(energy[0])


def test_the_solver_agrees_with_the_adaptive_reference():
    """On 30 s of rig-like voltage steps with both terms at a tenth of the yaw damping the
    fixed-step solution is within 1e-4 rad of diffrax's Kvaerno5."""
    model = build_model(list(MODEL))
    values = model.complete({**TABLE1, "D_x_pitch": 0.003, "D_x_yaw": -0.008})
    assert_solver_follows_the_reference(model, values, seed=2)


def test_zero_is_the_papers_model_and_the_description_round_trips():
    """D_x = 0 (the default) simulates the paper's model bit for bit; the parameters carry
    the axis; the stored description (posterior.nc, summary.json) rebuilds the model."""
    model = build_model(list(MODEL))
    again = model_from_description(model.describe())
    assert again.describe() == model.describe() and again.label == model.label
    assert [p.name for t in model.effects for p in t.parameters()] == ["D_x_pitch", "D_x_yaw"]
    u = np.tile([1.35, 0.9], (500, 1))
    x0 = [-0.5, 0.3, 0.0, 0.0]
    got = simulate(model.complete(TABLE1), x0, u, 0.01, model=model, substeps=2)
    np.testing.assert_array_equal(np.asarray(got), np.asarray(simulate(TABLE1, x0, u, 0.01, substeps=2)))
    assert model.complete(TABLE1)["D_x_yaw"] == pytest.approx(0.0)
