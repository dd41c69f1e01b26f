"""The parts of the discovery workflow, each against an independent form: blocked scores,
the implied torque, effect features, the pysindy ranking and the task executor."""

import dataclasses
import itertools
import json

import numpy as np
import pytest
from scipy.stats import norm

from heli_uq.discovery.implied import base_features, effect_features, implied_torque
from heli_uq.discovery.score import (
    MARGIN_PER_SAMPLE,
    MARGIN_SE,
    block_crps,
    block_scores,
    compare,
    gap_metrics,
    input_blocks,
    passes,
)
from heli_uq.discovery.sindy import rank_effects
from heli_uq.executor import TaskFailed, run_tasks
from heli_uq.model import RIG_FIT, RIG_FIT_X0, build_model
from heli_uq.model.terms.coulomb_friction import OMEGA_S
from heli_uq.model.terms.rigid_body import yaw_inertia
from heli_uq.simulation import synthetic_experiment

#: Relative tolerance of a torque recovered from smoothed, differentiated noise-free angles.
IMPLIED_RTOL = 0.05
#: An implied effect parameter from the sparse regression is a start value, not an
#: estimate: smoothing blurs the stick-slip transitions of friction.  Within this factor.
IMPLIED_PARAM_FACTOR = 2.0
#: Relative tolerance of a Monte Carlo CRPS of 20000 Gaussian draws against its closed form
#: (the estimator's relative sd there is about 0.5 %).
CRPS_MC_RTOL = 0.02
#: Longest wait [s] for the error about an unreachable scheduler (the connect timeout is 10 s).
UNREACHABLE_WAIT_S = 30.0
#: The connect timeout the unreachable-scheduler tests run with (the same code path).
SHORT_CONNECT_TIMEOUT = "2s"
#: A candidate refitted from "effect off" ends at most this far [nats] above the nested
#: model's MAP: the new parameter's own prior term (measured 1-6 nats for the effects of
#: the table on a 14 s window).
OFF_PRIOR_NATS = 8.0


def test_probe_values_of_scaled_effects_follow_the_fits_axis_inertia():
    # The common inertia scale is not identified: a fit at 7x every inertia and torque is
    # the same fit, and a friction level or an offset means the same only as a ratio to
    # its axis inertia.  Parameters that do not scale (a dead band in V) keep their start.
    from heli_uq.discovery.candidates import probe_values
    from heli_uq.model.terms.rigid_body import pitch_inertia

    model = build_model(["pitch:coulomb_friction", "yaw:quadratic_drag", "yaw:deadband"])
    new = ["F_c_pitch", "c_yaw", "delta_yaw"]
    scaled = {p.name for p in model.parameters() if p.scales_with_inertia}
    ref = model.complete(model.start_values())
    fit = {k: float(v) * (7.0 if k in scaled else 1.0) for k, v in RIG_FIT.items()}
    got = probe_values(model, fit, new)
    at_rig = model.complete({**RIG_FIT, **{n: 0.0 for n in new}})
    ratio_pitch = float(pitch_inertia(model.complete(fit)) / pitch_inertia(ref))
    assert ratio_pitch == pytest.approx(7.0 * float(pitch_inertia(at_rig) / pitch_inertia(ref)), rel=1e-12)
    assert got["F_c_pitch"] == pytest.approx(model.parameter("F_c_pitch").start_value() * ratio_pitch,
                                             rel=1e-12)
    ratio_yaw = float(yaw_inertia(model.complete(fit), 0.0) / yaw_inertia(ref, 0.0))
    assert got["c_yaw"] == pytest.approx(model.parameter("c_yaw").start_value() * ratio_yaw,
                                         rel=1e-12)
    assert got["delta_yaw"] == model.parameter("delta_yaw").start_value()
    # at the start values themselves every probe is the declared start
    assert probe_values(model, model.start_values(), new) == {
        n: model.parameter(n).start_value() for n in new}


def test_warm_starts_probe_next_to_the_current_fit_and_next_to_the_rig_fit():
    # A hidden effect can trap the current fit in a basin no local move leaves (pitch
    # friction: the model without it explains pitch with K_theta_theta/M11 = 0.08, the
    # truth 3.75), so a candidate also starts from the shipped rig fit.
    from heli_uq.discovery.candidates import probe_values, warm_starts

    effects = ["pitch:coulomb_friction"]
    model = build_model(effects)
    scaled = {p.name for p in model.parameters() if p.scales_with_inertia}
    current = {k: float(v) * (7.0 if k in scaled else 1.0) for k, v in RIG_FIT.items()}
    current["theta_0"] = -0.3  # a state of the current fit that the rig fit does not set
    starts = warm_starts(current, effects, {"F_c_pitch": 0.004})
    assert len(starts) == 3
    probe, seeded, rig = starts
    assert probe == {**current, **probe_values(model, current, ["F_c_pitch"])}
    assert seeded == {**probe, "F_c_pitch": 0.004}
    assert {k: rig[k] for k in RIG_FIT} == RIG_FIT and rig["theta_0"] == -0.3
    assert rig["F_c_pitch"] == pytest.approx(probe["F_c_pitch"] / 7.0, rel=1e-12)
    # an implied value outside the support, and a current fit that is the rig fit: one start
    at_rig = {**RIG_FIT, "theta_0": -0.3}
    assert warm_starts(at_rig, effects, {"F_c_pitch": -1.0}) == (
        {**at_rig, **probe_values(model, at_rig, ["F_c_pitch"])},)


def test_off_start_switches_the_new_effects_off_next_to_the_current_fit():
    from heli_uq.discovery.candidates import OFF_FRACTION, off_start, probe_values

    current = {**RIG_FIT, "theta_0": -0.3}
    effects = ["yaw:torsional_spring", "pitch:torque_offset"]
    model = build_model(effects)
    off = off_start(current, effects)
    probe = probe_values(model, current, ["k_yaw"])
    # k >= 0 is off at its bound 0: a small fraction of its probe; psi_0 and T_0 are real
    assert off == {**current, "k_yaw": OFF_FRACTION * probe["k_yaw"], "psi_0_yaw": 0.0, "T_0_pitch": 0.0}


# Session scope and one xdist group: the tests that use it run on one worker, which fits
# the base model once (a module fixture is fitted again after tests of other modules).
@pytest.fixture(scope="session")
def trap_record():
    """A 20 s rig-like record of the base model, and the base model's MAP on 0-14 s."""
    from heli_uq.discovery.candidates import FitTask, fitted_predictive

    rec = synthetic_experiment(RIG_FIT, RIG_FIT_X0, duration=20.0, inputs="rig_steps",
                               noise_std=(0.003, 0.008), seed=3, model=build_model([]))  # fmt: skip
    base = fitted_predictive(FitTask(rec, (0.0, 14.0), (14.0, 20.0), (), (RIG_FIT,), 0, 1, 8))
    return rec, base


