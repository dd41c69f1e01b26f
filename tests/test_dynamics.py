"""Physics: closed form vs autodiff Lagrangian, energy, ODE vs momentum/DAE form, h = 0."""

import math

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from heli_uq.model import (
    TABLE1,
    TABLE2,
    TABLE3_X0,
    HeliModel,
    LagrangianMechanics,
    LinearTorque,
    momentum_vector_field,
    total_energy,
)
from heli_uq.model.lagrangian import helicopter_lagrangian, mass_matrix, momenta
from heli_uq.model.terms.rigid_body import (
    MechanicsCoefficients,
    closed_form_acceleration,
    dl_dx,
)
from heli_uq.model.terms.rigid_body import mass_matrix as closed_form_mass_matrix
from heli_uq.simulation import simulate

EOM_AGREEMENT = 1e-10  # closed form vs autodiff, relative to the acceleration scale
ENERGY_DRIFT = 1e-8  # relative drift of K + P over 20 s with u = 0, D = 0
ODE_DAE_AGREEMENT = 1e-8  # rad, rad/s between the two formulations (tight solves)


def _params(values):
    return {k: jnp.asarray(v, dtype=jnp.float64) for k, v in values.items()}


def _random_params(rng):
    values = {k: v * (float(np.exp(rng.normal(0.0, 0.3))) if k != "g" else 1.0)
              for k, v in TABLE1.items()}  # fmt: skip
    values["h"] = rng.uniform(0.005, 0.03)  # h != 0 exercises the printed-term error
    return _params(values)


def _random_state(rng):
    return jnp.asarray(rng.uniform([-1.4, -3, -3, -3], [1.4, 3, 3, 3]))


@pytest.mark.parametrize("seed", range(5))
def test_autodiff_lagrangian_matches_closed_form(seed):
    rng = np.random.default_rng(seed)
    params, y = _random_params(rng), _random_state(rng)
    u = jnp.asarray(rng.uniform(0, 2, 2))
    x, v = y[:2], y[2:]
    force = LinearTorque()(params, x, v, u)
    lagrangian = HeliModel(mechanics=LagrangianMechanics())
    auto = lagrangian.acceleration(lagrangian.prepare(params), x, v, u)
    closed = closed_form_acceleration(params, x, v, force)
    fast = MechanicsCoefficients.from_params(params).acceleration((jnp.sin(x[0]), jnp.cos(x[0])),
                                                                  v, force)
    model = HeliModel()
    via_model = model.acceleration(model.prepare(params), x, v, u)
    scale = float(jnp.max(jnp.abs(auto)))
    assert float(jnp.max(jnp.abs(auto - closed))) <= EOM_AGREEMENT * scale
    assert float(jnp.max(jnp.abs(auto - fast))) <= EOM_AGREEMENT * scale
    assert float(jnp.max(jnp.abs(auto - via_model))) <= EOM_AGREEMENT * scale
    # The pieces too: M(x) and dL/dx.
    m_auto = mass_matrix(helicopter_lagrangian, x, v, params)
    np.testing.assert_allclose(m_auto, closed_form_mass_matrix(params, x[0]), rtol=1e-12)
    dl_auto = jax.grad(helicopter_lagrangian, argnums=0)(x, v, params)
    np.testing.assert_allclose(dl_auto, dl_dx(params, x, v), rtol=1e-12, atol=1e-15)


def test_paper_printed_h_term_is_wrong_and_derived_term_is_right():
    """Sec. 2.7 prints ``- r_c h (c^2 - s^2)`` in dL/dtheta; the derivation gives ``+ m r_c h``."""
    p = _params({**TABLE1, "h": 0.02})
    x, v = jnp.array([0.3, 0.0]), jnp.array([0.0, 2.0])
    c, s = math.cos(0.3), math.sin(0.3)
    w2 = 4.0
    m, r_c, h = p["m"], p["r_c"], p["h"]
    common = (p["J_bc"] + m * (r_c**2 - h**2)) * c * s
    grav = -m * p["g"] * (r_c * c - h * s)
    printed = -w2 * (common - r_c * h * (c * c - s * s)) + grav
    derived = -w2 * (common + m * r_c * h * (c * c - s * s)) + grav
    auto = jax.grad(helicopter_lagrangian, argnums=0)(x, v, p)[0]
    assert abs(float(auto - derived)) < 1e-12
    assert abs(float(auto - printed)) > 1e-4


