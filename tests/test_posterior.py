"""The posterior workflow on a short synthetic record with known truth (CI-sized)."""

import json

import arviz as az
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import SYNTHETIC_NOISE

from heli_uq.cli import main
from heli_uq.errors import ParameterError
from heli_uq.inference import run_emcee, run_nuts
from heli_uq.inference.density import constrain_draws, log_density_setup
from heli_uq.model import HeliModel, load_params_json
from heli_uq.model.tables import X0_NAMES
from heli_uq.output import summarize, to_inference_data
from heli_uq.probability import log_likelihood, make_problem
from heli_uq.simulation import SYNTHETIC_PARAMS, simulate, synthetic_experiment

NUTS = dict(chains=2, warmup=150, draws=150, chunk=75, seed=0, progress=False, target_accept=0.95)
#: Sampler health on the shared record.  It is short (4 s) with 3 mrad noise and its
#: posterior is far from Gaussian (weakly identified log-gains K_theta_psi, J_s): at
#: target acceptance 0.95 a few transitions diverge, where the full record gives 1 in
#: 4000.  The count is chaotic in the start and the seed (a 1-ulp change of the start
#: moved seed 0 from 0 to 19 of 300), so the bounds come from its spread, measured over
#: seeds 0-7 at exactly these settings (2026-11-25): 0, 0, 3, 0, 7, 9, 1, 0 divergent of
#: 300 (at most 3 %); 8-46 % of draws at the tree-depth limit.  The bounds flag a sampler
#: whose divergences or saturation grow well past that spread, not a few percent more.
#: The alternatives measured on the same seeds did worse: a diagonal mass matrix gave one
#: seed 34 divergent of 300, the Laplace mass matrix kept fixed (no adaptation) 39.
MAX_DIVERGENT_FRACTION = 0.05
#: Most draws at the tree-depth limit (measured: at most 46 %, above).
MAX_SATURATED_FRACTION = 0.6
#: The 90 % interval of the residual scale must contain the truth.
INTERVAL = (0.05, 0.95)
#: The posterior mean of the gravity ratio lies within this many posterior sd of the truth.
#: On this record the truth sits ~2.2 posterior sd from the posterior mean (2 x 400 draws:
#: mean 15.15, sd 0.062; truth 15.01); 2 x 150 draws estimate the sd at 0.048-0.067, so
#: the spread used is the larger of the draws' sd and the Laplace sd at the MAP (0.085),
#: a deterministic estimate of the same width.
TRUTH_SD = 3.0
#: NUTS and emcee posterior means of an identified quantity differ by at most this many
#: posterior sd (both runs are short, CI-sized).
AGREEMENT_SD = 2.0


def gravity_ratio(p):
    return p["m"] * p.get("g", 9.81) * p["r_c"] / (p["J_bc"] + p["m"] * p["r_c"] ** 2
                                                  + p["m"] * p["h"] ** 2)  # fmt: skip


# session scope: a module fixture is torn down whenever an xdist worker waits for work
@pytest.fixture(scope="session")
def nuts_run(synthetic_problem, synthetic_start, tmp_path_factory):
    return run_nuts(synthetic_problem, tmp_path_factory.mktemp("nuts"), start=synthetic_start,
                    **NUTS)  # fmt: skip


@pytest.mark.xdist_group("nuts_run")
def test_nuts_recovers_identified_quantities(nuts_run, synthetic_start):
    s = nuts_run.samples
    truth = gravity_ratio(SYNTHETIC_PARAMS)
    draws = gravity_ratio(s).ravel()
    laplace_sd = gravity_ratio(synthetic_start.laplace_draws(2000, seed=0)).std()
    spread = max(draws.std(), laplace_sd)
    assert abs(draws.mean() - truth) < TRUTH_SD * spread, (draws.mean(), spread, truth)
    for j in range(2):
        lo, hi = np.quantile(s["sigma"][..., j], INTERVAL)
        assert lo < SYNTHETIC_NOISE < hi
    assert nuts_run.stats["diverging"].mean() <= MAX_DIVERGENT_FRACTION
    saturated = nuts_run.stats["num_steps"] >= 2 ** nuts_run.info["max_tree_depth"] - 1
    assert saturated.mean() <= MAX_SATURATED_FRACTION