@pytest.mark.slow
@pytest.mark.xdist_group("trap_record")
def test_a_nested_candidate_in_a_poor_basin_is_refitted_from_effect_off(trap_record, monkeypatch):
    """A pitch dead band started at 5 V (beyond every pitch voltage: no pitch thrust) and
    fitted without the Newton polish ends ~11 nats below the base model it nests; with no
    slack, the fallback refits it from "dead band off" and keeps that MAP, which is the
    base's up to the new prior term.
    The dead band's start grid would give this fit a start below the pitch voltages and
    rescue it on its own; it is switched off here, so that the trap stands for any poor
    basin a grid does not reach.  The polish is off because the depth of this trap is the
    optimiser's path, not a basin: with the default 6 polish steps the same start ended
    11 nats below the base in the initial yaw rate's coordinates and 4.7 in its
    momentum's (2026-12-05); unpolished, 10.7."""
    import heli_uq.discovery.candidates as candidates
    import heli_uq.inference.least_squares as least_squares

    monkeypatch.setattr(least_squares, "GRID_GAIN", 0.0)  # never add the grid start
    rec, base = trap_record
    effects = ("pitch:deadband",)
    trapped = candidates.FitTask(rec, (0.0, 14.0), (14.0, 20.0), effects,
                                 ({**base.params, "delta_pitch": 5.0},), 0, 1, 8, newton_steps=0)  # fmt: skip
    alone = candidates.fitted_predictive(trapped)
    assert not alone.from_off and alone.start.map_value > base.start.map_value + OFF_PRIOR_NATS
    monkeypatch.setattr(candidates, "NESTED_SLACK_NATS", 0.0)
    guarded = dataclasses.replace(trapped, off=candidates.off_start(base.params, list(effects)),
                                  floor=base.start.map_value)  # fmt: skip
    fitted = candidates.fitted_predictive(guarded)
    assert fitted.from_off and fitted.start.map_value < alone.start.map_value
    assert fitted.start.map_value <= base.start.map_value + OFF_PRIOR_NATS
    assert candidates.score_fitted(fitted, guarded)["off_start"] is True


@pytest.mark.slow
@pytest.mark.xdist_group("trap_record")
def test_an_untrusted_laplace_gives_the_plug_in_predictive_at_the_map(trap_record, monkeypatch):
    """Where Pareto k rejects the importance weights, every predictive draw is the MAP: the
    simulations are one and the same, the band is the residual noise's, and the record
    says so (``laplace.predictive``)."""
    import heli_uq.discovery.candidates as candidates
    from heli_uq.inference.laplace_sampler import PARETO_K_MAX

    rec, base = trap_record
    assert base.importance["predictive"] == ("laplace" if base.importance["pareto_k"] <= PARETO_K_MAX
                                             else "map")  # fmt: skip
    real = candidates.importance_resample

    def untrusted(start, n, seed=0):
        sites, info = real(start, n, seed=seed)
        return sites, {**info, "pareto_k": float("inf")}

    monkeypatch.setattr(candidates, "importance_resample", untrusted)
    task = candidates.FitTask(rec, (0.0, 14.0), (14.0, 20.0), (), (base.params,), 0, 1, 8)
    fitted = candidates.fitted_predictive(task)
    assert fitted.importance["predictive"] == "map"
    np.testing.assert_array_equal(fitted.y_sim, np.broadcast_to(fitted.y_sim[:1], fitted.y_sim.shape))
    np.testing.assert_array_equal(fitted.sigma, np.broadcast_to(fitted.sigma[:1], fitted.sigma.shape))
    assert np.all(np.std(fitted.y_pred - fitted.y_sim, axis=0) > 0)  # the noise is kept
    assert candidates.score_fitted(fitted, task)["laplace"]["predictive"] == "map"


@pytest.mark.slow
@pytest.mark.xdist_group("trap_record")
# The failing fallback finishes the trapped start after all (87 s of CI time): in the long tier.
@pytest.mark.parametrize("fallback_fails", [False, pytest.param(True, marks=pytest.mark.long)])
def test_a_start_far_above_the_current_fit_is_abandoned_for_the_fallback(trap_record, monkeypatch,
                                                                         fallback_fails):  # fmt: skip
    """With no margin, the trapped dead-band start (above the base) is given up before its
    finish and the fallback from "effect off" is fitted instead.  If the fallback fails,
    the abandoned start is finished after all: a candidate is never lost to the shortcut."""
    import heli_uq.discovery.candidates as candidates
    from heli_uq.errors import ParameterError
    from heli_uq.inference.start import PoorBasin

    rec, base = trap_record
    effects = ("pitch:deadband",)
    off = candidates.off_start(base.params, list(effects))
    task = candidates.FitTask(rec, (0.0, 14.0), (14.0, 20.0), effects, ({**base.params, "delta_pitch": 5.0},),
                              0, 1, 8, off=off, floor=base.start.map_value)  # fmt: skip
    monkeypatch.setattr(candidates, "ABANDON_NATS", 0.0)
    monkeypatch.setattr(candidates, "NESTED_SLACK_NATS", 0.0)
    calls, real = [], candidates.prepare_start

    def spy(problem, **kw):
        start = "off" if kw["guesses"] == (off,) else "trapped"
        if fallback_fails and start == "off":
            calls.append("off failed")
            raise ParameterError("no MAP start gave a finite log density")
        try:
            out = real(problem, **kw)
        except PoorBasin:
            calls.append(f"{start} abandoned")
            raise
        calls.append(f"{start} finished")
        return out

    monkeypatch.setattr(candidates, "prepare_start", spy)
    fitted = candidates.fitted_predictive(task)
    if fallback_fails:
        assert calls == ["trapped abandoned", "off failed", "trapped finished"]
        assert not fitted.from_off and fitted.start.map_value > base.start.map_value
    else:
        assert calls == ["trapped abandoned", "off finished"]
        assert fitted.from_off and fitted.start.map_value <= base.start.map_value + OFF_PRIOR_NATS


def test_input_blocks_follow_voltage_changes_and_merge_short_runs():
    dt = 0.01
    u = np.zeros((1000, 2))
    u[300:, 0] = 1.0  # change at 3 s
    u[350:, 1] = 1.0  # 0.5 s later: too short a run, merged into the previous block
    u[700:, 0] = 2.0
    assert input_blocks(u, dt, min_block_s=2.0) == [(0, 350), (350, 700), (700, 1000)]
    assert input_blocks(u, dt, min_block_s=4.0) == [(0, 1000)]  # all shorter than 4 s: one block
    assert input_blocks(u, dt, min_block_s=4.0, min_blocks=4) == [(0, 250), (250, 500), (500, 750),
                                                                  (750, 1000)]  # fmt: skip
    assert input_blocks(u, dt, min_block_s=0.0) == [(0, 300), (300, 350), (350, 700), (700, 1000)]


def test_block_scores_equal_the_mixture_density_summed_per_block():
    rng = np.random.default_rng(0)
    s, n = 7, 40
    y_sim = rng.normal(size=(s, n, 2))
    sigma = rng.uniform(0.5, 2.0, size=(s, 2))
    y = rng.normal(size=(n, 2))
    blocks = [(0, 15), (15, 40)]
    dens = np.mean([np.prod(norm.pdf(y, y_sim[k], sigma[k]), axis=1) for k in range(s)], axis=0)
    want = [np.log(dens[a:b]).sum() for a, b in blocks]
    np.testing.assert_allclose(block_scores(y_sim, sigma, y, blocks), want, rtol=1e-10)


