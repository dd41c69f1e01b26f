"""Numerics of the simulator: accuracy, exact ZOH switches, gradients, failure flags, batching."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from reference import reference_solution

import heli_uq
from heli_uq import RESULTS, TABLE1, loss_v, simulate, solve
from heli_uq.data import load_experimental
from heli_uq.model import HeliModel, build_model
from heli_uq.simulation import default_substeps
from heli_uq.simulation.reference import solver_error

ACCURACY_RAD = 1e-6  # max |theta|, |psi| error vs the tight reference (issue requirement)
GRAD_FD_RTOL = 1e-5  # relative agreement of the adjoint gradient with central differences
ADJOINT_VS_AUTODIFF = 1e-10  # discrete adjoint vs plain reverse-mode through the scan

FITTED = dict(TABLE1)  # "fitted-looking" parameters: the paper's Table 1


@pytest.fixture(scope="module")
def record():
    try:
        return load_experimental()
    except heli_uq.HeliUQError as exc:  # pragma: no cover - depends on the machine
        pytest.skip(f"real record not available: {exc}")


def test_full_record_accuracy_against_tight_reference(record):
    """<= 1e-6 rad in theta and psi over the whole 131 s record, default settings."""
    x0 = np.array([record.y[0, 0], record.y[0, 1], 0.0, 0.0])
    ref = reference_solution(FITTED, x0, record.u, record.dt)
    got = np.asarray(simulate(FITTED, x0, record.u, record.dt))
    err = np.max(np.abs(got[:, :2] - ref[:, :2]))
    assert err <= ACCURACY_RAD, f"max angle error {err:.2e} rad"
    assert np.ptp(ref[:, 1]) > 0.5  # the trajectory actually moves


def test_zoh_switch_is_exact():
    """Inputs switching every few samples: one RK4 step per interval matches a reference
    restarted at each switch, while a solver that smooths the switch (linear interpolation
    of u) is visibly different."""
    rng = np.random.default_rng(3)
    n, dt = 600, 0.01
    levels = rng.uniform([1.2, 0.5], [1.5, 1.6], size=(n // 7 + 1, 2))
    u = np.repeat(levels, 7, axis=0)[:n]
    x0 = np.array([-0.5, 0.2, 0.0, 0.0])
    ref = reference_solution(FITTED, x0, u, dt)
    got = np.asarray(simulate(FITTED, x0, u, dt))
    assert np.max(np.abs(got - ref)) <= ACCURACY_RAD
    # The switch matters: shifting the switch by half a sample changes the answer a lot.
    u_late = np.vstack([u[:1], u[:-1]])
    half = 0.5 * (u + u_late)
    smeared = np.asarray(simulate(FITTED, x0, half, dt))
    assert np.max(np.abs(smeared[:, :2] - ref[:, :2])) > 100 * ACCURACY_RAD


def test_substeps_converge_to_reference():
    rng = np.random.default_rng(4)
    u = np.repeat(rng.uniform([1.2, 0.5], [1.5, 1.6], size=(20, 2)), 25, axis=0)
    x0 = np.array([-0.3, 0.0, 0.5, -0.5])
    ref = reference_solution(FITTED, x0, u, 0.05)  # coarse grid: RK4 error visible
    errs = [np.max(np.abs(np.asarray(simulate(FITTED, x0, u, 0.05, substeps=s)) - ref))
            for s in (1, 2, 4)]  # fmt: skip
    assert errs[2] < errs[1] < errs[0]
    # fourth order: halving the step divides the error by ~16
    assert errs[0] / errs[1] > 10 and errs[1] / errs[2] > 10


#: A light, heavily damped pitch, as a fit imitating a hidden pitch friction found it (a
#: discovery candidate's MAP on a synthetic record): ``D_theta / M11`` about 320 /s, past
#: RK4's stability limit 2.785 at one substep of 0.01 s.
OVERDAMPED = dict(TABLE1, r_c=0.01031, h=0.00206, m=0.77185, J_bc=0.00146, J_s=0.12579,
                  K_theta_theta=0.05665, K_theta_psi=0.00035, K_psi_theta=0.03017, K_psi_psi=0.044,
                  D_theta=0.5, D_psi=0.15444)  # fmt: skip


def test_substeps_cover_a_heavy_viscous_damping():
    """At one substep the overdamped pitch's fast mode blows up; ``default_substeps``
    counts the damping's rate ``D / M`` and the solve then follows the stiff reference."""
    rng = np.random.default_rng(5)
    u = np.repeat(rng.uniform([1.2, 0.5], [1.5, 1.6], size=(10, 2)), 100, axis=0)
    x0 = np.array([-0.55, 1.0, 0.0, 0.0])
    model = build_model()
    m11 = model.mechanics.inertia_bounds(OVERDAMPED)[0]
    assert OVERDAMPED["D_theta"] / m11 * 0.01 > 2.785
    n = default_substeps(model, OVERDAMPED, 0.01)
    assert n == int(np.ceil(OVERDAMPED["D_theta"] / m11 * 0.01 / 1.4))
    assert not bool(solve(OVERDAMPED, x0, u, 0.01, substeps=1).ok)
    assert solver_error(OVERDAMPED, x0, u, 0.01, substeps=n) < ACCURACY_RAD  # 2.4e-7 at 3
    assert default_substeps(model, FITTED, 0.01) == 1  # Table 1's damping: 1 substep


