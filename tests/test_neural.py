"""The neural torque of the hybrid model: the network against a plain numpy forward pass,
the projection that keeps it from absorbing the linear gains, the common-scale null
direction, its description round trip, and a fit that learns a hidden smooth torque."""

import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from heli_uq.errors import ParameterError
from heli_uq.model import RIG_FIT, RIG_FIT_X0, build_model, model_from_description
from heli_uq.simulation import simulate, synthetic_experiment

#: Agreement of the network with the numpy forward pass and of the projection with zero.
EXACT = 1e-12
#: The angles may change by at most this much [rad] when every inertia-scaled parameter
#: (including the network's output weights) is multiplied by one factor.
SCALE_INVARIANCE_RAD = 1e-9


def _record(seconds=40.0, seed=3, model=None, values=None):
    return synthetic_experiment({**RIG_FIT, **(values or {})}, RIG_FIT_X0, duration=seconds,
                                inputs="rig_steps", seed=seed, noise_std=(0.003, 0.008),
                                model=model)  # fmt: skip


def _random_weights(model, seed=0):
    rng = np.random.default_rng(seed)
    return {n: (0.03 if "_w_" in n else 1.0) * rng.normal() for n in model.names
            if n.startswith("nn_")}  # fmt: skip


@pytest.fixture(scope="module", params=["u", "1,u"])
def adapted(request):
    rec = _record()
    item = {"effect": "neural_torque", "axis": "yaw", "project": request.param}
    model = build_model([item]).adapted(rec.u, rec.y, rec.dt)
    return rec, model, model.effects[0]


def _numpy_network(term, p, q):
    """The network written out in numpy from the parameter dict (independent form)."""
    names = term.input_names
    s = (np.asarray(q) - np.asarray(term.center)) / np.asarray(term.scale)
    w_in = np.array([[p[term.name(f"nn_W_{j}_{n}")] for n in names] for j in range(term.hidden)])
    b = np.array([p[term.name(f"nn_b_{j}")] for j in range(term.hidden)])
    w_out = np.array([p[term.name(f"nn_w_{j}")] for j in range(term.hidden)])
    return np.tanh(s @ w_in.T + b) @ w_out


def test_network_matches_numpy_and_is_orthogonal_to_the_linear_gains(adapted):
    rec, model, term = adapted
    p = model.complete(_random_weights(model))
    pairs = np.asarray(term.reference)
    assert len(pairs) >= 4, "the record must hold enough distinct voltage pairs"
    raw = _numpy_network(term, p, pairs)
    columns = ([np.ones(len(pairs))] if term.project == "1,u" else []) + [pairs[:, 0], pairs[:, 1]]
    basis = np.column_stack(columns)
    _, counts = np.unique(rec.u, axis=0, return_counts=True)
    w = np.sqrt(counts)
    beta = np.linalg.lstsq(w[:, None] * basis, w * raw, rcond=None)[0]
    expected = raw - basis @ beta
    prepared = model.prepare(p)[1]
    got = np.array([float(term.torque(prepared, jnp.zeros(2), jnp.zeros(2), pair)) for pair in pairs])
    np.testing.assert_allclose(got, expected, atol=EXACT * np.abs(raw).max())
    # orthogonal to (1,) u_theta, u_psi in the record's sample weights: K owns the linear part
    np.testing.assert_allclose(basis.T @ (counts * got), 0.0, atol=EXACT * np.abs(raw).max() * len(rec.u))


