"""Simulation-based calibration (heli_uq.calibration): the Dask and the serial scheduler
give the same replicates, a rerun resumes (and refuses other settings), a failing
replicate is reported while the others finish, and the rank statistics tell uniform
ranks from broken ones."""

import json
import os

import jax
import numpy as np
import pytest

from heli_uq.calibration import SBCSettings, run_sbc, sbc, summarise
from heli_uq.calibration.ranks import (
    expected_interval_coverage,
    expected_rank_coverage,
    rank_covered,
    thinned_ranks,
)
from heli_uq.errors import ParameterError
from heli_uq.executor import MIN_COMPILE_ENV
from heli_uq.probability.priors import X0_ANGLE_SD

#: The smallest useful replicate: a short record, one short chain, 19 ranked draws (not
#: thinned: 20 draws of a 30-step warm-up have an ESS of a few; thinning is tested apart).
TINY = SBCSettings(duration=1.5, h_sd=0.0, chains=1, warmup=30, draws=20, ranks=19,
                   x0_prior="generator", thin_to_ess=False)  # fmt: skip
#: Replicates run by the serial scheduler; the Dask worker runs the last of them alone.
REPLICATES = 2
DASK_REPLICATE = REPLICATES - 1
#: The same replicate computed in another process may differ in the last bits (XLA's
#: floating-point order is the same program, so it should not; this bounds it).
SAME_PROCESS_RTOL = 1e-9
#: Replicates of the synthetic rank-statistics case, and its ranked draws.
N_SYNTHETIC = 200
L_SYNTHETIC = 19
#: Chi-square p-value below which ranks are called non-uniform (and above which uniform
#: ones must stay).
P_REJECT = 1e-3
#: Coverage of exactly uniform ranks with the 90 % interval's flags set from the ranks.
COVERAGE_TOL = 0.05
#: Monte Carlo replicates of the calibrated-Gaussian cases (coverage sd ~ 0.003).
N_MONTE_CARLO = 10_000
#: Their coverage agrees with the formula within 4 Monte Carlo sd.
MC_COVERAGE_TOL = 0.012
#: Lag-1 autocorrelation of the AR(1) "sampler" whose raw ranks are not uniform.
AR_RHO = 0.99


@pytest.fixture(scope="module")
def serial_run(tmp_path_factory):
    """Replicates 0 and 1 of TINY, serial, in this process (also fills the persistent
    compilation cache that the Dask workers then read)."""
    out = tmp_path_factory.mktemp("sbc_serial")
    return out, run_sbc(out, TINY, REPLICATES, scheduler="serial")


def _comparable(rep):
    """The parts of a replicate that do not depend on timing."""
    drop = {"wall_s", "start_s", "nuts_s", "provenance"}
    return {k: v for k, v in rep.items() if k not in drop}


@pytest.mark.slow  # ~40 s cold for the worker's replicate (each replicate compiles its own programs)
@pytest.mark.xdist_group("sbc_run")
def test_dask_and_serial_give_the_same_replicates(serial_run, tmp_path, monkeypatch):
    """A spawned Dask worker computes replicate 1 alone exactly as the serial path computed
    it after replicate 0: a replicate's randomness depends only on its index and the
    settings, not on the process or on what ran before it."""
    # the workers share this process's persistent compilation cache (conftest.py)
    monkeypatch.setenv("JAX_COMPILATION_CACHE_DIR", jax.config.jax_compilation_cache_dir)
    monkeypatch.setenv(MIN_COMPILE_ENV, "0")
    monkeypatch.setenv("JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES", "0")
    _, serial = serial_run
    dask = run_sbc(tmp_path, TINY, [DASK_REPLICATE], scheduler="local", workers=1)
    assert [r["replicate"] for r in serial] == list(range(REPLICATES))
    assert [r["replicate"] for r in dask] == [DASK_REPLICATE]
    for s, d in zip(serial[DASK_REPLICATE:], dask):
        assert s["L"] == TINY.ranks
        assert s["ranks"] == d["ranks"] and s["covered90"] == d["covered90"]
        assert all(0 <= v <= s["L"] for v in s["ranks"].values())
        np.testing.assert_allclose(d["step_size"], s["step_size"], rtol=SAME_PROCESS_RTOL)
        assert _comparable(s).keys() == _comparable(d).keys()
        assert s["truth"] == d["truth"] and s["sigma"] == d["sigma"]
    # the two replicates differ (the index seeds them)
    assert serial[0]["truth"] != serial[1]["truth"]


