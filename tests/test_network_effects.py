"""Named effects from a network of the states: the effects' columns equal their torque
formulas written out by hand (or finite differences of the model's force, for the effects
that act through the gains); draws of a known effect's torque name that effect with its
magnitude inside the interval; draws that do not agree, or agree on a friction of the wrong
sign, name nothing; the named effects replace the network."""

import numpy as np
import pytest

from heli_uq.discovery.network_check import check_candidates, check_line
from heli_uq.discovery.network_effects import (
    EXPLAINED_MIN,
    effect_columns,
    effects_sentence,
    input_dependence,
    name_network_effects,
    network_effects_of,
)
from heli_uq.discovery.network_equation import equation_model
from heli_uq.errors import ParameterError
from heli_uq.model import RIG_FIT, build_model
from heli_uq.model.terms import NeuralTorque
from heli_uq.model.terms.coulomb_friction import OMEGA_S

#: Agreement of a column with its closed form (autodiff of a formula: rounding).
EXACT = 1e-12
#: Agreement with a central difference of the force at step FD_STEP.
FD_TOL, FD_STEP = 1e-6, 1e-6
#: Hidden magnitudes of the "posterior draws": F_c [N m], c [N m s^2/rad^2].
TRUE_F_C, TRUE_C = 0.012, 0.05
#: Spread of the draws around the truth [N m] (the network torque's posterior sd on the
#: rig's FNN(u, x, v) run was ~0.01 N m per point, on 0.04 N m of torque).
DRAW_NOISE = 0.002
#: A true effect is kept by at least this fraction of draws.
TRUE_INCLUSION = 0.9


def _points(seed=0, k=200):
    rng = np.random.default_rng(seed)
    return {"theta": rng.uniform(-0.65, -0.3, k), "psi": rng.uniform(-1.0, 2.0, k),
            "omega_theta": rng.uniform(-0.3, 0.3, k), "omega_psi": rng.uniform(-0.8, 0.8, k),
            "u_theta": rng.uniform(1.2, 1.5, k), "u_psi": rng.uniform(0.5, 1.55, k)}  # fmt: skip


def _basis(points):
    return NeuralTorque("yaw", "u,x,v", 2, "u").basis(points, np)


@pytest.fixture(scope="module")
def yaw_columns():
    points = _points()
    return points, effect_columns(build_model(), RIG_FIT, "yaw", points)


def test_columns_are_the_effects_torques_per_unit_magnitude(yaw_columns):
    points, cols = yaw_columns
    w = points["omega_psi"]
    closed = {"coulomb_friction": ("F_c_yaw", -np.tanh(w / OMEGA_S)),
              "quadratic_drag": ("c_yaw", -w * np.abs(w)),
              "torsional_spring": ("k_yaw", -points["psi"]),  # the rest angle's probe value: 0
              "quadratic_thrust": ("k_q_yaw", -points["u_psi"] * np.abs(points["u_psi"])),
              "torque_offset": ("T_0_yaw", np.ones_like(w))}  # fmt: skip
    for kind, (name, column) in closed.items():
        assert cols[kind][0] == name
        np.testing.assert_allclose(cols[kind][1], column, atol=EXACT, err_msg=kind)


def test_a_dead_band_column_acts_through_the_fitted_gains(yaw_columns):
    """d T_yaw / d delta at the probe, against a central difference of the model's force."""
    import jax.numpy as jnp

    points, cols = yaw_columns
    model = build_model(["yaw:deadband"])
    name, column = cols["deadband"]
    p0 = model.complete({**RIG_FIT, name: model.parameter(name).start_value()})

    def force(delta, i):
        _, q = model.prepare({**p0, name: delta})
        x = jnp.array([points["theta"][i], points["psi"][i]])
        v = jnp.array([points["omega_theta"][i], points["omega_psi"][i]])
        u = jnp.stack(model.input_voltages(q, jnp.array([points["u_theta"][i], points["u_psi"][i]])))
        return float(model.force_vector(q, x, v, u)[1])

    fd = [(force(p0[name] + FD_STEP, i) - force(p0[name] - FD_STEP, i)) / (2 * FD_STEP) for i in range(10)]
    np.testing.assert_allclose(column[:10], fd, atol=FD_TOL)
    # the yaw motor's torque is -K_psi_psi u_psi: a wider dead band on positive voltages
    # takes K_psi_psi per volt of it away
    np.testing.assert_allclose(column, RIG_FIT["K_psi_psi"], atol=EXACT)