@pytest.mark.xdist_group("nuts_run")
def test_nuts_and_emcee_agree(nuts_run, synthetic_problem, synthetic_start, tmp_path):
    em = run_emcee(synthetic_problem, tmp_path, start=synthetic_start, ensembles=2, steps=600,
                   seed=1, progress=False)  # fmt: skip
    a, b = gravity_ratio(nuts_run.samples).ravel(), gravity_ratio(em.samples).ravel()
    assert abs(a.mean() - b.mean()) < AGREEMENT_SD * a.std()


#: The stored pointwise log likelihood sums to the model's log likelihood of the same draw.
LOGLIK_SUM_RTOL = 1e-10


# arviz warns when some observation's Pareto k exceeds 0.6; on this short 2-chain run that
# happened on a fresh machine (2026-11-27) and not before.  The assertion below (elpd > 0
# at 3 mrad noise, about +4.5 nats per observation) does not rest on those few weights.
@pytest.mark.filterwarnings("ignore:Estimated shape parameter of Pareto distribution")
@pytest.mark.xdist_group("nuts_run")
def test_inference_data_groups_and_dims(nuts_run, synthetic_problem):
    idata = to_inference_data(nuts_run, prior_draws=50, pp_draws=40)
    for group in ("posterior", "sample_stats", "log_likelihood", "prior",
                  "posterior_predictive", "observed_data", "constant_data"):  # fmt: skip
        assert group in idata.groups(), group
    n = synthetic_problem.n_train
    assert idata.posterior["sigma"].dims == ("chain", "draw", "output")
    assert list(idata.posterior["output"].values) == ["theta", "psi"]
    assert idata.log_likelihood["y"].shape == (2, NUTS["draws"], n, 2)  # block of 1 sample
    np.testing.assert_allclose(idata.log_likelihood["time_block"].values, synthetic_problem.t[:n])
    assert idata.posterior_predictive["y_pred"].dims == ("chain", "draw", "time", "output")
    assert "m" in idata.posterior and "g" not in idata.posterior  # g is fixed
    # the pointwise log likelihood sums to the model's log likelihood of that draw, which we
    # recompute here from the draw's parameters through the problem's own simulation
    post = idata.posterior
    for chain, draw in ((0, 0), (1, 77)):
        stored = float(idata.log_likelihood["y"].sel(chain=chain, draw=draw).sum())
        params = {k: float(post[k].sel(chain=chain, draw=draw)) for k in synthetic_problem.coords.free}
        x0 = [float(post[k].sel(chain=chain, draw=draw)) for k in
              ("theta0", "psi0", "omega_theta0", "omega_psi0")]  # fmt: skip
        sim = synthetic_problem.solve(params, jnp.asarray(x0), n).ys[:, :2]
        sigma = jnp.asarray(post["sigma"].sel(chain=chain, draw=draw).values)
        direct = float(log_likelihood(sim, jnp.asarray(synthetic_problem.y[:n]), sigma))
        assert abs(stored - direct) <= LOGLIK_SUM_RTOL * abs(direct), (stored, direct)
    summary = summarize(idata)
    for key in ("rhat_max", "ess_bulk_min", "ess_tail_min", "divergences", "rmse", "coverage90"):
        assert key in summary
    assert summary["rmse"]["theta"] < 5 * SYNTHETIC_NOISE
    assert 0.8 <= summary["coverage90"]["theta"] <= 1.0
    assert az.loo(idata).elpd_loo > 0  # 3 mrad noise on 800 observations: a high density


def test_failed_solve_is_a_rejected_proposal(synthetic_problem, synthetic_start):
    density = synthetic_start.density
    sites = density.unravel(jnp.asarray(synthetic_start.x_map))
    bad = dict(sites)
    i = synthetic_problem.coords.sampled_names.index("log_K_theta_theta_ratio")
    bad["z"] = sites["z"].at[i].set(40.0)  # K_theta_theta / M11 = e^40: the model blows up
    x_bad = jax.flatten_util.ravel_pytree(bad)[0]
    value = density.potential(x_bad)
    assert np.isposinf(float(value))
    assert np.isfinite(float(density.potential(jnp.asarray(synthetic_start.x_map))))