def test_block_crps_equals_its_definition_and_the_gaussian_closed_form():
    """The blocked CRPS against two independent forms: the O(S^2) definition E|X - y| -
    E|X - X'| / 2 with the fair (S - 1) denominator, and for many Gaussian draws the closed
    form sigma (z (2 Phi(z) - 1) + 2 phi(z) - 1/sqrt(pi)); failed draws are left out."""
    rng = np.random.default_rng(1)
    s, n = 9, 30
    y_pred = rng.normal(size=(s, n, 2))
    y = rng.normal(size=(n, 2))
    blocks = [(0, 12), (12, 30)]
    e1 = np.abs(y_pred - y[None]).mean(axis=0)
    e2 = np.abs(y_pred[:, None] - y_pred[None, :]).sum(axis=(0, 1)) / (s * (s - 1))
    direct = e1 - 0.5 * e2
    want = [direct[a:b].sum() for a, b in blocks]
    np.testing.assert_allclose(block_crps(y_pred, y, blocks), want, rtol=1e-12)
    failed = np.concatenate([y_pred, np.full((1, n, 2), np.nan)])  # a draw whose solve failed
    np.testing.assert_allclose(block_crps(failed, y, blocks), want, rtol=1e-12)
    assert np.isnan(block_crps(failed[-2:], y, blocks)).all()  # one finite draw: not scored

    mu, sigma = np.array([0.3, -1.0]), np.array([0.5, 2.0])
    draws = mu + sigma * rng.standard_normal(size=(20000, 1, 2))
    obs = np.array([[0.9, -1.5]])
    z = (obs - mu) / sigma
    closed = sigma * (z * (2 * norm.cdf(z) - 1) + 2 * norm.pdf(z) - 1 / np.sqrt(np.pi))
    assert block_crps(draws, obs, [(0, 1)])[0] == pytest.approx(closed.sum(), rel=CRPS_MC_RTOL)
    # the rig's yaw on 91-131 s: the base 0.95 rad off with sd 0.28, a candidate 0.6 rad off
    # with sd 0.1: better by the CRPS, worse by the log density
    (off_wide, sd_wide), (off_near, sd_near) = (0.95, 0.28), (0.6, 0.1)
    wide = off_wide + sd_wide * rng.standard_normal(size=(4000, 1, 2))
    near = off_near + sd_near * rng.standard_normal(size=(4000, 1, 2))
    truth = np.zeros((1, 2))
    assert block_crps(near, truth, [(0, 1)])[0] < block_crps(wide, truth, [(0, 1)])[0]
    wide_sim, near_sim = np.full((1, 1, 2), off_wide), np.full((1, 1, 2), off_near)
    assert (block_scores(near_sim, np.full((1, 2), sd_near), truth, [(0, 1)])[0]
            < block_scores(wide_sim, np.full((1, 2), sd_wide), truth, [(0, 1)])[0])  # fmt: skip


def test_compare_and_margin():
    d = np.array([3.0, 5.0, 4.0, 6.0])
    diff, se = compare(d + 10.0, np.full(4, 10.0))
    assert diff == pytest.approx(18.0)
    assert se == pytest.approx(2.0 * np.std(d, ddof=1))
    assert compare([1.0, -np.inf], [0.0, 0.0])[0] == -np.inf
    n = 1000  # held-out samples: the per-sample margin is MARGIN_PER_SAMPLE * n nats
    need = MARGIN_PER_SAMPLE * n
    base = np.zeros(5)
    assert passes(base + 2 * need / 5, base, n)  # every block better, above the margin
    assert not passes(base + 0.5 * need / 5, base, n)  # below the per-sample margin
    mixed = np.array([10.0, -9.0, 10.0, -9.0, 10.0]) * need  # big total, inconsistent blocks
    assert not passes(mixed, base, n)
    growing = np.array([-0.1, 1.0, 10.0, 100.0, 1000.0]) * need / 5  # drift: large SE, no block
    assert compare(growing, base)[0] < MARGIN_SE * compare(growing, base)[1]  # clearly worse
    assert passes(growing, base, n)
    assert not passes(growing - [2 * need / 5, 0, 0, 0, 0], base, n)  # one block clearly worse


#: Sampling tolerance of a coverage estimated from 2000 points (about 4.5 standard errors).
COVERAGE_ATOL = 0.03


def test_gap_metrics_of_a_known_ensemble():
    """Data drawn from the predictive distribution itself: 90 % coverage, RMSE and V of the
    mean simulation against their direct forms."""
    rng = np.random.default_rng(1)
    mu = np.array([0.1, -0.2])
    sim = np.zeros((400, 2000, 2)) + mu
    pred = sim + rng.normal(size=sim.shape)
    y = mu + rng.normal(size=(2000, 2))
    g = gap_metrics(sim, pred, y)
    rmse = np.sqrt(np.mean((y - mu) ** 2, axis=0))
    assert g["rmse_theta"] == pytest.approx(rmse[0]) and g["rmse_psi"] == pytest.approx(rmse[1])
    assert g["V"] == pytest.approx(np.mean(np.sum((y - mu) ** 2, axis=1)))  # Eq. 1
    assert abs(g["coverage90_theta"] - 0.9) < COVERAGE_ATOL
    assert abs(g["coverage90_psi"] - 0.9) < COVERAGE_ATOL


@pytest.fixture(scope="module")
def friction_record():
    """Noise-free rig-like record with Coulomb friction F_c = 0.015 N m hidden in yaw."""
    model = build_model(["yaw:coulomb_friction"])
    params = {**RIG_FIT, "F_c_yaw": 0.015}
    rec = synthetic_experiment(params, RIG_FIT_X0, duration=40.0, inputs="rig_steps",
                               noise_std=(0.0, 0.0), seed=5, model=model)  # fmt: skip
    return rec, params


def test_implied_torque_is_the_hidden_friction(friction_record):
    """With the true base parameters, the implied yaw torque is -F_c tanh(omega/omega_s)
    (independent form) wherever yaw moves steadily."""
    rec, params = friction_record
    data = implied_torque(build_model([]), RIG_FIT, rec.y, rec.u, rec.dt)
    omega = data.v[:, 1]
    accel = np.abs(data.a[:, 1])
    steady = (np.abs(omega) > 0.05) & (accel < 0.2)
    steady[:100] = steady[-100:] = False
    assert steady.sum() > 500
    want = -params["F_c_yaw"] * np.tanh(omega[steady] / OMEGA_S)
    np.testing.assert_allclose(np.median(data.tau[steady, 1] / want), 1.0, rtol=IMPLIED_RTOL)


def test_effect_feature_is_the_torque_per_unit_parameter(friction_record):
    rec, _ = friction_record
    data = implied_torque(build_model([]), RIG_FIT, rec.y, rec.u, rec.dt)
    names, cols = effect_features(build_model([]), RIG_FIT, "yaw:torque_offset", data)
    assert names == ["T_0_yaw"]
    m22 = np.asarray(yaw_inertia(RIG_FIT, data.x[:, 0]))
    np.testing.assert_allclose(cols[:, 1, 0], 1.0 / m22, rtol=1e-9)
    np.testing.assert_allclose(cols[:, 0, 0], 0.0, atol=1e-12)


def test_sparse_regression_ranks_the_hidden_effect_first(friction_record):
    rec, params = friction_record
    base = build_model([])
    data = implied_torque(base, RIG_FIT, rec.y, rec.u, rec.dt)
    cands = {e: effect_features(base, RIG_FIT, e, data)
             for e in ("yaw:coulomb_friction", "yaw:torque_offset", "yaw:quadratic_drag",
                       "pitch:coulomb_friction", "pitch:torque_offset")}  # fmt: skip
    ranking = rank_effects(data.residual, base_features(base, RIG_FIT, data), cands, seed=0)
    assert ranking[0]["effect"] == "yaw:coulomb_friction"
    ratio = ranking[0]["implied"]["F_c_yaw"] / params["F_c_yaw"]
    assert 1 / IMPLIED_PARAM_FACTOR < ratio < IMPLIED_PARAM_FACTOR


def _square_or_fail(x):
    if x < 0:
        raise ValueError("negative input")
    return x * x


@pytest.mark.parametrize("scheduler", ["serial", "local"])
def test_run_tasks_reports_each_failure_and_finishes_the_rest(scheduler):
    seen = []
    out = run_tasks(_square_or_fail, {"a": 2, "b": -1, "c": 3}, scheduler=scheduler, workers=2,
                    on_result=lambda k, r: seen.append(k))  # fmt: skip
    assert list(out) == ["a", "b", "c"]
    assert out["a"] == 4 and out["c"] == 9
    assert isinstance(out["b"], TaskFailed) and "ValueError: negative input" in out["b"]["error"]
    assert sorted(seen) == ["a", "b", "c"]