@pytest.mark.parametrize("axis", ["yaw", "pitch"])
@pytest.mark.parametrize("project", ["u", "1,u"])
def test_a_network_of_the_states_is_orthogonal_to_the_linear_physics(axis, project):
    """A network of (u, x, v) is projected off what the axis's physics owns: the gains, the
    damping rate and (pitch) the gravity torque's cos/sin, over evenly spaced training
    samples with smoothed rates; a sample-weighted projection of u alone would leave the
    damping's direction in it."""
    from heli_uq.data.rates import measured_rates

    rec = _record(seconds=20.0)
    item = {"effect": "neural_torque", "axis": axis, "inputs": "u,x,v", "hidden": 3, "project": project}
    model = build_model([item]).adapted(rec.u, rec.y, rec.dt)
    term = model.effects[0]
    points = np.asarray(term.reference)
    rates = measured_rates(rec.y, rec.dt)
    samples = np.column_stack([rec.u, rec.y, rates])
    # the reference points are training samples, first and last included
    rows = [int(np.flatnonzero(np.all(samples == p_, axis=1))[0]) for p_ in points]
    assert rows[0] == 0 and rows[-1] == len(rec.u) - 1 and len(set(rows)) == len(rows) > 100
    j = 4 if axis == "pitch" else 5
    columns = [np.ones(len(points))] if project == "1,u" else []
    columns += [points[:, 0], points[:, 1], points[:, j]]
    if axis == "pitch":
        columns += [np.cos(points[:, 2]), np.sin(points[:, 2])]
    basis = np.column_stack(columns)
    p = model.complete(_random_weights(model))
    prepared = model.prepare(p)[1]
    got = np.array([float(term.torque(prepared, q[2:4], q[4:6], q[:2])) for q in points])
    raw = _numpy_network(term, p, points)
    beta = np.linalg.lstsq(basis, raw, rcond=None)[0]
    np.testing.assert_allclose(got, raw - basis @ beta, atol=EXACT * np.abs(raw).max())
    assert np.abs(basis.T @ raw).max() > 1e-3 * np.abs(raw).max() * len(points)  # there was a part to remove
    np.testing.assert_allclose(basis.T @ got, 0.0, atol=EXACT * np.abs(raw).max() * len(points))


def test_common_scale_leaves_the_angles_unchanged(adapted):
    rec, model, _ = adapted
    p = model.complete({**RIG_FIT, **_random_weights(model)})
    base = simulate(p, RIG_FIT_X0, rec.u, rec.dt, model=model)
    factor = 1.7
    scaled = {k: v * factor if k in model.scale_names else v for k, v in p.items()}
    assert any(k.startswith("nn_w_") for k in model.scale_names)
    moved = simulate(scaled, RIG_FIT_X0, rec.u, rec.dt, model=model)
    assert float(jnp.max(jnp.abs(moved[:, :2] - base[:, :2]))) < SCALE_INVARIANCE_RAD


def test_description_round_trip_keeps_the_record_scaling(adapted):
    _, model, term = adapted
    again = model_from_description(model.describe())
    assert again == model and again.effects[0].reference == term.reference
    # adapting again (a reloaded model on another window) keeps the stored scaling
    other = _record(seconds=20.0, seed=9)
    assert again.adapted(other.u, other.y, other.dt) == model


def test_with_effects_keeps_the_rest_and_readapts_to_a_new_record(adapted):
    # with_effects rebuilds a model without some effects (the base of a hybrid, or the
    # network replaced by an equation): the mechanics and the other effects are kept,
    # and a kept network drops its record's scaling, so it adapts to the next record.
    from heli_uq.model import with_effects

    rec, model, term = adapted
    lagrangian = build_model([term.describe(), "pitch:torque_offset"], mechanics="lagrangian")
    base = with_effects(lagrangian, lambda e: e["effect"] != "neural_torque")
    assert base.describe() == build_model(["pitch:torque_offset"], mechanics="lagrangian").describe()
    kept = with_effects(lagrangian, lambda e: e["effect"] == "neural_torque", ["yaw:quadratic_drag"])
    assert [t.label for t in kept.effects] == ["neural_torque(yaw)", "quadratic_drag(yaw)"]
    assert kept.effects[0].center == () and kept.mechanics.kind == "lagrangian"
    other = _record(seconds=20.0, seed=9)
    again = kept.adapted(other.u, other.y, other.dt).effects[0]
    assert again.center != term.center and again.hidden == term.hidden