def _fake_replicate(task):
    """A replicate that takes no time: ranks follow the index."""
    r, settings = task
    return {"replicate": r, "names": ["a", "b"], "L": settings.ranks, "sigma": 0.01,
            "ranks": {"a": r, "b": settings.ranks - r}, "covered90": {"a": True, "b": False},
            "settings": settings.to_dict(), "wall_s": 0.0, "divergences": 0, "mean_steps": 3.0}  # fmt: skip


def test_a_rerun_reuses_stored_replicates_and_refuses_other_settings(tmp_path, monkeypatch):
    monkeypatch.setattr(sbc, "run_replicate", _fake_replicate)
    first = run_sbc(tmp_path, TINY, 3, scheduler="serial")
    assert [r["replicate"] for r in first] == [0, 1, 2]
    stamps = {p.name: p.stat().st_mtime_ns for p in tmp_path.glob("rep_*.json")}
    assert len(stamps) == 3
    assert json.loads((tmp_path / sbc.SETTINGS_FILE).read_text()) == TINY.to_dict()

    def must_not_run(task):
        raise AssertionError(f"replicate {task[0]} recomputed")

    monkeypatch.setattr(sbc, "run_replicate", must_not_run)
    again = run_sbc(tmp_path, TINY, 3, scheduler="serial")
    assert again == first
    assert {p.name: p.stat().st_mtime_ns for p in tmp_path.glob("rep_*.json")} == stamps
    # a larger count runs only the new replicate
    monkeypatch.setattr(sbc, "run_replicate", _fake_replicate)
    assert len(run_sbc(tmp_path, TINY, 4, scheduler="serial")) == 4
    assert {p.name: p.stat().st_mtime_ns for p in tmp_path.glob("rep_*.json") if p.name in stamps} == stamps

    changed = SBCSettings(**{**TINY.to_dict(), "warmup": TINY.warmup + 1, "x0_prior": "data"})
    with pytest.raises(ParameterError, match=r"warmup \(stored 30, requested 31\).*x0_prior"):
        run_sbc(tmp_path, changed, 4, scheduler="serial")
    assert len(list(tmp_path.glob("rep_*.json"))) == 4


def test_a_directory_from_before_thinning_refuses_thinned_replicates(tmp_path, monkeypatch):
    """A field added later counts with its old value: a directory whose settings lack
    ``thin_to_ess`` ranked unthinned draws, so thinned replicates must not join it."""
    monkeypatch.setattr(sbc, "run_replicate", _fake_replicate)
    run_sbc(tmp_path, TINY, 1, scheduler="serial")
    old = {k: v for k, v in TINY.to_dict().items() if k != "thin_to_ess"}
    (tmp_path / sbc.SETTINGS_FILE).write_text(json.dumps(old))
    thinned = SBCSettings(**{**TINY.to_dict(), "thin_to_ess": True})
    with pytest.raises(ParameterError, match=r"thin_to_ess \(stored False, requested True\)"):
        run_sbc(tmp_path, thinned, 2, scheduler="serial")
    assert not TINY.thin_to_ess
    assert len(run_sbc(tmp_path, TINY, 2, scheduler="serial")) == 2


def test_interval_and_rank_coverage_of_a_calibrated_gaussian_posterior():
    """Truth and 100 posterior draws from one N(0, 1): the quantile interval covers
    (n - 1) 0.9 / (n + 1) = 88.2 %, the central ranks exactly 90 %."""
    rng = np.random.default_rng(1)
    n = 100
    truth = rng.standard_normal(N_MONTE_CARLO)
    draws = rng.standard_normal((N_MONTE_CARLO, n))
    lo, hi = np.quantile(draws, [0.05, 0.95], axis=1)
    interval = np.mean((lo <= truth) & (truth <= hi))
    assert interval == pytest.approx(expected_interval_coverage(n), abs=MC_COVERAGE_TOL)
    assert expected_interval_coverage(n) == pytest.approx(0.8822, abs=1e-4)
    ranks = np.sum(draws[:, :99] < truth[:, None], axis=1)
    assert np.mean([rank_covered(k, 99) for k in ranks]) == pytest.approx(0.9, abs=MC_COVERAGE_TOL)
    assert [rank_covered(k, 99) for k in (4, 5, 94, 95)] == [False, True, True, False]