def test_effects_the_model_has_are_not_regressed_on():
    points = _points(k=5)
    cols = effect_columns(build_model(["yaw:coulomb_friction"]), RIG_FIT, "yaw", points)
    assert "coulomb_friction" not in cols and "quadratic_drag" in cols
    with pytest.raises(ParameterError, match="unknown effect"):
        effect_columns(build_model(), RIG_FIT, "yaw", points, effects=["backlash"])


def _draws(points, cols, truth: dict, seed=1, n=120):
    rng = np.random.default_rng(seed)
    torque = sum(value * cols[kind][1] for kind, value in truth.items())
    return torque[None, :] + DRAW_NOISE * rng.standard_normal((n, len(points["psi"])))


def _supports():
    return {name: "nonnegative" for name in ("F_c_yaw", "c_yaw", "k_yaw", "delta_yaw")}


def test_a_friction_and_a_drag_are_named_with_their_magnitudes(yaw_columns):
    points, cols = yaw_columns
    draws = _draws(points, cols, {"coulomb_friction": TRUE_F_C, "quadratic_drag": TRUE_C})
    out = name_network_effects(draws, cols, _basis(points), supports=_supports())
    assert sorted(out["selected"]) == ["coulomb_friction", "quadratic_drag"]
    assert min(out["inclusion"]["coulomb_friction"], out["inclusion"]["quadratic_drag"]) >= TRUE_INCLUSION
    for kind, true in (("coulomb_friction", TRUE_F_C), ("quadratic_drag", TRUE_C)):
        lo, hi = out["magnitudes"][kind]["ci95"]
        assert lo <= true <= hi, (kind, lo, hi)
    # the linear physics' span is projected out: the rate's linear part is the damping's
    assert "deadband" not in out["selected"] and "torque_offset" not in out["selected"]


def test_an_anti_friction_is_not_a_friction(yaw_columns):
    """The same torque with the friction's sign flipped: the draws agree on it, but a
    negative F_c is outside its support."""
    points, cols = yaw_columns
    draws = _draws(points, cols, {"coulomb_friction": -TRUE_F_C})
    out = name_network_effects(draws, cols, _basis(points), supports=_supports())
    assert "coulomb_friction" not in out["selected"]
    assert out["inclusion"]["coulomb_friction"] < 0.5


def test_draws_that_disagree_name_nothing(yaw_columns):
    """Each draw a different smooth function of the states (random mixtures of the
    columns, zero on average): the least-BIC path keeps features in most draws, the
    credibility of the joint fit keeps them out."""
    points, cols = yaw_columns
    rng = np.random.default_rng(3)
    stack = np.column_stack([c for _, c in cols.values()])
    draws = (rng.standard_normal((120, stack.shape[1])) * 0.01 / np.abs(stack).max(0)) @ stack.T
    out = name_network_effects(draws, cols, _basis(points), supports=_supports())
    assert out["selected"] == [] and out["credible"] == []
    assert out["not_credible"]  # the path kept something in most draws; it was not credible
    assert check_candidates({"yaw": out}) == [] and check_line("rec.csv", {"yaw": out}, (0, 91), "o") is None


def test_named_effects_replace_the_network():
    network = {"effect": "neural_torque", "axis": "yaw", "inputs": "u,x,v"}
    model = build_model([network, "pitch:torque_offset"])
    refit = equation_model(model, "yaw", ["coulomb_friction", "torque_offset"])
    kinds = {(e["effect"], e["axis"]) for e in refit.describe()["effects"]}
    assert kinds == {("coulomb_friction", "yaw"), ("torque_offset", "yaw"), ("torque_offset", "pitch")}