def test_bad_options_are_refused():
    for item, needle in (({"effect": "neural_torque", "axis": "yaw", "inputs": "x"}, "inputs"),
                         ({"effect": "neural_torque", "axis": "yaw", "hidden": 0}, "hidden"),
                         ({"effect": "neural_torque", "axis": "yaw", "project": "u2"}, "project"),
                         ({"effect": "neural_torque", "axis": "yaw", "width": 3}, "width")):  # fmt: skip
        with pytest.raises(ParameterError, match=needle):
            build_model([item])


#: A hidden quadratic motor torque on yaw [N m/V^2] (curvature in u_psi, which the
#: linear gains cannot express).
HIDDEN_K_Q = 0.05
#: An Adam learning rate (in log parameters) that makes joint training blow the model up.
BLOW_UP_LEARNING_RATE = 50.0
#: Angle [rad] beyond which the test's loss counts a simulation as failed.
BLOW_UP_RAD = 50.0
NOISE = (0.003, 0.008)
#: V [rad^2] at the truth is the noise floor sigma_theta^2 + sigma_psi^2; a trained hybrid
#: must come within these factors of it (frozen true physics; joint training).
FLOOR_FACTOR_FROZEN = 1.15
FLOOR_FACTOR_JOINT = 1.3
#: Without the network the hidden torque leaves V at least this many times the floor.
BASE_FACTOR = 10.0


@pytest.mark.slow
def test_training_learns_a_hidden_smooth_torque():
    """The paper's route (Adam then L-BFGS on V): with the physics frozen at the truth an
    unprojected network reaches the noise floor; trained jointly with the physics, the
    default network (orthogonal to the gains) does too."""
    from heli_uq.inference import train
    from heli_uq.probability import loss_v, make_problem

    rec = synthetic_experiment({**RIG_FIT, "k_q_yaw": HIDDEN_K_Q}, RIG_FIT_X0, duration=60.0,
                               inputs="rig_steps", seed=5, noise_std=NOISE,
                               model=build_model(["yaw:quadratic_thrust"]))  # fmt: skip
    floor = NOISE[0] ** 2 + NOISE[1] ** 2
    base = make_problem(rec, error="iid")
    v_base = float(loss_v(base.solve(dict(RIG_FIT), jnp.asarray(RIG_FIT_X0)).ys, base.y))
    assert v_base > BASE_FACTOR * floor
    for project, trainable, factor in (("none", None, FLOOR_FACTOR_FROZEN),
                                       ("u", "all", FLOOR_FACTOR_JOINT)):  # fmt: skip
        item = {"effect": "neural_torque", "axis": "yaw", "hidden": 4, "project": project}
        problem = make_problem(rec, model=build_model([item]), error="iid")
        result = train(problem, dict(RIG_FIT), RIG_FIT_X0, trainable=trainable)
        assert result.v_start == pytest.approx(v_base, rel=1e-9)  # the network starts silent
        assert result.v < factor * floor, (project, result.v, floor)
        held = set(problem.model.names) - set(result.trained)
        assert all(result.params[n] == pytest.approx(problem.model.complete(RIG_FIT)[n])
                   for n in held if n in RIG_FIT)  # fmt: skip


def test_network_gradient_matches_finite_differences():
    rec = _record()
    item = {"effect": "neural_torque", "axis": "yaw", "hidden": 4}  # names of units 0-3 below
    model = build_model([item]).adapted(rec.u, rec.y, rec.dt)
    p = model.complete({**RIG_FIT, **_random_weights(model)})
    u, n = rec.u[:300], 300

    @jax.jit
    def loss(q):
        return jnp.sum(simulate(q, RIG_FIT_X0, u, rec.dt, model=model)[:n, 1] ** 2)

    g = jax.grad(loss)(p)
    for name in ("nn_W_1_u_psi_yaw", "nn_b_2_yaw", "nn_w_0_yaw"):
        h = 1e-6 * max(1.0, abs(float(p[name])))
        fd = (loss({**p, name: p[name] + h}) - loss({**p, name: p[name] - h})) / (2 * h)
        np.testing.assert_allclose(float(g[name]), float(fd), rtol=1e-5, err_msg=name)