def _ar1_replicates(thin_to_ess: bool, n_reps: int = 1000, n: int = 1000):
    """Replicates of a calibrated but autocorrelated sampler: truth ~ N(0, 1), draws a
    stationary AR(1) chain with N(0, 1) marginals, independent of the truth."""
    rng = np.random.default_rng(2)
    reps = []
    for _ in range(n_reps):
        truth = rng.standard_normal()
        x = np.empty(n)
        x[0] = rng.standard_normal()
        innovations = np.sqrt(1 - AR_RHO**2) * rng.standard_normal(n)
        for t in range(1, n):
            x[t] = AR_RHO * x[t - 1] + innovations[t]
        ranks, big_l, thin, ess = thinned_ranks(x[None, :, None], np.array([truth]), 99,
                                                thin_to_ess=thin_to_ess)  # fmt: skip
        reps.append({"names": ["q"], "L": big_l, "sigma": 0.01, "ranks": {"q": int(ranks[0])},
                     "covered90": {"q": rank_covered(int(ranks[0]), big_l)}, "ess": {"q": float(ess[0])},
                     "divergences": 0, "mean_steps": 1.0, "wall_s": 1.0})  # fmt: skip
    return reps


def test_thinning_to_the_ess_makes_autocorrelated_ranks_uniform():
    """Raw ranks among strongly autocorrelated draws pile up at the ends (the draws cover
    only part of the posterior, so the truth often lies beyond all of them); thinned to
    the ESS they are uniform.  Also checks the pooled histogram when L differs between replicates."""
    raw, thinned = summarise(_ar1_replicates(False)), summarise(_ar1_replicates(True))
    assert raw["quantities"]["q"]["chi2_pvalue"] < P_REJECT
    assert thinned["quantities"]["q"]["chi2_pvalue"] > P_REJECT
    reps = _ar1_replicates(True)
    assert len({r["L"] for r in reps}) > 1 and max(r["L"] for r in reps) < 99
    # the draws' ESS is far below their number (~ n (1 - rho) / (1 + rho) = 5)
    assert thinned["quantities"]["q"]["ess_median"] < 0.02 * 1000
    # raw ranks of too few effective draws also under-cover
    assert raw["quantities"]["q"]["coverage90_rank"] < 0.9 - 2 * COVERAGE_TOL


def test_expected_rank_coverage_is_the_share_of_covered_ranks():
    """For every L the closed form equals the share of the L + 1 equally likely ranks that
    :func:`rank_covered` accepts; 90 % only when 20 divides L + 1, all ranks below L = 19."""
    for big_l in (1, 3, 18, 19, 20, 50, 99):
        share = np.mean([rank_covered(k, big_l) for k in range(big_l + 1)])
        assert expected_rank_coverage(big_l) == pytest.approx(share, abs=1e-12)
    assert expected_rank_coverage(18) == 1.0 and expected_rank_coverage(99) == pytest.approx(0.9)


def test_anti_correlated_draws_are_not_thinned():
    """NUTS draws can be anti-correlated (a replicate of the drag SBC: ESS 2100 of 100
    draws in one coordinate); numpyro's ESS estimate of strongly anti-correlated draws is
    negative, which must not thin them to one draw: they are ranked as they are."""
    rng = np.random.default_rng(7)
    x = np.zeros(100)
    for i in range(1, x.size):
        x[i] = -0.95 * x[i - 1] + rng.normal()
    ranks, big_l, thin, ess = thinned_ranks(x[None, :, None], np.array([0.0]), 99)
    assert thin == 1 and big_l == 99 and ess[0] == x.size
    assert ranks[0] == np.sum(x[:99] < 0.0)