#: ``r h`` of a damping just inside and just outside RK4's stability limit (2.785).
INSIDE_EDGE_RH, OUTSIDE_EDGE_RH = 2.6, 2.95


@pytest.mark.parametrize("axis", ["pitch", "yaw"])
def test_a_damping_at_the_solvers_stability_limit_is_reported_with_its_axis(axis):
    """``damping_edge`` names the axis whose viscous decay ``D / M`` sits at RK4's limit on
    the given substeps, and nothing inside it.  Checked against the solver itself on pitch
    (whose inertia is constant; yaw's is taken at its smallest): just inside the limit the
    overdamped mode is simulated, just outside it blows up."""
    from heli_uq.simulation.stiffness import EDGE_FRACTION, RK4_STABILITY, damping_edge

    model = build_model()
    m11, m22 = model.mechanics.inertia_bounds(FITTED)
    name, inertia, substeps, dt = ("D_theta", m11, 4, 0.01) if axis == "pitch" else ("D_psi", m22, 1, 0.01)
    at = {rh: dict(FITTED, **{name: rh * substeps / dt * inertia})
          for rh in (INSIDE_EDGE_RH, OUTSIDE_EDGE_RH)}  # fmt: skip
    assert EDGE_FRACTION * RK4_STABILITY < INSIDE_EDGE_RH < RK4_STABILITY < OUTSIDE_EDGE_RH
    edge = damping_edge(model, at[INSIDE_EDGE_RH], dt, substeps)
    assert edge["axis"] == axis and edge["substeps"] == substeps
    assert edge["rh"] == pytest.approx(INSIDE_EDGE_RH, rel=1e-12)
    assert damping_edge(model, at[INSIDE_EDGE_RH], dt, 2 * substeps) is None  # r h 1.3: inside
    assert damping_edge(model, FITTED, dt, 1) is None  # Table 1's damping
    if axis == "yaw":
        return
    rng = np.random.default_rng(5)
    u = np.repeat(rng.uniform([1.2, 0.5], [1.5, 1.6], size=(10, 2)), 100, axis=0)
    x0 = np.array([-0.55, 1.0, 0.0, 0.0])
    assert bool(solve(at[INSIDE_EDGE_RH], x0, u, dt, substeps=substeps).ok)
    assert not bool(solve(at[OUTSIDE_EDGE_RH], x0, u, dt, substeps=substeps).ok)


def test_a_synthetic_record_past_the_substep_cap_is_made_at_the_cap_with_a_warning(caplog):
    """A model needing more than MAX_SUBSTEPS substeps is simulated at the cap (here still
    stable) and says so once through the package's logging, naming the synthetic record."""
    from heli_uq.simulation import stiffness
    from heli_uq.simulation.synthetic import synthetic_experiment

    params = dict(OVERDAMPED, D_theta=6 * OVERDAMPED["D_theta"])
    model = build_model()
    assert default_substeps(model, params, 0.01, margin=2.0) > stiffness.MAX_SUBSTEPS
    with caplog.at_level("WARNING", logger="heli_uq"):
        exp = synthetic_experiment(params, x0=[-0.55, 1.0, 0.0, 0.0], duration=2.0, seed=0, model=model)
    lines = [r.getMessage() for r in caplog.records if r.name == "heli_uq.simulation.stiffness"]
    assert len(lines) == 1 and lines[0].startswith("a synthetic record needs"), lines
    assert f"using {stiffness.MAX_SUBSTEPS}" in lines[0] and np.all(np.isfinite(exp.y))