#: A warning every task of the test below logs, and one only its task "c" logs.
SHARED_WARNING = "the MAP needs 4 solver substeps per sample; using 2"
OWN_WARNING = "task c's own warning"


def _square_and_warn(x):
    import logging

    for _ in range(1 + (x == 2)):  # task "b" gives it twice
        logging.getLogger("heli_uq.simulation.stiffness").warning(SHARED_WARNING)
    if x == 3:
        logging.getLogger("heli_uq.inference.start").warning(OWN_WARNING)
    logging.getLogger("heli_uq.simulation.stiffness").info("progress is not sent back")
    return x * x


def test_the_workers_warnings_are_logged_once_each_naming_the_tasks(caplog, capfd):
    """Candidate fits nesting one stiff base model each logged the same long warning on
    their worker's stderr (eleven times on a 12-candidate record).  Each distinct warning
    is now logged once in the calling process, under its own logger, naming its task; a
    line at the end names the other tasks that gave it; the workers print none of them."""
    import logging

    with caplog.at_level(logging.INFO, logger="heli_uq"):
        out = run_tasks(_square_and_warn, {"a": 1, "b": 2, "c": 3}, scheduler="local", workers=2)
    assert out == {"a": 1, "b": 4, "c": 9}
    shared = [r for r in caplog.records if r.getMessage().startswith(SHARED_WARNING)]
    assert len(shared) == 1 and shared[0].name == "heli_uq.simulation.stiffness", caplog.records
    first = shared[0].getMessage().removeprefix(SHARED_WARNING + " (task ").rstrip(")")
    own = [r for r in caplog.records if r.getMessage() == f"{OWN_WARNING} (task c)"]
    assert len(own) == 1 and own[0].name == "heli_uq.inference.start" and own[0].levelno == logging.WARNING
    (more,) = [r for r in caplog.records if r.name == "heli_uq.executor"]
    others = sorted(set("abc") - {first})
    quoted = f"2 more task(s) gave the warning of task {first} (\"{SHARED_WARNING}\"):"  # short: whole
    assert more.getMessage().startswith(quoted)
    assert sorted(more.getMessage().rsplit(": ", 1)[1].split(", ")) == others
    assert not any("progress" in r.getMessage() for r in caplog.records)
    printed = capfd.readouterr().err.splitlines()  # (the calling process may print its own lines)
    assert not any(line.endswith(SHARED_WARNING) for line in printed), printed  # no worker printed it


def test_the_repeat_line_quotes_a_long_warning_cut_and_a_short_one_whole(caplog):
    """The line naming the other tasks quotes the warning's head: a warning longer than
    :data:`~heli_uq.executor.WARNING_HEAD` is cut there and marked "...", a shorter one is
    quoted as it is (no "..." after a whole sentence)."""
    import logging

    from heli_uq.executor import WARNING_HEAD, _Warnings

    long = "x" * WARNING_HEAD + "the tail"
    warnings = _Warnings()
    for task in "ab":
        warnings.report(task, [("heli_uq.inference.start", logging.WARNING, long),
                               ("heli_uq.inference.start", logging.WARNING, "short")])  # fmt: skip
    with caplog.at_level(logging.WARNING, logger="heli_uq"):
        warnings.close()
    lines = [r.getMessage() for r in caplog.records if r.name == "heli_uq.executor"]
    assert lines == [f"1 more task(s) gave the warning of task a (\"{'x' * WARNING_HEAD}...\"): b",
                     "1 more task(s) gave the warning of task a (\"short\"): b"]  # fmt: skip


UNGUARDED_SCRIPT = """
from heli_uq.executor import run_tasks


def double(x):
    return 2 * x


print(run_tasks(double, {"a": 1}, scheduler="local", workers=1))
"""


def test_a_script_without_a_main_guard_gets_a_clear_error_from_the_local_cluster(tmp_path):
    """Each spawned worker imports the calling script, so an unguarded call starts the
    cluster again inside the worker, which Python refuses: the caller is told the cause and
    the fix in one line, not left with Dask's "Nanny failed to start"."""
    import subprocess
    import sys

    script = tmp_path / "unguarded.py"
    script.write_text(UNGUARDED_SCRIPT)
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                          timeout=120, cwd=tmp_path)  # fmt: skip
    assert done.returncode != 0
    last = done.stderr.strip().splitlines()[-1]
    assert last.startswith("heli_uq.errors.ParameterError: scheduler 'local'"), last
    assert 'if __name__ == "__main__":' in last and 'scheduler="serial"' in last, last


#: Seconds a worker process of the closing test lingers at exit: longer than the 4 s its
#: nanny waits before it kills the process with a warning.
SLOW_EXIT_S = 6.0


def _closing_race_filtered(_):
    import atexit
    import logging
    import time

    from heli_uq.executor import HEARTBEAT_RACE

    atexit.register(time.sleep, SLOW_EXIT_S)  # this worker process exits slowly
    logger = logging.getLogger("distributed.worker")
    race = logger.makeRecord(logger.name, logging.ERROR, __file__, 0, HEARTBEAT_RACE + ".", (), None)
    other = logger.makeRecord(logger.name, logging.ERROR, __file__, 0, "Worker stream died", (), None)
    return (not logger.filter(race), bool(logger.filter(other)))


def test_a_local_cluster_closes_without_the_messages_its_closing_causes():
    """A worker whose heartbeat meets the closing scheduler logs a traceback at ERROR;
    run_tasks' own workers drop that record and keep every other one.  A worker process
    that takes longer to exit than its nanny waits is killed with a warning in this
    process; run_tasks drops that warning while it closes its cluster, and only then."""
    import logging

    from heli_uq.executor import NANNY_KILL

    seen = []
    nanny = logging.getLogger("distributed.nanny")
    handler = logging.Handler(logging.WARNING)
    handler.emit = lambda record: seen.append(record.getMessage())
    nanny.addHandler(handler)
    try:
        out = run_tasks(_closing_race_filtered, {"a": 0, "b": 0}, scheduler="local", workers=2)
        assert not nanny.filters  # the filter is gone with the cluster
        kill = nanny.makeRecord(nanny.name, logging.WARNING, __file__, 0, f"{NANNY_KILL} 4.0 seconds",
                                (), None)  # fmt: skip
        nanny.handle(kill)
    finally:
        nanny.removeHandler(handler)
    assert out == {"a": (True, True), "b": (True, True)}, out
    assert seen == [kill.getMessage()], seen  # none during the close; outside it, logged


def test_an_unreachable_scheduler_is_one_clear_error_not_a_hang(monkeypatch):
    """Nothing listens on a closed loopback port: the executor says so in one line, within
    its connect timeout, instead of waiting for a scheduler that never answers.  The
    timeout is bounded here, then shortened (Dask retries a refused connection until it
    passes: the 10 s of waiting tested nothing the short one does not)."""
    import time

    from dask.utils import parse_timedelta

    import heli_uq.executor as executor
    from heli_uq.errors import ParameterError

    assert parse_timedelta(executor.CONNECT_TIMEOUT) < UNREACHABLE_WAIT_S
    monkeypatch.setattr(executor, "CONNECT_TIMEOUT", SHORT_CONNECT_TIMEOUT)
    t0 = time.perf_counter()
    with pytest.raises(ParameterError, match="cannot reach a Dask scheduler at 'tcp://127.0.0.1:1'") as exc:
        run_tasks(_square_or_fail, {"a": 2}, scheduler="tcp://127.0.0.1:1")
    assert "\n" not in str(exc.value)
    assert time.perf_counter() - t0 < UNREACHABLE_WAIT_S


