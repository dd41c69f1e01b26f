"""emcee on the model's posterior: shapes, recovery of the truth, reproducibility,
non-finite log densities, chunked resume and option checks (heli_uq.inference.emcee_sampler)."""

import jax.numpy as jnp
import numpy as np
import pytest
from jax.flatten_util import ravel_pytree

from heli_uq.errors import ParameterError
from heli_uq.inference import emcee_sampler as ensemble
from heli_uq.inference import run_emcee
from heli_uq.inference.checkpoint import Checkpoint
from heli_uq.inference.density import coordinate_names
from heli_uq.simulation import SYNTHETIC_PARAMS

NOISE_STD = 0.003  # rad, the truth of sigma
#: The posterior mean of an identified quantity lies within this many posterior sd of the truth.
TRUTH_BAND_SD = 4.0
#: Posterior sd / Laplace sd of log sigma: the walkers spread from the 0.1-scaled start.
SPREAD_RANGE = (0.5, 2.0)
#: stats["lp"] equals -potential recomputed from the constrained draws.
LP_RTOL = 1e-9
#: Main run: long enough to spread past the initial scatter (tau is about 20 steps).
MAIN = dict(ensembles=2, steps=400, chunk=200, seed=0)
#: Small runs for reproducibility and resume (3 chunks per ensemble).
SMALL = dict(ensembles=2, steps=120, chunk=40, burn=40, thin=2, seed=5)
UNCONSTRAINED_SITES = ("omega_theta0", "p_psi0_ratio", "psi0", "scale_noise", "sigma_psi",
                       "sigma_theta", "theta0", "z")  # fmt: skip


def gravity_ratio(p):
    """m g r_c / (J_bc + m r_c^2 + m h^2): the pitch gravity term, identified by the data."""
    g = p.get("g", SYNTHETIC_PARAMS["g"])
    return p["m"] * g * p["r_c"] / (p["J_bc"] + p["m"] * p["r_c"] ** 2 + p["m"] * p["h"] ** 2)


@pytest.fixture(scope="module")
def problem(synthetic_problem):
    return synthetic_problem


@pytest.fixture(scope="module")
def start(synthetic_start):
    return synthetic_start


@pytest.fixture(scope="module")
def main_run(problem, start, tmp_path_factory):
    return run_emcee(problem, tmp_path_factory.mktemp("main"), start=start, progress=False, **MAIN)


@pytest.fixture(scope="module")
def small_run(problem, start, tmp_path_factory):
    return run_emcee(problem, tmp_path_factory.mktemp("small"), start=start, progress=False,
                     **SMALL)  # fmt: skip


def assert_same_run(a, b):
    assert a.samples.keys() == b.samples.keys()
    for k in a.samples:
        np.testing.assert_array_equal(a.samples[k], b.samples[k], err_msg=k)
    np.testing.assert_array_equal(a.stats["lp"], b.stats["lp"])
    for key in ("acceptance", "tau", "ess_emcee"):
        np.testing.assert_array_equal(a.info[key], b.info[key], err_msg=key)


def unconstrained(samples, index):
    """The flat unconstrained vector of draw ``index`` (chain, draw), as numpyro ravels it."""
    sites = {k: samples[k][index] for k in UNCONSTRAINED_SITES}
    for k in ("sigma_psi", "sigma_theta"):
        sites[k] = np.log(sites[k])
    return ravel_pytree({k: jnp.asarray(v) for k, v in sites.items()})[0]