def test_h_zero_reduces_to_section_2_8():
    p = _params({**TABLE1, "h": 0.0})
    rng = np.random.default_rng(7)
    for _ in range(5):
        y = _random_state(rng)
        f = jnp.asarray(rng.normal(size=2))
        th, wt, wp = y[0], y[2], y[3]
        c, s = jnp.cos(th), jnp.sin(th)
        jb = p["J_bc"] + p["m"] * p["r_c"] ** 2
        a_theta = (-(wp**2) * jb * c * s - p["m"] * p["g"] * p["r_c"] * c + f[0]) / jb
        a_psi = (2 * wp * wt * jb * c * s + f[1]) / (jb * c**2 + p["J_s"])
        got = closed_form_acceleration(p, y[:2], y[2:], f)
        np.testing.assert_allclose(got, jnp.stack([a_theta, a_psi]), rtol=1e-12)


def test_energy_conserved_without_input_and_damping():
    p = _params({**TABLE1, "h": 0.01, "D_theta": 0.0, "D_psi": 0.0})
    dt = 0.01
    ys = simulate(p, jnp.asarray(TABLE3_X0), jnp.zeros((2001, 2)), dt, substeps=4)
    e = total_energy(p, ys)
    drift = float(jnp.max(jnp.abs(e - e[0])) / jnp.abs(e[0]))
    assert drift <= ENERGY_DRIFT
    # and the motion is not trivial
    assert float(jnp.ptp(ys[:, 0])) > 0.5


def test_energy_balance_with_damping():
    """dE/dt = v . F: with D > 0 and u = 0 energy decreases monotonically."""
    p = _params(TABLE2)
    ys = simulate(p, jnp.asarray(TABLE3_X0), jnp.zeros((1001, 2)), 0.01)
    e = np.asarray(total_energy(p, ys))
    assert np.all(np.diff(e) <= 1e-12)
    assert e[-1] < e[0]


def _diffrax_solve(field, z0, args, t1, n):
    sol = diffrax.diffeqsolve(
        diffrax.ODETerm(field), diffrax.Dopri8(), 0.0, t1, None, z0, args,
        stepsize_controller=diffrax.PIDController(rtol=1e-12, atol=1e-12, dtmin=None),
        saveat=diffrax.SaveAt(ts=jnp.linspace(0.0, t1, n)), max_steps=200_000,
    )  # fmt: skip
    return sol.ys


@pytest.mark.parametrize("h", [0.0, 0.01])
def test_ode_and_momentum_dae_forms_agree(h):
    """Paper Figs. 4-6: the ODE (x, v) and the DAE/momentum (x, p) forms give one solution."""
    p = _params({**TABLE2, "h": h})
    x0 = jnp.asarray(TABLE3_X0)
    u = jnp.zeros(2)
    model = HeliModel()
    ode = _diffrax_solve(model, x0, (p, u), 10.0, 101)
    mm = closed_form_mass_matrix(p, x0[0])
    z0 = jnp.concatenate([x0[:2], mm @ x0[2:]])
    dae = _diffrax_solve(momentum_vector_field, z0, (model, p, u), 10.0, 101)
    v_from_p = jax.vmap(lambda z: jnp.linalg.solve(closed_form_mass_matrix(p, z[0]), z[2:]))(dae)
    np.testing.assert_allclose(dae[:, :2], ode[:, :2], atol=ODE_DAE_AGREEMENT)
    np.testing.assert_allclose(v_from_p, ode[:, 2:], atol=ODE_DAE_AGREEMENT)
    p_from_v = jax.vmap(lambda y: momenta(helicopter_lagrangian, y[:2], y[2:], p))(ode)
    np.testing.assert_allclose(p_from_v, dae[:, 2:], atol=ODE_DAE_AGREEMENT)
    assert float(jnp.ptp(ode[:, 0])) > 0.1  # not a trivial trajectory