def test_a_torque_the_table_does_not_hold_is_not_named(yaw_columns):
    """An offset under a larger torque of the pitch rate (no effect of the table on yaw):
    what is credible (part of the pitch-rate torque leaks into an effect's column) explains
    too little of the torque to name; without the pitch-rate torque the offset is named."""
    points, cols = yaw_columns
    other = 0.02 * np.tanh(points["omega_theta"] / 0.1)
    offset = _draws(points, cols, {"torque_offset": 0.005})
    out = name_network_effects(offset + other[None, :], cols, _basis(points), supports=_supports())
    assert out["selected"] == [] and out["unexplained"]
    assert out["r2"] < EXPLAINED_MIN
    alone = name_network_effects(offset, cols, _basis(points), supports=_supports())
    assert alone["selected"] == ["torque_offset"] and not alone["unexplained"]
    # on positive yaw voltages a dead band is a constant torque: the offset's column
    assert alone["ties"] == {"torque_offset": ["deadband"]} and "deadband" not in alone["inclusion"]
    # the held-out check tries the tied effect too, and judges a credible effect that is
    # too small a part of the torque to name
    assert check_candidates({"yaw": alone}) == ["yaw:torque_offset", "yaw:deadband"]
    assert out["credible"] and check_candidates({"yaw": out}) == [f"yaw:{k}" for k in out["credible"]]
    assert check_line("rec.csv", {"yaw": alone}, (0.0, 91.0), "o/check") == (
        "check them on held-out blocks: heli-uq discover rec.csv --window 0:91 --candidates "
        "yaw:torque_offset,yaw:deadband --max-effects 2 --out o/check")
    # a network on top of named effects is checked against them (its base model, less the
    # network), under the run's prior options; options --base-effects cannot carry are named
    hybrid = build_model(["yaw:coulomb_friction", "yaw:thrust_tilt",
                          {"effect": "coulomb_friction", "axis": "pitch", "omega_s": 0.01},
                          {"effect": "neural_torque", "axis": "yaw", "inputs": "u,x,v",
                           "hidden": 2}])  # fmt: skip
    assert check_line("rec.csv", {"yaw": alone}, (0.0, 91.0), "o/check", model=hybrid,
                      prior_options=["--fix", "a_yaw=1", "--priors", "my priors.json"]) == (
        "check them on held-out blocks: heli-uq discover rec.csv --window 0:91 --base-effects "
        "yaw:coulomb_friction,yaw:thrust_tilt,pitch:coulomb_friction --fix a_yaw=1 --priors 'my priors.json' "
        "--candidates yaw:torque_offset,yaw:deadband --max-effects 2 --out o/check (its base model takes "
        "each effect's default options; this run's differ for pitch:coulomb_friction)")  # fmt: skip
    # discover refuses windows under 20 s: the line says so instead of a command that fails
    assert check_line("rec.csv", {"yaw": alone}, (2.0, 16.4), "o").endswith(
        "needs a training window of at least 20 s; this one is 14.4 s")


def test_input_dependence_finds_the_input_a_torque_is_a_function_of():
    points = _points(k=400)
    out = input_dependence(np.tanh(points["omega_theta"] / 0.1), points)
    assert out["omega_theta"] > 0.9
    assert max(v for k, v in out.items() if k != "omega_theta") < 0.1  # independent inputs


def test_the_sentence_says_what_was_named_or_what_the_torque_depends_on():
    depends = {"theta": 0.1, "psi": 0.1, "omega_theta": 0.51, "omega_psi": 0.2, "u_theta": 0.1, "u_psi": 0.1}
    named = {"selected": ["coulomb_friction"], "inclusion": {"coulomb_friction": 1.0}, "r2": 0.26,
             "explained": {"coulomb_friction": 0.26}, "depends_on": depends}  # fmt: skip
    assert effects_sentence("yaw", named) == (
        "the network of the states on yaw is made of: coulomb_friction (in 100% of the draws); together 26% "
        "of its torque; its torque depends most on omega_theta (51% of its variance by that input alone)")
    nothing = {**named, "selected": [], "explained": {"coulomb_friction": 0.007, "torsional_spring": 0.023}}
    assert effects_sentence("yaw", nothing) == (
        "the network of the states on yaw is no effect of the table (the best, torsional_spring, explains 2% "
        "of it); its torque depends most on omega_theta (51% of its variance by that input alone)")
    weak = {**nothing, "credible": ["coulomb_friction"], "r2": 0.186}
    assert effects_sentence("yaw", weak) == (
        "the network of the states on yaw is no effect of the table (the best, torsional_spring, explains 2% "
        "of it); credible but too small a part of it to name: coulomb_friction (together 19%); its torque "
        "depends most on omega_theta (51% of its variance by that input alone)")