def test_an_effect_is_drawn_from_its_declared_prior_and_ranked_and_a_directory_keeps_its_model(
        tmp_path, monkeypatch):  # fmt: skip
    """With ``effects``, the base parameters keep the study prior around Table 1 and the
    effect's parameter its term's declared prior; a replicate's truth holds it, and the
    sampled coordinates that are ranked include it.  A directory of the paper's model
    (settings written before ``effects`` existed count as none) refuses replicates of
    another model."""
    from heli_uq.probability import make_problem

    settings = SBCSettings(**{**TINY.to_dict(), "effects": ["yaw:quadratic_drag"]})
    assert settings.effects == ("yaw:quadratic_drag",)
    assert settings.to_dict()["effects"] == ["yaw:quadratic_drag"]
    model = settings.model
    priors = sbc.study_priors(TINY.prior_sd, TINY.h_sd, TINY.x0_prior, model)
    assert priors.params["c_yaw"] == model.parameter("c_yaw").prior
    assert priors.params["m"].kind == "lognormal" and priors.params["m"].b == TINY.prior_sd
    truth, _, _, rec, _ = sbc.draw_replicate(0, priors, TINY.duration, model)
    assert truth["c_yaw"] >= 0.0 and rec.n == round(TINY.duration / 0.01)
    coords = make_problem(rec, model=model, priors=priors, error="iid").coords
    assert "c_yaw" in coords.free and np.all(np.isfinite(coords.from_physical(truth)))

    monkeypatch.setattr(sbc, "run_replicate", _fake_replicate)
    run_sbc(tmp_path, TINY, 1, scheduler="serial")
    old = {k: v for k, v in TINY.to_dict().items() if k != "effects"}
    (tmp_path / sbc.SETTINGS_FILE).write_text(json.dumps(old))
    with pytest.raises(ParameterError, match=r"effects \(stored \[\], requested \['yaw:quadratic_drag'\]\)"):
        run_sbc(tmp_path, settings, 2, scheduler="serial")


def test_settings_of_an_older_directory_come_from_its_replicates(tmp_path, monkeypatch):
    """A directory written before settings.json existed is checked against the settings
    recorded in its replicates."""
    monkeypatch.setattr(sbc, "run_replicate", _fake_replicate)
    run_sbc(tmp_path, TINY, 1, scheduler="serial")
    os.remove(tmp_path / sbc.SETTINGS_FILE)
    with pytest.raises(ParameterError, match=r"rep_0000\.json.*duration"):
        run_sbc(tmp_path, SBCSettings(**{**TINY.to_dict(), "duration": 2.0}), 1, scheduler="serial")


def test_a_failing_replicate_is_reported_and_the_others_finish(tmp_path, monkeypatch):
    """Replicate 1 raises; replicates 0 and 2 are still stored, the failure is logged and
    kept in failed.json, and a rerun that succeeds retries it and clears the file."""
    def broken(task):
        if task[0] == 1:
            raise RuntimeError("injected failure")
        return _fake_replicate(task)

    monkeypatch.setattr(sbc, "run_replicate", broken)
    messages = []
    reps = run_sbc(tmp_path, TINY, 3, scheduler="serial", log=messages.append)
    assert [r["replicate"] for r in reps] == [0, 2]
    failed = json.loads((tmp_path / sbc.FAILED_FILE).read_text())
    assert list(failed) == ["1"] and "RuntimeError: injected failure" in failed["1"]
    assert any("replicate 1: FAILED" in m and "injected failure" in m for m in messages)
    assert any("1 replicate(s) failed: [1]" in m for m in messages)
    monkeypatch.setattr(sbc, "run_replicate", _fake_replicate)
    assert [r["replicate"] for r in run_sbc(tmp_path, TINY, 3, scheduler="serial")] == [0, 1, 2]
    assert not (tmp_path / sbc.FAILED_FILE).exists()


def _synthetic(ranks, sigmas):
    """Replicate dicts with the given ranks of one quantity; covered90 is what the ranks
    imply (the truth inside the central 90 % of the L draws)."""
    lo, hi = 0.05 * L_SYNTHETIC, 0.95 * L_SYNTHETIC
    return [{"names": ["q"], "L": L_SYNTHETIC, "sigma": float(s), "ranks": {"q": int(k)},
             "covered90": {"q": bool(lo < k < hi)}, "divergences": 0, "mean_steps": 1.0,
             "wall_s": 1.0} for k, s in zip(ranks, sigmas)]  # fmt: skip


