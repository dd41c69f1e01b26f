"""MAP machinery: the Newton polish converges where a gradient-norm criterion cannot, and a
term's start grid reaches a basin no local move does."""

import jax.numpy as jnp
import numpy as np
import pytest

from heli_uq.inference.density import LogDensity
from heli_uq.inference.map import laplace, newton_polish

#: Distance to the known optimum after the polish, relative to the smallest posterior sd.
OPTIMUM_TOL = 1e-6
#: Curvatures [1/coordinate^2] of the Hessian at a 92 s synthetic record's MAP (yaw drag
#: model): the prior-only inertia split and common scale at the weak end, the pitch
#: gain-gravity balance at the stiff end.
RECORD_CURVATURES = (0.43, 2.4, 9.7, 1.6e3, 6.8e10)
#: Relative error allowed in a Laplace sd (the finite-difference Hessian of an exact
#: quadratic is exact up to rounding).
LAPLACE_SD_TOL = 1e-6


def _quadratic(curvatures, seed=0):
    """``-log p = 0.5 (x - m)^T A (x - m)`` with ``A = Q diag(curvatures) Q^T``, ``Q`` a
    random rotation: ``(density, m, Q)``."""
    rng = np.random.default_rng(seed)
    q, _ = np.linalg.qr(rng.normal(size=(len(curvatures),) * 2))
    a = (q * np.asarray(curvatures)) @ q.T
    m = rng.normal(size=len(curvatures))

    def potential(x):
        d = x - m
        return 0.5 * d @ jnp.asarray(a) @ d

    return LogDensity(None, potential, None, np.zeros(len(curvatures))), m, q


def _sd_along(q, cov):
    """Standard deviations of ``cov`` along the columns of ``q``."""
    return np.sqrt(np.einsum("ij,jk,ki->i", q.T, cov, q))


def test_laplace_keeps_the_weak_curvatures_of_a_long_record():
    """The covariance is the inverse Hessian along every eigendirection, the weakest too:
    a floor at 1e-10 of the largest curvature (until 2026-11-27) raised 0.43 and 2.4 to
    6.8 and made the prior-dominated directions 4x too narrow."""
    density, m, q = _quadratic(RECORD_CURVATURES)
    _, cov = laplace(density, m)
    np.testing.assert_allclose(_sd_along(q, cov), 1.0 / np.sqrt(RECORD_CURVATURES), rtol=LAPLACE_SD_TOL)


def test_laplace_counts_a_negative_curvature_by_its_magnitude():
    """At a saddle the covariance stays positive definite with the curvature's own scale
    (the old floor, 1e-10 of the largest curvature, made that direction 141 times wider)."""
    density, m, q = _quadratic((-2.0, 1.0, 1e6))
    _, cov = laplace(density, m)
    np.testing.assert_allclose(_sd_along(q, cov), 1.0 / np.sqrt([2.0, 1.0, 1e6]), rtol=LAPLACE_SD_TOL)


def test_newton_polish_reaches_the_optimum_of_an_ill_conditioned_density():
    # -log p = 0.5 (x - m)^T A (x - m) + 0.25 sum (x - m)^4 with cond(A) = 1e9, as at the
    # rig's MAP (pitch gain vs gravity); the quartic makes it non-quadratic.
    rng = np.random.default_rng(0)
    q, _ = np.linalg.qr(rng.normal(size=(5, 5)))
    a = (q * np.logspace(0, 9, 5)) @ q.T
    m = rng.normal(size=5)

    def potential(x):
        d = x - m
        return 0.5 * d @ jnp.asarray(a) @ d + 0.25 * jnp.sum(d**4)

    density = LogDensity(None, potential, None, np.zeros(5))
    start = m + q[:, 0] * 0.3 + q[:, -1] * 1e-3  # off along the weakest and stiffest axes
    x, value, grad_max, decrement, steps = newton_polish(density, start)
    smallest_sd = 1.0 / np.sqrt(1e9)
    assert np.max(np.abs(x - m)) < OPTIMUM_TOL * smallest_sd
    assert decrement < 1e-12 and 0 < steps
    assert value <= float(potential(start))


def test_newton_polish_converges_from_the_steep_side_of_an_exponential_wall():
    # -log p = exp(a x) - b x + x^2 / 2 along one coordinate (a rate identified only from
    # above, as J_s/M11 on the synthetic default record, with a unit Gaussian prior),
    # Gaussian in the other: from the steep side a plain Newton step covers ~1/a, so 20
    # steps leave the decrement above tolerance.
    a, b = 20.0, 1.0

    def potential(x):
        return jnp.exp(a * x[0]) - b * x[0] + 0.5 * x[0] ** 2 + 0.5 * (x[1] - 1.0) ** 2

    # the optimum solves a exp(a x) - b + x = 0 (bisection, independent of Newton)
    lo, hi = -1.0, 1.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if a * np.exp(a * mid) - b + mid < 0 else (lo, mid)
    x_opt = 0.5 * (lo + hi)
    density = LogDensity(None, potential, None, np.zeros(2))
    x, _, _, decrement, steps = newton_polish(density, np.array([x_opt + 1.5, 0.0]))
    assert abs(x[0] - x_opt) < OPTIMUM_TOL and abs(x[1] - 1.0) < OPTIMUM_TOL
    assert decrement < 1e-12 and steps < 20


