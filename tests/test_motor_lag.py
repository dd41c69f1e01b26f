"""The motor lag: its exact step means against the lag's closed-form step response, the
fixed-step solver against the lag as two more states of an adaptive ODE solve, the paper's
model at tau 0, the gradient in tau (through the sequence), its feature for discovery, a
posterior that recovers a hidden lag, and what it refuses."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from heli_uq.errors import ParameterError
from heli_uq.model import EFFECTS, RIG_FIT, RIG_FIT_X0, build_model, model_from_description
from heli_uq.model.terms import TERMS
from heli_uq.simulation import reference_solve, simulate

#: Agreement of the step means with the closed form (float64 arithmetic only).
CLOSED_FORM_RTOL = 1e-12
#: Angle agreement [rad] of the fixed-step solver (3 substeps) with the continuous lag's
#: adaptive solve: the solver's accuracy goal on every effect (tests/test_effects.py).
SOLVER_TOL = 1e-4
#: The lag must move the angles by this much more than the two solves differ, so that a
#: filter left out (or wrong) fails the agreement test.
EFFECT_OVER_ERROR = 100
GRAD_RTOL = 1e-6
#: Central 95 % of the Laplace draws must hold the hidden time constant.
RECOVERY_INTERVAL = (0.025, 0.975)
LAPLACE_DRAWS = 2000


def _steps(seconds, seed, dt=0.01, hold=1.5):
    """Voltage staircase in the rig's ranges, each level held ``hold`` s."""
    rng = np.random.default_rng(seed)
    n, k = round(seconds / dt), round(hold / dt)
    levels = rng.uniform([1.25, 0.45], [1.42, 1.6], size=(n // k + 1, 2))
    return np.repeat(levels, k, axis=0)[:n]


def test_step_means_are_the_closed_form_step_response():
    """After a unit step the lagged voltage is ``1 - exp(-t / tau)``; the filter's value on
    step ``k`` must be its mean over ``[k h, (k + 1) h)``, on the lagged axis only."""
    model = build_model(["pitch:motor_lag"])
    (term,) = model.effects
    h, tau = 0.01, 0.23
    u = np.zeros((400, 2))
    u[0] = [-1.0, 0.7]  # held before the record and on step 0: u'(0) = u(0)
    u[1:] = [0.0, 0.7]
    u[100:, 0] = 1.0  # a unit step at t = 1 s, from rest at 0
    got = np.asarray(term.filter_sequence({"tau_pitch": tau}, jnp.asarray(u), h))
    np.testing.assert_array_equal(got[:, 1], u[:, 1])
    def decay_mean(k):  # mean of exp(-t / tau) over step k
        return tau / h * (np.exp(-k * h / tau) - np.exp(-(k + 1) * h / tau))

    # superposition: -1 held on step 0 and decaying from t = h, plus the unit step's
    # response from t = 1 s
    k = np.arange(400)
    mean = np.where(k >= 1, -decay_mean(k - 1), -1.0) + np.where(k >= 100, 1.0 - decay_mean(k - 100), 0.0)
    np.testing.assert_allclose(got[:, 0], mean, rtol=CLOSED_FORM_RTOL)
    np.testing.assert_array_equal(np.asarray(term.filter_sequence({"tau_pitch": 0.0}, jnp.asarray(u), h)), u)


def test_the_solver_matches_the_lag_as_states_of_an_adaptive_solve():
    """Both motors lagging: the fixed-step solve (the lag solved exactly per step) and the
    adaptive Kvaerno5 solve of the 6-state ODE (the lagged voltages as states) agree to the
    solver's tolerance, while the lag moves the angles by far more."""
    model = build_model(["pitch:motor_lag", "yaw:motor_lag"])
    p = dict(RIG_FIT, tau_pitch=0.15, tau_yaw=0.4)
    u = _steps(20.0, 0)
    ys = np.asarray(simulate(p, RIG_FIT_X0, u, 0.01, model=model, substeps=3))
    ref = reference_solve(p, RIG_FIT_X0, u, 0.01, model=model)
    error = np.max(np.abs(ys[:, :2] - ref[:, :2]))
    paper = np.asarray(simulate(RIG_FIT, RIG_FIT_X0, u, 0.01, substeps=3))
    effect = np.max(np.abs(paper[:, :2] - ref[:, :2]))
    assert error < SOLVER_TOL, error
    assert effect > EFFECT_OVER_ERROR * error, (effect, error)


def test_tau_zero_is_the_paper_model():
    model = build_model(["yaw:motor_lag"])
    u = _steps(5.0, 1)
    got = np.asarray(simulate(dict(RIG_FIT, tau_yaw=0.0), RIG_FIT_X0, u, 0.01, model=model, substeps=2))
    np.testing.assert_array_equal(got, np.asarray(simulate(RIG_FIT, RIG_FIT_X0, u, 0.01, substeps=2)))


def test_gradient_in_tau_matches_central_differences():
    """Through the adjoint solver, whose inputs now depend on a parameter."""
    model = build_model(["yaw:motor_lag"])
    u = jnp.asarray(_steps(6.0, 2))

    def loss(tau):
        ys = simulate(dict(RIG_FIT, tau_yaw=tau), RIG_FIT_X0, u, 0.01, model=model, substeps=2)
        return jnp.sum(ys[:, :2] ** 2)

    tau, eps = 0.3, 1e-6
    fd = (loss(tau + eps) - loss(tau - eps)) / (2 * eps)
    assert float(jax.grad(loss)(tau)) == pytest.approx(float(fd), rel=GRAD_RTOL)


def test_the_feature_for_discovery_reads_the_whole_sequence():
    """The acceleration's derivative in tau at the measured states (what the sparse
    regression sees) equals central differences of the implied accelerations: a pointwise
    evaluation, which cannot see a lag, would give 0."""
    from heli_uq.discovery.implied import _accelerations, effect_features, implied_torque
    from heli_uq.simulation import synthetic_experiment

    rec = synthetic_experiment(RIG_FIT, RIG_FIT_X0, inputs=_steps(10.0, 3), noise_std=(0.003, 0.008),
                               seed=3)  # fmt: skip
    base = build_model([])
    data = implied_torque(base, RIG_FIT, rec.y, rec.u, rec.dt)
    (name,), column = effect_features(base, RIG_FIT, "yaw:motor_lag", data)
    model = build_model(["yaw:motor_lag"])
    a = _accelerations(model, data)
    p = model.complete({**RIG_FIT, name: 0.1})
    eps = 1e-6
    fd = (np.asarray(a({**p, name: 0.1 + eps})) - np.asarray(a({**p, name: 0.1 - eps}))) / (2 * eps)
    assert np.max(np.abs(fd)) > 0.1  # rad/s^2 per s of lag after the record's steps
    np.testing.assert_allclose(column[:, :, 0], fd, rtol=1e-5, atol=1e-6 * np.max(np.abs(fd)))


@pytest.mark.long  # 18 s; the lag's other tests hold its physics in CI
def test_a_hidden_yaw_lag_is_recovered():
    """A record simulated by the continuous lag's adaptive solve, τ = 0.3 s on the yaw
    motor: the MAP converges and the central 95 % of its Laplace draws hold τ."""
    from heli_uq.inference import prepare_start
    from heli_uq.probability import make_problem
    from heli_uq.simulation import synthetic_experiment

    model = build_model(["yaw:motor_lag"])
    truth = dict(RIG_FIT, tau_yaw=0.3)

    def reference(p, x0, u, dt):
        return reference_solve(p, x0, u, dt, model=model)

    record = synthetic_experiment(truth, RIG_FIT_X0, inputs=_steps(12.0, 4), noise_std=(0.003, 0.008),
                                  seed=4, simulator=reference)  # fmt: skip
    start = prepare_start(make_problem(record, model=model, error="iid"), n_starts=1)
    assert start.map_decrement < 1e-8
    draws = np.ravel(start.laplace_draws(LAPLACE_DRAWS, seed=0)["tau_yaw"])
    lo, hi = np.quantile(draws, RECOVERY_INTERVAL)
    assert lo <= truth["tau_yaw"] <= hi, (lo, hi)
    assert hi - lo < truth["tau_yaw"], (lo, hi)  # the record identifies it, not only its prior


def test_description_support_refusals_and_not_a_discovery_candidate():
    model = build_model(["yaw:coulomb_friction", "yaw:motor_lag"])
    again = model_from_description(model.describe())
    assert again.describe() == model.describe()
    (par,) = [e for e in again.effects if e.kind == "motor_lag"][0].parameters()
    assert (par.name, par.bare, par.unit, par.support) == ("tau_yaw", "tau", "s", "nonnegative")
    assert not par.scales_with_inertia
    assert "motor_lag" in TERMS and "motor_lag" not in EFFECTS
    with pytest.raises(ParameterError, match="set up on the recorded voltages, which a motor lag"):
        build_model(["yaw:motor_lag", {"effect": "neural_torque", "axis": "yaw"}])