def test_overlapping_windows_and_bad_draws_are_clear_errors(synthetic_problem, tmp_path):
    record = synthetic_experiment(duration=2.0, seed=2)
    with pytest.raises(ParameterError, match="overlaps"):
        make_problem(record, (0.0, 1.5), (1.0, 2.0))
    with pytest.raises(ParameterError, match=r"^test: window 1.5:3 s: outside the record"):
        make_problem(record, (0.0, 1.5), (1.5, 3.0))
    with pytest.raises(ParameterError, match=r"^train: window -1:1.5 s: outside the record"):
        make_problem(record, (-1.0, 1.5), (1.5, 2.0))
    with pytest.raises(ParameterError, match="draws"):
        run_nuts(synthetic_problem, tmp_path, draws=0)


#: A tree-depth limit the short synthetic posterior reaches (its trees are 3-4 deep).
TREE_DEPTH = 2
#: The MAP's simulation fits the 3 mrad noise of the CLI record to within this RMS [rad]
#: per axis (Table 1's start values are ~0.1 rad off on it).
MAP_FIT_RMSE = 0.006


def _cli_record():
    """The record of both CLI end-to-end tests.  They run in one xdist group with the same
    windows (``run``'s 91/131 split of 2 s is 0-1.39 s), so the second reuses the first's
    compiled log density from the persistent cache."""
    return synthetic_experiment(duration=2.0, seed=4, noise_std=(0.003, 0.003))