#: Size of the rounding-like noise put on the gradient below [nats per unit of x].
GRADIENT_NOISE = 1e-6


def test_newton_polish_stops_where_the_value_cannot_resolve_the_predicted_gain():
    """-log p = 71423 + |x - m|^2 / 2 in 20 dimensions (a 92 s record's value and a
    friction model's size) with a gradient off by ~1e-6 at random, as rounding over ~1e4
    likelihood terms leaves it: the decrement floors near 1e-11, above NEWTON_TOL, and a
    polish that waits for NEWTON_TOL spends every step (a stiff friction refit: 200 steps,
    125 s, the value unchanged; this test too, before the floor)."""
    import jax

    from heli_uq.inference.map import NEWTON_STEPS, NEWTON_TOL, VALUE_RESOLUTION

    m = np.linspace(-2.0, 2.0, 20)

    @jax.custom_jvp
    def potential(x):
        return 71423.0 + 0.5 * jnp.sum((x - m) ** 2)

    @potential.defjvp
    def _jvp(primals, tangents):
        (x,), (dx,) = primals, tangents
        noisy = (x - m) + GRADIENT_NOISE * jnp.sin(1e12 * x)
        return potential(x), noisy @ dx

    density = LogDensity(None, potential, None, np.zeros(20))
    x, value, _, decrement, steps = newton_polish(density, m + 1.0)
    assert steps < NEWTON_STEPS // 10
    assert 0.5 * np.sum((x - m) ** 2) < VALUE_RESOLUTION * value  # the gain left [nats]
    assert decrement < VALUE_RESOLUTION * value and not decrement < NEWTON_TOL
    assert VALUE_RESOLUTION * 71423.0 < 1e-7  # what is left is far below any nat that matters


def test_find_map_scouts_every_start_then_polishes_the_best_to_convergence(monkeypatch):
    # Two starts on the quartic of the first test; with one scouting step each, only the
    # continuation of the better one can reach the optimum.
    import heli_uq.inference.map as map_module

    monkeypatch.setattr(map_module, "NEWTON_SCOUT_STEPS", 1)
    rng = np.random.default_rng(1)
    m = rng.normal(size=3)

    def potential(x):
        d = x - m
        return 0.5 * jnp.sum(d**2) + 0.25 * jnp.sum(d**4)

    density = LogDensity(None, potential, None, np.zeros(3))
    result = map_module.find_map(density, [m + 3.0, m - 0.5], maxiter=0)
    assert np.max(np.abs(result.x - m)) < OPTIMUM_TOL
    assert result.newton_decrement < 1e-12 and result.newton_steps > 1
    assert result.value == min(result.start_values)


#: Agreement of the finite-difference Hessian with the exact one (relative, Frobenius).
HESSIAN_TOL = 1e-6


def test_fd_hessian_steps_around_a_wall_where_the_model_diverges():
    # The gradient of 0.5 x^T A x is NaN for x_0 > 1e-6 (a solve that diverges just
    # beside the optimum, as a stiff friction model can): the Hessian at 0 must still be
    # A, from one-sided differences, not NaN.
    from heli_uq.inference.map import _fd_hessian

    a = np.array([[2.0, 0.5, 0.0], [0.5, 1.0, 0.1], [0.0, 0.1, 3.0]])

    def grad(x):
        return a @ x if x[0] <= 1e-6 else np.full(3, np.nan)

    h = _fd_hessian(grad, np.zeros(3))
    assert np.all(np.isfinite(h))
    assert np.linalg.norm(h - a) / np.linalg.norm(a) < HESSIAN_TOL


def test_fd_hessian_is_nan_where_no_step_is_finite():
    from heli_uq.inference.map import _fd_hessian

    def grad(x):
        return x if np.all(x == 0) else np.full(2, np.nan)

    assert np.all(np.isnan(_fd_hessian(grad, np.zeros(2))[:, 0]))


