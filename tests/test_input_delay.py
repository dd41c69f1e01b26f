"""The input delay (a motor's dead time): its step means against the shifted voltage
integrated on a fine grid, a whole-sample delay against a simulation of the shifted record,
the fixed-step solver against the adaptive reference solve with delayed switch times, the
paper's model at d 0, the gradient in d, and its description."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from heli_uq.model import EFFECTS, RIG_FIT, RIG_FIT_X0, build_model, model_from_description
from heli_uq.model.terms import TERMS
from heli_uq.simulation import reference_solve, simulate

#: Agreement of the step means with the fine-grid integral (the grid resolves the switch
#: times exactly, so float64 rounding only).
MEAN_RTOL = 1e-12
#: Angle agreement [rad] of the fixed-step solver (3 substeps) with the adaptive solve: the
#: solver's accuracy goal on every effect (tests/test_effects.py).
SOLVER_TOL = 1e-4
#: The delay must move the angles by this much more than the two solves differ, so that a
#: delay left out (or wrong) fails the agreement test.
EFFECT_OVER_ERROR = 100
GRAD_RTOL = 1e-6


def _steps(seconds, seed, dt=0.01, hold=1.5):
    """Voltage staircase in the rig's ranges, each level held ``hold`` s."""
    rng = np.random.default_rng(seed)
    n, k = round(seconds / dt), round(hold / dt)
    levels = rng.uniform([1.25, 0.45], [1.42, 1.6], size=(n // k + 1, 2))
    return np.repeat(levels, k, axis=0)[:n]


def test_step_means_are_the_delayed_voltage_integrated_on_a_fine_grid():
    """On step ``k`` the filter holds the mean of ``u(t - d)`` over ``[k h, (k + 1) h)``,
    with ``u`` held at its first value before the record; only the named motor moves."""
    model = build_model(["yaw:input_delay"])
    (term,) = model.effects
    h, fine = 0.01, 1000  # 1000 points per step: d = 0.2374 s puts its switches on the grid
    u = _steps(4.0, 0, hold=0.37)
    for d in (0.0, 0.01, 0.2374, 1.05):
        got = np.asarray(term.filter_sequence({"d_yaw": d}, jnp.asarray(u), h))
        np.testing.assert_array_equal(got[:, 0], u[:, 0])
        t = (np.arange(len(u) * fine) + 0.5) * (h / fine)  # midpoints of the fine grid
        source = np.clip(np.floor((t - d) / h).astype(int), 0, None)
        want = u[source, 1].reshape(len(u), fine).mean(axis=1)
        np.testing.assert_allclose(got[:, 1], want, rtol=MEAN_RTOL)


def test_a_whole_number_of_samples_is_the_record_shifted():
    """d = 25 samples: the model simulates exactly what the paper's model simulates on the
    yaw voltage shifted by 25 samples (its first value held before)."""
    u = _steps(6.0, 1)
    shifted = u.copy()
    shifted[25:, 1] = u[:-25, 1]
    shifted[:25, 1] = u[0, 1]
    model = build_model(["yaw:input_delay"])
    got = np.asarray(simulate(dict(RIG_FIT, d_yaw=0.25), RIG_FIT_X0, u, 0.01, model=model, substeps=2))
    want = np.asarray(simulate(RIG_FIT, RIG_FIT_X0, shifted, 0.01, substeps=2))
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)


def test_the_solver_matches_the_adaptive_solve_with_delayed_switches():
    """Both motors delayed (by fractions of a sample), the yaw one lagging too: the
    fixed-step solve (step means) and the adaptive Kvaerno5 solve (the voltage read d late,
    the delayed switches as jump times, the lag as states) agree to the solver's tolerance,
    while the delays move the angles by far more."""
    model = build_model(["pitch:input_delay", "yaw:input_delay", "yaw:motor_lag"])
    p = dict(RIG_FIT, d_pitch=0.1234, d_yaw=0.4567, tau_yaw=0.2)
    u = _steps(20.0, 2)
    ys = np.asarray(simulate(p, RIG_FIT_X0, u, 0.01, model=model, substeps=3))
    ref = reference_solve(p, RIG_FIT_X0, u, 0.01, model=model)
    error = np.max(np.abs(ys[:, :2] - ref[:, :2]))
    undelayed = reference_solve(dict(p, d_pitch=0.0, d_yaw=0.0), RIG_FIT_X0, u, 0.01, model=model)
    effect = np.max(np.abs(undelayed[:, :2] - ref[:, :2]))
    assert error < SOLVER_TOL, error
    assert effect > EFFECT_OVER_ERROR * error, (effect, error)


def test_d_zero_is_the_paper_model():
    model = build_model(["pitch:input_delay"])
    u = _steps(5.0, 3)
    got = np.asarray(simulate(dict(RIG_FIT, d_pitch=0.0), RIG_FIT_X0, u, 0.01, model=model, substeps=2))
    np.testing.assert_array_equal(got, np.asarray(simulate(RIG_FIT, RIG_FIT_X0, u, 0.01, substeps=2)))


def test_gradient_in_d_matches_central_differences():
    """Through the adjoint solver, at a delay between sample times (the step means are
    linear in d there)."""
    model = build_model(["yaw:input_delay"])
    u = jnp.asarray(_steps(6.0, 4))

    def loss(d):
        ys = simulate(dict(RIG_FIT, d_yaw=d), RIG_FIT_X0, u, 0.01, model=model, substeps=2)
        return jnp.sum(ys[:, :2] ** 2)

    d, eps = 0.3333, 1e-6
    fd = (loss(d + eps) - loss(d - eps)) / (2 * eps)
    grad = float(jax.grad(loss)(d))
    assert abs(grad) > 1.0  # the delay matters to the loss
    assert grad == pytest.approx(float(fd), rel=GRAD_RTOL)


def test_description_support_and_not_a_discovery_candidate():
    model = build_model(["yaw:coulomb_friction", "yaw:input_delay"])
    again = model_from_description(model.describe())
    assert again.describe() == model.describe()
    (par,) = [e for e in again.effects if e.kind == "input_delay"][0].parameters()
    assert (par.name, par.bare, par.unit, par.support) == ("d_yaw", "d", "s", "nonnegative")
    assert not par.scales_with_inertia
    assert "input_delay" in TERMS and "input_delay" not in EFFECTS


#: Central 95 % of the Laplace draws must hold the hidden dead time.
RECOVERY_INTERVAL = (0.025, 0.975)
LAPLACE_DRAWS = 2000


@pytest.mark.long  # about 20 s; the delay's other tests hold its physics in CI
def test_a_hidden_yaw_dead_time_is_recovered():
    """A record simulated by the adaptive solve with the yaw voltage read 0.3 s late: the
    MAP converges and the central 95 % of its Laplace draws hold d, narrower than d."""
    from heli_uq.inference import prepare_start
    from heli_uq.probability import make_problem
    from heli_uq.simulation import synthetic_experiment

    model = build_model(["yaw:input_delay"])
    truth = dict(RIG_FIT, d_yaw=0.3)

    def reference(p, x0, u, dt):
        return reference_solve(p, x0, u, dt, model=model)

    record = synthetic_experiment(truth, RIG_FIT_X0, inputs=_steps(12.0, 5), noise_std=(0.003, 0.008),
                                  seed=5, simulator=reference)  # fmt: skip
    start = prepare_start(make_problem(record, model=model, error="iid"), n_starts=1)
    assert start.map_decrement < 1e-8
    draws = np.ravel(start.laplace_draws(LAPLACE_DRAWS, seed=0)["d_yaw"])
    lo, hi = np.quantile(draws, RECOVERY_INTERVAL)
    assert lo <= truth["d_yaw"] <= hi, (lo, hi)
    assert hi - lo < truth["d_yaw"], (lo, hi)  # the record identifies it, not only its prior