def test_summary_tells_uniform_ranks_from_broken_ones():
    rng = np.random.default_rng(0)
    sigmas = np.where(np.arange(N_SYNTHETIC) % 2, X0_ANGLE_SD / 5, X0_ANGLE_SD * 4)  # half below
    uniform = summarise(_synthetic(rng.integers(0, L_SYNTHETIC + 1, N_SYNTHETIC), sigmas))
    q = uniform["quantities"]["q"]
    assert q["chi2_pvalue"] > P_REJECT
    assert q["coverage90"] == pytest.approx(0.9, abs=COVERAGE_TOL)
    assert uniform["replicates"] == N_SYNTHETIC and uniform["L"] == L_SYNTHETIC

    zeros = summarise(_synthetic(np.zeros(N_SYNTHETIC, int), sigmas))
    assert zeros["quantities"]["q"]["chi2_pvalue"] < P_REJECT
    assert zeros["quantities"]["q"]["coverage90"] == 0.0
    # too narrow a posterior: ranks pile up at both ends, the mean rank stays central
    ends = summarise(_synthetic(np.tile([0, L_SYNTHETIC], N_SYNTHETIC // 2), sigmas))
    assert ends["quantities"]["q"]["chi2_pvalue"] < P_REJECT

    # the noise split: broken ranks only in the high-noise replicates
    mixed_ranks = np.where(sigmas < X0_ANGLE_SD, L_SYNTHETIC // 2, 0)
    mixed = summarise(_synthetic(mixed_ranks, sigmas))
    half = N_SYNTHETIC // 2
    assert mixed["coverage90_sigma_below_x0_sd"] == {"replicates": half, "mean_over_quantities": 1.0,
                                                     "rank_mean_over_quantities": 1.0}  # fmt: skip
    assert mixed["coverage90_sigma_above_x0_sd"] == {"replicates": half, "mean_over_quantities": 0.0,
                                                     "rank_mean_over_quantities": 0.0}  # fmt: skip
    assert mixed["coverage90_mean_over_quantities"] == 0.5


def test_exactly_uniform_ranks_pass_also_when_bins_do_not_divide_the_ranks():
    """L + 1 = 20 ranks in 7 bins: equal expected counts would reject exactly uniform
    ranks; the expected counts follow the number of ranks per bin."""
    ranks = np.tile(np.arange(L_SYNTHETIC + 1), 50)
    summary = summarise(_synthetic(ranks, np.full(ranks.size, 0.01)), bins=7)
    assert summary["quantities"]["q"]["chi2_pvalue"] == pytest.approx(1.0)


def test_bad_settings_and_requests_are_refused(tmp_path):
    with pytest.raises(ParameterError, match="x0_prior"):
        SBCSettings(x0_prior="prior")
    with pytest.raises(ParameterError, match="unknown effect 'backlash'"):
        SBCSettings(effects=("yaw:backlash",))
    # a term set up from the record: it used to fail every replicate with "KeyError: 'gp_f_0_yaw'"
    for effect in ("yaw:gp_torque", "pitch:neural_torque"):
        kind = effect.split(":")[1]
        with pytest.raises(ParameterError, match=f"{kind}.*SBC draws a replicate's truth before"):
            SBCSettings(effects=("yaw:coulomb_friction", "yaw:deadband", effect))
    assert SBCSettings(effects=("yaw:coulomb_friction", "yaw:deadband")).effects  # named effects pass
    with pytest.raises(ParameterError, match="ranks"):
        SBCSettings(ranks=0)
    with pytest.raises(ParameterError, match="workers"):
        run_sbc(tmp_path, TINY, 1, workers=0)


def test_the_script_plots_and_summarises_stored_replicates(tmp_path, monkeypatch):
    """studies/sbc.py --plot reads the replicates, writes the figure and a summary with
    provenance."""
    import importlib.util
    import pathlib

    monkeypatch.setattr(sbc, "run_replicate", _fake_replicate)
    run_sbc(tmp_path, TINY, 4, scheduler="serial")
    path = pathlib.Path(__file__).resolve().parents[1] / "studies" / "sbc.py"
    spec = importlib.util.spec_from_file_location("sbc_script", path)
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    fig = tmp_path / "ranks.png"
    assert script.main(["--out", str(tmp_path), "--plot", "--fig", str(fig)]) == 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["replicates"] == 4 and summary["provenance"]["argv"][0] == "sbc.py"
    assert fig.stat().st_size > 0
    # a rerun under other settings is one error line, exit code 2
    assert script.main(["--out", str(tmp_path), "--replicates", "4", "--warmup", "31",
                        "--h-sd", "0", "--chains", "1", "--draws", "20", "--ranks", "19",
                        "--x0-prior", "generator", "--duration", "1.5", "--scheduler", "serial"]) == 2