def test_leave_saddles_moves_from_a_saddle_to_a_minimum():
    """-log p = (x0^2 - 1)^2 + x1^2: x = 0 is a saddle (Hessian diag(-4, 2)), where Newton
    with |eigenvalues| stops (zero gradient); the minima are x0 = +-1.  Two hidden units
    that do the same thing give a network's posterior such points."""
    from heli_uq.inference.map import leave_saddles

    def potential(x):
        return (x[0] ** 2 - 1.0) ** 2 + x[1] ** 2

    density = LogDensity(None, potential, None, np.zeros(2))
    stuck = newton_polish(density, np.zeros(2))
    assert np.allclose(stuck[0], 0.0)  # the polish alone does not leave the saddle
    x, value, _, decrement, escapes = leave_saddles(density, np.zeros(2))
    assert escapes == 1 and abs(abs(x[0]) - 1.0) < 1e-6 and abs(x[1]) < 1e-6
    assert value < 1e-10 and decrement < 1e-10
    # at a minimum nothing moves
    assert leave_saddles(density, x)[4] == 0


#: A yaw dead band above the record's lowest yaw voltage (0.506 V; next level 0.720 V).
GRID_DELTA = 0.6
#: The MAP's dead band [V] within this of the truth (measured: 0.0005; the noise is 8 mrad).
GRID_DELTA_TOL = 0.02


@pytest.mark.slow
def test_a_dead_band_between_voltage_levels_is_reached_from_the_grid_start():
    """From a start below every voltage level a local fit stays in the offset-like basin
    (measured: delta 0.133 V, 3139 nats worse than the truth's basin); the dead band's
    start grid puts one more start in the interval that holds the truth."""
    from heli_uq.inference.least_squares import grid_start
    from heli_uq.inference.start import prepare_start
    from heli_uq.model import RIG_FIT, RIG_FIT_X0, build_model
    from heli_uq.probability import make_problem
    from heli_uq.simulation import synthetic_experiment
    from heli_uq.simulation.synthetic import ENCODER_QUANTUM

    model = build_model(["yaw:deadband"])
    rec = synthetic_experiment({**RIG_FIT, "delta_yaw": GRID_DELTA}, RIG_FIT_X0, duration=40.0,
                               inputs="rig_steps", noise_std=(0.003, 0.008), seed=5, model=model,
                               quantum=ENCODER_QUANTUM)  # fmt: skip
    levels = np.unique(np.round(np.abs(rec.u[:, 1]), 5))
    below, above = levels[levels < GRID_DELTA].max(), levels[levels > GRID_DELTA].min()
    problem = make_problem(rec, model=model, error="iid")
    low = {**model.start_values(), **RIG_FIT, "delta_yaw": 0.1}
    screened = grid_start(problem, low)
    assert screened is not None and below < screened["delta_yaw"] < above
    start = prepare_start(problem, n_starts=1, guesses=(low,))
    params, _ = start.map_point()
    assert abs(params["delta_yaw"] - GRID_DELTA) < GRID_DELTA_TOL


#: Angles of a start moved along the common scale against the unmoved start [rad]:
#: rounding only (the scaling is an exact symmetry of the equations of motion).
SCALE_INVARIANCE_TOL = 1e-9


def test_a_start_moved_to_a_fixed_mass_keeps_its_angles():
    """Table 1 with ``m`` fixed at a fit's value: written in as is, the gravity torque no
    longer matches Table 1's gains and the pitch of the start runs away; moved along the
    common scale (every inertia-scaled parameter, an effect's included, times one factor)
    the start simulates the same angles as Table 1 itself, with the fixed value kept."""
    from heli_uq.model import RIG_FIT, build_model
    from heli_uq.simulation import simulate

    model = build_model(["yaw:coulomb_friction", "pitch:torque_offset"])
    start = {**model.start_values(), "F_c_yaw": 0.01, "T_0_pitch": -0.002}
    fixed = {"m": RIG_FIT["m"], "g": start["g"]}
    moved = model.on_the_scale_of(start, fixed)
    assert moved["m"] == fixed["m"] and moved["g"] == fixed["g"]
    factor = fixed["m"] / start["m"]
    assert abs(factor - 1.0) > 0.1  # the test means something only if the scales differ
    for name in model.scale_names:
        assert moved[name] == pytest.approx(start[name] * factor, rel=1e-12), name
    x0, u = [-0.5, 0.3, 0.0, 0.0], jnp.tile(jnp.asarray([[1.3, 1.1]]), (300, 1))
    y_start = np.asarray(simulate(start, x0, u, 0.01, model=model, substeps=4))[:, :2]
    y_moved = np.asarray(simulate(moved, x0, u, 0.01, model=model, substeps=4))[:, :2]
    y_written = np.asarray(simulate({**start, **fixed}, x0, u, 0.01, model=model, substeps=4))[:, :2]
    np.testing.assert_allclose(y_moved, y_start, atol=SCALE_INVARIANCE_TOL)
    assert np.max(np.abs(y_written - y_start)) > 100 * SCALE_INVARIANCE_TOL


#: The MAP's pitch residual RMS over the record's noise sd: at the noise, not a wrong basin.
MAP_NOISE_RATIO = 1.2


