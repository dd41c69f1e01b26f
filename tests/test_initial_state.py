"""The initial state's default prior from the record's start (heli_uq.data.initial_rates,
heli_uq.probability.RecordStart): still starts measured, moving starts left alone."""

import jax
import numpy as np

from heli_uq.data import Experiment, initial_rates
from heli_uq.inference.density import log_density_setup
from heli_uq.inference.least_squares import x0_guess
from heli_uq.model import Prior, build_model
from heli_uq.probability import PriorSet, make_problem
from heli_uq.probability.priors import X0_ANGLE_SD, X0_RATE_FLOOR, X0_RATE_SD, RecordStart
from heli_uq.simulation import synthetic_experiment

DT = 0.01
NOISE = np.array([0.003, 0.008])  # rad: the rig's encoder noise, pitch and yaw
#: Monte Carlo replicates of a noisy record, and how far the reported standard error may
#: sit from the replicates' spread of the estimate (200 replicates: about 5 % sampling error).
REPLICATES = 200
SE_RTOL = 0.2
#: A still start is called still at least this often (the test is at 3 SE on two
#: coefficients per angle: a false alarm about 0.5 % of the time per angle).
STILL_RATE = 0.95


def _still_record(n=300, seed=0, level=(-0.6, 0.8)):
    rng = np.random.default_rng(seed)
    return np.asarray(level) + rng.normal(size=(n, 2)) * NOISE


def test_a_still_start_is_still_and_its_error_is_the_estimates_spread():
    results = [initial_rates(_still_record(seed=s), DT) for s in range(REPLICATES)]
    still = np.array([r[0] for r in results])
    rates = np.array([r[1] for r in results])
    se = np.array([r[2] for r in results])
    assert np.all(still.mean(axis=0) >= STILL_RATE)
    spread = rates.std(axis=0)
    np.testing.assert_allclose(np.median(se, axis=0), spread, rtol=SE_RTOL)
    assert np.all(np.abs(rates.mean(axis=0)) < 3 * spread / np.sqrt(REPLICATES))
    # the yaw's 8 mrad give about 0.01 rad/s over the first second (the rig's yaw: 0.010)
    assert 0.005 < np.median(se[:, 1]) < 0.02


def test_a_moving_start_is_not_still_and_its_rate_is_measured():
    t = np.arange(300) * DT
    rate = np.array([0.05, -0.2])
    y = np.array([-0.6, 0.8]) + np.outer(t, rate) + np.random.default_rng(1).normal(size=(300, 2)) * NOISE
    still, got, se = initial_rates(y, DT)
    assert not still.any()
    assert np.all(np.abs(got - rate) < 3 * se)


def test_a_start_that_accelerates_is_not_still():
    """At rest, then driven from the first sample: the polynomial's slope is biased far
    beyond its error (0.15 rad/s at 0.007), so such a start keeps the wide prior."""
    rec = synthetic_experiment(duration=4.0, seed=1, noise_std=(0.003, 0.003))  # starts at rest
    still, rates, se = initial_rates(rec.y, rec.dt, rec.u)
    assert not still.any()
    start = RecordStart.of(rec.y, rec.dt, rec.u)
    assert [start.rate_prior(i) for i in (0, 1)] == [Prior("normal", 0.0, X0_RATE_SD)] * 2


def test_the_fit_stops_at_the_first_voltage_change():
    y = _still_record(seed=3)
    u = np.full((300, 2), 1.0)
    u[30:] = 1.3  # the voltages change after 0.3 s, and the angles then swing away
    moved = y.copy()
    moved[30:] += np.outer(np.arange(270) * DT, [0.5, -1.0]) ** 2
    got = initial_rates(moved, DT, u)
    want = initial_rates(y[:30], DT)
    for a, b in zip(got, want):
        np.testing.assert_array_equal(a, b)
    assert got[0].all()
    assert not initial_rates(moved, DT)[0].any()  # without the voltages the swing is seen


def test_too_short_a_start_says_nothing():
    still, rates, se = initial_rates(_still_record(n=4), DT)
    assert not still.any() and np.all(rates == 0) and np.all(np.isinf(se))


