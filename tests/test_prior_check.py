"""The prior predictive check: draws from the priors, their simulations set against a
record with a known truth, and ``heli-uq sample --sampler prior``."""

import json

import arviz as az
import numpy as np
import pytest

from heli_uq.cli.main import main
from heli_uq.errors import ParameterError
from heli_uq.model import TABLE1, HeliModel, build_model
from heli_uq.model.prior import Prior
from heli_uq.model.tables import X0_NAMES
from heli_uq.output.prior_check import COVERAGE_NOTE, prior_draws, prior_predictive_check
from heli_uq.probability import PriorSet, make_problem
from heli_uq.simulation import SYNTHETIC_PARAMS, SYNTHETIC_X0, synthetic_experiment
from heli_uq.simulation.stiffness import MAX_SUBSTEPS, STABLE_STEP, stiffness_rates

NOISE = 0.002  # rad: the synthetic record's noise sd on both angles
#: Draws of the moment test, and how many standard errors a mean may be off.
MOMENT_DRAWS, MEAN_SE = 20_000, 4.0
#: Relative error allowed on a coordinate's sd at MOMENT_DRAWS draws (its SE is 0.5 %).
SD_REL = 0.03
#: A prior that is the truth covers 90 % of the record's samples; allowed error at 400
#: draws (each band edge's probability is off by ~0.011) over 1000 samples.
COVERAGE_TOL = 0.04


def test_prior_draws_follow_every_prior_in_its_coordinate():
    """Each free parameter's draws have the exact mean and sd of the sampler's prior in
    the sampling coordinate (log for log-normal and half-normal, identity for normal:
    :meth:`Prior.coordinate_moments`): its own prior's, except that every log-normal
    inertia-scaled parameter, ``log X = log M11 + c_X``, has the common scale's
    conditional sd ``S`` (the tightest such prior's, 2) in place of the product's pooled
    ``1 / sqrt(sum 1 / sd_i^2)``, i.e. variance ``sd^2 - pooled^2 + S^2``
    (:mod:`heli_uq.probability.common_scale`); the initial angles centre on the record's
    first sample; AR(1) gives rho = exp(-dt / tau)."""
    record = synthetic_experiment(duration=2.0, seed=1)
    problem = make_problem(record, error="ar1")
    draws = prior_draws(problem, MOMENT_DRAWS, seed=3)
    free = [n for n, p in problem.priors.params.items() if p.free]
    assert set(free) <= set(draws) and not set(problem.priors.params) - set(free) & set(draws)
    scaled = [n for n in free if problem.model.parameter(n).scales_with_inertia]
    assert all(problem.priors.params[n].kind == "lognormal" for n in scaled) and len(scaled) >= 8
    sds = np.array([problem.priors.params[n].b for n in scaled])
    pooled, common = 1.0 / np.sqrt(np.sum(1.0 / sds**2)), sds.min()
    for name in free:
        prior = problem.priors.params[name]
        w = np.asarray(prior.to_coordinate(draws[name])).ravel()
        mean, sd = prior.coordinate_moments()
        if name in scaled:
            sd = np.sqrt(sd**2 - pooled**2 + common**2)
        assert abs(w.mean() - mean) <= MEAN_SE * sd / np.sqrt(MOMENT_DRAWS), name
        assert w.std() == pytest.approx(sd, rel=SD_REL), name
    for i, name in enumerate(X0_NAMES[:2]):
        assert abs(draws[name].mean() - record.y[0, i]) < 0.01
    assert draws["sigma"].shape == draws["tau"].shape == (1, MOMENT_DRAWS, 2)
    np.testing.assert_allclose(draws["rho"], np.exp(-problem.dt / draws["tau"]))


def _priors_at(values: dict, model: HeliModel | None = None) -> PriorSet:
    """Every parameter, the initial state and the noise fixed: the prior is one point."""
    model = HeliModel() if model is None else model
    changes = {n: Prior("fixed", v) for n, v in values.items() if n in model.names}
    changes.update({n: Prior("fixed", v) for n, v in zip(X0_NAMES, SYNTHETIC_X0)})
    changes.update({"sigma_theta": Prior("fixed", NOISE), "sigma_psi": Prior("fixed", NOISE)})
    return PriorSet.default(model).updated(model, changes)


