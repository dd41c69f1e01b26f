"""The tilted yaw axis: its torques against the Euler-Lagrange equations of the tilted
potential by autodiff, the energy it conserves, its rate near rest against the linearised
vector field, the solver against the adaptive reference, and the paper's model at zero."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import assert_solver_follows_the_reference

from heli_uq.cli.options import EFFECTS_HELP
from heli_uq.model import TABLE1, build_model, model_from_description, total_energy
from heli_uq.model.lagrangian import euler_lagrange_acceleration, helicopter_lagrangian
from heli_uq.model.terms import EFFECTS, TERMS
from heli_uq.simulation import simulate

#: Relative agreement of the closed-form accelerations with the autodiff Euler-Lagrange ones.
ACCEL_RTOL = 1e-10
#: Relative drift of K + P + P_tilt over a free swing without damping.
CONSERVATION_RTOL = 1e-8
#: A tilt of a few degrees, as a base levelled by eye may have [rad].
TILT = {"b_c_yaw": 0.04, "b_s_yaw": -0.03}
MODEL = build_model(["yaw:axis_tilt"])
TERM = MODEL.effects[0]


def _free(params):
    """Table 1 with ``params``, no damping and an ``h`` off the arm (both arm terms act)."""
    return MODEL.complete({**TABLE1, "D_theta": 0.0, "D_psi": 0.0, "h": 0.01, **params})


def test_the_torques_are_the_euler_lagrange_equations_of_the_tilted_potential():
    """``M a = dL/dx - (dp/dx) v`` with ``L = K - P - P_tilt`` (autodiff, no force typed
    by hand) gives the model's accelerations at random states, with voltages and damping."""
    p = MODEL.complete({**TABLE1, "h": 0.01, **TILT})

    def lagrangian(x, v, params):
        return helicopter_lagrangian(x, v, params) - TERM.potential(params, x)

    rng = np.random.default_rng(3)
    for _ in range(8):
        x, v = rng.uniform(-1.2, 1.2, 2), rng.uniform(-2, 2, 2)
        u = rng.uniform(0.5, 1.5, 2)
        damping = -jnp.array([p["D_theta"] * v[0], p["D_psi"] * v[1]])
        gains = jnp.array([p["K_theta_theta"] * u[0] - p["K_theta_psi"] * u[1],  # Sec. 2.5
                           p["K_psi_theta"] * u[0] - p["K_psi_psi"] * u[1]])  # fmt: skip
        want = euler_lagrange_acceleration(lagrangian, jnp.asarray(x), jnp.asarray(v), p, gains + damping)
        got = MODEL.acceleration(MODEL.prepare(p), jnp.asarray(x), jnp.asarray(v), jnp.asarray(u))
        np.testing.assert_allclose(np.asarray(got), np.asarray(want), rtol=ACCEL_RTOL, atol=1e-12)


def test_a_free_swing_conserves_the_energy_with_the_tilts_potential():
    """Without damping or voltages, ``K + P + P_tilt`` is conserved; the tilt turns the yaw
    by more than 0.05 rad against the level rig, and ``K + P`` alone is not conserved."""
    p = _free(TILT)
    x0 = jnp.array([-0.4, 0.5, 0.3, 0.6])
    u = jnp.zeros((2001, 2))
    ys = np.asarray(simulate(p, x0, u, 0.005, model=MODEL, substeps=4))
    level = np.asarray(simulate(_free({}), x0, u, 0.005, model=MODEL, substeps=4))
    energy = np.asarray(total_energy(p, ys)) + np.asarray(
        jax.vmap(lambda y: TERM.potential(p, y[:2]))(jnp.asarray(ys)))
    scale = np.max(np.abs(np.asarray(total_energy(p, ys))))
    assert np.max(np.abs(ys[:, 1] - level[:, 1])) > 0.05
    assert np.max(np.abs(energy - energy[0])) < CONSERVATION_RTOL * scale
    assert np.ptp(np.asarray(total_energy(p, ys))) > 1e3 * CONSERVATION_RTOL * scale


def test_the_rate_near_rest_is_the_linearised_yaw_pendulum():
    """At level pitch with ``h = 0`` the yaw oscillates about its lowest azimuth at
    ``sqrt(m g r_c beta / M22)``: the eigenvalue of the linearised vector field."""
    p = MODEL.complete({**TABLE1, "D_theta": 0.0, "D_psi": 0.0, "h": 0.0, **TILT})
    beta = np.hypot(TILT["b_c_yaw"], TILT["b_s_yaw"])
    lowest = np.arctan2(TILT["b_s_yaw"], TILT["b_c_yaw"]) + np.pi
    # the pitch is not at rest there (gravity), so take the Jacobian's yaw block
    y = jnp.array([0.0, lowest, 0.0, 0.0])
    jac = np.asarray(jax.jacfwd(lambda y: MODEL(0.0, y, (p, jnp.zeros(2))))(y))
    eigenvalues = np.linalg.eigvals(jac[np.ix_([1, 3], [1, 3])])  # +-i omega
    want = np.sqrt(p["m"] * p["g"] * p["r_c"] * beta / (p["J_bc"] + p["m"] * p["r_c"] ** 2 + p["J_s"]))
    np.testing.assert_allclose(np.sort(eigenvalues.imag), [-want, want], rtol=1e-9)
    np.testing.assert_allclose(eigenvalues.real, 0.0, atol=1e-12)
    assert MODEL.stiffness(p, thetas=np.array([0.0])) == pytest.approx(want, rel=1e-9)


def test_the_solver_agrees_with_the_adaptive_reference():
    """On 30 s of rig-like voltage steps with the tilt, the fixed-step solution is within
    1e-4 rad of diffrax's Kvaerno5, and the tilt moves the angles by far more than that."""
    assert_solver_follows_the_reference(MODEL, MODEL.complete({**TABLE1, **TILT}), seed=5)


def test_zero_is_the_papers_model_and_only_the_yaw_axis_tilts():
    """``b_c = b_s = 0`` (the defaults) simulates the paper's model bit for bit; the stored
    description rebuilds the model; a tilt of the pitch axis is refused; the tilt is an
    angle (not scaled with the inertias), offered by ``--effects`` and not a discovery
    candidate."""
    again = model_from_description(MODEL.describe())
    assert again.describe() == MODEL.describe() and again.label == MODEL.label
    u = np.tile([1.35, 0.9], (500, 1))
    x0 = [-0.5, 0.3, 0.0, 0.0]
    got = simulate(MODEL.complete(TABLE1), x0, u, 0.01, model=MODEL, substeps=2)
    np.testing.assert_array_equal(np.asarray(got), np.asarray(simulate(TABLE1, x0, u, 0.01, substeps=2)))
    with pytest.raises(Exception, match="axis_tilt tilts the yaw axis"):
        build_model(["pitch:axis_tilt"])
    pars = TERM.parameters()
    assert [(q.name, q.unit, q.support, q.scales_with_inertia) for q in pars] == [
        ("b_c_yaw", "rad", "real", False), ("b_s_yaw", "rad", "real", False)]
    assert "axis_tilt" in TERMS and "axis_tilt" not in EFFECTS and "axis_tilt" in EFFECTS_HELP