def test_a_still_starts_rate_prior_adds_the_measurement_to_the_wide_prior():
    start = RecordStart((-0.6, 0.8), (True, False), (0.005, 0.3), (0.01, 0.01))
    measured_var = 0.01**2 + X0_RATE_FLOOR**2
    precision = 1 / X0_RATE_SD**2 + 1 / measured_var
    want = Prior("normal", 0.005 / measured_var / precision, precision**-0.5)
    got = start.rate_prior(0)
    assert got.kind == "normal"
    np.testing.assert_allclose([got.a, got.b], [want.a, want.b], rtol=1e-12)
    assert got.b < np.sqrt(measured_var) < X0_RATE_SD
    assert start.rate_prior(1) == Prior("normal", 0.0, X0_RATE_SD)  # moving: the wide prior


def _record_with_still_start(seed):
    """A synthetic record whose first second is replaced by a still, noisy level."""
    rec = synthetic_experiment(duration=1.5, seed=seed, x0=(-0.5, 0.1 * seed, 0, 0))
    y = np.array(rec.y)
    y[:100] = _still_record(n=100, seed=seed, level=y[100])
    u = np.array(rec.u)
    u[:100] = u[0]
    return Experiment(rec.t, u, y, rec.dt, "still start")


def test_the_problem_takes_the_default_from_the_record_and_a_named_prior_wins():
    rec = _record_with_still_start(1)
    problem = make_problem(rec, error="iid")
    start = RecordStart.of(rec.y, rec.dt, rec.u)
    assert start.still == (True, True)
    priors = problem.x0_priors()
    assert priors[:2] == (Prior("normal", float(rec.y[0, 0]), X0_ANGLE_SD),
                          Prior("normal", float(rec.y[0, 1]), X0_ANGLE_SD))  # fmt: skip
    assert priors[2:] == (start.rate_prior(0), start.rate_prior(1))
    assert priors[3].b < 2 * X0_RATE_FLOOR  # measured: far narrower than X0_RATE_SD
    np.testing.assert_array_equal(x0_guess(problem), [p.a for p in priors])
    model = problem.model
    named = PriorSet.default(model).updated(model, {"omega_psi0": Prior("normal", 0.0, 0.3),
                                                    "omega_theta0": 0.0})  # fmt: skip
    changed = make_problem(rec, error="iid", priors=named).x0_priors()
    assert changed[2:] == (Prior("fixed", 0.0), Prior("normal", 0.0, 0.3))


def test_the_models_friction_says_which_axes_it_can_hold_still():
    assert build_model().held_still == (False, False)
    assert build_model(["yaw:coulomb_friction"]).held_still == (False, True)
    assert build_model(["pitch:stiction", "yaw:quadratic_drag"]).held_still == (True, False)
    assert build_model(["yaw:deadband", "yaw:torque_offset"]).held_still == (False, False)


def test_a_still_axis_held_by_friction_starts_at_rest_and_a_named_prior_wins():
    """Friction stops a small initial rate after a slide the initial angle absorbs (the
    ridge of the module docstring), so a still axis it holds starts at rate 0; the other
    axis keeps its measured prior, a moving start the wide one."""
    rec = _record_with_still_start(1)
    start = RecordStart.of(rec.y, rec.dt, rec.u)
    model = build_model(["yaw:coulomb_friction"])
    priors = make_problem(rec, model=model, error="iid").x0_priors()
    assert priors[2:] == (start.rate_prior(0), Prior("fixed", 0.0))
    assert priors[2].kind == "normal"
    both = build_model(["pitch:stiction", "yaw:coulomb_friction"])
    assert make_problem(rec, model=both, error="iid").x0_priors()[2:] == (Prior("fixed", 0.0),) * 2
    wide = Prior("normal", 0.0, 0.3)
    named = PriorSet.default(model).updated(model, {"omega_psi0": wide})
    assert make_problem(rec, model=model, priors=named, error="iid").x0_priors()[3] == wide
    moving = synthetic_experiment(duration=1.5, seed=2, x0=(-0.5, 0.2, 0, 0))
    moving_priors = make_problem(moving, model=model, error="iid").x0_priors()
    assert moving_priors[2:] == (Prior("normal", 0.0, X0_RATE_SD),) * 2
    problem = make_problem(rec, model=model, error="iid")
    assert x0_guess(problem)[3] == 0.0