def _loss_fn(u, y_data, dt):
    def loss(p, x0):
        return loss_v(simulate(p, x0, u, dt), y_data)

    return loss


def test_gradient_matches_finite_differences():
    rng = np.random.default_rng(5)
    n, dt = 400, 0.01
    u = jnp.asarray(np.repeat(rng.uniform([1.2, 0.5], [1.5, 1.6], size=(8, 2)), 50, axis=0))
    x0 = jnp.array([-0.6, 0.1, 0.0, 0.0])
    truth = simulate(FITTED, x0, u, dt)
    y_data = truth[:, :2] + 0.05 * jnp.asarray(rng.normal(size=(n, 2)))
    p0 = {k: v * 1.1 for k, v in FITTED.items()}
    p0["h"] = 0.003
    loss = jax.jit(_loss_fn(u, y_data, dt))
    g_p, g_x = jax.jit(jax.grad(loss, argnums=(0, 1)))(p0, x0)
    for name in heli_uq.TABLE2:
        eps = 1e-6 * max(abs(p0[name]), 1e-3)
        up, dn = dict(p0), dict(p0)
        up[name] += eps
        dn[name] -= eps
        fd = (loss(up, x0) - loss(dn, x0)) / (2 * eps)
        assert abs(float(g_p[name]) - float(fd)) <= GRAD_FD_RTOL * max(abs(float(fd)), 1e-8), name
    for i in range(4):
        e = jnp.zeros(4).at[i].set(1e-6)
        fd = (loss(p0, x0 + e) - loss(p0, x0 - e)) / 2e-6
        assert abs(float(g_x[i]) - float(fd)) <= GRAD_FD_RTOL * max(abs(float(fd)), 1e-8)


def test_adjoint_equals_reverse_mode_through_the_solver():
    """The custom discrete adjoint is the exact gradient of the discrete scheme (also wrt u)."""
    from heli_uq.simulation.solver import _rk4_step

    rng = np.random.default_rng(6)
    u = jnp.asarray(rng.uniform([1.2, 0.5], [1.5, 1.6], size=(300, 2)))
    x0 = jnp.array([-0.4, 0.0, 0.1, 0.0])
    w = jnp.asarray(rng.normal(size=(300, 4)))
    model = HeliModel()

    def plain(p, x0, u):
        prepared = model.prepare(model.complete(p))

        def body(y, uk):
            return _rk4_step(model, prepared, y, uk, 0.01)[0], y

        return jnp.sum(w * jax.lax.scan(body, x0, u)[1])

    def ours(p, x0, u):
        return jnp.sum(w * simulate(p, x0, u, 0.01))

    ga = jax.grad(plain, argnums=(0, 1, 2))(FITTED, x0, u)
    gb = jax.grad(ours, argnums=(0, 1, 2))(FITTED, x0, u)
    for a, b in zip(jax.tree.leaves(ga), jax.tree.leaves(gb), strict=True):
        scale = float(jnp.max(jnp.abs(a))) + 1e-30
        assert float(jnp.max(jnp.abs(a - b))) <= ADJOINT_VS_AUTODIFF * scale