@pytest.mark.slow
def test_the_map_with_the_mass_fixed_fits_at_the_noise():
    """``--fix m=<a fit's value>`` on a record of that fit: every MAP start used to be Table
    1 with that m written in.  From the first start, on this 10 s record, the model
    diverged ("no MAP start gave a finite log density"); on 20 s the fit ended with the
    pitch turned over (pitch RMSE 16 rad; through the CLI, with 4 starts, on the 20 s
    record of the hybrid tests: 2.4 rad, -log p 12,800 nats above the unfixed MAP).  With
    the starts moved along the common scale the MAP fits at the noise."""
    from heli_uq.inference import prepare_start
    from heli_uq.model import RIG_FIT, RIG_FIT_X0, X0_NAMES, build_model
    from heli_uq.model.prior import Prior
    from heli_uq.probability import PriorSet, make_problem
    from heli_uq.simulation import synthetic_experiment

    noise = 0.003
    rec = synthetic_experiment(RIG_FIT, RIG_FIT_X0, duration=10.0, inputs="steps", seed=5,
                               noise_std=(noise, noise))  # fmt: skip
    model = build_model([])
    priors = PriorSet.default(model).updated(model, {"m": Prior("fixed", RIG_FIT["m"])}, where="test")
    problem = make_problem(rec, model=model, priors=priors, error="iid")
    start = prepare_start(problem, n_starts=1)
    params, x0 = start.map_point()
    assert params["m"] == RIG_FIT["m"]
    guess = start.map_guess()  # the same point as one refit guess, initial state by name
    assert guess == {**params, **dict(zip(X0_NAMES, x0.tolist()))}
    y = np.asarray(problem.solve(params, x0, problem.n_train).ys)[:, :2]
    rms = np.sqrt(np.mean((y - np.asarray(problem.y)) ** 2, axis=0))
    assert rms[0] < MAP_NOISE_RATIO * noise, rms


def test_substeps_cap_is_a_logged_warning(synthetic_problem, monkeypatch, caplog):
    """A MAP stiffer than MAX_SUBSTEPS allows is reported through the package's logging (one
    ``warning:`` line in the CLI), not as a Python warning with a source line."""
    import logging

    from heli_uq.inference import start as start_module
    from heli_uq.inference import substeps as substeps_module
    from heli_uq.simulation import stiffness

    monkeypatch.setattr(substeps_module, "required_substeps", lambda problem, params, decay=True: 99)
    for module in (stiffness, substeps_module):
        monkeypatch.setattr(module, "MAX_SUBSTEPS", synthetic_problem.substeps)
    with caplog.at_level(logging.WARNING, logger="heli_uq"):
        start = start_module.prepare_start(synthetic_problem, n_starts=1, seed=0)
    assert start.problem.substeps == synthetic_problem.substeps
    lines = [r.getMessage() for r in caplog.records if r.name == "heli_uq.simulation.stiffness"]
    assert len(lines) == 1 and "the MAP needs 99 solver substeps" in lines[0], lines


def test_a_map_whose_damping_sits_at_the_solvers_limit_says_so_and_is_held(synthetic_problem, monkeypatch,
                                                                           caplog):  # fmt: skip
    """A MAP whose viscous decay sits at RK4's limit (a base model imitating a hidden
    friction by damping) follows the limit at every raise, so it is raised to
    EDGE_SUBSTEPS only and held there: the cap's warning names the axis and why (not a
    friction to smooth), once, and the returned start carries the edge.  The edge is
    remembered: a MAP pinned at 1 substep and not at 2 is still held at 2."""
    import logging

    from heli_uq.inference import start as start_module
    from heli_uq.inference import substeps as substeps_module

    edge = {"axis": "pitch", "rate": 270.0, "rh": 2.7, "substeps": 1}
    monkeypatch.setattr(substeps_module, "required_substeps", lambda problem, params, decay=True: 99)
    for pinned_only_at_one in (False, True):
        def pinned(problem, params):
            return edge if problem.substeps == 1 or not pinned_only_at_one else None

        monkeypatch.setattr(substeps_module, "map_edge", pinned)
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="heli_uq"):
            start = start_module.prepare_start(synthetic_problem, n_starts=1, seed=0)
        lines = [r.getMessage() for r in caplog.records if r.name == "heli_uq.simulation.stiffness"]
        assert start.problem.substeps == substeps_module.EDGE_SUBSTEPS
        assert len(lines) == 1 and "the fit damps pitch as hard as the solver allows" in lines[0], lines
        assert f"using {substeps_module.EDGE_SUBSTEPS}:" in lines[0] and "held at" in lines[0]
        assert "270 /s" in lines[0] and "smoother" not in lines[0]
        assert ("at 1 substep(s) was pinned" in lines[0]) == pinned_only_at_one  # which MAP it was
        assert start.solver_edge == edge


