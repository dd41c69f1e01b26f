"""Experiment design: staircases within bounds, the information criterion against finite
differences and the model's known scale invariance, the search beating the published
profile, discrimination of rival models, and the CLI's bad input."""

import json
import os
import pathlib

import jax.numpy as jnp
import numpy as np
import pytest

from heli_uq.cli.main import main
from heli_uq.data import read_record
from heli_uq.design import (
    DesignPrior,
    InformationGain,
    Rivals,
    StaircaseBounds,
    design,
    search_staircase,  # fmt: skip
)
from heli_uq.design.search import SearchBudget
from heli_uq.design.staircase import mutate, random_staircase
from heli_uq.errors import ParameterError

#: The published record (``HELI_UQ_DATA``, set by conftest.py to ../shared/data when present).
REAL_FILE = (pathlib.Path(os.environ.get("HELI_UQ_DATA", "/nonexistent"))
             / "Lab-Helicopter_Experimental-data.csv")
#: Relative agreement of the autodiff Fisher information with central finite differences.
FD_RTOL = 1e-4
#: Finite-difference step in w (log coordinates).
FD_STEP = 1e-5
#: A direction counts as not informed when its posterior sd is this close to its prior sd.
UNINFORMED_TOL = 1e-6
#: D(4 dT) = 16 D(dT) up to this: the centrifugal coupling of the yaw rate into pitch is not
#: linear in the torque (measured 1e-3 at these offsets).
QUADRATIC_RTOL = 1e-2
#: A small search (the test's budget), seconds of experiment and bounds.
TINY = SearchBudget(random=6, climb=12, draws=1)
DURATION = 12.0
#: A pitch envelope [deg] narrower than the default, for the CLI test.
ENVELOPE_DEG = (-50.0, -5.0)
BOUNDS = StaircaseBounds(DURATION, 0.01, ((1.22, 1.47), (0.45, 1.6)), (2.0, 5.0))


@pytest.mark.parametrize("bounds", [BOUNDS, StaircaseBounds(7.0, 0.01, hold=(3.0, 4.0)),
                                    StaircaseBounds(131.0, 0.01)])  # fmt: skip
def test_random_and_mutated_staircases_stay_within_bounds(bounds):
    rng = np.random.default_rng(3)
    a, b = bounds.hold_samples
    for _ in range(200):
        stairs = random_staircase(bounds, rng)
        for _ in range(5):
            stairs = mutate(stairs, bounds, rng)
        stairs.check(bounds)
        assert stairs.lengths.sum() == bounds.n and a <= stairs.lengths.min() and stairs.lengths.max() <= b
        u = stairs.inputs()
        assert u.shape == (bounds.n, 2)
        for j, (lo, hi) in enumerate(bounds.ranges):
            assert lo <= u[:, j].min() and u[:, j].max() <= hi


@pytest.mark.parametrize("kwargs, needle", [
    (dict(duration=2.0, hold=(3.0, 14.0)), "cannot be split into segments of 3-14 s"),
    (dict(duration=7.0, hold=(4.0, 5.0)), "cannot be split"),
    (dict(duration=60.0, ranges=((1.4, 1.3), (0.45, 1.6))), "u_theta range"),
    (dict(duration=60.0, ranges=((1.2, 1.4), (0.5, 0.5))), "u_psi range"),
    (dict(duration=60.0, hold=(5.0, 3.0)), "segment lengths"),
    (dict(duration=1e9), "1e\\+11 samples, more than a design's 1,000,000"),
])  # fmt: skip
def test_bounds_that_cannot_be_met_are_refused(kwargs, needle):
    with pytest.raises(ParameterError, match=needle):
        StaircaseBounds(dt=0.01, **kwargs)


@pytest.fixture(scope="module")
def gain():
    return InformationGain(DesignPrior.default(dt=0.01), 0.01)


def test_fisher_information_matches_finite_differences(gain):
    u = jnp.asarray(random_staircase(BOUNDS, np.random.default_rng(0)).inputs())
    w = jnp.asarray(gain.prior.center)
    fisher, ok = gain.fisher(w, u)
    assert bool(ok)
    sigma = np.asarray(gain.prior.sigma)
    cols = []
    for i in range(w.shape[0]):
        e = jnp.zeros_like(w).at[i].set(FD_STEP)
        diff = np.asarray(gain.angles(w + e, u)[0] - gain.angles(w - e, u)[0]) / (2 * FD_STEP)
        cols.append((diff / sigma).ravel())
    jac = np.column_stack(cols)
    np.testing.assert_allclose(np.asarray(fisher), jac.T @ jac, rtol=FD_RTOL,
                               atol=FD_RTOL * np.abs(jac.T @ jac).max())  # fmt: skip


def test_the_common_scale_is_never_informed(gain):
    """Scaling the inertias, the gains and the damping together leaves the motion unchanged
    (the paper's model is homogeneous in them), so no input can inform that direction: its
    posterior sd stays the prior's, while the identifiable combinations shrink."""
    u = random_staircase(BOUNDS, np.random.default_rng(1)).inputs()
    shrink = gain.shrinkage(u)
    assert shrink[-1] == pytest.approx(1.0, abs=UNINFORMED_TOL)
    assert shrink[0] < 1e-3