def test_input_only_torques_held_per_sample_equal_their_evaluation_at_every_stage():
    """A network of the voltages, a quadratic thrust and a torque offset are evaluated once
    per sample (per distinct voltage pair for a concrete ``u``); states and gradients
    (parameters, x0, u) equal those of the plain scheme that evaluates every term at every
    Runge-Kutta stage, with ``u`` concrete and traced, next to a term that is not held."""
    from heli_uq.model import build_model
    from heli_uq.simulation.solver import _rk4_step

    rng = np.random.default_rng(3)
    u = jnp.asarray(np.repeat(rng.uniform([1.1, 0.6], [1.5, 1.5], size=(15, 2)), 20, axis=0))
    x0 = jnp.array([-0.4, 0.0, 0.1, 0.0])
    w = jnp.asarray(rng.normal(size=(300, 4)))
    model = build_model([{"effect": "neural_torque", "axis": "yaw", "hidden": 3},
                         "pitch:quadratic_thrust", "yaw:torque_offset",
                         "yaw:quadratic_drag"]).adapted(u, jnp.zeros((300, 2)), 0.01)  # fmt: skip
    assert model.holds_torque and [t.input_only for t in model.torques] == [False, True, True, True, False]
    p = {**FITTED, **{n: float(rng.normal(0.0, 0.5)) for n in model.names if n.startswith("nn_")},
         "k_q_pitch": 0.01, "T_0_yaw": -0.005, "c_yaw": 0.01}  # fmt: skip

    def plain(p, x0, u):
        prepared = model.prepare(model.complete(p))

        def body(y, uk):
            return _rk4_step(model, prepared, y, uk, 0.01)[0], y

        return jnp.sum(w * jax.lax.scan(body, x0, u)[1])

    def held(p, x0, u):
        return jnp.sum(w * simulate(p, x0, u, 0.01, model=model))

    assert float(held(p, x0, u)) == pytest.approx(float(plain(p, x0, u)), rel=1e-12)
    ga = jax.grad(plain, argnums=(0, 1, 2))(p, x0, u)
    for gb in (jax.grad(held, argnums=(0, 1))(p, x0, u),  # concrete u: distinct pairs
               jax.grad(held, argnums=(0, 1, 2))(p, x0, u)):  # traced u: every sample
        for a, b in zip(jax.tree.leaves(ga), jax.tree.leaves(gb)):
            scale = float(jnp.max(jnp.abs(a))) + 1e-30
            assert float(jnp.max(jnp.abs(a - b))) <= ADJOINT_VS_AUTODIFF * scale


def test_accepts_arrays_and_vmap_batches():
    u = jnp.ones((50, 2)) * jnp.array([1.3, 1.0])
    x0 = jnp.array([-0.5, 0.0, 0.0, 0.0])
    a = simulate(FITTED, x0, u, 0.01)
    b = simulate({k: jnp.asarray(v) for k, v in FITTED.items()}, x0, u, 0.01)
    np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    scales = jnp.linspace(0.9, 1.1, 8)
    batch = {k: v * scales for k, v in FITTED.items()}
    ys = jax.jit(jax.vmap(lambda p: simulate(p, x0, u, 0.01)))(batch)
    assert ys.shape == (8, 50, 4)
    one = simulate({k: v * scales[3] for k, v in FITTED.items()}, x0, u, 0.01)
    np.testing.assert_allclose(ys[3], one, rtol=1e-13, atol=1e-15)


def test_missing_names_take_table2_and_unknown_names_fail():
    u = jnp.ones((20, 2))
    x0 = jnp.zeros(4)
    a = simulate({"m": 0.5}, x0, u, 0.01)
    b = simulate(heli_uq.TABLE2, x0, u, 0.01)
    np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    with pytest.raises(heli_uq.ParameterError, match="mass"):
        simulate({"mass": 1.0}, x0, u, 0.01)
    with pytest.raises(heli_uq.ParameterError, match="J_s"):  # outside its support
        simulate({"J_s": -0.001}, x0, u, 0.01)


@pytest.mark.parametrize(
    "x0, u, match",
    [(jnp.zeros(3), jnp.ones((5, 2)), "x0"), (jnp.zeros(4), jnp.ones((5, 3)), "u"),
     (jnp.zeros(4), jnp.ones(5), "u")],
)  # fmt: skip
def test_bad_shapes_give_clear_errors(x0, u, match):
    with pytest.raises(heli_uq.ParameterError, match=match):
        simulate(FITTED, x0, u, 0.01)


def test_failure_is_a_flag_not_an_exception():
    """A singular yaw inertia (M22 -> 0) gives NaN; huge gains blow up: both are flagged."""
    u = jnp.ones((500, 2)) * jnp.array([1.3, 1.0])
    x0 = jnp.array([0.0, 0.0, 0.0, 0.0])
    ok = solve(FITTED, x0, u, 0.01)
    assert int(ok.result) == RESULTS.successful and bool(ok.ok)
    blown = solve({**FITTED, "K_psi_theta": 1e6}, x0, u, 0.01)
    assert int(blown.result) != RESULTS.successful
    # Traced values are not checked against their supports (a sampler may propose
    # anything): a negative shaft inertia makes M22 vanish, and that is a flag too.
    f = jax.jit(lambda p: solve(p, x0, u, 0.01).result)
    assert int(f({**FITTED, "J_s": -0.0029, "J_bc": 1e-4, "m": 1e-3})) != RESULTS.successful
    assert int(f({**FITTED, "K_psi_theta": 1e6})) != RESULTS.successful