def test_a_guess_pinned_at_the_solvers_limit_is_refitted_where_it_was_held(synthetic_problem):
    """The nested fallback of discovery refits the current model's MAP at the substeps its
    stiffness needs (guess_substeps).  A viscous decay is not raised for while the solver
    holds it (inside RK4's limit): a MAP held at EDGE_SUBSTEPS with its pitch decay at the
    limit there, which the stiffness rule would give twice that, is refitted at the count it
    was held at, so a candidate nesting it is compared on the same solver.  A decay stable
    only at more substeps (a fit held at 16 before) and a friction's need keep the rule."""
    from heli_uq.inference.substeps import EDGE_SUBSTEPS, guess_substeps, required_substeps
    from heli_uq.model import build_model
    from heli_uq.probability import make_problem
    from heli_uq.simulation import synthetic_experiment
    from heli_uq.simulation.stiffness import MAX_SUBSTEPS, RK4_STABILITY

    problem = synthetic_problem
    model = problem.model
    values = model.complete(model.start_values())
    m11 = float(model.mechanics.inertia_bounds(values, problem.y[: problem.n_train, 0])[0])

    def with_rh(rh, substeps, guess=values):  # D_theta whose pitch decay D/M11 has r h = rh there
        return {**guess, "D_theta": rh * substeps / problem.dt * m11}

    pinned = with_rh(RK4_STABILITY, EDGE_SUBSTEPS)  # at the limit, to rounding
    assert required_substeps(problem, pinned) > EDGE_SUBSTEPS
    assert guess_substeps(problem, [pinned]) == EDGE_SUBSTEPS
    inside_at_one = with_rh(0.7 * RK4_STABILITY, 1)
    assert required_substeps(problem, inside_at_one) == 2 and guess_substeps(problem, [inside_at_one]) == 1
    beyond = with_rh(0.97 * RK4_STABILITY, MAX_SUBSTEPS)  # unstable at EDGE_SUBSTEPS
    assert guess_substeps(problem, [beyond]) == MAX_SUBSTEPS
    record = synthetic_experiment(duration=4.0, seed=1)
    friction = make_problem(record, error="iid", model=build_model(["yaw:coulomb_friction"]))
    sharp = {**values, "F_c_yaw": 0.01}  # its stiffness, not a decay, asks for the substeps
    assert guess_substeps(friction, [sharp]) == required_substeps(friction, sharp) > friction.substeps


def test_a_map_that_stiffens_at_every_raise_is_raised_until_covered(synthetic_problem, monkeypatch):
    """A model that imitates a missing friction by ever larger damping gets a stiffer MAP at
    every raise of the substeps (on a stiff pitch-friction record: 1 -> 2 -> 4 -> 8 -> 16).
    The raising goes on until the MAP's need is covered or capped, so the returned MAP is
    polished on substeps that cover it; three raises left such a base model at 8 substeps
    needing 16, while the candidates that nest it were fitted at 16 (their support then
    held the solver's difference, 48 nats)."""
    from heli_uq.inference import start as start_module
    from heli_uq.inference import substeps as substeps_module
    from heli_uq.simulation.stiffness import MAX_SUBSTEPS

    seen = []

    def stiffening(problem, params, decay=True):  # a friction's need, with or without the decay
        seen.extend([problem.substeps] if decay else [])
        return 2 * problem.substeps

    monkeypatch.setattr(substeps_module, "required_substeps", stiffening)
    start = start_module.prepare_start(synthetic_problem, n_starts=1, seed=0)
    assert start.problem.substeps == MAX_SUBSTEPS
    assert seen == [1, 2, 4, 8, 16], seen
    assert start.map_decrement <= start_module.MAP_DECREMENT_MAX


def test_laplace_draws_stiffer_than_the_map_raise_the_substeps(synthetic_problem, monkeypatch, caplog):
    """When the Laplace draws need more substeps than the MAP (a posterior that reaches
    stiffer models than its mode), the problem is rebuilt with them, logged, and the MAP
    polished again on it (the returned start is converged on the new problem)."""
    import logging

    from heli_uq.inference import start as start_module
    from heli_uq.inference import substeps as substeps_module

    need = synthetic_problem.substeps + 1
    monkeypatch.setattr(substeps_module, "tail_substeps", lambda problem, *args: need)
    with caplog.at_level(logging.INFO, logger="heli_uq"):
        start = start_module.prepare_start(synthetic_problem, n_starts=1, seed=0)
    assert start.problem.substeps == need
    assert start.density.problem.substeps == need
    assert start.map_decrement <= start_module.MAP_DECREMENT_MAX
    lines = [r.getMessage() for r in caplog.records if r.name == "heli_uq.inference.substeps"]
    assert any(f"-> {need}" in line for line in lines), lines