@pytest.mark.long
def test_cli_sample_names_what_its_network_of_the_states_learned(tmp_path, capsys):
    """``heli-uq sample --model hybrid --nn-inputs u,x,v`` stores in summary.json, and
    prints, what the library finds in the posterior it wrote (tiny size: Laplace)."""
    import json

    from heli_uq.cli import main
    from heli_uq.model import RIG_FIT_X0
    from heli_uq.output.inference_data import load_posterior
    from heli_uq.simulation import synthetic_experiment

    rec = synthetic_experiment({**RIG_FIT, "F_c_yaw": TRUE_F_C}, RIG_FIT_X0, duration=6.0, inputs="steps",
                               seed=5, noise_std=(0.003, 0.008),
                               model=build_model(["yaw:coulomb_friction"]))  # fmt: skip
    out = tmp_path / "o"
    main(["sample", "--data", str(rec.to_csv(tmp_path / "rec.csv")), "--model", "hybrid",
          "--nn-inputs", "u,x,v", "--sampler", "laplace", "--error", "iid", "--chains", "1",
          "--draws", "60", "--no-progress", "--out", str(out)])  # fmt: skip
    stored = json.loads((out / "summary.json").read_text())["network_effects"]
    idata, model = load_posterior(out / "posterior.nc")
    again = json.loads(json.dumps(network_effects_of(idata, model, "yaw")))
    assert set(stored) == {"yaw"} and stored["yaw"] == again
    printed = capsys.readouterr().out
    assert effects_sentence("yaw", again) in printed
    # the held-out check's line (6 s: why there is none), printed exactly when something is named
    line = check_line(str(tmp_path / "rec.csv"), stored, (0.0, 6.0), out / "check")
    assert (line is None and "held-out blocks" not in printed) or line in printed


@pytest.mark.long
def test_the_held_out_check_drops_a_named_effect_the_record_does_not_need(tmp_path):
    """A network named an offset and a spring (as one named a spring beside a hidden
    friction, studies/notes/hybrid.md); the record holds only the offset.  ``discover``
    restricted to the named effects, on a training window, adds the offset and stops."""
    from heli_uq.discovery import Budget, discover
    from heli_uq.model import RIG_FIT_X0
    from heli_uq.simulation import synthetic_experiment
    from heli_uq.simulation.synthetic import ENCODER_QUANTUM

    true_t0 = -0.04
    rec = synthetic_experiment({**RIG_FIT, "T_0_yaw": true_t0}, RIG_FIT_X0, duration=30.0, inputs="rig_steps",
                               noise_std=(0.003, 0.008), seed=11, model=build_model(["yaw:torque_offset"]),
                               quantum=ENCODER_QUANTUM)  # fmt: skip
    named = {"yaw": {"selected": ["torque_offset", "torsional_spring"], "ties": {}}}
    candidates = check_candidates(named)
    small = Budget(n_starts=2, cold_starts=0, draws=40, pair_top=2, chains=2, warmup=50, samples=50,
                   max_tree_depth=5)  # fmt: skip
    res = discover(rec, tmp_path, window=(0.0, 30.0), candidates=candidates, max_effects=len(candidates),
                   budget=small, scheduler="serial", log=lambda m: None)  # fmt: skip
    assert [(a["effect"], a["axis"]) for a in res["added"]] == [("torque_offset", "yaw")]
    lo, hi = res["parameters"]["T_0"]["ci95"]
    assert lo <= true_t0 <= hi