@pytest.mark.skipif(not REAL_FILE.is_file(), reason="the published record is not available")
def test_design_beats_the_published_profile_and_random_staircases(tmp_path, gain):
    published = read_record(REAL_FILE)
    summary = design(tmp_path, BOUNDS, prior=gain.prior, published=published, budget="quick",
                     seed=0)  # fmt: skip
    assert summary["value"] > summary["baselines"]["published"]["value"]
    assert summary["value"] >= summary["baselines"]["random"]["best"]
    assert summary["volume_ratio_vs_published"] < 1.0
    stairs_u = read_record(tmp_path / "design.csv").u
    for j, (lo, hi) in enumerate(BOUNDS.ranges):
        assert lo <= stairs_u[:, j].min() and stairs_u[:, j].max() <= hi
    assert gain.value(stairs_u) == pytest.approx(summary["value"], rel=1e-9)
    stored = json.loads((tmp_path / "design.json").read_text())
    assert stored["segments"] == summary["segments"]


def test_a_seed_makes_the_search_reproducible(gain):
    runs = [search_staircase(gain.value, BOUNDS, budget=TINY, seed=5) for _ in range(2)]
    assert np.array_equal(runs[0].best.inputs(), runs[1].best.inputs())
    assert runs[0].value == runs[1].value
    assert np.all(np.diff(runs[0].trace) >= 0)  # the hill climb never loses the best


def _discovery_dir(tmp_path, offsets):
    """A discover output with two candidates (best first) whose yaw torque offsets are ``offsets``."""
    (tmp_path / "candidates").mkdir(parents=True)
    ranked = []
    for i, t0 in enumerate(offsets):
        name = "yaw:torque_offset" if i == 0 else "pitch:torque_offset+yaw:torque_offset"
        ranked.append({"model": name, "step": 1, "score": 10.0 - i})
        fitted = {"map": {"T_0_yaw": t0, **({"T_0_pitch": 0.0} if i else {}), "theta0": -0.6}}
        path = tmp_path / "candidates" / (name.replace(":", "-") + ".json")
        path.write_text(json.dumps({"signature": "x", "result": fitted}))
    (tmp_path / "discovery.json").write_text(json.dumps({"candidates": ranked}))
    return tmp_path


def test_discrimination_is_zero_between_identical_models_and_grows_with_their_difference(tmp_path):
    sigma, x0 = (0.003, 0.008), (-0.6, 0.0, 0.0, 0.0)
    u = random_staircase(BOUNDS, np.random.default_rng(2)).inputs()
    same = Rivals.from_discovery(_discovery_dir(tmp_path / "a", [0.002, 0.002]), sigma=sigma, x0=x0)
    small = Rivals.from_discovery(_discovery_dir(tmp_path / "b", [0.002, 0.001]), sigma=sigma, x0=x0)
    large = Rivals.from_discovery(_discovery_dir(tmp_path / "c", [0.002, -0.002]), sigma=sigma, x0=x0)
    assert same.a.name == "yaw:torque_offset" and same.b.name == "pitch:torque_offset+yaw:torque_offset"
    assert same.value(u) == pytest.approx(0.0, abs=1e-12)
    # a torque difference dT drives the yaw gap linearly (up to the yaw rate's coupling into
    # pitch), so D scales as dT^2
    assert large.value(u) == pytest.approx(16.0 * small.value(u), rel=QUADRATIC_RTOL)
    assert small.value(u) > 1.0


@pytest.mark.parametrize("candidates", [["a", "b"], [{"score": 1}, {"score": 2}],
                                        [{"model": "yaw:deadband", "score": "high"}]])  # fmt: skip
def test_a_malformed_discovery_result_is_named_in_one_line(tmp_path, candidates):
    from heli_uq.errors import DataFormatError

    (tmp_path / "discovery.json").write_text(json.dumps({"candidates": candidates}))
    with pytest.raises(DataFormatError, match=r"discovery.json: 'candidates' must be a list of objects"):
        Rivals.from_discovery(tmp_path, sigma=(0.003, 0.008), x0=(-0.6, 0.0, 0.0, 0.0))