def test_tied_candidates_are_named_and_the_whole_record_breaks_the_tie():
    """Two effects that score alike on held-out blocks are reported as tied, and the one
    with the larger whole-record support (BIC-penalised log posterior on the fitting
    window plus held-out log score) is chosen; an effect the best beats by the margin is
    not tied, however well it fits the fitting window."""
    from heli_uq.discovery.decide import choose

    n_scored, n_fit, blocks = 4000, 9000, 8
    base = np.zeros(blocks)
    per_block = 4 * MARGIN_PER_SAMPLE * n_scored / blocks  # all pass against the base
    a = base + per_block + 1.0  # best on held-out, by 8 nats in all
    b = base + per_block  # tied with a (8 nats << the margin)
    c = base + per_block / 2  # a beats it by twice the margin; it still passes the base
    params = {"p": 0.0, "q": 0.0}
    results = {"yaw:x": {"block_scores": a, "map_value": -100.0, "map": {**params, "x": 1.0}},
               "yaw:y": {"block_scores": b, "map_value": -110.0, "map": {**params, "y": 1.0}},
               "yaw:z": {"block_scores": c, "map_value": -500.0, "map": {**params, "z": 1.0}}}  # fmt: skip
    rows = []
    for key, res in results.items():
        diff, se = compare(res["block_scores"], base)
        rows.append({"effect": key, "added": [key], "score": diff, "score_se": se,
                     "passes": passes(res["block_scores"], base, n_scored), "supported": True})  # fmt: skip
    assert all(r["passes"] for r in rows)

    def choice():
        for r in rows:
            r.pop("tied", None), r.pop("chosen_by", None), r.pop("tie_break", None)
        return choose(rows, results, n_scored, n_fit)

    # y leads by 10 nats on the fitting window, x by 8 on held-out blocks: y by 2
    chosen = choice()
    assert chosen["effect"] == "yaw:y" and chosen["chosen_by"] == "whole-record evidence"
    assert chosen["tie_break"] == {"by": "support", "margin": pytest.approx(2.0)}
    assert [r["effect"] for r in rows if r.get("tied")] == ["yaw:x", "yaw:y"]
    # one parameter more costs 0.5 log(n_fit) = 4.6 nats: the 10-nat lead is no longer enough
    results["yaw:y"]["map"]["y2"] = 0.0
    assert choice()["effect"] == "yaw:x"
    # a fitting-window lead smaller than the held-out one does not decide (it did when the
    # fitting window alone broke ties)
    del results["yaw:y"]["map"]["y2"]
    results["yaw:y"]["map_value"] = -104.0
    chosen = choice()
    assert chosen["effect"] == "yaw:x" and chosen["tie_break"]["margin"] == pytest.approx(4.0)


def test_the_laplace_evidence_breaks_a_tie_when_every_tied_fit_has_it():
    """A dead band and an offset tied on held-out blocks: the log posterior at the MAP
    favours the offset (its prior density is in 1/(N m), the dead band's in 1/V), the
    evidence the dead band; with the evidence stored for both it decides and the margin
    is reported, with one fit lacking it the BIC-penalised log posterior decides."""
    from heli_uq.discovery.decide import choose
    from heli_uq.discovery.report_page import tie_text

    n_scored, n_fit, blocks = 4000, 9000, 8
    scores = np.full(blocks, 4 * MARGIN_PER_SAMPLE * n_scored / blocks)
    params = {"p": 0.0}
    results = {"yaw:deadband": {"block_scores": scores + 0.05, "map_value": -1000.0, "log_evidence": 900.25,
                                "map": {**params, "delta": 0.3}},
               "yaw:torque_offset": {"block_scores": scores, "map_value": -1002.2, "log_evidence": 900.0,
                                     "map": {**params, "T_0": 0.03}}}  # fmt: skip

    def rows():
        out = []
        for key, res in results.items():
            diff, se = compare(res["block_scores"], np.zeros(blocks))
            out.append({"effect": key, "added": [key], "score": diff, "score_se": se,
                        "passes": passes(res["block_scores"], np.zeros(blocks), n_scored),
                        "supported": True})  # fmt: skip
        return out

    choice = choose(rows(), results, n_scored, n_fit)
    assert choice["effect"] == "yaw:deadband" and "chosen_by" not in choice
    assert choice["tie_break"]["by"] == "evidence"
    assert choice["tie_break"]["margin"] == pytest.approx(0.25 + blocks * 0.05)  # + the held-out lead
    text = tie_text({"tied": ["yaw:torque_offset"], "tie_break": choice["tie_break"]})
    assert "0.65 nats" in text and "cannot tell them apart" in text
    del results["yaw:torque_offset"]["log_evidence"]  # a fit stored before the evidence was kept
    choice = choose(rows(), results, n_scored, n_fit)
    assert choice["effect"] == "yaw:torque_offset" and choice["chosen_by"] == "whole-record evidence"
    assert choice["tie_break"] == {"by": "support", "margin": pytest.approx(2.2 - blocks * 0.05)}
    assert "cannot tell" not in tie_text({"tied": ["yaw:deadband"], "tie_break": choice["tie_break"]})


def test_the_laplace_evidence_is_the_integral_of_a_gaussian_posterior():
    """``Start.log_evidence`` against quadrature: for ``-log p(x) = c + (x - m)' A (x - m) / 2``
    (2-D, correlated) the integral of ``p`` over a grid equals ``exp`` of the evidence."""
    from heli_uq.inference.start import Start

    a = np.array([[400.0, -150.0], [-150.0, 100.0]])
    m, c = np.array([0.3, -1.0]), 1234.5
    start = Start(None, None, m, c, np.linalg.inv(a), 0.0)
    sd = np.sqrt(np.diag(np.linalg.inv(a)))
    g = [np.linspace(mi - 10 * si, mi + 10 * si, 801) for mi, si in zip(m, sd)]
    x = np.stack(np.meshgrid(*g, indexing="ij"), axis=-1) - m
    density = np.exp(-0.5 * np.einsum("...i,ij,...j", x, a, x))
    quad = np.log(np.trapezoid(np.trapezoid(density, g[1]), g[0])) - c
    assert start.log_evidence() == pytest.approx(quad, abs=1e-6)


def test_the_pairs_hold_each_best_fitting_single_with_every_supported_other():
    """The single that fits 5th best is paired with the 2 best (the record of
    2026-11-28 whose dead band fitted 2nd and drag 5th), each pair once; the best
    held-out single joins the top ones; a single the fitting window does not support, or
    a failed one, is not paired with the best."""
    from heli_uq.discovery.decide import pairs_to_fit

    fit_order = ["yaw:thrust", "pitch:deadband", "yaw:offset", "yaw:spring", "yaw:drag", "pitch:offset",
                 "pitch:friction"]  # fmt: skip
    rows = [{"effect": e, "score": -float(i), "fit": {"V": 1e-4 * (1 + i)},
             "supported": e != "pitch:friction"} for i, e in enumerate(fit_order)]  # fmt: skip
    rows[5]["score"] = 10.0  # best held out, poor fit
    rows.sort(key=lambda r: -r["score"])
    rows.append({"effect": "yaw:friction", "score": None, "error": "diverged"})
    pairs = pairs_to_fit(rows, 3, 2)
    as_sets = [frozenset(p) for p in pairs]
    assert len(set(as_sets)) == len(pairs)
    assert frozenset(("pitch:deadband", "yaw:drag")) in as_sets
    # top 3 + best held out: 6 pairs; the 2 best add the supported others not yet paired
    among_top = {frozenset(p) for p in itertools.combinations(fit_order[:3] + ["pitch:offset"], 2)}
    anchored = {frozenset((a, b)) for a in fit_order[:2] for b in ("yaw:spring", "yaw:drag")}
    assert set(as_sets) == among_top | anchored
    assert not any("yaw:friction" in p or "pitch:friction" in p for p in pairs)
    # without anchors the weak member is missed (the search of before)
    assert frozenset(("pitch:deadband", "yaw:drag")) not in {frozenset(p) for p in pairs_to_fit(rows, 3, 0)}