def test_training_rejects_steps_that_blow_up_the_model(monkeypatch):
    """Joint training with a learning rate far too large sends the model far off.  Steps
    whose V is not finite (here: V is made NaN once an angle leaves +-BLOW_UP_RAD, as a
    failed solve would give) are rejected, and the result is the best finite iterate: never
    NaN parameters, never worse than the start."""
    from heli_uq.inference import train
    from heli_uq.probability import loss_v, make_problem

    def fragile_loss_v(ys, y):
        return jnp.where(jnp.max(jnp.abs(ys[:, :2])) > BLOW_UP_RAD, jnp.nan, loss_v(ys, y))

    monkeypatch.setattr(sys.modules["heli_uq.inference.train"], "loss_v", fragile_loss_v)
    rec = _record(seconds=10.0, seed=7)
    item = {"effect": "neural_torque", "axis": "yaw", "hidden": 2}
    problem = make_problem(rec, model=build_model([item]), error="iid")
    result = train(problem, dict(RIG_FIT), RIG_FIT_X0, trainable="all", adam_steps=20, lbfgs_steps=5,
                   learning_rate=BLOW_UP_LEARNING_RATE)
    assert not np.all(np.isfinite(result.v_adam)), "the learning rate did not blow the model up"
    assert np.isfinite(result.v) and result.v <= result.v_start
    assert all(np.isfinite(v) for v in result.params.values())


#: ``rate * dt`` of a yaw damping's decaying mode that makes the start stiff: past RK4's
#: stability limit 2.785 at one step per sample (a MAP of the rig's first 14 s has
#: D_psi = 3.5 N m s/rad on a yaw inertia of 0.008 kg m^2: 4.3).
STIFF_RATE_STEP = 4.0


def test_training_takes_the_substeps_a_stiff_start_needs():
    """A start whose yaw damping blows up a one-step solve (V is NaN there) is trained on
    the substeps it needs, not refused, and its V is the V of that solve."""
    from heli_uq.inference import train
    from heli_uq.model.terms.rigid_body import yaw_inertia
    from heli_uq.probability import loss_v, make_problem
    from heli_uq.simulation import default_substeps

    rec = _record(seconds=4.0, seed=8)
    item = {"effect": "neural_torque", "axis": "yaw", "hidden": 2}
    problem = make_problem(rec, model=build_model([item]), error="iid", substeps=1)
    inertia = min(float(yaw_inertia(RIG_FIT, th)) for th in np.asarray(rec.y)[:, 0])
    start = dict(RIG_FIT, D_psi=STIFF_RATE_STEP * inertia / rec.dt)
    assert not np.isfinite(float(loss_v(problem.solve(start, RIG_FIT_X0).ys, problem.y)))
    need = default_substeps(problem.model, start, rec.dt)
    assert need > 1
    result = train(problem, start, RIG_FIT_X0, adam_steps=3, lbfgs_steps=0)
    assert result.substeps == need
    covered = problem.with_substeps(need)
    v_start = float(loss_v(covered.solve({**start, **{n: 0.0 for n in result.trained if "nn_w_" in n}},
                                         RIG_FIT_X0).ys, problem.y))  # fmt: skip
    assert result.v_start == pytest.approx(v_start, rel=1e-12)
    assert np.isfinite(result.v) and result.v <= result.v_start


#: Smoothed rates of a noisy synthetic record must be this much closer to the true rates
#: than plain central differences (the noise of a difference is sigma sqrt(2) / (2 dt)).
RATE_GAIN = 5.0