def test_records_with_other_starts_share_compiled_programs():
    """The initial rates' prior (centre and sd) reaches the compiled log density as
    arguments: a record that starts still and one that starts moving, of one length,
    lower to one program."""
    still = _record_with_still_start(1)
    moving = synthetic_experiment(duration=1.5, seed=2, x0=(-0.5, 0.2, 0, 0))
    assert RecordStart.of(moving.y, moving.dt, moving.u).still == (False, False)
    programs = []
    for rec in (still, moving):
        density = log_density_setup(make_problem(rec, error="iid"))
        programs.append(jax.jit(density.potential).lower(density.x_init).as_text())
    assert programs[0] == programs[1]


#: The momentum-ratio density equals the rate density plus its log-Jacobian to rounding.
JACOBIAN_ATOL = 1e-8


def test_the_initial_yaw_rate_sampled_as_a_momentum_keeps_the_users_prior(monkeypatch):
    """In identifiable coordinates a free initial yaw rate is sampled as
    ``p = omega M22(theta0) / M22(theta_ref)`` (heli_uq.probability.coordinates).  At the
    same physical point the log density is the one sampled in the rate itself plus
    ``log(M22(theta_ref) / M22(theta0))``, with ``M22`` written out here from its closed
    form; the point maps back to the rate it came from; other strategies sample the rate."""
    from heli_uq.inference.density import constrain_draws, coordinate_names, init_sites
    from heli_uq.model.terms.rigid_body import yaw_inertia
    from heli_uq.probability.coordinates import Coordinates

    rec = synthetic_experiment(duration=1.0, seed=4, x0=(-0.55, 0.3, 0.1, -0.7), noise_std=(0.003, 0.008))
    model = build_model(["yaw:coulomb_friction"])
    problem = make_problem(rec, model=model, error="iid")
    assert problem.coords.resolved == "identifiable" and problem.x0_priors()[3].kind == "normal"
    rng = np.random.default_rng(0)
    start = model.start_values()
    for _ in range(4):
        params = {**start, **{k: start[k] * float(np.exp(rng.normal(0, 0.2))) for k in ("J_s", "m", "J_bc")}}
        x0 = np.array([-0.55, 0.3, 0.1, -0.7]) + rng.normal(0, [0.05, 0.05, 0.1, 0.3])
        sites = init_sites(problem, params, x0)
        assert "omega_psi0" not in sites and "p_psi0_ratio" in sites
        momentum = log_density_setup(problem, init_values=sites)
        assert "p_psi0_ratio" in coordinate_names(momentum)
        back = constrain_draws(momentum, momentum.x_init[None])
        np.testing.assert_allclose(back["omega_psi0"][0], x0[3], rtol=1e-12)
        with monkeypatch.context() as m:
            m.setattr(Coordinates, "samples_yaw_momentum", lambda self, prior: False)
            rate = log_density_setup(problem, init_values=init_sites(problem, params, x0))
            assert "omega_psi0" in coordinate_names(rate)
            u_rate = float(rate.potential_jit(rate.x_init))
        phys = {k: back[k][0] for k in ("J_bc", "m", "r_c", "h", "J_s")}
        m22 = yaw_inertia(phys, x0[0]), yaw_inertia(phys, problem.coords.yaw_theta_ref)
        u_momentum = float(momentum.potential_jit(momentum.x_init))
        np.testing.assert_allclose(u_momentum, u_rate - float(np.log(m22[1] / m22[0])), atol=JACOBIAN_ATOL)
    plain = make_problem(rec, model=model, error="iid", strategy="log")
    assert "omega_psi0" in coordinate_names(log_density_setup(plain))