def test_a_candidate_the_fitting_window_does_not_support_is_not_added():
    """Support is the BIC-penalised fitting-window log posterior over the current model's:
    a 2-parameter effect must gain more than log(n_fit) nats.  An effect that passes the
    held-out margin without that support (the rig's yaw spring at k = 3e-5 N m/rad) is not
    chosen; the next passing, supported one is."""
    from heli_uq.discovery.decide import choose, rank

    n_scored, n_fit, blocks = 4000, 9000, 8
    bic = 0.5 * np.log(n_fit)
    per_block = 4 * MARGIN_PER_SAMPLE * n_scored / blocks
    current = {"block_scores": np.zeros(blocks), "map_value": 0.0, "map": {"K": 0.1}}

    def fitted(scores, gain, n_new):
        new = {f"p{i}": 0.0 for i in range(n_new)}
        return {"block_scores": scores, "map_value": -gain, "map": {"K": 0.1, **new}, "score": {},
                "fit": {"V": 0.1}, "seconds": 1.0}

    results = {"yaw:spring": fitted(np.full(blocks, 3 * per_block), 1.5 * bic, 2),  # best held out
               "yaw:offset": fitted(np.full(blocks, per_block), 1.5 * bic, 1)}  # fmt: skip
    rows = rank(results, current, n_scored, n_fit)
    for r in rows:
        r["added"] = [r["effect"]]
    by = {r["effect"]: r for r in rows}
    assert by["yaw:spring"]["passes"] and not by["yaw:spring"]["supported"]
    assert by["yaw:spring"]["support"] == pytest.approx(-0.5 * bic)
    assert by["yaw:offset"]["supported"] and by["yaw:offset"]["support"] == pytest.approx(0.5 * bic)
    assert choose(rows, results, n_scored, n_fit)["effect"] == "yaw:offset"
    results["yaw:offset"]["map_value"] = -0.5 * bic  # now neither is supported: none
    rows = rank(results, current, n_scored, n_fit)
    for r in rows:
        r["added"] = [r["effect"]]
    assert choose(rows, results, n_scored, n_fit) is None


def test_a_much_better_candidate_restarts_the_current_model_from_its_values():
    from heli_uq.discovery.nesting import RESTART_NATS, nested_guess

    current = {"map_value": 1000.0, "map": {"K_pp": 0.1, "theta_0": 0.0}}
    better = {"map_value": 1000.0 - 2 * RESTART_NATS, "map": {"K_pp": 0.3, "theta_0": 0.1, "T_0_yaw": -0.01}}
    close = {"map_value": 1000.0 - 0.5 * RESTART_NATS, "map": {"K_pp": 0.2, "theta_0": 0.0, "F_c_yaw": 0.01}}
    failed = {"error": "ParameterError: diverged"}
    # the nested parameters of the best fit, without the candidate's own
    guess = nested_guess({"a": close, "b": better, "c": failed}, current, current["map"])
    assert guess == {"K_pp": 0.3, "theta_0": 0.1}
    # no candidate clearly better, or none fitted: keep the current MAP
    assert nested_guess({"a": close}, current, current["map"]) is None
    assert nested_guess({"c": failed}, current, current["map"]) is None
    # a current fit pinned at the solver's limit: a candidate that is not (its effect does
    # what the damping imitated) restarts nothing; one pinned too still does
    pinned = {**current, "solver_edge": {"axis": "pitch", "rate": 557.0, "rh": 2.78, "substeps": 2}}
    assert nested_guess({"a": close, "b": better}, pinned, pinned["map"]) is None
    both = {**better, "solver_edge": pinned["solver_edge"]}
    assert nested_guess({"a": close, "b": both}, pinned, pinned["map"]) == {"K_pp": 0.3, "theta_0": 0.1}


def test_after_a_restart_only_the_candidates_worse_than_the_new_current_fit_are_refitted():
    """A candidate nests the current model: one whose MAP is worse than the refitted current
    model's sits in a poorer basin and is refitted; one at least as good is kept."""
    from heli_uq.discovery.nesting import beyond

    again = {"map_value": 900.0}
    results = {"winner": {"map_value": 100.0}, "equal": {"map_value": 900.0},
               "trapped": {"map_value": 900.5}, "failed": {"error": "ParameterError: diverged"}}
    assert list(beyond(results, again)) == ["winner", "equal"]


@pytest.mark.slow
@pytest.mark.xdist_group("trap_record")
def test_a_prior_change_reaches_the_fit_and_its_stored_signature(trap_record):
    """A parameter fixed for a discovery run (``--fix``) stays at its value in a candidate's
    MAP while the rest is fitted, and the fit's signature changes with it, so a rerun
    under other priors fits again instead of reusing a fit of other settings."""
    from heli_uq.discovery.candidates import FitTask, fitted_predictive
    from heli_uq.discovery.rounds import task_signature
    from heli_uq.model.prior import Prior

    rec, base = trap_record
    fixed = 0.02  # N m, off the truth (0): the MAP would not land on it
    task = FitTask(rec, (0.0, 14.0), (14.0, 20.0), ("yaw:torque_offset",), (base.params,), 0, 1, 8)
    pinned = dataclasses.replace(task, priors=(("T_0_yaw", Prior("fixed", fixed)),))
    moved = dataclasses.replace(task, priors=(("T_0_yaw", Prior("fixed", 2 * fixed)),))
    assert len({task_signature(rec, t) for t in (task, pinned, moved)}) == 3
    fitted = fitted_predictive(pinned)
    assert fitted.params["T_0_yaw"] == fixed
    priors = fitted.start.problem.priors.params
    assert priors["T_0_yaw"] == Prior("fixed", fixed)
    # the free parameters moved to absorb the fixed offset: the fit is not the base's values
    free = [n for n, p in priors.items() if p.kind != "fixed" and n in base.params]
    assert free and any(not np.isclose(fitted.params[n], base.params[n], rtol=1e-6) for n in free)


def test_a_run_s_prior_changes_reach_the_models_that_have_the_parameter():
    """``--fix a_yaw=1`` with the tilt as a candidate: the candidate's model is fitted at the
    fixed tilt, the base model (without the tilt) at its defaults; the initial state's
    change holds in both.  A fixed parameter is no fitted coordinate, so it costs the
    candidate no BIC penalty in the fitting window's support."""
    from heli_uq.discovery.candidates import model_priors
    from heli_uq.discovery.decide import _training_support
    from heli_uq.discovery.workflow import checked_priors, cold_starts
    from heli_uq.model.prior import Prior

    base, candidate = ["yaw:torque_offset"], "yaw:thrust_tilt"
    changes = checked_priors(base + [candidate], {"a_yaw": 1.0, "omega_psi0": 0.0})
    assert changes == (("a_yaw", Prior("fixed", 1.0)), ("omega_psi0", Prior("fixed", 0.0)))
    with_tilt = model_priors(build_model(base + [candidate]), changes)
    without = model_priors(build_model(base), changes)
    assert with_tilt.params["a_yaw"] == Prior("fixed", 1.0)
    assert "a_yaw" not in without.params and without.x0["omega_psi0"] == Prior("fixed", 0.0)
    assert model_priors(build_model(base), (("a_yaw", Prior("fixed", 1.0)),)) is None
    # with every new parameter fixed the candidate nests nothing: at least one cold start
    assert cold_starts(0, base, candidate, changes) == 1 and cold_starts(2, base, candidate, changes) == 2
    assert cold_starts(0, base, candidate, changes[1:]) == 0  # the tilt free: warm starts suffice
    assert cold_starts(0, base, "yaw:coulomb_friction", changes) == 0
    n_fit = 9100
    fit = {"map_value": -100.0, "map": {"x": 0.0, "a_yaw": 1.0}}
    assert _training_support({**fit, "n_fitted": 1}, n_fit) - _training_support(fit, n_fit) == (
        pytest.approx(0.5 * np.log(n_fit)))  # fmt: skip