def test_measured_rates_follow_the_true_rates_through_the_noise():
    from heli_uq.data.rates import measured_rates

    rec = _record(seconds=20.0)
    truth = np.asarray(simulate(RIG_FIT, RIG_FIT_X0, rec.u, rec.dt))[:, 2:4]
    smooth = measured_rates(rec.y, rec.dt) - truth
    plain = np.gradient(np.asarray(rec.y), rec.dt, axis=0) - truth
    for j in range(2):
        assert np.sqrt(np.mean(plain[:, j] ** 2)) > RATE_GAIN * np.sqrt(np.mean(smooth[:, j] ** 2))


def _state_network_idata(rate_slope, damping):
    """A hand-made posterior of a yaw network of the states: mechanics at the rig fit in
    every draw, the network torque ``rate_slope[s] * omega_psi + curve`` on a grid of
    training samples, and ``D_psi`` per draw."""
    import arviz as az

    from heli_uq.model.terms.rigid_body import MECHANICS_PARAMETERS

    rng = np.random.default_rng(1)
    k, s = 40, len(rate_slope)
    points = {"u_theta": rng.uniform(1, 2, k), "u_psi": rng.uniform(0.5, 1.5, k),
              "omega_psi": rng.normal(0, 0.5, k), "time": np.arange(k) * 0.1}  # fmt: skip
    curve = points["omega_psi"] * np.abs(points["omega_psi"])
    basis = np.column_stack([points["u_theta"], points["u_psi"], points["omega_psi"]])
    curve = curve - basis @ np.linalg.lstsq(basis, curve, rcond=None)[0]  # no linear part
    torque = rate_slope[:, None] * points["omega_psi"] + 0.01 * curve
    post = {n.name: np.full((1, s), RIG_FIT[n.name]) for n in MECHANICS_PARAMETERS if n.name in RIG_FIT}
    post.update(D_psi=damping[None], K_psi_psi=np.full((1, s), RIG_FIT["K_psi_psi"]),
                K_psi_theta=np.full((1, s), RIG_FIT["K_psi_theta"]), nn_torque_yaw=torque[None])  # fmt: skip
    idata = az.from_dict(posterior=post, dims={"nn_torque_yaw": ["nn_point_yaw"]},
                         constant_data={"u": np.ones((5, 2)), "y_obs": np.full((5, 2), -0.4),
                                        "train_mask": np.ones(5, bool)})  # fmt: skip
    coords = {f"nn_point_yaw_{q}": ("nn_point_yaw", v) for q, v in points.items()}
    idata.posterior = idata.posterior.assign_coords(coords)
    return idata


def test_the_trade_off_of_a_state_network_includes_the_damping():
    """For a network of the states, ``gain_trade_off`` regresses its torque on the gains'
    voltages and on the axis's rate: a rate slope that the damping compensates draw by draw
    is a perfect trade-off (corr -1, their sum fixed); a network without a linear part
    leaves the damping alone (no linear part, corr undefined)."""
    from heli_uq.output.network import axis_inertia, gain_trade_off

    slope = np.random.default_rng(2).normal(0, 0.02, 300)
    idata = _state_network_idata(np.zeros(300), np.full(300, RIG_FIT["D_psi"]))
    inertia = float(axis_inertia(idata, "yaw")[0])
    traded = gain_trade_off(_state_network_idata(slope, RIG_FIT["D_psi"] + slope), "yaw")
    assert set(traded) == {"u_theta", "u_psi", "omega_psi"} and traded["omega_psi"]["gain"] == "D_psi"
    row = traded["omega_psi"]
    assert row["corr"] == pytest.approx(-1.0, abs=1e-9)
    assert row["sd_linear"] == pytest.approx(slope.std() / inertia, rel=1e-6)
    assert row["sd_total"] < 1e-9 * row["sd_gain"]
    alone = gain_trade_off(_state_network_idata(np.zeros(300), RIG_FIT["D_psi"] + slope), "yaw")["omega_psi"]
    assert np.isnan(alone["corr"]) and alone["sd_linear"] < 1e-9 * alone["sd_gain"]