def test_recovers_known_state_derivative():
    """The first step of the simulator follows the vector field: (y1 - y0)/dt ~ f(y0)."""
    x0 = jnp.array([0.3, 0.0, 0.0, 0.0])
    u = jnp.zeros((2, 2))
    dt = 1e-5
    ys = simulate(FITTED, x0, u, dt)
    p = FITTED
    m11 = p["J_bc"] + p["m"] * p["r_c"] ** 2 + p["m"] * p["h"] ** 2
    expected = -p["m"] * p["g"] * (p["r_c"] * jnp.cos(0.3) - p["h"] * jnp.sin(0.3)) / m11
    assert abs(float((ys[1, 2] - ys[0, 2]) / dt - expected)) < 1e-3 * abs(float(expected))


def test_forward_mode_available_with_autodiff_gradients():
    u = jnp.ones((100, 2)) * jnp.array([1.3, 1.0])
    x0 = jnp.array([-0.5, 0.0, 0.0, 0.0])

    def out(x, gradients):
        return simulate(FITTED, x, u, 0.01, gradients=gradients)[:, :2]

    jf = jax.jacfwd(lambda x: out(x, "autodiff"))(x0)
    jr = jax.jacrev(lambda x: out(x, "adjoint"))(x0)
    np.testing.assert_allclose(jf, jr, rtol=1e-10, atol=1e-12)
    with pytest.raises(heli_uq.ParameterError, match="gradients"):
        simulate(FITTED, x0, u, 0.01, gradients="magic")


@pytest.mark.parametrize("chunk", [None, 64])
def test_substeps_and_chunked_adjoint_equal_plain_nested_rk4(monkeypatch, chunk):
    """Substeps run as rows of their own and the adjoint runs in chunks (``chunk`` steps,
    forced small here so that several chunks and a partial one occur); the states and the
    gradients (parameters, x0, u) must be those of plain reverse-mode autodiff through
    ``substeps`` nested RK4 steps per sample, on a stiff friction model."""
    import heli_uq.simulation.solver as solver
    from heli_uq.model import build_model
    from heli_uq.simulation.solver import _rk4_step

    substeps, n = 3, 100  # 300 steps: 4 chunks of 64 and 44 steps before them
    if chunk is not None:
        monkeypatch.setattr(solver, "ADJOINT_CHUNK", chunk)
    model = build_model(["yaw:coulomb_friction"])
    rng = np.random.default_rng(3)
    u = jnp.asarray(rng.uniform([1.2, 0.5], [1.5, 1.6], size=(n, 2)))
    w = jnp.asarray(rng.normal(size=(n, 4)))
    x0 = jnp.array([-0.4, 0.2, 0.1, 0.0])
    params = {**FITTED, "F_c_yaw": 0.004}

    def plain(p, x0, u):
        prepared = model.prepare(model.complete(p))

        def body(y, uk):
            y_next = y
            for _ in range(substeps):
                y_next = _rk4_step(model, prepared, y_next, uk, 0.01 / substeps)[0]
            return y_next, y

        return jnp.sum(w * jax.lax.scan(body, x0, u)[1])

    def ours(p, x0, u):
        return jnp.sum(w * simulate(p, x0, u, 0.01, model=model, substeps=substeps))

    assert float(ours(params, x0, u)) == pytest.approx(float(plain(params, x0, u)), rel=1e-13)
    ga = jax.grad(plain, argnums=(0, 1, 2))(params, x0, u)
    gb = jax.grad(ours, argnums=(0, 1, 2))(params, x0, u)
    for a, b in zip(jax.tree.leaves(ga), jax.tree.leaves(gb), strict=True):
        scale = float(jnp.max(jnp.abs(a))) + 1e-30
        assert float(jnp.max(jnp.abs(a - b))) <= ADJOINT_VS_AUTODIFF * scale