def test_an_effect_parameter_the_run_fixes_is_reported_at_its_value():
    """discovery.json's ``parameters`` of the named effect: a sampled parameter as the
    posterior summary has it; one the run's priors fix at its value with a zero-width
    interval and ``fixed``, not left out (the tilt named at ``a = 1``)."""
    from heli_uq.discovery.report import _effect_parameters
    from heli_uq.model.prior import Prior

    summary = {"F_c_yaw": {"mean": 0.02, "sd": 0.005, "ci95": [0.01, 0.03], "unit": "N m", "bare": "F_c"}}
    fix = (("a_yaw", Prior("fixed", 1.0)), ("omega_psi0", Prior("fixed", 0.0)))
    assert _effect_parameters(summary, "yaw:coulomb_friction", fix) == {
        "F_c": {"mean": 0.02, "ci95": [0.01, 0.03], "unit": "N m"}}
    assert _effect_parameters(summary, "yaw:thrust_tilt", fix) == {
        "a": {"mean": 1.0, "ci95": [1.0, 1.0], "unit": "1", "fixed": True}}
    assert _effect_parameters(summary, "yaw:thrust_tilt") == {}  # free but not sampled: absent
    # report.md's lines
    from heli_uq.discovery.report_page import parameter_text

    assert parameter_text("F_c", _effect_parameters(summary, "yaw:coulomb_friction")["F_c"]) == (
        "F_c = 0.02 [0.01, 0.03] N m")
    tilt = _effect_parameters(summary, "yaw:thrust_tilt", fix)["a"]
    assert parameter_text("a", tilt) == "a = 1, fixed by the run's priors"
    ratio = {"mean": 0.8, "ci95": [0.5, 1.1], "unit": "(N m) / (kg m^2)", "inertia": "M22(theta_ref)",
             "theta_ref": -0.4}  # fmt: skip
    with_ratio = _effect_parameters({"F_c_yaw": {**summary["F_c_yaw"], "per_inertia": ratio}},
                                    "yaw:coulomb_friction")["F_c"]  # fmt: skip
    assert with_ratio["per_inertia"] == ratio
    assert parameter_text("F_c", with_ratio) == (
        "F_c = 0.02 [0.01, 0.03] N m; F_c / M22(theta_ref) = 0.8 [0.5, 1.1] (N m) / (kg m^2), "
        "what the record identifies")


def test_the_store_keeps_each_task_of_a_model_for_a_rerun(tmp_path):
    """A model fitted twice (before and after a restart) is reused for both tasks; the
    latest fit is its ``result`` (what ``heli-uq design`` reads)."""
    from heli_uq.discovery.rounds import CandidateStore

    store = CandidateStore(tmp_path)
    store.save("yaw:x", "sig-1", {"map_value": 2.0})
    store.save("yaw:x", "sig-2", {"map_value": 1.0})
    assert store.load("yaw:x", "sig-1") == {"map_value": 2.0}
    assert store.load("yaw:x", "sig-2") == {"map_value": 1.0}
    assert store.load("yaw:x", "sig-3") is None and store.load("yaw:y", "sig-1") is None
    stored = json.loads(store.path("yaw:x").read_text())
    assert stored["signature"] == "sig-2" and stored["result"] == {"map_value": 1.0}
    store.save("yaw:x", "sig-1", {"map_value": 3.0})  # refitted: the newer fit replaces it
    assert store.load("yaw:x", "sig-1") == {"map_value": 3.0}
    assert store.load("yaw:x", "sig-2") == {"map_value": 1.0}
    store.path("yaw:x").write_text("{not json")  # a damaged file is a missing fit, not a crash
    assert store.load("yaw:x", "sig-1") is None


def test_the_refit_of_a_split_run_starts_from_the_candidates_map_alone(monkeypatch):
    """With a split the refit's posterior is conditioned on the fitting window, where the
    candidate's MAP is already the multi-start MAP of the same model: it is the only start.
    On a single window (the posterior also sees the scoring part) the budget's starts too.
    The budget's mass-matrix choice reaches the sampler: kept at the Laplace metric by the
    quick budget, adapted by the full one."""
    from heli_uq.discovery import report
    from heli_uq.discovery.workflow import BUDGETS

    seen, priors = [], []

    def fake_sample_posterior(record, out, **kw):
        seen.append((kw["n_starts"], kw["guesses"], kw["train"], kw["test"], kw["adapt_mass_matrix"]))
        priors.append(kw["priors"])
        raise StopIteration

    monkeypatch.setattr(report, "sample_posterior", fake_sample_posterior)
    guess = {"m": 0.07}
    cost = BUDGETS["quick"]
    for test in ((91.0, 131.0), None):
        with pytest.raises(StopIteration):
            report._posterior(None, build_model([]), (0.0, 91.0), test, None, cost, 0, guess)
    assert seen == [(1, (guess,), (0.0, 91.0), (91.0, 131.0), False),
                    (cost.n_starts, (guess,), (0.0, 91.0), None, False)]
    assert cost.n_starts > 1 and not cost.adapt_mass_matrix  # the quick refit keeps the Laplace metric
    with pytest.raises(StopIteration):  # the full budget adapts a dense mass matrix
        report._posterior(None, build_model([]), (0.0, 91.0), None, None, BUDGETS["full"], 0, guess)
    assert seen[-1][-1] is True
    # a discovery run's prior changes reach the refit's posterior; without, the defaults
    from heli_uq.model.prior import Prior

    tilt = build_model(["yaw:thrust_tilt"])
    with pytest.raises(StopIteration):
        report._posterior(None, tilt, (0.0, 91.0), None, None, cost, 0, guess,
                          priors=(("a_yaw", Prior("fixed", 1.0)),))  # fmt: skip
    assert priors[:-1] == [None] * 3 and priors[-1].params["a_yaw"] == Prior("fixed", 1.0)


def test_the_budgets_give_their_nuts_runs_the_time_their_targets_leave():
    """The full budget's 60 min target: a run 10 min in leaves its refit 50 min less the
    time the outputs need (a share of it to the base model's posterior when both are
    sampled, less than the refit's); past the target, none.  The quick budget's 10 min
    target: a run 6 min in leaves its refit 4 min less the outputs' time."""
    import time

    from heli_uq.discovery import report
    from heli_uq.discovery.workflow import BUDGETS

    full = BUDGETS["full"]
    now = time.perf_counter()
    left = report._time_left(full, now - 600.0)
    expected = 60.0 * full.minutes - 600.0 - report.OUTPUT_SECONDS
    assert full.minutes == 60.0 and expected - 5.0 < left <= expected
    share = report.BEFORE_SHARE
    assert 0.0 < share < 0.5
    assert report._time_left(full, now - 600.0, share) == pytest.approx(left * share, abs=2.5)
    assert report._time_left(full, now - 7200.0) == 0.0
    quick = BUDGETS["quick"]
    expected = 60.0 * quick.minutes - 360.0 - report.OUTPUT_SECONDS
    assert quick.minutes == 10.0 and expected - 5.0 < report._time_left(quick, now - 360.0) <= expected


