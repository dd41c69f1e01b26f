"""The Gaussian-process torque (model discrepancy over the voltages): its values at the
voltage pairs against the kernel written out in numpy, its prior covariance in both forms
(whitened; centred at the training pairs), the centred form's joint prior against scipy and
in the sampler's log prior, the projection that leaves the linear gains to the mechanics,
its gradient against finite differences, the pairs of a test window it holds, and its
description round trip."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.stats

from heli_uq.errors import ParameterError
from heli_uq.model import RIG_FIT, RIG_FIT_X0, build_model, model_from_description
from heli_uq.model.terms.gp_torque import JITTER
from heli_uq.probability import make_problem
from heli_uq.simulation import simulate, synthetic_experiment

#: Agreement with the numpy form (float64 round-off of a 30 x 30 triangular solve).
EXACT = 1e-10
#: Relative agreement of the autodiff gradient with central differences.
FD_RTOL = 1e-6
#: The angles may change by at most this much [rad] under the common scale.
SCALE_INVARIANCE_RAD = 1e-9
LENGTH = 0.15  # kernel length scale of these tests [V]
#: A test-window pair's value may move the training window's angles by at most this [rad]:
#: between the pairs the interpolant carries the nugget (``JITTER``), ~1e-6 rad here.
NUGGET_LEAK_RAD = 1e-5
#: Prior draws for the covariance check, and its tolerance: the sd of a sample covariance
#: entry of unit-variance normals is at most sqrt(2 / DRAWS) = 0.014; 5 of them.
DRAWS = 20000
COV_ATOL = 5 * np.sqrt(2 / DRAWS)


def _record(seconds=60.0, seed=3):
    return synthetic_experiment(RIG_FIT, RIG_FIT_X0, duration=seconds, inputs="rig_steps", seed=seed,
                                noise_std=(0.003, 0.008))  # fmt: skip


def _numpy_kernel(a, b):
    """``exp(-|a - b|^2 / (2 l^2))``, written out pair by pair (independent form)."""
    out = np.empty((len(a), len(b)))
    for i, x in enumerate(a):
        for j, y in enumerate(b):
            out[i, j] = np.exp(-((x[0] - y[0]) ** 2 + (x[1] - y[1]) ** 2) / (2 * LENGTH**2))
    return out


def _problem(project="1,u", form="centred", train=(0.0, 45.0), test=(45.0, 60.0)):
    rec = _record()
    item = {"effect": "gp_torque", "axis": "yaw", "length_scale": LENGTH, "project": project, "form": form}
    model = build_model(["yaw:torque_offset", item] if project == "1,u" else [item])
    return rec, make_problem(rec, train, test, model=model, error="iid")


def _values(model, seed=0, tau=0.01):
    """Rig-fit mechanics, whitened values from N(0, 1), centred ones from their joint prior."""
    rng = np.random.default_rng(seed)
    z = {n: rng.normal() for n in model.names if n.startswith("gp_z_")}
    return {k: float(v) for k, v in model.draw_joint(model.complete({**RIG_FIT, **z, "gp_tau_yaw": tau}),
                                                     rng).items()}  # fmt: skip


def _value_names(term):
    """The parameters that set ``f`` at the reference pairs, in pair order."""
    t = len(term.joint_names())
    return [term.name(f"gp_f_{j}" if j < t else f"gp_z_{j}") for j in range(term.n_pairs)]


@pytest.fixture(scope="module", params=[("1,u", "centred"), ("none", "centred"), ("1,u", "whitened")],
                ids=["1,u-centred", "none-centred", "1,u-whitened"])
def problem(request):
    return _problem(*request.param)


def test_the_span_pairs_are_the_reference_and_get_standard_normal_priors(problem):
    rec, pr = problem
    term = pr.model.effects[-1]
    span_pairs = np.unique(pr.u, axis=0)
    train_pairs = np.unique(pr.u[: pr.n_train], axis=0)
    reference = np.asarray(term.reference)
    # the training window's pairs first, then the test window's new ones: every span pair once
    np.testing.assert_array_equal(reference[: len(train_pairs)], train_pairs)
    np.testing.assert_array_equal(np.unique(reference, axis=0), span_pairs)
    assert len(reference) == len(span_pairs)
    assert len(span_pairs) > len(train_pairs), "the test window must hold pairs the training window does not"
    centred = len(train_pairs) if term.form == "centred" else 0
    assert term.n_fitted == len(train_pairs)
    values = [n for n in pr.model.names if n.startswith(("gp_f_", "gp_z_"))]
    expected = [f"gp_f_{j}_yaw" for j in range(centred)]
    expected += [f"gp_z_{j}_yaw" for j in range(centred, len(span_pairs))]
    assert values == expected
    assert all(pr.priors.params[n].describe() == "normal(0, 1)" for n in values[centred:])
    assert list(pr.model.joint_names) == values[:centred]
    assert "gp_tau_yaw" in pr.model.scale_names
    assert all(n in pr.model.scale_names for n in values[:centred])  # torques: the common scale holds


def test_a_new_pairs_value_leaves_the_training_window_unchanged(problem):
    # block lower-triangular factor: the z of a pair only the test window holds moves the
    # torque there and nowhere in the training window, so its posterior is its prior given
    # the fitted pairs (the GP's conditional)
    _, pr = problem
    term = pr.model.effects[-1]
    n_seen = len(np.unique(pr.u[: pr.n_train], axis=0))
    p = _values(pr.model, seed=4)
    moved = {**p, f"gp_z_{term.n_pairs - 1}_yaw": p[f"gp_z_{term.n_pairs - 1}_yaw"] + 3.0}
    a = simulate(p, RIG_FIT_X0, pr.u, pr.dt, model=pr.model)
    b = simulate(moved, RIG_FIT_X0, pr.u, pr.dt, model=pr.model)
    assert term.n_pairs > n_seen
    assert float(jnp.max(jnp.abs(a[: pr.n_train, :2] - b[: pr.n_train, :2]))) < NUGGET_LEAK_RAD
    assert float(jnp.max(jnp.abs(a[pr.n_train:, 1] - b[pr.n_train:, 1]))) > 1e-3


def test_values_at_the_pairs_follow_the_kernel(problem):
    _, pr = problem
    term = pr.model.effects[-1]
    pairs = np.asarray(term.reference)
    names = _value_names(term)
    p = _values(pr.model)
    v = np.array([p[n] for n in names])
    gram = _numpy_kernel(pairs, pairs) + JITTER * np.eye(len(pairs))
    prepared = pr.model.prepare(p)[1]
    f = np.asarray(term.values_at(prepared, jnp.asarray(pairs)))
    t = len(term.joint_names())
    if t:  # centred: the fitted pairs' values are the parameters (up to the nugget's tau J alpha)
        np.testing.assert_allclose(f[:t], v[:t], atol=1e-4 * 0.01)
    else:  # whitened: f(P) = tau L z
        np.testing.assert_allclose(f, 0.01 * np.linalg.cholesky(gram) @ v, atol=1e-5 * 0.01 * np.abs(v).max())
    # f(P) is linear in the values: f = B v, whose prior covariance is blockdiag(tau^2 K_tt, I)
    # (centred) or I (whitened); B cov B^T must be the GP's tau^2 (K + nugget) in both forms
    jac = np.asarray(jax.jacfwd(lambda vv: term.values_at(
        pr.model.prepare({**p, **dict(zip(names, vv))})[1], jnp.asarray(pairs)))(jnp.asarray(v)))  # fmt: skip
    cov_v = np.eye(len(pairs))
    cov_v[:t, :t] = 0.01**2 * gram[:t, :t]
    np.testing.assert_allclose(jac @ cov_v @ jac.T, 0.01**2 * gram, atol=1e-4 * 1e-5)


def test_the_centred_joint_prior_is_the_gps_normal_and_enters_the_samplers_log_prior():
    _, pr = _problem("1,u", "centred")
    term = pr.model.effects[-1]
    names = list(term.joint_names())
    pairs = np.asarray(term.reference)[: len(names)]
    cov = 0.007**2 * (_numpy_kernel(pairs, pairs) + JITTER * np.eye(len(names)))
    p = _values(pr.model, seed=5, tau=0.007)
    f = np.array([p[n] for n in names])
    expected = scipy.stats.multivariate_normal(np.zeros(len(names)), cov).logpdf(f)
    assert abs(float(term.joint_log_prior(p)) - expected) < EXACT * abs(expected)
    # in the sampler's coordinates: moving only the centred values changes the log prior by the
    # joint prior's difference (their own declared normal priors do not enter; the Jacobian of a
    # torque ratio does not depend on the torque)
    coords = pr.coords
    moved = {**p, **{n: p[n] + 0.004 * (-1) ** j for j, n in enumerate(names)}}
    f2 = np.array([moved[n] for n in names])
    got = float(coords.log_prior(jnp.asarray(coords.from_physical(moved)))
                - coords.log_prior(jnp.asarray(coords.from_physical(p))))  # fmt: skip
    want = scipy.stats.multivariate_normal(np.zeros(len(names)), cov).logpdf(f2) - expected
    assert abs(got - want) < 1e-8 * max(1.0, abs(want))
    # a prior of another kind on a centred value is refused (only fixing it is allowed)
    from heli_uq.model.prior import Prior

    with pytest.raises(ParameterError, match="joint prior"):
        pr.priors.updated(pr.model, {names[0]: Prior("lognormal", 0.01, 1.0)})


def test_prior_draws_of_the_centred_values_have_the_gps_covariance():
    _, pr = _problem("1,u", "centred")
    names = list(pr.model.joint_names)
    pairs = np.asarray(pr.model.effects[-1].reference)[: len(names)]
    draws = pr.priors.draw(pr.model, np.random.default_rng(11), (1, DRAWS))
    f = np.stack([draws[n][0] for n in names], axis=-1)  # (DRAWS, t)
    scaled = f / draws["gp_tau_yaw"][0][:, None]  # f / tau ~ N(0, K) exactly
    corr = _numpy_kernel(pairs, pairs) + JITTER * np.eye(len(names))
    np.testing.assert_allclose(np.cov(scaled.T), corr, atol=COV_ATOL)
    # the amplitude keeps its own half-normal prior: E|tau| = sd sqrt(2 / pi)
    assert abs(draws["gp_tau_yaw"].mean() / (0.01 * np.sqrt(2 / np.pi)) - 1) < 5 / np.sqrt(DRAWS)


def test_the_torque_is_orthogonal_to_the_gains_over_the_training_pairs(problem):
    rec, pr = problem
    term = pr.model.effects[-1]
    p = pr.model.prepare(_values(pr.model, seed=1))[1]
    pairs, counts = np.unique(pr.u[: pr.n_train], axis=0, return_counts=True)
    got = np.array([float(term.torque(p, jnp.asarray(q))) for q in pairs])
    raw = np.asarray(term.values_at(p, jnp.asarray(pairs)))
    if term.project == "none":
        np.testing.assert_allclose(got, raw, atol=EXACT)
        return
    basis = np.column_stack([np.ones(len(pairs)), pairs])
    np.testing.assert_allclose(basis.T @ (counts * got), 0.0, atol=EXACT * counts.sum())
    # and only a linear function was taken off: the residual of raw - got on the basis is 0
    coef = np.linalg.lstsq(basis, raw - got, rcond=None)[0]
    np.testing.assert_allclose(basis @ coef, raw - got, atol=EXACT)


def test_gradient_matches_finite_differences(problem):
    _, pr = problem
    term = pr.model.effects[-1]
    p = _values(pr.model, seed=2)
    u = jnp.asarray(np.unique(pr.u, axis=0)[-1] + 0.013)  # between the pairs
    names = ["gp_tau_yaw", _value_names(term)[0], f"gp_z_{term.n_pairs - 1}_yaw"]

    def torque(values):
        q = {**p, **dict(zip(names, values))}
        return term.torque(pr.model.prepare(q)[1], u)

    x = jnp.asarray([p[n] for n in names])
    grad = np.asarray(jax.grad(torque)(x))
    h = 1e-6
    fd = np.array([(torque(x.at[i].add(h)) - torque(x.at[i].add(-h))) / (2 * h) for i in range(len(x))])
    np.testing.assert_allclose(grad, fd, rtol=FD_RTOL, atol=1e-12)
    assert np.all(np.abs(grad) > 0)


def test_common_scale_leaves_the_angles_unchanged(problem):
    _, pr = problem
    p = _values(pr.model, seed=3)
    base = simulate(p, RIG_FIT_X0, pr.u, pr.dt, model=pr.model)
    scaled = {k: v * 1.7 if k in pr.model.scale_names else v for k, v in p.items()}
    moved = simulate(scaled, RIG_FIT_X0, pr.u, pr.dt, model=pr.model)
    assert float(jnp.max(jnp.abs(moved[:, :2] - base[:, :2]))) < SCALE_INVARIANCE_RAD
    assert float(jnp.max(jnp.abs(base[:, 1] - simulate(RIG_FIT, RIG_FIT_X0, pr.u, pr.dt)[:, 1]))) > 1e-3


def test_description_round_trip_keeps_the_pairs(problem):
    rec, pr = problem
    again = model_from_description(pr.model.describe())
    assert again == pr.model
    assert again.adapted(rec.u[:100], rec.y[:100], rec.dt) == pr.model


def test_bad_options_are_refused():
    for item, needle in (({"effect": "gp_torque", "axis": "yaw", "length_scale": 0.0}, "length_scale"),
                         ({"effect": "gp_torque", "axis": "yaw", "project": "x"}, "project"),
                         ({"effect": "gp_torque", "axis": "yaw", "form": "x"}, "form"),
                         ({"effect": "gp_torque", "axis": "yaw", "width": 1}, "width")):  # fmt: skip
        with pytest.raises(ParameterError, match=needle):
            build_model([item])



def test_a_users_priors_from_the_unadapted_model_are_kept_and_completed():
    # the CLI builds priors before the record is read; the values at the voltage pairs that
    # the term creates when it adapts get their declared prior, the user's choices stay
    from heli_uq.model.prior import Prior
    from heli_uq.probability import PriorSet

    rec = _record()
    model = build_model([{"effect": "gp_torque", "axis": "yaw", "length_scale": LENGTH}])
    priors = PriorSet.default(model).updated(model, {"gp_tau_yaw": Prior("halfnormal", 0.003),
                                                     "m": Prior("fixed", RIG_FIT["m"])})  # fmt: skip
    pr = make_problem(rec, (0.0, 45.0), (45.0, 60.0), model=model, priors=priors, error="iid")
    assert pr.priors.params["gp_tau_yaw"].describe() == Prior("halfnormal", 0.003).describe()
    assert not pr.priors.params["m"].free
    value_names = [n for n in pr.model.names if n.startswith(("gp_f_", "gp_z_"))]
    assert len(value_names) == pr.model.effects[-1].n_pairs > 0
    assert list(pr.priors.params) == list(pr.model.names)
    # a pair's value is not a name before the record is read: the refusal says why
    with pytest.raises(ParameterError, match=r"unknown name 'gp_f_0_yaw'.*gp_torque\(yaw\) gets more "
                                             "parameters from the record"):  # fmt: skip
        PriorSet.default(model).updated(model, {"gp_f_0_yaw": Prior("fixed", 0.01)})
    with pytest.raises(ParameterError, match=r"unknown name 'bogus'; expected one of [^(]*$"):
        PriorSet.default(build_model([])).updated(build_model([]), {"bogus": Prior("fixed", 0.01)})


def test_fixing_the_amplitude_at_zero_is_one_clear_line_in_the_centred_form(tmp_path, capsys):
    # the centred values' joint prior N(0, tau^2 K_tt) has no density at tau = 0: refused where
    # the priors meet the adapted model, not a numpyro "no valid initial parameters" traceback
    import json

    from heli_uq.cli import main

    csv = _record(seconds=20.0).to_csv(tmp_path / "rec.csv")
    codes = {}
    for form in ("centred", "whitened"):
        spec = tmp_path / f"{form}.json"
        spec.write_text(json.dumps({"effects": [{"effect": "gp_torque", "axis": "yaw", "form": form}]}))
        argv = ["sample", "--data", str(csv), "--model-file", str(spec), "--train", "0:14", "--test", "14:20",
                "--fix", "gp_tau_yaw=0", "--sampler", "prior", "--draws", "20", "--out", str(tmp_path / form)]
        codes[form] = main(argv)
        if form == "centred":
            err = capsys.readouterr().err.strip()
            assert len(err.splitlines()) == 1 and "gp_tau_yaw fixed at 0" in err
    assert codes == {"centred": 2, "whitened": 0}  # the whitened form at tau = 0 is a model without it


def test_the_posterior_stores_the_gp_torque_at_its_pairs():
    # per draw, at the training pairs the stored torque of a term without projection is the
    # centred values themselves (to the nugget); the pairs and their "fitted" flags are coords
    import arviz as az

    from heli_uq.output.inference_data import _add_gp_torques

    _, pr = _problem("none", "centred")
    term = pr.model.effects[-1]
    samples = pr.priors.draw(pr.model, np.random.default_rng(2), (2, 3))
    idata = az.from_dict(posterior=samples)
    _add_gp_torques(idata, pr, samples)
    torque = idata.posterior["gp_torque_yaw"]
    assert torque.dims == ("chain", "draw", "gp_pair_yaw") and torque.attrs["units"] == "N m"
    pairs = np.asarray(term.reference)
    np.testing.assert_array_equal(torque["gp_pair_yaw_u_theta"], pairs[:, 0])
    np.testing.assert_array_equal(torque["gp_pair_yaw_u_psi"], pairs[:, 1])
    fitted = np.asarray(torque["gp_pair_yaw_fitted"])
    assert fitted.sum() == term.n_fitted and fitted[: term.n_fitted].all()
    f = np.stack([samples[n] for n in term.joint_names()], axis=-1)  # (2, 3, t)
    scale = np.abs(f).max()
    np.testing.assert_allclose(np.asarray(torque)[..., : term.n_fitted], f, atol=1e-4 * scale)