def test_tail_substeps_cover_the_laplace_draws_of_a_friction_posterior():
    """On a record with yaw friction hidden, the substeps chosen cover the stiffness of
    fresh Laplace draws (another seed): each keeps ``rate h`` within RK4's stability limit."""
    from heli_uq.inference import prepare_start
    from heli_uq.model import build_model
    from heli_uq.probability import make_problem
    from heli_uq.simulation import SYNTHETIC_PARAMS, synthetic_experiment
    from heli_uq.simulation.stiffness import RK4_STABILITY, stiffness_rates

    model = build_model(["yaw:coulomb_friction"])
    rec = synthetic_experiment({**SYNTHETIC_PARAMS, "F_c_yaw": 0.005}, duration=20.0, seed=3, model=model)
    problem = make_problem(rec, model=model, error="iid")
    start = prepare_start(problem, n_starts=1, seed=0)
    draws = start.laplace_draws(1000, seed=11)
    fixed = {k: float(p.a) for k, p in problem.priors.params.items() if not p.free}
    rates = stiffness_rates(model, draws, fixed=fixed, thetas=problem.y[:, 0])
    h = problem.dt / start.problem.substeps
    assert start.problem.substeps > 1
    assert np.max(rates) * h < RK4_STABILITY, (np.max(rates), start.problem.substeps)


def test_a_warm_start_with_an_effect_at_its_no_effect_default_is_used(tmp_path):
    """``sample --init`` with a fit of a smaller model read the file completed with the
    model's defaults: the new effect's "no effect" level 0 lies on the bound of its log
    coordinate, the start's least-squares cost was infinite and the user's start was
    dropped in silence (2026-11-30, a GP torque on the rig's tilt model).  Such a value now
    takes the model's start value, and the CLI reads only the file's names."""
    import json
    import math

    from heli_uq.inference.density import log_density_setup
    from heli_uq.inference.multistart import map_starts, startable
    from heli_uq.model import RIG_FIT, RIG_FIT_X0, build_model, load_params_json
    from heli_uq.probability import make_problem
    from heli_uq.simulation import synthetic_experiment

    rec = synthetic_experiment(RIG_FIT, RIG_FIT_X0, duration=3.0, inputs="rig_steps", seed=2,
                               noise_std=(0.003, 0.008))  # fmt: skip
    model = build_model(["yaw:quadratic_drag"])
    problem = make_problem(rec, model=model, error="iid")
    path = tmp_path / "fit.json"
    path.write_text(json.dumps(RIG_FIT))
    completed = load_params_json(path, model)
    assert completed["c_yaw"] == 0.0  # the default: no drag, on the bound of c's support
    assert load_params_json(path, model, complete=False) == {k: float(v) for k, v in RIG_FIT.items()}
    kept = startable(problem, completed)
    assert "c_yaw" not in kept and all(kept[k] == v for k, v in RIG_FIT.items())
    costs = []
    map_starts(problem, log_density_setup(problem), 1, guesses=(completed,),
               log=lambda line: costs.append(float(line.split("cost ")[1].split()[0])))  # fmt: skip
    assert len(costs) == 1 and math.isfinite(costs[0]), costs


#: Damping [N m s / rad] far past the stability limit of RK4 at one substep per 0.01 s sample.
DIVERGING_DAMPING = 1e6


def test_no_start_that_simulates_is_the_documented_error_and_a_nested_candidate_falls_back(monkeypatch):
    """Every start's least-squares fit leaving a model that diverges gave ``ValueError:
    min() arg is an empty sequence`` from inside ``find_map`` (2026-12-05, the base model's
    whole-record refit in ``discover``).  It is now ``prepare_start``'s documented
    ParameterError, so a nested candidate with such a start falls back to its
    "effect off" start, as it does for any other failed start.  (With more substeps the
    least-squares fit recovers even from this damping, so the cap on the substeps of the
    retry is set to the problem's one substep.)"""
    import dataclasses

    import heli_uq.inference.start as start_module
    from heli_uq.discovery.candidates import FitTask, _nested_map, off_start
    from heli_uq.errors import ParameterError
    from heli_uq.inference.start import prepare_start

    monkeypatch.setattr(start_module, "MAX_SUBSTEPS", 1)
    from heli_uq.model import RIG_FIT, RIG_FIT_X0, build_model
    from heli_uq.probability import make_problem
    from heli_uq.simulation import synthetic_experiment

    rec = synthetic_experiment(RIG_FIT, RIG_FIT_X0, duration=1.0, inputs="rig_steps", seed=5,
                               noise_std=(0.003, 0.008))  # fmt: skip
    diverging = {**RIG_FIT, "D_theta": DIVERGING_DAMPING, "D_psi": DIVERGING_DAMPING}
    problem = make_problem(rec, error="iid", substeps=1)
    with pytest.raises(ParameterError, match="no MAP start simulates the record"):
        prepare_start(problem, n_starts=1, guesses=[diverging])
    effects = ["yaw:torque_offset"]
    nested = make_problem(rec, model=build_model(effects), error="iid", substeps=1)
    task = FitTask(rec, (0.0, 1.0), None, tuple(effects), ({**diverging, "T_0_yaw": 0.0},), 0, 1, 8)
    with pytest.raises(ParameterError, match="no MAP start simulates the record"):
        _nested_map(nested, task)
    base = prepare_start(problem, n_starts=1, guesses=[RIG_FIT])
    guarded = dataclasses.replace(task, off=off_start(RIG_FIT, effects), floor=base.map_value)
    start, from_off = _nested_map(nested, guarded)
    assert from_off and np.isfinite(start.map_value)