def test_a_pair_starts_from_both_members_and_nests_the_better_one():
    from heli_uq.discovery.nesting import pair_start

    a = {"map_value": -100.0, "map": {"K_pp": 0.1, "F_c_yaw": 0.01}}
    b = {"map_value": -300.0, "map": {"K_pp": 0.2, "T_0_pitch": 0.002}}
    guess, member = pair_start(a, b)
    # a's shared parameters, b's own one
    assert guess == {"K_pp": 0.1, "F_c_yaw": 0.01, "T_0_pitch": 0.002}
    assert member is b
    assert pair_start(b, a)[1] is b


def test_pair_fits_holding_the_chosen_single_are_carried_into_the_next_step():
    """Step 2's singles (the chosen model plus one effect) that step 1 fitted as pairs are
    not fitted again, under the next step's key, unless they fit worse than the chosen
    model by more than the nesting slack (a poorer basin: fitted again from it)."""
    from heli_uq.discovery.candidates import NESTED_SLACK_NATS
    from heli_uq.discovery.nesting import carried

    chosen = {"map_value": -1000.0}
    results = {"yaw:deadband": chosen,
               "pitch:spring": {"map_value": -900.0},
               "pitch:spring+yaw:deadband": {"map_value": -1001.0},  # other member order
               "yaw:deadband+yaw:offset": {"map_value": -1000.0 + 0.5 * NESTED_SLACK_NATS, "reused": True},
               "yaw:deadband+yaw:drag": {"map_value": -1000.0 + 2 * NESTED_SLACK_NATS},  # poorer basin
               "yaw:deadband+pitch:drag": {"error": "ParameterError: diverged"},
               "pitch:spring+yaw:offset": {"map_value": -2000.0}}  # does not hold the chosen one
    out = carried(results, ["yaw:deadband"], chosen, step=1)
    assert list(out) == ["yaw:deadband+pitch:spring", "yaw:deadband+yaw:offset"]
    assert out["yaw:deadband+pitch:spring"] == {"map_value": -1001.0, "reused": False, "carried": 1}
    # carried from this run, not reused from an earlier one
    assert out["yaw:deadband+yaw:offset"]["reused"] is False
    # after a pair was chosen nothing is one effect beyond it
    assert carried(results, ["pitch:spring", "yaw:deadband"], results["pitch:spring+yaw:deadband"], 1) == {}


def test_a_stored_fit_is_not_reused_under_other_library_versions(monkeypatch):
    """A candidate fit stored by another heli_uq, jax or numpyro version is fitted again: its
    signature holds the versions, as a sampler run's manifest does."""
    from heli_uq.discovery import rounds
    from heli_uq.discovery.candidates import FitTask
    from heli_uq.inference.manifest import library_versions

    rec = synthetic_experiment(duration=1.0, seed=3)
    task = FitTask(rec, (0.0, 0.7), (0.7, 1.0), ("yaw:torque_offset",))
    now = rounds.task_signature(rec, task)
    assert rounds.task_signature(rec, task) == now
    for name in ("heli_uq", "jax", "numpyro"):
        monkeypatch.setattr(rounds, "library_versions", lambda n=name: {**library_versions(), n: "0.0.0"})
        assert rounds.task_signature(rec, task) != now, name


def test_the_crps_decides_when_asked_with_its_own_margin():
    """Under ``CRPS`` a model passes if its held-out CRPS is lower than the other's by
    ``MARGIN_CRPS_FRACTION`` of it (and significantly); the rig's case, a candidate far
    worse by the log density and much better by the CRPS, is chosen under the CRPS and
    not under the log density, which chooses the candidate it prefers; a fit stored
    without the CRPS never passes under it."""
    from heli_uq.discovery.decide import choose, rank
    from heli_uq.discovery.score import CRPS, LOG_DENSITY, MARGIN_CRPS_FRACTION, gain_text

    n_scored, n_fit, blocks = 4000, 9000, 8
    base_crps = np.full(blocks, 100.0)  # [rad] per block
    current = {"block_scores": np.zeros(blocks), "block_crps": base_crps, "map_value": 0.0, "map": {"K": 0.1}}

    def fitted(log_gain, crps_fraction, wobble=0.0):
        crps = base_crps * (1 - crps_fraction) + wobble * np.linspace(-1, 1, blocks)
        return {"block_scores": np.full(blocks, log_gain / blocks), "block_crps": crps,
                "map_value": -100.0, "map": {"K": 0.1, "x": 1.0}, "score": {}, "fit": {"V": 0.1},
                "seconds": 1.0}  # fmt: skip

    above, below = 2 * MARGIN_CRPS_FRACTION, 0.5 * MARGIN_CRPS_FRACTION
    assert CRPS.passes(fitted(0.0, above), current, n_scored)
    assert not CRPS.passes(fitted(0.0, below), current, n_scored)  # every block better, under the margin
    assert LOG_DENSITY.passes(fitted(4 * MARGIN_PER_SAMPLE * n_scored, 0.0), current, n_scored)
    assert not LOG_DENSITY.passes(fitted(0.0, 0.5), current, n_scored)  # the log density ignores the CRPS
    stored_before = {k: v for k, v in fitted(0.0, 0.5).items() if k != "block_crps"}
    assert not CRPS.passes(stored_before, current, n_scored)

    results = {"yaw:narrow": fitted(-20000.0, 0.35),  # the rig's pair: -21761 nats, CRPS 35 % lower
               "yaw:wide": fitted(4 * MARGIN_PER_SAMPLE * n_scored, 0.005)}  # fmt: skip
    picks = {}
    for criterion in (LOG_DENSITY, CRPS):
        rows = rank(results, current, n_scored, n_fit, criterion)
        for r in rows:
            r["added"] = [r["effect"]]
        chosen = choose(rows, results, n_scored, n_fit, criterion)
        picks[criterion.name] = (chosen["effect"], rows[0]["effect"])
    assert picks == {"log": ("yaw:wide", "yaw:wide"), "crps": ("yaw:narrow", "yaw:narrow")}
    row = next(r for r in rows if r["effect"] == "yaw:narrow")
    assert row["crps_gain"] == pytest.approx(0.35 * base_crps.sum())
    text = gain_text(row, "crps", n_scored)
    assert text.startswith(f"a CRPS lower by {0.35 * base_crps.sum() / n_scored:.3g} ± 0")
    assert text.endswith("rad per sample (log density -20000 ± 0 nats)")
    assert gain_text(row, "log", n_scored) == "-20000 ± 0 nats"


def test_a_budget_reads_as_its_preset_and_the_settings_that_differ():
    """The report names the budget a person chose (``--cold-starts 1`` on the quick one),
    not the dataclass's repr of twelve fields."""
    import dataclasses

    from heli_uq.discovery.budget import BUDGETS, label

    assert label("quick") == "quick"
    assert label(BUDGETS["full"]) == "full"
    assert label(dataclasses.replace(BUDGETS["quick"], cold_starts=1)) == "quick, cold_starts=1"
    two = dataclasses.replace(BUDGETS["full"], chains=2, minutes=None)
    assert label(two) == "full, chains=2, minutes=None"


def test_strict_json_leaves_no_number_json_lacks():
    """``discovery.json`` is read by other tools: Python's ``Infinity`` and ``NaN`` break
    strict parsers, so non-finite numbers are null, everything else as it was."""
    from heli_uq.io import strict_json

    value = {"score": -np.inf, "rows": [1.5, float("nan"), {"se": np.inf, "n": 3, "name": "x"}],
             "pair": (0.25, None)}  # fmt: skip
    clean = strict_json(value)
    assert clean == {"score": None, "rows": [1.5, None, {"se": None, "n": 3, "name": "x"}],
                     "pair": [0.25, None]}
    assert json.loads(json.dumps(clean, allow_nan=False)) == clean