@pytest.mark.slow
def test_a_saved_posterior_becomes_the_design_prior_with_its_fixed_values(tmp_path):
    """The design prior from a ``posterior.nc``: its free parameters and their draws, and
    a parameter the run fixed (here K_theta_psi at half the rig fit) at that fixed value,
    not at the model's start value."""
    from heli_uq.model import RIG_FIT, RIG_FIT_X0, HeliModel
    from heli_uq.model.prior import Prior
    from heli_uq.output.posterior_study import sample_posterior
    from heli_uq.probability import PriorSet
    from heli_uq.simulation import synthetic_experiment

    model = HeliModel()
    rec = synthetic_experiment(RIG_FIT, RIG_FIT_X0, duration=10.0, inputs="rig_steps", seed=2,
                               noise_std=(0.003, 0.008))  # fmt: skip
    fixed = 0.5 * RIG_FIT["K_theta_psi"]
    priors = PriorSet.default(model).updated(model, {"K_theta_psi": Prior("fixed", fixed)}, where="test")
    sample_posterior(rec, tmp_path, model=model, priors=priors, sampler="laplace", error="iid",
                     chains=1, warmup=0, draws=40, progress=False, n_starts=1)  # fmt: skip
    prior = DesignPrior.from_posterior(tmp_path / "posterior.nc", draws=3)
    assert prior.pv.base["K_theta_psi"] == fixed != model.start_values()["K_theta_psi"]
    assert "K_theta_psi" not in prior.pv.free and "K_psi_psi" in prior.pv.free
    assert prior.draws.shape == (3, len(prior.pv.free))
    assert prior.chol.shape == (len(prior.pv.free),) * 2


def test_cli_design_rejects_bad_input_in_one_line(tmp_path, capsys):
    cases = [(["--duration", "2"], "--duration: 2 s cannot be split"),
             (["--u-psi", "1.0:0.5"], "--u-psi range"),
             (["--segment", "abc"], "--segment: expected LOW:HIGH"),
             (["--noise", "0.003,-1"], "noise: expected two numbers > 0"),
             (["--pitch", "10:-5"], "pitch envelope: expected -90 <= LOW < HIGH <= 90 deg"),
             (["--discovery", str(tmp_path / "nowhere")], "discovery.json: not a discovery result"),
             # a term not set up from a record: the design used to leave it out without a word
             (["--effects", "yaw:gp_torque"], "gp_torque(yaw) is set up from a record"),
             (["--model", "hybrid", "--nn-inputs", "u"], "neural_torque(yaw) is set up from a record"),
             # the models come from the posterior: a model option beside it was ignored
             (["--posterior", "p.nc", "--effects", "yaw:deadband"],
              "--effects with --posterior: the models come from --posterior")]
    for extra, needle in cases:
        code = main(["design", *extra, "--out", str(tmp_path / "o")])
        err = capsys.readouterr().err
        assert code == 2 and err.count("\n") == 1 and needle in err, (extra, err)


def test_a_term_awaits_its_record_until_it_is_set_up_from_one():
    from heli_uq.model import build_model
    from heli_uq.simulation import synthetic_experiment

    rec = synthetic_experiment(duration=2.0, seed=1)
    for effect in ("yaw:gp_torque", "yaw:neural_torque"):
        model = build_model([effect])
        assert model.effects[0].awaits_record
        assert not model.adapted(rec.u, rec.y, rec.dt).effects[0].awaits_record
    assert not build_model(["yaw:coulomb_friction"]).effects[0].awaits_record  # takes nothing from one


def test_cli_design_end_to_end_and_quiet(tmp_path, capsys):
    """The command writes a design within its bounds that reads back as a record; progress
    goes through logging to stdout, and --quiet leaves only the result lines."""
    argv = ["design", "--duration", "6", "--segment", "2:3", "--compare-with", "none", "--seed", "1",
            "--pitch=" + ":".join(map(str, ENVELOPE_DEG))]
    assert main([*argv, "--out", str(tmp_path / "loud")]) == 0
    loud = capsys.readouterr().out.splitlines()
    assert any(line.startswith("hill climb 60/60") for line in loud)
    assert main([*argv, "--quiet", "--out", str(tmp_path / "quiet")]) == 0
    quiet = capsys.readouterr().out.splitlines()
    assert len(quiet) == 2 and json.loads(quiet[0])["published"] is None, quiet
    assert quiet[0] == loud[-2]  # same seed, same design
    rec = read_record(tmp_path / "quiet" / "design.csv")
    assert rec.n == 600 and rec.dt == 0.01
    changes = np.flatnonzero(np.any(np.diff(rec.u, axis=0) != 0, axis=1))
    lengths = np.diff(np.concatenate([[-1], changes, [rec.n - 1]]))
    assert lengths.min() >= 200 and lengths.max() <= 300
    low, high = np.radians(ENVELOPE_DEG)
    assert low <= rec.y[:, 0].min() and rec.y[:, 0].max() <= high  # predicted pitch kept in --pitch
    stored = json.loads((tmp_path / "quiet" / "design.json").read_text())
    assert stored["baselines"]["published"]["skipped"] and stored["volume_ratio_vs_published"] is None


def test_an_input_whose_predicted_pitch_leaves_the_envelope_is_infeasible(gain):
    """The same input is feasible in the default envelope and infeasible in one that the
    predicted pitch leaves (it starts near -34 deg and never reaches -85 deg)."""
    u = random_staircase(BOUNDS, np.random.default_rng(4)).inputs()
    theta = np.asarray(gain.angles(jnp.asarray(gain.prior.center), jnp.asarray(u))[0][:, 0])
    assert np.degrees(theta.max()) > -85.0
    narrow = InformationGain(gain.prior, gain.dt, (np.radians(-90.0), np.radians(-85.0)))
    assert np.isfinite(gain.value(u)) and narrow.value(u) == -np.inf