@pytest.mark.xdist_group("emcee_main_run")
def test_shapes_sites_and_info(main_run, problem, start):
    walkers = 2 * start.density.dim + 2
    burn = MAIN["steps"] // 2
    draws = (MAIN["steps"] - burn) * walkers
    expected = set(UNCONSTRAINED_SITES) | set(problem.coords.free) | {"log_J_pitch", "sigma", "omega_psi0"}
    assert set(main_run.samples) == expected
    for k, v in main_run.samples.items():
        assert v.shape[:2] == (MAIN["ensembles"], draws), k
        assert np.all(np.isfinite(v)), k
    assert main_run.samples["z"].shape[2] == len(problem.coords.sampled_names)
    assert main_run.samples["sigma"].shape[2] == 2
    assert main_run.stats["lp"].shape == (MAIN["ensembles"], draws)
    info = main_run.info
    assert (info["sampler"], info["walkers"], info["burn"]) == ("emcee", walkers, burn)
    assert len(info["acceptance"]) == len(info["ess_emcee"]) == MAIN["ensembles"]
    assert np.shape(info["tau"]) == (MAIN["ensembles"], start.density.dim)
    assert len(info["coordinates"]) == start.density.dim
    assert all(0.0 < a < 1.0 for a in info["acceptance"])
    assert all(0.0 < e <= draws for e in info["ess_emcee"])
    # 200 post-burn steps with tau ~ 20 is < 50 tau: the run must say so.
    assert len(info["warnings"]) == MAIN["ensembles"]
    assert all("shorter than 50 tau" in w for w in info["warnings"])


@pytest.mark.xdist_group("emcee_main_run")
def test_lp_is_the_log_posterior_of_the_draws(main_run, start):
    for index in [(0, 0), (0, 777), (1, 1234), (1, -1)]:
        x = unconstrained(main_run.samples, index)
        lp = -float(start.density.potential(x))
        np.testing.assert_allclose(main_run.stats["lp"][index], lp, rtol=LP_RTOL)


@pytest.mark.xdist_group("emcee_main_run")
def test_posterior_contains_truth(main_run):
    s = main_run.samples
    ratio = gravity_ratio(s)
    truth = gravity_ratio(SYNTHETIC_PARAMS)
    assert abs(ratio.mean() - truth) <= TRUTH_BAND_SD * ratio.std()
    for j in range(2):
        sigma = s["sigma"][..., j]
        assert abs(sigma.mean() - NOISE_STD) <= TRUTH_BAND_SD * sigma.std()


@pytest.mark.xdist_group("emcee_main_run")
def test_walkers_spread_to_posterior_width(main_run, start):
    sigma_index = [i for i, n in enumerate(main_run.info["coordinates"]) if n.startswith("sigma")]
    laplace_sd = np.sqrt(np.diag(start.covariance))[sigma_index]
    for e in range(MAIN["ensembles"]):
        sd = np.log(main_run.samples["sigma"][e]).std(axis=0)
        ratio = sd / laplace_sd
        assert np.all((ratio > SPREAD_RANGE[0]) & (ratio < SPREAD_RANGE[1])), ratio


@pytest.mark.xdist_group("emcee_small_run")
def test_same_seed_same_draws(small_run, problem, start, tmp_path):
    again = run_emcee(problem, tmp_path / "a", start=start, progress=False, **SMALL)
    assert_same_run(small_run, again)
    # An ensemble's draws do not depend on how many ensembles are run ...
    one = run_emcee(problem, tmp_path / "b", start=start, progress=False,
                    **dict(SMALL, ensembles=1))  # fmt: skip
    np.testing.assert_array_equal(one.samples["z"][0], small_run.samples["z"][0])
    # ... and the ensembles are different (independent seeds and starts).
    assert not np.array_equal(small_run.samples["z"][0], small_run.samples["z"][1])
    other = run_emcee(problem, tmp_path / "c", start=start, progress=False,
                      **dict(SMALL, seed=6))  # fmt: skip
    assert not np.array_equal(other.samples["z"], small_run.samples["z"])


def test_a_dimension_above_max_dim_is_reported(problem, start, tmp_path, monkeypatch):
    from heli_uq.output.health import UNCONVERGED, check_health

    monkeypatch.setattr(ensemble, "MAX_DIM", start.density.dim - 1)
    run = run_emcee(problem, tmp_path, ensembles=1, steps=20, chunk=20, seed=3, progress=False,
                    start=start)  # fmt: skip
    dimension = [w for w in run.info["warnings"] if "MAX_DIM" in w]
    assert len(dimension) == 1 and f"on {start.density.dim} coordinates" in dimension[0]
    assert check_health({"warnings": run.info["warnings"]})["flags"] == [UNCONVERGED]


def test_default_start_is_prepare_start(problem, start, tmp_path, monkeypatch):
    calls = []

    def fake_prepare_start(p, *, seed):
        calls.append((p, seed))
        return start

    monkeypatch.setattr(ensemble, "prepare_start", fake_prepare_start)
    run = run_emcee(problem, tmp_path, ensembles=1, steps=20, chunk=20, seed=3, progress=False)
    assert calls == [(problem, 3)]
    assert run.samples["z"].shape[:2] == (1, 10 * run.info["walkers"])