#: Pitch damping [N m s / rad] whose linear mode RK4 resolves at 4 substeps per 0.01 s
#: sample (``r h`` about 1.3) and not at one (about 5, past the limit 2.785).
STIFF_DAMPING = 5.0


def test_a_start_too_stiff_for_the_substeps_is_fitted_again_with_more():
    """A warm guess fitted on another window may need more substeps than the model's start
    values: ``discover``'s whole-record refit of its base model stopped with "no MAP start
    simulates the record" at 1 substep where its guess needs 3 (2026-12-05).  The starts
    are now fitted again with the substeps the guess needs."""
    from heli_uq.inference.start import prepare_start
    from heli_uq.inference.substeps import required_substeps
    from heli_uq.model import RIG_FIT, RIG_FIT_X0
    from heli_uq.probability import make_problem
    from heli_uq.simulation import synthetic_experiment

    rec = synthetic_experiment(RIG_FIT, RIG_FIT_X0, duration=1.0, inputs="rig_steps", seed=5,
                               noise_std=(0.003, 0.008))  # fmt: skip
    stiff = {**RIG_FIT, "D_theta": STIFF_DAMPING}
    problem = make_problem(rec, error="iid", substeps=1)
    need = required_substeps(problem, stiff)
    assert need > 1
    start = prepare_start(problem, n_starts=1, guesses=[stiff])
    assert np.isfinite(start.map_value)
    assert start.problem.substeps >= need


def test_the_nested_fallback_is_fitted_at_its_starts_substeps_without_the_grid(monkeypatch):
    """The fallback from "effect off" restarts the current model's fit, so it is built at
    the substeps that fit needs (it climbed to 11 from 1 through a failed least-squares
    start, 12 s, and a dead band's grid screen, 21 s, of a 205 s candidate fit on a stiff
    pitch friction record; 2026-12-06) and without the grid's start, which would look for
    another basin."""
    import heli_uq.discovery.candidates as candidates
    from heli_uq.inference.start import prepare_start
    from heli_uq.inference.substeps import guess_substeps, required_substeps
    from heli_uq.model import RIG_FIT, RIG_FIT_X0, build_model
    from heli_uq.probability import make_problem
    from heli_uq.simulation import synthetic_experiment

    rec = synthetic_experiment(RIG_FIT, RIG_FIT_X0, duration=1.0, inputs="rig_steps", seed=5,
                               noise_std=(0.003, 0.008))  # fmt: skip
    stiff = {**RIG_FIT, "D_theta": STIFF_DAMPING}
    effects = ["pitch:deadband"]
    nested = make_problem(rec, model=build_model(effects), error="iid", substeps=1)
    off = candidates.off_start(stiff, effects)
    need = required_substeps(nested, off)
    assert need > 1 and guess_substeps(nested, [off, RIG_FIT]) == need
    calls = []

    def spy(problem, **kw):
        calls.append((kw["guesses"] == (off,), problem.substeps, kw["grid"], kw["from_fit"]))
        return prepare_start(problem, **kw)

    monkeypatch.setattr(candidates, "prepare_start", spy)
    task = candidates.FitTask(rec, (0.0, 1.0), None, tuple(effects), ({**stiff, "delta_pitch": 5.0},),
                              0, 1, 8, off=off, floor=-np.inf)  # every start is above: the fallback runs
    start, from_off = candidates._nested_map(nested, task)
    assert calls == [(False, 1, True, False), (True, need, False, True)]
    assert np.isfinite(start.map_value)
    # a known fit of the model itself (discovery's "before" on the whole record) likewise
    base = make_problem(rec, model=build_model([]), error="iid", substeps=1)
    need_base = required_substeps(base, stiff)
    assert need_base > 1
    calls.clear()
    refit = candidates.FitTask(rec, (0.0, 1.0), None, (), (stiff,), 0, 1, 8, refit=True)
    start, from_off = candidates._nested_map(base, refit)
    assert calls == [(False, need_base, False, True)] and not from_off
    assert np.isfinite(start.map_value)


