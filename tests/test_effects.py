"""Named effects: their equations against independent forms, the solver's accuracy on them,
their parameters' declarations, and every effect through every stage of the package."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from heli_uq.errors import ParameterError
from heli_uq.identifiability.structural import (
    ParameterVector,
    scaling_direction,
    structural_analysis,
)
from heli_uq.model import (
    EFFECTS,
    TABLE1,
    HeliModel,
    LagrangianMechanics,
    build_model,
    parse_effects,
    total_energy,
)
from heli_uq.model.terms.rigid_body import pitch_inertia, yaw_inertia
from heli_uq.simulation import default_substeps, reference_solve, simulate, solve
from heli_uq.simulation.reference import solver_error
from heli_uq.simulation.stiffness import STABLE_STEP, stiffness_check, stiffness_rates, substeps_covering

#: One value per effect parameter: large enough to matter on a record, physically plausible.
EFFECT_VALUES = {
    "deadband": {"delta": 0.3},
    "coulomb_friction": {"F_c": 0.004},
    "quadratic_drag": {"c": 0.02},
    "torsional_spring": {"k": 0.004, "psi_0": 0.4},
    "quadratic_thrust": {"k_q": 0.01},
    "torque_offset": {"T_0": 0.002},
}
#: Every effect once; the axes alternate so both are exercised.
ALL_EFFECTS = ("pitch:deadband", "yaw:coulomb_friction", "yaw:quadratic_drag",
               "yaw:torsional_spring", "pitch:quadratic_thrust", "yaw:torque_offset")  # fmt: skip
#: The solver must stay within this angle error [rad] of the adaptive reference (issue goal).
SOLVER_TOL = 1e-4
EOM_AGREEMENT = 1e-10


def test_the_tables_of_this_file_hold_every_effect_of_the_vocabulary():
    """A new effect in ``EFFECTS`` must come with a value here and join the lists that run
    every effect (README, "Adding a term"): without this check the lists left it out
    silently and the value table failed with a bare ``KeyError``."""
    kinds = set(EFFECTS)
    missing = kinds - set(EFFECT_VALUES)
    assert not missing, f"add a value per parameter of {sorted(missing)} to EFFECT_VALUES"
    for name, table in (("ALL_EFFECTS", ALL_EFFECTS), ("PIPELINE_MODEL", PIPELINE_MODEL)):
        listed = {item.split(":")[1] if isinstance(item, str) else item["effect"] for item in table}
        assert kinds <= listed, f"add {sorted(kinds - listed)} to {name}"


def _values(model: HeliModel) -> dict:
    out = dict(TABLE1)
    for term in model.effects:
        for par in term.parameters():
            out[par.name] = EFFECT_VALUES[term.kind][par.bare]
    return out


def _rig_like_inputs(seconds: float, seed: int = 0, dt: float = 0.01) -> np.ndarray:
    """Voltage staircase in the rig's ranges (u_theta 1.22-1.47 V, u_psi 0.45-1.6 V)."""
    rng = np.random.default_rng(seed)
    n = round(seconds / dt)
    levels = rng.uniform([1.25, 0.45], [1.42, 1.6], size=(n // 150 + 1, 2))
    return np.repeat(levels, 150, axis=0)[:n]


# ------------------------------------------------------------------ the equations


def _independent_force(kind, axis, p, x, v, u):
    """The effects table's equations, written out here with numpy (no heli_uq code)."""
    i = 0 if axis == "pitch" else 1
    t = np.zeros(2)
    if kind == "coulomb_friction":
        t[i] = -p["F_c"] * np.tanh(v[i] / 0.002)
    elif kind == "quadratic_drag":
        t[i] = -p["c"] * v[i] * abs(v[i])
    elif kind == "torsional_spring":
        t[i] = -p["k"] * (x[i] - p["psi_0"])
    elif kind == "quadratic_thrust":  # same sense as +K_theta_theta u_theta / -K_psi_psi u_psi
        t[i] = (1.0 if axis == "pitch" else -1.0) * p["k_q"] * u[i] * abs(u[i])
    elif kind == "torque_offset":
        t[i] = p["T_0"]
    return t


def _linear(p, v, u):
    return np.array([p["K_theta_theta"] * u[0] - p["K_theta_psi"] * u[1] - p["D_theta"] * v[0],
                     p["K_psi_theta"] * u[0] - p["K_psi_psi"] * u[1] - p["D_psi"] * v[1]])  # fmt: skip


@pytest.mark.parametrize("kind", sorted(EFFECTS))
@pytest.mark.parametrize("axis", ["pitch", "yaw"])
def test_effect_equations_match_the_table(kind, axis):
    model = build_model([f"{axis}:{kind}"])
    values = _values(model)
    p = model.complete(values)
    bare = EFFECT_VALUES[kind]
    rng = np.random.default_rng(0)
    for _ in range(6):
        x = rng.uniform([-1.0, -2.0], [0.5, 2.0])
        v = rng.normal(0.0, 0.5, 2) * rng.choice([1e-3, 1.0])  # near rest too
        u = rng.uniform([-1.5, -1.5], [1.5, 1.5])
        if kind == "deadband":
            i = 0 if axis == "pitch" else 1
            mapped = np.array(u, dtype=float)
            mapped[i] = np.sign(u[i]) * max(abs(u[i]) - bare["delta"], 0.0)
            np.testing.assert_allclose(np.asarray(model.input_voltages(p, jnp.asarray(u))), mapped,
                                       atol=1e-15)  # fmt: skip
            expected = _linear(values, v, mapped)  # the dead band feeds every gain of that motor
        else:
            expected = _linear(values, v, u) + _independent_force(kind, axis, bare, x, v, u)
        got = model.force(p, jnp.asarray(x), jnp.asarray(v), model.input_voltages(p, jnp.asarray(u)))
        np.testing.assert_allclose(np.asarray(got), expected, rtol=1e-12, atol=1e-15)


def test_torques_flagged_input_only_read_neither_angles_nor_rates():
    """A torque flagged ``input_only`` is evaluated once per sample and held (the solver
    never passes it the states), so it must not depend on them: its value and its
    derivatives with respect to ``x`` and ``v`` are checked at random states."""
    terms = [*ALL_EFFECTS, "pitch:torque_offset", "yaw:quadratic_thrust",
             {"effect": "neural_torque", "axis": "yaw", "hidden": 3, "inputs": "u"},
             {"effect": "neural_torque", "axis": "pitch", "hidden": 3, "inputs": "u,x,v"},
             {"effect": "feature_torque", "axis": "yaw", "features": ["u_psi^2", "cos(u_psi)"]}]  # fmt: skip
    model = build_model(terms)
    rng = np.random.default_rng(1)
    learned = [par.name for t in model.torques if t.kind in ("neural_torque", "feature_torque")
               for par in t.parameters()]  # fmt: skip
    p = model.complete({**_values(build_model(list(ALL_EFFECTS))),
                        **{n: float(rng.normal(0.0, 0.5)) for n in learned}})
    flagged = {t.label: t.input_only for t in model.torques}
    assert flagged["neural_torque(yaw)"] and not flagged["neural_torque(pitch)"]
    assert not flagged["linear"] and not flagged["coulomb_friction(yaw)"]
    u = jnp.asarray(rng.uniform([1.2, 0.5], [1.5, 1.6]))
    for term in model.torques:
        if not term.input_only:
            continue

        def torque(x, v, term=term):
            return jnp.stack([jnp.asarray(f, dtype=jnp.float64) for f in term(p, x, v, u)])

        x, v = jnp.asarray(rng.normal(size=2)), jnp.asarray(rng.normal(size=2))
        np.testing.assert_array_equal(torque(x, v), torque(jnp.zeros(2), jnp.zeros(2)), err_msg=term.label)
        jx, jv = jax.jacfwd(torque, argnums=(0, 1))(x, v)
        assert not np.any(np.asarray(jx)) and not np.any(np.asarray(jv)), term.label


def test_the_dead_band_declares_one_start_per_interval_between_voltage_levels():
    """Levels 0.5, 0.8 and 1.2 V on the yaw motor (signs and repeats ignored): one start
    below them all and one between each two; the pitch motor's levels give the pitch
    dead band's; terms without a grid declare none."""
    u = np.array([[1.3, 0.8], [1.3, -0.5], [1.4, 1.2], [1.4, 0.8], [1.3, 0.0]])
    model = build_model(["yaw:deadband", "pitch:deadband", "yaw:torque_offset"])
    grid = model.start_grid(u)
    assert set(grid) == {"delta_yaw", "delta_pitch"}
    np.testing.assert_allclose(grid["delta_yaw"], [0.25, 0.65, 1.0])
    np.testing.assert_allclose(grid["delta_pitch"], [0.65, 1.35])
    assert build_model([]).start_grid(u) == {}


def test_effect_names_carry_the_axis_and_the_bare_name():
    model = parse_effects(",".join(ALL_EFFECTS))
    names = {p.name: p for t in model.effects for p in t.parameters()}
    assert set(names) == {"delta_pitch", "F_c_yaw", "c_yaw", "k_yaw", "psi_0_yaw", "k_q_pitch",
                          "T_0_yaw"}  # fmt: skip
    assert names["F_c_yaw"].bare == "F_c" and names["psi_0_yaw"].bare == "psi_0"
    # torque-type parameters scale with the inertias, widths and angles do not
    assert {n for n, p in names.items() if p.scales_with_inertia} == {
        "F_c_yaw", "c_yaw", "k_yaw", "k_q_pitch", "T_0_yaw"}
    # a friction level or a dead band may be exactly 0: the default prior allows it
    for n in ("delta_pitch", "F_c_yaw", "c_yaw", "k_yaw"):
        assert names[n].prior.kind == "halfnormal" and names[n].prior.support[0] == 0.0


def test_mechanics_by_autodiff_agree_with_the_closed_form_with_every_effect():
    closed = parse_effects(",".join(ALL_EFFECTS))
    auto = HeliModel(LagrangianMechanics(), closed.inputs, closed.torques)
    p = closed.complete(dict(_values(closed), h=0.01))
    rng = np.random.default_rng(1)
    for _ in range(5):
        y = jnp.asarray(rng.uniform([-1.2, -3, -2, -2], [1.2, 3, 2, 2]))
        u = jnp.asarray(rng.uniform([1.2, 0.4], [1.5, 1.6]))
        a = closed(0.0, y, (p, u))
        b = auto(0.0, y, (p, u))
        assert float(jnp.max(jnp.abs(a - b))) <= EOM_AGREEMENT * float(jnp.max(jnp.abs(a)))


def test_energy_balance_with_friction_drag_and_spring():
    """With u = 0, D = 0 and the spring's energy added, dE/dt = v . (friction + drag): the
    energy lost over a run equals the integral of the dissipated power, and with friction
    and drag removed the total energy (incl. the spring) is conserved."""
    model = parse_effects("yaw:coulomb_friction,yaw:quadratic_drag,yaw:torsional_spring")
    p = dict(_values(model), D_theta=0.0, D_psi=0.0, h=0.01, F_c_yaw=0.002)
    x0 = jnp.array([0.6, 0.0, -0.3, 1.2])
    dt, n = 0.005, 1201
    u = jnp.zeros((n, 2))
    ys = np.asarray(simulate(p, x0, u, dt, model=model, substeps=8))
    spring = 0.5 * p["k_yaw"] * (ys[:, 1] - p["psi_0_yaw"]) ** 2
    energy = np.asarray(total_energy(model.complete(p), ys)) + spring
    power = -p["F_c_yaw"] * np.tanh(ys[:, 3] / 0.002) * ys[:, 3] - p["c_yaw"] * np.abs(ys[:, 3]) ** 3
    dissipated = np.concatenate([[0.0], np.cumsum(0.5 * (power[1:] + power[:-1]) * dt)])
    drop = energy - energy[0]
    assert drop[-1] < -0.1 * abs(energy[0] - energy.min() + 1e-12) or drop[-1] < 0
    np.testing.assert_allclose(drop, dissipated, atol=2e-3 * abs(drop[-1]))
    conservative = dict(p, F_c_yaw=0.0, c_yaw=0.0)
    ys = np.asarray(simulate(conservative, x0, u, dt, model=model, substeps=4))
    energy = np.asarray(total_energy(model.complete(conservative), ys)) + 0.5 * p["k_yaw"] * (
        ys[:, 1] - p["psi_0_yaw"]) ** 2
    assert np.max(np.abs(energy - energy[0])) < 1e-8 * abs(energy[0])


# ------------------------------------------------------------------ the solver


@pytest.mark.parametrize("effect", ALL_EFFECTS)
def test_default_substeps_keep_the_angle_error_below_tolerance(effect):
    """At its documented smoothing, each effect's default substeps keep the fixed-step
    solution within 1e-4 rad of the adaptive stiff reference (diffrax Kvaerno5) on 30 s of
    rig-like inputs, and the error falls as the substeps grow."""
    model = build_model([effect])
    values = _values(model)
    u = _rig_like_inputs(30.0, seed=2)
    x0 = [-0.5, 0.3, 0.0, 0.0]
    ref = reference_solve(values, x0, u, 0.01, model=model)
    assert np.ptp(ref[:, 1]) > 0.05  # the yaw actually moves
    n = default_substeps(model, values, 0.01, margin=2.0, thetas=ref[:, 0])
    errs = {s: solver_error(values, x0, u, 0.01, model=model, substeps=s, reference=ref)
            for s in sorted({n, 2 * n, 4 * n})}  # fmt: skip
    assert errs[n] <= SOLVER_TOL, errs
    assert errs[4 * n] <= errs[n], errs


def test_sharp_friction_needs_substeps_and_gets_them():
    """A friction level that makes the term stiff: one substep is visibly wrong (or
    unstable), the default count is accurate."""
    model = build_model(["yaw:coulomb_friction"])
    values = dict(_values(model), F_c_yaw=0.02)
    u = _rig_like_inputs(20.0, seed=3)
    x0 = [-0.5, 0.3, 0.0, 0.0]
    ref = reference_solve(values, x0, u, 0.01, model=model)
    n = default_substeps(model, values, 0.01, margin=2.0, thetas=ref[:, 0])
    assert n >= 4
    one = solver_error(values, x0, u, 0.01, model=model, substeps=1, reference=ref)
    assert not one <= 10 * SOLVER_TOL  # NaN (unstable) or far off
    assert solver_error(values, x0, u, 0.01, model=model, substeps=n, reference=ref) <= SOLVER_TOL


#: ``rate h`` of the draws the stiffness check is tested on: two within STABLE_STEP, one
#: stable but past it, two past RK4's stability limit 2.785.
RATE_STEPS = (1.0, 1.4, 2.5, 3.2, 4.5)


def test_stiffness_rates_are_the_friction_slope_at_rest():
    """The rate a draw is checked with is the slope of the pitch acceleration the friction
    adds at rest, ``-d a_theta / d omega_theta`` (autodiff of the model's equations), also
    where a fixed inertia differs from the start value."""
    model = build_model(["pitch:coulomb_friction"])
    levels = np.array([0.002, 0.01, 0.04])
    for fixed in (_values(model), dict(_values(model), J_bc=0.02)):
        rates = stiffness_rates(model, {"F_c_pitch": levels}, fixed=fixed)
        for level, rate in zip(levels, rates):
            def pitch_acc(w, f):
                p = model.complete(dict(fixed, F_c_pitch=f))
                x, v, u = jnp.array([-0.5, 0.3]), jnp.array([w, 0.0]), jnp.array([1.3, 1.0])
                return model.acceleration(model.prepare(p), x, v, u)[0]

            slope = jax.grad(pitch_acc)(0.0, float(level)) - jax.grad(pitch_acc)(0.0, 0.0)
            np.testing.assert_allclose(rate, -float(slope), rtol=1e-9)


def test_stiffness_of_many_draws_at_once_equals_each_draw_from_the_inertia_definition():
    """The rates of a run's draws, computed for all draws in one call, equal per draw the
    sum of each yaw term's rate over the smallest ``M22`` found by evaluating
    ``M22(theta)`` at every pitch angle of a record (pitch: over ``M11``), the larger axis;
    a single draw as scalars gives the same float."""
    model = build_model(["yaw:coulomb_friction", "yaw:stiction", "yaw:torsional_spring",
                         "pitch:coulomb_friction"])
    rng = np.random.default_rng(3)
    n = 200
    values = dict(TABLE1, F_c_yaw=0.004, F_s_yaw=0.002, k_yaw=0.004, psi_0_yaw=0.4, F_c_pitch=0.004)
    draws = {name: float(values[name]) * np.exp(0.3 * rng.standard_normal(n))
             for name in ("r_c", "m", "J_bc", "J_s", "F_c_yaw", "F_s_yaw", "k_yaw", "F_c_pitch")}  # fmt: skip
    draws["h"] = 0.05 * rng.standard_normal(n)  # either sign: the minimum moves with it
    thetas = rng.uniform(-1.2, 0.4, size=500)
    rates = stiffness_rates(model, draws, thetas=thetas)
    omega_s = 0.002  # the terms' default smoothing width [rad/s]
    for i in range(n):
        p = {k: v[i] for k, v in draws.items()}
        m22 = float(np.min(yaw_inertia(p, thetas)))  # M22 at every angle (one call, not 500)
        m11 = float(pitch_inertia(p))
        yaw = (p["F_c_yaw"] + p["F_s_yaw"]) / (omega_s * m22) + math.sqrt(p["k_yaw"] / m22)
        np.testing.assert_allclose(rates[i], max(yaw, p["F_c_pitch"] / (omega_s * m11)), rtol=1e-12)
    one = model.stiffness(dict(values, **{k: v[7] for k, v in draws.items()}), thetas)
    assert isinstance(one, float) and one == pytest.approx(rates[7], rel=1e-12)
    # a missing angle (NaN) is left out; one angle is that angle's inertia
    np.testing.assert_array_equal(stiffness_rates(model, draws, thetas=np.append(thetas, np.nan)), rates)
    single = model.mechanics.inertia_bounds({k: v[:5] for k, v in draws.items()}, [0.3])[1]
    np.testing.assert_allclose(single, [float(yaw_inertia({k: v[i] for k, v in draws.items()}, 0.3))
                                        for i in range(5)], rtol=1e-12)  # fmt: skip


def test_stiffness_check_flags_the_draws_the_solver_gets_wrong():
    """Of five friction draws at 2 substeps, the check counts exactly the two past RK4's
    stability limit, the adaptive reference finds exactly those two off by more than the
    tolerance, and the substeps that cover all five bring every one within it."""
    model = build_model(["pitch:coulomb_friction"])
    values = _values(model)
    u = _rig_like_inputs(20.0, seed=5)
    x0 = [-0.5, 0.3, 0.0, 0.0]
    dt, substeps = 0.01, 2
    per_level = stiffness_rates(model, {"F_c_pitch": np.array([1.0])}, fixed=values)[0]
    levels = np.array([r / (per_level * dt / substeps) for r in RATE_STEPS])
    rates = stiffness_rates(model, {"F_c_pitch": levels}, fixed=values)
    check = stiffness_check(model, {"F_c_pitch": levels}, substeps, dt, fixed=values)
    assert check["beyond"] == 2 and check["of"] == 5 and check["stiffest"] == 4, check
    covering = substeps_covering(rates, dt)
    assert covering > substeps
    for level, rate in zip(levels, rates):
        p = dict(values, F_c_pitch=float(level))
        ref = reference_solve(p, x0, u, dt, model=model)
        error = solver_error(p, x0, u, dt, model=model, substeps=substeps, reference=ref)
        assert (error > SOLVER_TOL) == (rate > check["rate_limit"]), (rate, error)
        assert solver_error(p, x0, u, dt, model=model, substeps=covering, reference=ref) <= SOLVER_TOL


def test_viscous_damping_within_the_stable_step_is_accurate_and_past_the_limit_blows_up():
    """Why a run's draws are checked for the damping only past :data:`STABLE_STEP`: a linear
    decaying mode (``D / M`` times the step up to 1.4, on either axis) is simulated within
    the solver tolerance at one substep, and past RK4's limit 2.785 the solve fails, which
    the sampler rejects (between the two the yaw errs up to ~1e-4 rad: the next test)."""
    model = HeliModel()
    values = model.complete({})
    u = _rig_like_inputs(20.0, seed=5)
    x0 = [-0.5, 0.3, 0.0, 0.0]
    dt = 0.01
    # the yaw inertia varies with the pitch: its extremes over the pitch angles visited
    thetas = np.asarray(solve(values, x0, u, dt, model=model).ys)[:, 0]
    yaw = np.array([float(yaw_inertia(values, th)) for th in thetas])
    pitch = float(pitch_inertia(values))
    for name, smallest, largest in (("D_theta", pitch, pitch), ("D_psi", yaw.min(), yaw.max())):
        p = dict(values, **{name: STABLE_STEP / dt * smallest})  # r h at most 1.4 all along
        assert solver_error(p, x0, u, dt, model=model, substeps=1) <= SOLVER_TOL, name
        beyond = dict(values, **{name: 3.0 / dt * largest})  # past 2.785 all along
        assert not bool(solve(beyond, x0, u, dt, model=model, substeps=1).ok), name


def test_a_posterior_damped_past_the_stable_step_is_compared_with_the_reference(synthetic_problem):
    """The posterior's solver check (:func:`heli_uq.output.posterior_study._solver_check`)
    skips a model without stiff terms whose damping every draw resolves, and compares the
    most damped draw with the adaptive reference once one is past :data:`STABLE_STEP`."""
    import arviz as az

    from heli_uq.model import X0_NAMES
    from heli_uq.output.posterior_study import _solver_check

    problem = synthetic_problem
    values = problem.model.complete({})
    free = [n for n, prior in problem.priors.params.items() if prior.free]
    x0 = [-0.5, 0.3, 0.0, 0.0]
    yaw_least = float(np.min(yaw_inertia(values, problem.y[: problem.n_train, 0])))
    heavy = 2.5 / problem.dt * problem.substeps * yaw_least  # r h 2.5 at the smallest inertia

    def posterior(d_psi_of_draw):
        shape = (2, 3)
        post = {n: np.full(shape, float(values[n])) for n in free}
        post.update({n: np.full(shape, v) for n, v in zip(X0_NAMES, x0)})
        post["D_psi"] = np.reshape(d_psi_of_draw, shape)
        lp = -np.arange(6.0).reshape(shape)  # the draw of highest density: chain 0, draw 0
        return az.from_dict(posterior=post, sample_stats={"lp": lp})

    rig = np.full(6, float(values["D_psi"]))
    assert _solver_check(problem, posterior(rig)) == (None, None)
    damped = rig.copy()
    damped[4] = heavy  # chain 1, draw 1
    error, stiffness = _solver_check(problem, posterior(damped))
    assert stiffness is None
    p = {n: float(prior.a) for n, prior in problem.priors.params.items()}
    p.update({n: float(values[n]) for n in free}, D_psi=heavy)
    expected = solver_error(p, x0, problem.u, problem.dt, model=problem.model, substeps=problem.substeps)
    assert error == pytest.approx(expected, rel=1e-9) and error > 0.0


# ------------------------------------------------------------------ identifiability


def _structural(effects, values_extra=None):
    model = parse_effects(",".join(effects))
    values = dict(_values(model), h=0.004, **(values_extra or {}))
    u = _rig_like_inputs(6.0, seed=4)
    free = [n for n in model.names if n != "g"]
    x0 = [-0.5, 0.3, 0.1, -0.2]
    pv = ParameterVector(model, free, values, substeps=2)
    w = pv.from_model(values, x0)
    return model, values, u, x0, pv, w, structural_analysis(pv, [w], u, 0.01)


def _distance_to(basis, v):
    v = np.asarray(v, dtype=float) / np.linalg.norm(v)
    return float(np.linalg.norm(v - basis @ (basis.T @ v)))


def test_null_direction_from_the_declarations_matches_the_svd():
    """With every effect but the offset in the model, the structural null space is one-
    dimensional and equals the common scaling derived from the ``scales_with_inertia``
    flags (loading 1 on log coordinates, the value on linear ones such as k_q)."""
    effects = [e for e in ALL_EFFECTS if "torque_offset" not in e]
    model, values, u, x0, pv, w, st = _structural(effects)
    assert st.rank == pv.dim - 1
    derived = scaling_direction(pv, w)
    assert derived[pv.names.index("k_q_pitch")] != 0 and derived[pv.names.index("delta_pitch")] == 0
    assert _distance_to(st.null_basis, derived) < 1e-8
    assert [d["key"] for d in st.null_directions] == ["common_scaling"]
    # the invariance itself: scale every flagged parameter, the angles do not move
    scaled = {n: v * (2.5 if n in model.scale_names else 1.0) for n, v in values.items()}
    a = np.asarray(simulate(values, x0, u, 0.01, model=model, substeps=2))[:, :2]
    b = np.asarray(simulate(scaled, x0, u, 0.01, model=model, substeps=2))[:, :2]
    assert np.max(np.abs(a - b)) < 1e-10


def test_a_constant_torque_twice_on_one_axis_is_found_by_the_svd():
    """A spring and an offset on one axis both add a constant torque (T_0 + k psi_0): the
    declarations do not know this trade, the numerical null space finds it, and the report
    describes it instead of hiding it."""
    model, values, u, x0, pv, w, st = _structural(["yaw:torsional_spring", "yaw:torque_offset"])
    assert st.rank == pv.dim - 2
    assert _distance_to(st.null_basis, scaling_direction(pv, w)) < 1e-8
    trade = np.zeros(pv.dim)
    trade[pv.names.index("psi_0_yaw")] = 1.0
    trade[pv.names.index("T_0_yaw")] = -values["k_yaw"]  # d T_0 = -k d psi_0
    assert _distance_to(st.null_basis, trade) < 1e-8
    keys = [d["key"] for d in st.null_directions]
    assert keys[0] == "common_scaling" and keys[1] == "unexplained"
    assert "psi_0_yaw" in st.null_directions[1]["description"]


def test_bad_effect_options_and_priors_are_clear_errors():
    with pytest.raises(ParameterError, match="expected one of deadband"):
        parse_effects("yaw:backlash")
    with pytest.raises(ParameterError, match="unknown axis 'roll'"):
        parse_effects("roll:deadband")
    with pytest.raises(ParameterError, match="AXIS:EFFECT"):
        parse_effects("coulomb_friction")
    with pytest.raises(ParameterError, match="omega_s"):
        build_model([{"effect": "coulomb_friction", "axis": "yaw", "omega_s": -1.0}])
    with pytest.raises(ParameterError, match="unknown option"):
        build_model([{"effect": "coulomb_friction", "axis": "yaw", "width": 1.0}])
    from heli_uq.model import Prior
    from heli_uq.probability import PriorSet

    model = parse_effects("yaw:coulomb_friction")
    with pytest.raises(ParameterError, match="outside its support"):
        PriorSet.default(model).updated(model, {"F_c_yaw": Prior("normal", 0.0, 0.01)})
    with pytest.raises(ParameterError, match="F_c_yaw"):
        solve({"F_c_yaw": -0.1}, [0.0] * 4, np.ones((3, 2)), 0.01, model=model)


def test_model_description_round_trips():
    from heli_uq.model import model_from_description

    model = build_model([{"effect": "coulomb_friction", "axis": "yaw", "omega_s": 0.001},
                         "pitch:deadband"])  # fmt: skip
    again = model_from_description(model.describe())
    assert again.describe() == model.describe() and again.label == model.label
    assert math.isclose(again.effects[1].omega_s, 0.001)
    assert jax.tree.structure(again) == jax.tree.structure(model)


# ------------------------------------------------------------------ every stage

#: One model with every effect once, with no two constant torques on one axis (one model:
#: compiling the sampler for it is most of this test's time).  Friction is smoothed over
#: 0.02 rad/s: on a 1.5 s record the MAP's friction level is poorly determined, and a
#: sharp one would need many substeps (slow to compile).
PIPELINE_MODEL = ("pitch:deadband", {"effect": "coulomb_friction", "axis": "yaw", "omega_s": 0.02},
                  "yaw:quadratic_drag", "pitch:torque_offset", "yaw:torsional_spring",
                  "yaw:quadratic_thrust")  # fmt: skip


@pytest.mark.slow
def test_every_effect_runs_through_every_stage(tmp_path):
    """solve, the numpyro model, the MAP, NUTS, the results and identifiability all take a
    model with effects and name its parameters with their axes (a run-through at small
    sizes; the statistics are checked by the recovery test below and tests/test_posterior)."""
    from heli_uq.inference import prepare_start, run_nuts
    from heli_uq.output import to_inference_data
    from heli_uq.probability import make_problem
    from heli_uq.simulation import synthetic_experiment

    model = build_model(list(PIPELINE_MODEL))
    truth = _values(model)
    record = synthetic_experiment(truth, (-0.5, 0.3, 0.0, 0.0), inputs=_rig_like_inputs(1.5, 5),
                                  noise_std=(0.005, 0.005), seed=6, model=model)  # fmt: skip
    problem = make_problem(record, model=model, error="iid")
    effect_names = [p.name for t in model.effects for p in t.parameters()]
    assert all(any(n in c for c in problem.coords.names) for n in effect_names)
    start = prepare_start(problem, n_starts=1)
    assert np.isfinite(start.map_value)
    run = run_nuts(problem, tmp_path, chains=1, warmup=10, draws=10, progress=False,
                   start=start, max_tree_depth=4)  # fmt: skip
    idata = to_inference_data(run, prior_draws=20, pp_draws=5)
    for name in effect_names:
        draws = np.asarray(idata.posterior[name])
        assert draws.shape == (1, 10) and np.all(np.isfinite(draws)), name
        assert name in idata.prior
    assert np.all(np.isfinite(np.asarray(idata.log_likelihood["y"])))
    assert "effects" in idata.posterior.attrs["model"]
    # identifiability at the truth: the common scaling, derived from the declarations, is
    # a null direction of the sensitivities (on a 1.5 s record there are others too, e.g.
    # a dead band the voltage never drops below acts as constant torques; the rank of a
    # rich record is checked by test_null_direction_from_the_declarations_matches_the_svd)
    free = [n for n in model.names if n != "g"]
    pv = ParameterVector(model, free, dict(truth, h=0.004), substeps=run.problem.substeps)
    w = pv.from_model(pv.base, (-0.5, 0.3, 0.0, 0.0))
    st = structural_analysis(pv, [w], record.u, record.dt)
    assert st.rank < pv.dim
    assert _distance_to(st.null_basis, scaling_direction(pv, w)) < 1e-8


# ------------------------------------------------------------------ recovery

#: The central posterior interval that must hold the hidden truth.
RECOVERY_INTERVAL = (0.025, 0.975)
#: Draws of the Laplace approximation.
LAPLACE_DRAWS = 4000
#: The truth's yaw inertia must lie between these quantiles of its posterior: away from
#: the edges of the 95 % interval, where the product of the priors put it (0.025).
SCALE_QUANTILES = (0.1, 0.9)
#: The effect whose recovery CI runs: the stiffest.  The others (about 20 s each, most of it
#: compiling their own model) are in the long tier; the discovery confusion study recovers
#: every effect on both axes with NUTS, from 131 s records of the reference solver.
CI_RECOVERY = "coulomb_friction"


@pytest.mark.slow
@pytest.mark.parametrize("kind", [k if k == CI_RECOVERY else pytest.param(k, marks=pytest.mark.long)
                                  for k in sorted(EFFECTS)])  # fmt: skip
def test_hidden_effect_is_recovered(kind):
    """A 15 s record simulated by the *adaptive stiff reference solver* (not the fixed-step
    one the model uses), noise 5 mrad, with one effect hidden on yaw: the 95 % intervals
    of the posterior hold the truth, for each effect parameter: its value, and its ratio
    to the yaw inertia if it scales with the inertia (what the record identifies).  The
    posterior is the Laplace approximation at the MAP (in the sampler's unconstrained
    coordinates, so skewed in physical units), to keep CI short;
    ``studies/effect_recovery.py`` checks the same with NUTS.

    A torque's physical value is the ratio times the common scale of every inertia, gain
    and torque, which no record fixes (the null direction above), so its interval is where
    the scale's prior puts it.  Under the product of the priors the yaw friction's interval
    [0.0041, 0.062] N m ended at the truth 0.004: the truth's yaw inertia lay at the 2.5 %
    quantile (:mod:`heli_uq.probability.common_scale`).  Now the truth's yaw inertia must
    lie inside the central :data:`SCALE_QUANTILES` of its posterior (0.33 on this
    record)."""
    from heli_uq.inference import prepare_start
    from heli_uq.model.terms.rigid_body import yaw_inertia
    from heli_uq.probability import make_problem
    from heli_uq.simulation import synthetic_experiment

    model = build_model([f"yaw:{kind}"])
    truth = _values(model)

    def reference(p, x0, u, dt):
        return reference_solve(p, x0, u, dt, model=model)

    record = synthetic_experiment(truth, (-0.5, 0.3, 0.0, 0.0), inputs=_rig_like_inputs(15.0, 1),
                                  noise_std=(0.005, 0.005), seed=1, simulator=reference)  # fmt: skip
    problem = make_problem(record, model=model, error="iid")
    start = prepare_start(problem, n_starts=1)
    assert start.map_decrement < 1e-8
    s = start.laplace_draws(LAPLACE_DRAWS, seed=0)
    theta_ref = problem.coords.yaw_theta_ref
    m22, m22_true = yaw_inertia(s, theta_ref), yaw_inertia(truth, theta_ref)
    quantile = float(np.mean(np.ravel(m22) < m22_true))
    assert SCALE_QUANTILES[0] < quantile < SCALE_QUANTILES[1], quantile
    for par in model.effects[0].parameters():
        checks = [(par.name, s[par.name], truth[par.name])]
        if par.scales_with_inertia:
            checks.append((f"{par.name} / M22", s[par.name] / m22, truth[par.name] / m22_true))
        for label, draws, value in checks:
            lo, hi = np.quantile(np.ravel(draws), RECOVERY_INTERVAL)
            assert lo <= value <= hi, (label, value, lo, hi)