def test_nan_log_density_is_a_rejection(problem, start, tmp_path, monkeypatch):
    names = coordinate_names(start.density)
    i = names.index("psi0")
    cut = float(start.x_map[i])
    log_post = ensemble._batched_log_post(start.density.potential)

    def log_post_with_nan(x):  # NaN on half of the posterior: psi0 above its MAP value
        x = np.asarray(x)
        return np.where(x[:, i] > cut, np.nan, np.asarray(log_post(x)))

    monkeypatch.setattr(ensemble, "_batched_log_post", lambda potential: log_post_with_nan)
    above = np.array(start.x_map, dtype=float)
    above[i] += 0.01
    assert np.isnan(log_post_with_nan(above[None]))[0]
    np.testing.assert_array_equal(ensemble._log_prob_fn(start.density)(above[None]), [-np.inf])

    run = run_emcee(problem, tmp_path, ensembles=1, steps=60, chunk=30, seed=2, start=start,
                    progress=False)  # fmt: skip
    for k, v in run.samples.items():
        assert np.all(np.isfinite(v)), k
    assert np.all(np.isfinite(run.stats["lp"]))
    assert np.all(run.samples["psi0"] <= cut)
    assert 0.0 < run.info["acceptance"][0] < 1.0


@pytest.mark.xdist_group("emcee_small_run")
def test_resume_after_interrupt(small_run, problem, start, tmp_path, monkeypatch):
    saved = []
    real_save = Checkpoint.save
    per_ensemble = SMALL["steps"] // SMALL["chunk"]

    def save_then_interrupt(self, *args):
        real_save(self, *args)
        saved.append(args[:2])
        if len(saved) == per_ensemble + 1:  # ensemble 0 done, first chunk of ensemble 1
            raise KeyboardInterrupt

    monkeypatch.setattr(Checkpoint, "save", save_then_interrupt)
    with pytest.raises(KeyboardInterrupt):
        run_emcee(problem, tmp_path, start=start, progress=False, **SMALL)
    monkeypatch.setattr(Checkpoint, "save", real_save)
    files = sorted(p.name for p in (tmp_path / ensemble.CHUNK_DIR).glob("ensemble_*.pkl"))
    assert len(files) == per_ensemble + 1
    resumed = run_emcee(problem, tmp_path, start=start, progress=False, resume=True, **SMALL)
    assert_same_run(small_run, resumed)


@pytest.mark.xdist_group("emcee_small_run")
def test_resume_with_more_steps(small_run, problem, start, tmp_path):
    shorter = dict(SMALL, steps=SMALL["steps"] - SMALL["chunk"])
    run_emcee(problem, tmp_path, start=start, progress=False, **shorter)
    longer = run_emcee(problem, tmp_path, start=start, progress=False, resume=True, **SMALL)
    assert_same_run(small_run, longer)


def test_resume_with_other_settings_is_refused(problem, start, tmp_path):
    run_emcee(problem, tmp_path, start=start, progress=False, **dict(SMALL, steps=40, burn=0))
    for change in ({"seed": 6}, {"walkers": 2 * start.density.dim + 4}):
        with pytest.raises(ParameterError, match="resume"):
            run_emcee(problem, tmp_path, start=start, progress=False, resume=True,
                      **dict(SMALL, **change))  # fmt: skip


@pytest.mark.parametrize("option, message", [
    ({"steps": 0}, "^steps"), ({"ensembles": 0}, "^ensembles"), ({"thin": 0}, "^thin"),
    ({"chunk": -1}, "^chunk"), ({"walkers": 0}, "^walkers"), ({"steps": 2.5}, "^steps"),
    ({"burn": 100, "steps": 100}, "^burn"), ({"burn": -1}, "^burn"),
    ({"walkers": 5}, "at least 2 \\* dimension"),
])  # fmt: skip
def test_bad_options(problem, start, tmp_path, option, message):
    with pytest.raises(ParameterError, match=message):
        run_emcee(problem, tmp_path, start=start, progress=False, **option)