@pytest.mark.slow
@pytest.mark.xdist_group("cli_record")
def test_cli_sample_end_to_end(tmp_path, capsys):
    record = _cli_record()
    csv = tmp_path / "rec.csv"
    record.to_csv(csv)
    out = tmp_path / "post"
    code = main(["sample", "--data", str(csv), "--train", "0:1.39", "--test", "1.39:2",
                 "--chains", "1", "--warmup", "40", "--draws", "30", "--error", "iid",
                 "--max-tree-depth", str(TREE_DEPTH), "--no-progress", "--out", str(out)])  # fmt: skip
    assert code == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["max_tree_depth"] == TREE_DEPTH
    assert summary["windows"]["test"]["n_samples"] == 61
    assert set(summary["coverage90_test"]) == {"theta", "psi"}
    idata = az.from_netcdf(out / "posterior.nc")
    assert idata.posterior.sizes["draw"] == 30
    # the limit reaches the sampler: no draw takes more than 2^D - 1 leapfrog steps
    assert int(idata.sample_stats["n_steps"].max()) <= 2**TREE_DEPTH - 1
    assert (out / "bands.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "m" in (out / "summary.csv").read_text()
    # map.json: every parameter of the model at the MAP, which simulates the fitting window
    # to the noise (simulate --params reads it; sample --init DIR starts from it)
    fit = load_params_json(out / "map.json")
    start = HeliModel().start_values()  # the record's truth: a fit of noisy data moves off it
    assert set(fit) == set(start) and any(abs(fit[k] / start[k] - 1) > 1e-6 for k in start)
    x0 = [float(idata.posterior[n].mean()) for n in X0_NAMES]
    states = np.asarray(simulate(fit, x0, record.u, record.dt, substeps=summary["substeps"]))
    n_train = summary["windows"]["train"]["n_samples"]
    rmse = np.sqrt(np.mean((states[:n_train, :2] - record.y[:n_train]) ** 2, axis=0))
    assert np.all(rmse < MAP_FIT_RMSE), rmse
    assert np.isfinite(summary["map_value"])
    capsys.readouterr()  # forget the successful run's output (arviz logs 1-chain warnings)
    for bad in (["--train", "0:1.39", "--test", "1:2"], ["--draws", "0"],
                ["--window", "5:9"], ["--fix", "m=lognormal:1:1"],
                ["--target-accept", "1.0"], ["--max-tree-depth", "0"]):  # fmt: skip
        code = main(["sample", "--data", str(csv), "--out", str(out), *bad])
        assert code == 2
        err = capsys.readouterr().err
        assert err.startswith("heli-uq: error:") and "Traceback" not in err, err
        assert len(err.strip().splitlines()) == 1, err


def test_ar1_model_uses_the_correlation_time(tmp_path):
    """With AR(1) errors the model samples tau and reports rho = exp(-dt / tau)."""
    record = synthetic_experiment(duration=1.0, seed=5, noise_std=(0.003, 0.003))
    problem = make_problem(record, error="ar1")
    density = log_density_setup(problem)
    sites = {k: v[0] for k, v in constrain_draws(density, density.x_init[None]).items()}
    np.testing.assert_allclose(sites["rho"], np.exp(-record.dt / np.asarray(sites["tau"])),
                               rtol=1e-12)  # fmt: skip
    assert np.isfinite(float(density.potential(jnp.asarray(density.x_init))))


@pytest.mark.slow
@pytest.mark.xdist_group("cli_record")
def test_cli_run_main_job_end_to_end(tmp_path, capsys):
    """``heli-uq run`` on a record file: figures, simulations and the posterior stage with the
    documented train/test split (first 91/131 of the record for training)."""
    from heli_uq.cli.run import RUN_TRAIN_FRACTION

    record = _cli_record()
    csv = tmp_path / "rec.csv"
    record.to_csv(csv)
    out = tmp_path / "out"
    code = main(["run", "--data", str(csv), "--chains", "1", "--warmup", "40", "--draws", "30",
                 "--no-progress", "--out", str(out)])  # fmt: skip
    assert code == 0, capsys.readouterr().err
    for f in ("data/data.png", "table3/simulation.png", "record_table1/simulation.csv",
              "posterior/posterior.nc", "posterior/bands.png", "posterior/summary.json",
              "prior/prior.nc", "prior/bands.png"):  # fmt: skip
        assert (out / f).is_file(), f
    prior = json.loads((out / "prior" / "summary.json").read_text())
    assert prior["sampler"] == "prior" and set(prior["coverage90"]) == {"train", "test"}
    idata = az.from_netcdf(out / "posterior" / "posterior.nc")
    n_train = int(idata.constant_data["train_mask"].sum())
    n_test = int(idata.constant_data["test_mask"].sum())
    assert n_train + n_test == record.n
    assert abs(n_train - RUN_TRAIN_FRACTION * record.n) <= 1
    summary = json.loads((out / "posterior" / "summary.json").read_text())
    assert set(summary["windows"]) == {"train", "test"}
    assert summary["error_model"] == "iid"
    assert main(["run", "--data", str(csv), "--draws", "0", "--out", str(out)]) == 2
    # a resume under another seed or model is refused before any stage writes: the prior
    # check of the new settings had replaced the finished run's beside its old posterior
    written = {f: (out / f).read_bytes() for f in ("prior/summary.json", "data/data.png")}
    capsys.readouterr()
    for change, needle in ((["--seed", "1"], "seed 0 -> 1"), (["--effects", "yaw:torque_offset"], "model")):
        code = main(["run", "--data", str(csv), "--chains", "1", "--warmup", "40", "--draws", "30",
                     "--no-progress", "--out", str(out), "--resume", *change])  # fmt: skip
        err = capsys.readouterr().err
        assert code == 2 and "--resume: the run in" in err and needle in err, err
    assert all((out / f).read_bytes() == b for f, b in written.items())


#: A Gaussian target's sd in each of its coordinates, and its correlation, for the
#: importance-resampling check (a known posterior, so the resampled sd has a truth).
TARGET_SD = np.array([1.0, 2.0, 0.5, 3.0])
TARGET_CORRELATION = 0.6
#: The too-wide Gaussian's sd, a multiple of the target's in every direction; the too
#: narrow one's.  A narrower proposal has heavy-tailed weights (Pareto k about
#: ``1 - factor**2`` in one dimension, more in four), a wider one bounded weights.
WIDE_SD_FACTOR = 1.5
NARROW_SD_FACTOR = 0.25
#: Draws of the resampling check.
RESAMPLE_DRAWS = 4000
#: The resampled draws' sd agree with the target's within this relative error in every
#: coordinate (ESS about 1900 of 4000 at the wide proposal: about 2 % standard error).
RESAMPLED_SD_RTOL = 0.1
#: The real model's Laplace approximation with its sd this many times too large in every
#: direction (17 coordinates) is flagged by Pareto k (k 2.3-3.9 over six seeds, 400 draws).
MODEL_WIDE_SD_FACTOR = 1.5


def _gaussian_start(proposal_factor: float):
    """A :class:`~heli_uq.inference.start.Start` whose posterior is the known Gaussian
    ``N(0, C)`` (:data:`TARGET_SD`, :data:`TARGET_CORRELATION`) and whose Laplace
    approximation is ``N(0, proposal_factor**2 C)``."""
    from heli_uq.inference import Start
    from heli_uq.inference.density import LogDensity

    d = TARGET_SD.size
    corr = np.full((d, d), TARGET_CORRELATION) + (1 - TARGET_CORRELATION) * np.eye(d)
    cov = corr * np.outer(TARGET_SD, TARGET_SD)
    precision = jnp.asarray(np.linalg.inv(cov))
    density = LogDensity(None, lambda x: 0.5 * x @ precision @ x, None, np.zeros(d))
    return Start(None, density, np.zeros(d), 0.0, proposal_factor**2 * cov, 0.0)


def test_importance_resampling_corrects_a_too_wide_gaussian_and_flags_a_too_narrow_one():
    """Resampled by their importance weights, draws of a Gaussian 1.5x too wide have the
    known posterior's sd; the raw draws do not.  A Gaussian 4x too narrow cannot be
    corrected (its weights are heavy-tailed) and Pareto k says so."""
    from heli_uq.inference.laplace_sampler import PARETO_K_MAX, resampled_draws

    x, wide = resampled_draws(_gaussian_start(WIDE_SD_FACTOR), RESAMPLE_DRAWS, seed=1)
    raw = _gaussian_start(WIDE_SD_FACTOR).gaussian_draws(RESAMPLE_DRAWS, np.random.default_rng(1))
    assert np.allclose(np.std(x, axis=0), TARGET_SD, rtol=RESAMPLED_SD_RTOL)
    assert np.all(np.std(raw, axis=0) > TARGET_SD * (1 + 3 * RESAMPLED_SD_RTOL))
    assert wide["pareto_k"] < PARETO_K_MAX and wide["ess"] > RESAMPLE_DRAWS / 4
    _, narrow = resampled_draws(_gaussian_start(NARROW_SD_FACTOR), RESAMPLE_DRAWS, seed=1)
    assert narrow["pareto_k"] > PARETO_K_MAX
    assert narrow["ess"] < wide["ess"] / 10


#: The mean spread [nats] of the 39 largest log-weights below the largest in the overflow check.
SPREAD_NATS = 750.0


def test_weights_hundreds_of_nats_apart_are_flagged_without_a_warning():
    """Log-weights hundreds of nats apart make arviz's tail fit give k ~ 180, whose inverse
    CDF overflows (numpy warned, an error under the tests' warning filter; it failed the
    hybrid CLI test once, 2026-12-05): the weights are finite, sum to 1, and k flags them."""
    from heli_uq.inference.laplace_sampler import PARETO_K_MAX, psis_weights

    tail = -SPREAD_NATS * np.random.default_rng(13).exponential(1, 39)
    log_w = np.concatenate([np.linspace(-5000.0, -3000.0, 160), tail, [0.0]])
    with np.errstate(over="raise"):  # these weights do overflow inside arviz
        with pytest.raises(FloatingPointError):
            az.psislw(log_w.copy())
    w, k = psis_weights(log_w)
    assert np.all(np.isfinite(w)) and w.sum() == pytest.approx(1.0)
    assert k > PARETO_K_MAX


def test_pareto_k_flags_a_too_wide_laplace_of_the_model(synthetic_start):
    """On the model's own posterior the importance weights of a Laplace approximation
    1.5x too wide flag it, and the resampled draws come back as the model's sites."""
    import dataclasses

    from heli_uq.inference import importance_resample
    from heli_uq.inference.laplace_sampler import PARETO_K_MAX

    inflated = synthetic_start.covariance * MODEL_WIDE_SD_FACTOR**2
    wide = dataclasses.replace(synthetic_start, covariance=inflated)
    sites, info = importance_resample(wide, RESAMPLE_DRAWS // 10, seed=1)
    assert info["pareto_k"] > PARETO_K_MAX
    assert sites["z"].shape == (RESAMPLE_DRAWS // 10, len(synthetic_start.problem.coords.sampled_names))


#: A relative change of the Laplace covariance at the level of rounding (another CPU's
#: compiled MAP), and the most it may move a seeded draw, in units of the largest sd.
COVARIANCE_ROUNDING = 1e-14
SEEDED_DRAW_SHIFT_MAX = 1e-9
#: Changes of the covariance tried, and the draws compared after each.
ROUNDING_CHANGES = 10
ROUNDED_DRAWS = 40


def test_a_seed_gives_the_same_laplace_draws_when_the_covariance_changes_by_rounding(synthetic_start):
    """Seeded Laplace draws are continuous in the covariance: relative changes of 1e-14
    move them by rounding only.  (Drawn through eigenvectors, 2 of these 10 changes moved
    them by 0.12 sd: this covariance has two eigenvalues equal to 4 digits, whose
    eigenvectors turn freely.)"""
    import dataclasses

    cov = synthetic_start.covariance
    a = synthetic_start.gaussian_draws(ROUNDED_DRAWS, np.random.default_rng(1))
    rng = np.random.default_rng(5)
    for _ in range(ROUNDING_CHANGES):
        noise = rng.standard_normal(cov.shape) * COVARIANCE_ROUNDING
        moved = dataclasses.replace(synthetic_start, covariance=cov * (1 + 0.5 * (noise + noise.T)))
        b = moved.gaussian_draws(ROUNDED_DRAWS, np.random.default_rng(1))
        assert np.max(np.abs(a - b)) < SEEDED_DRAW_SHIFT_MAX * np.sqrt(np.max(np.diag(cov)))


#: Draws of the per-inertia summary check, and the log-sd of their common scale.
SCALE_DRAWS = 500
SCALE_LOG_SD = 1.0


def test_per_inertia_summary_removes_the_common_scale():
    """Draws that differ only along the common scale (every inertia-scaled parameter times
    one factor per draw, what no record can see) have a wide physical interval of a
    friction level and a pitch offset, and a zero-width ``per_inertia`` interval at the
    truth's ratio to the inertia of the parameter's axis."""
    from heli_uq.model import build_model
    from heli_uq.model.terms.rigid_body import pitch_inertia, yaw_inertia
    from heli_uq.output import parameter_summary

    model = build_model(["yaw:coulomb_friction", "pitch:torque_offset"])
    truth = {**{p.name: p.default for p in model.parameters()}, "F_c_yaw": 0.01, "T_0_pitch": -0.02}
    problem = make_problem(synthetic_experiment(duration=1.0, seed=1), model=model, error="iid")
    scale = np.exp(SCALE_LOG_SD * np.random.default_rng(0).standard_normal(SCALE_DRAWS))
    post = {p.name: truth[p.name] * (scale if p.scales_with_inertia else np.ones(SCALE_DRAWS))[None]
            for p in model.parameters() if p.name != "g"}  # fmt: skip
    out = parameter_summary(az.from_dict(posterior=post), model, problem)
    inertia = {"pitch": pitch_inertia(truth), "yaw": yaw_inertia(truth, problem.coords.yaw_theta_ref)}
    for name, axis in (("F_c_yaw", "yaw"), ("T_0_pitch", "pitch"), ("K_psi_psi", "yaw")):
        lo, hi = out[name]["ci95"]
        assert abs(np.log(hi / lo)) > 2 * SCALE_LOG_SD  # the physical value: as wide as the scale
        ratio = out[name]["per_inertia"]
        assert ratio["ci95"] == pytest.approx([truth[name] / float(inertia[axis])] * 2, rel=1e-12)
    assert out["F_c_yaw"]["per_inertia"]["theta_ref"] == problem.coords.yaw_theta_ref
    assert out["F_c_yaw"]["per_inertia"]["unit"] == "(N m) / (kg m^2)"
    assert out["J_s"]["per_inertia"]["unit"] == "1"  # an inertia over an inertia
    assert "theta_ref" not in out["T_0_pitch"]["per_inertia"]  # M11 does not depend on the pitch
    assert "per_inertia" not in out["m"] and "per_inertia" not in out["r_c"]  # no axis; unscaled


def test_records_of_one_length_share_compiled_programs():
    """The log density of two records of one length (other inputs, angles, initial pitch
    and median pitch) lowers to one program: the record reaches it as arguments
    (``heli_uq._jax_config``), so the second record's run reads the first's compiled
    programs from the persistent cache.  A record of another length is another program."""
    programs = {}
    for seed, duration in ((1, 1.5), (2, 1.5), (1, 2.0)):
        rec = synthetic_experiment(duration=duration, seed=seed, x0=(-0.3 - 0.2 * seed, 0.1 * seed, 0, 0))
        density = log_density_setup(make_problem(rec, error="iid"))
        programs[seed, duration] = jax.jit(density.potential).lower(density.x_init).as_text()
    assert programs[1, 1.5] == programs[2, 1.5]
    assert programs[1, 1.5] != programs[1, 2.0]