def test_a_prior_at_the_truth_covers_ninety_percent_and_a_wrong_one_is_noted(tmp_path):
    """Priors fixed at the record's truth: the prior predictive is the data's own
    distribution, so its 90 % band covers 90 % of the samples and nothing is noted.  A yaw
    gain 1.5x too large leaves the yaw outside the band (noted); a pitch gain 3x too large
    lifts the body over the top in every draw (noted as unphysical)."""
    record = synthetic_experiment(duration=10.0, seed=2, noise_std=(NOISE, NOISE))
    truth = dict(SYNTHETIC_PARAMS)
    _, right = prior_predictive_check(record, tmp_path / "right", priors=_priors_at(truth), draws=400)
    for angle in ("theta", "psi"):
        assert abs(right["coverage90"]["train"][angle] - 0.9) <= COVERAGE_TOL, right["coverage90"]
    assert right["failed"] == 0.0 and right["unphysical"] == 0.0 and right["notes"] == []

    wrong = dict(truth, K_psi_psi=1.5 * truth["K_psi_psi"])
    _, yaw = prior_predictive_check(record, tmp_path / "yaw", priors=_priors_at(wrong), draws=100)
    assert yaw["coverage90"]["train"]["psi"] < COVERAGE_NOTE - 0.3
    assert any("window's psi" in n for n in yaw["notes"]), yaw["notes"]

    over = dict(truth, K_theta_theta=3.0 * truth["K_theta_theta"])
    _, pitch = prior_predictive_check(record, tmp_path / "pitch", priors=_priors_at(over), draws=100)
    assert pitch["unphysical"] == 1.0 and any("physical range" in n for n in pitch["notes"])


def test_stiff_prior_draws_raise_the_substeps_up_to_the_cap_and_past_it_are_noted(tmp_path):
    """A yaw friction whose rate needs 3 substeps gets them (no note); one that needs more
    than MAX_SUBSTEPS gets the cap, and every draw is noted as past RK4's limit."""
    model = build_model(["yaw:coulomb_friction"])
    record = synthetic_experiment(duration=2.0, seed=5, noise_std=(NOISE, NOISE))
    thetas = record.y[:, 0]
    per_level = stiffness_rates(model, {"F_c_yaw": np.array([1.0])}, fixed=dict(TABLE1, F_c_yaw=1.0),
                                thetas=thetas)[0]  # fmt: skip
    for need, cap in ((3, False), (3 * MAX_SUBSTEPS, True)):
        level = 0.9 * need * STABLE_STEP / (per_level * record.dt)  # rate h just inside `need` substeps
        priors = _priors_at(dict(TABLE1, F_c_yaw=level, F_s_yaw=0.0), model)
        _, out = prior_predictive_check(record, tmp_path / str(need), model=model, priors=priors, draws=4)
        assert out["substeps"] == (MAX_SUBSTEPS if cap else need), out["substeps"]
        assert out["stiffness"]["beyond"] == (4 if cap else 0)
        assert any("stiffer than RK4" in n for n in out["notes"]) == cap


def test_cli_prior_check_writes_the_draws_summary_and_figure(tmp_path, capsys):
    record = synthetic_experiment(duration=3.0, seed=4)
    csv = record.to_csv(tmp_path / "rec.csv")
    out = tmp_path / "prior"
    code = main(["sample", "--sampler", "prior", "--data", str(csv), "--draws", "30", "--error", "ar1",
                 "--train", "0:2", "--test", "2:3", "--out", str(out)])  # fmt: skip
    assert code == 0
    idata = az.from_netcdf(out / "prior.nc")
    assert {"prior", "prior_predictive", "observed_data", "constant_data"} <= set(idata.groups())
    assert idata.prior_predictive["y_pred"].dims == ("chain", "draw", "time", "output")
    assert idata.prior_predictive["y_pred"].shape == (1, 30, record.n, 2)
    assert idata.prior["sigma"].dims == ("chain", "draw", "output")
    summary = json.loads((out / "summary.json").read_text())
    assert summary["sampler"] == "prior" and set(summary["coverage90"]) == {"train", "test"}
    assert (out / "bands.png").stat().st_size > 0
    with pytest.raises(ParameterError, match="draws: expected an integer >= 1, found 0"):
        prior_predictive_check(record, out, draws=0)
    capsys.readouterr()
    assert main(["sample", "--sampler", "prior", "--data", str(csv), "--resume", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--resume" in err[0]