def test_a_start_from_a_fit_is_fitted_once_from_its_state_with_its_own_scales(monkeypatch):
    """``map_starts(..., from_fit=True)``: a guess that is a fit (here the truth of the
    record, with its initial state) is fitted by least squares from that state, weighted
    by the residual scales it leaves (the record's noise, not ``LSQ_SIGMA``), and not a
    second time: the scales do not move.  Without ``from_fit`` the same guess is fitted
    twice, from the priors' initial state, first with ``LSQ_SIGMA``.  (The second pass was
    47 s of a 93 s nested fallback at 11 substeps, 2026-12-06.)"""
    import heli_uq.inference.multistart as start_module
    from heli_uq.inference.density import log_density_setup
    from heli_uq.inference.least_squares import LSQ_SIGMA, x0_guess
    from heli_uq.model import RIG_FIT, RIG_FIT_X0, X0_NAMES
    from heli_uq.probability import make_problem
    from heli_uq.simulation import synthetic_experiment

    noise = (0.003, 0.008)
    rec = synthetic_experiment(RIG_FIT, RIG_FIT_X0, duration=2.0, inputs="rig_steps", seed=3,
                               noise_std=noise)  # fmt: skip
    problem = make_problem(rec, error="iid")
    guess = {**RIG_FIT, **dict(zip(X0_NAMES, map(float, RIG_FIT_X0)))}
    x_guess = x0_guess(problem, guess)
    free = [p.free for p in problem.x0_priors()]
    np.testing.assert_array_equal(x_guess[free], np.asarray(RIG_FIT_X0)[free])
    np.testing.assert_array_equal(x_guess[~np.asarray(free)], x0_guess(problem)[~np.asarray(free)])
    assert not np.allclose(x0_guess(problem), x_guess)  # the test means something
    real = start_module.least_squares_fit

    def counting(prob):
        fit = real(prob)

        def spy(z0, x0, sigma=LSQ_SIGMA):
            passes.append((np.asarray(x0).copy(), np.asarray(sigma, dtype=float)))
            return fit(z0, x0, sigma)

        return spy

    monkeypatch.setattr(start_module, "least_squares_fit", counting)
    density = log_density_setup(problem)
    passes = []
    (refit,) = start_module.map_starts(problem, density, 1, guesses=(guess,), grid=False, from_fit=True)
    assert len(passes) == 1
    np.testing.assert_array_equal(passes[0][0], x_guess)
    np.testing.assert_allclose(passes[0][1], noise, rtol=start_module.RESCALE_RTOL)
    passes = []
    (twice,) = start_module.map_starts(problem, density, 1, guesses=(guess,), grid=False)
    assert len(passes) == 2 and np.array_equal(passes[0][1], LSQ_SIGMA)
    assert np.isfinite(density.potential(refit)) and np.isfinite(density.potential(twice))


def test_a_fit_held_at_the_solvers_limit_is_settled_by_refits_from_its_own_map(monkeypatch):
    """A MAP held at the solver's limit is a boundary point: Newton stops short there (on a
    pitch friction record the base model held at 2 substeps kept a decrement of 355 nats,
    and every candidate nesting it beat it by hundreds of nats).  It is refitted from its
    own MAP, at its own problem, while its decrement exceeds EDGE_DECREMENT and the refit
    improves it, at most EDGE_PASSES times; a fit off the limit, or converged, is kept."""
    import dataclasses

    import heli_uq.inference.settle as settle
    from heli_uq.model import X0_NAMES

    @dataclasses.dataclass
    class Fit:
        map_value: float
        map_decrement: float
        solver_edge: dict | None = dataclasses.field(default_factory=lambda: {"axis": "pitch"})
        problem: str = "held at 2 substeps"

        def map_guess(self):
            return {"D_theta": self.map_value, **dict.fromkeys(X0_NAMES, 0.0)}

    def run(first, refits):
        queue, seen = list(refits), []

        def refit(problem, **kw):
            seen.append((problem, kw["guesses"][0]["D_theta"], kw["from_fit"], kw["grid"]))
            return queue.pop(0)

        monkeypatch.setattr(settle, "prepare_start", refit)
        return settle.settle_edge(first, newton_steps=4), seen

    big = settle.EDGE_DECREMENT * 30
    out, seen = run(Fit(-100.0, big), [Fit(-500.0, big), Fit(-600.0, 0.5 * settle.EDGE_DECREMENT)])
    assert out.map_value == -600.0 and len(seen) == 2
    assert seen[0] == ("held at 2 substeps", -100.0, True, False) and seen[1][1] == -500.0
    out, seen = run(Fit(-100.0, big), [Fit(-90.0, 1.0)])  # a refit that ends worse is not kept
    assert out.map_value == -100.0 and len(seen) == 1
    out, seen = run(Fit(-100.0, big), [Fit(-100.0 - k, big) for k in range(1, 10)])
    assert len(seen) == settle.EDGE_PASSES and out.map_value == -100.0 - settle.EDGE_PASSES
    for kept in (Fit(-100.0, big, None), Fit(-100.0, 0.5 * settle.EDGE_DECREMENT)):
        out, seen = run(kept, [])
        assert out is kept and not seen
