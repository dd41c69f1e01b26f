"""Identifiability: structural null space vs derivation, FIM vs Hessian, profile classes, contraction."""

import json

import arviz as az
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from heli_uq.cli import main
from heli_uq.identifiability.contraction import contraction, draws_in_w
from heli_uq.identifiability.fisher import WhitenedResiduals, fisher_information, fit_likelihood
from heli_uq.identifiability.profiles import THRESHOLD_95
from heli_uq.identifiability.report import profile_coordinates
from heli_uq.identifiability.structural import (
    ParameterVector,
    analytic_null_directions,
    random_points,
    structural_analysis,
)
from heli_uq.model import TABLE1, HeliModel
from heli_uq.simulation import simulate, synthetic_experiment

#: Invariances are exact in exact arithmetic: simulations along them agree to round-off.
INVARIANCE_TOL = 1e-10
#: Derived and computed null spaces: largest sine of the principal angles.
SUBSPACE_TOL = 1e-8
#: Gauss-Newton FIM vs exact Hessian at a zero-residual point (relative Frobenius error).
HESSIAN_RTOL = 1e-6
#: Exact contraction along a null direction with an isotropic prior on its coordinates.
NULL_CONTRACTION_TOL = 1e-6

PAPER = HeliModel()
FREE_ALL = tuple(n for n in TABLE1 if n != "g")
FREE_H0 = tuple(n for n in FREE_ALL if n != "h")


@pytest.fixture(scope="module")
def record():
    return synthetic_experiment(duration=3.0, seed=5, noise_std=(0.005, 0.005))


def _w(pv, params, rec):
    return pv.from_model(params, [rec.y[0, 0], rec.y[0, 1], 0.0, 0.0])


def _angles(params, rec, x0=None):
    x0 = [-0.5, 0.0, 0.0, 0.0] if x0 is None else x0
    return np.asarray(simulate(params, x0, rec.u, rec.dt))[:, :2]


def test_common_scaling_leaves_angles_unchanged(record):
    params = dict(TABLE1, h=0.004)
    scaled = {n: v * (3.7 if n in ("m", "J_bc", "J_s") or n[0] in "KD" else 1.0)
              for n, v in params.items()}  # fmt: skip
    assert np.max(np.abs(_angles(params, record) - _angles(scaled, record))) < INVARIANCE_TOL


def test_rc_m_jbc_trade_is_invisible_only_when_h_is_zero(record):
    def traded(p, a):
        q = dict(p, m=p["m"] * a, r_c=p["r_c"] / a)
        q["J_bc"] = p["J_bc"] + p["m"] * p["r_c"] ** 2 - q["m"] * q["r_c"] ** 2
        return q

    p0 = dict(TABLE1, h=0.0)
    assert np.max(np.abs(_angles(p0, record) - _angles(traded(p0, 1.3), record))) < INVARIANCE_TOL
    p1 = dict(TABLE1, h=0.004)
    assert np.max(np.abs(_angles(p1, record) - _angles(traded(p1, 1.3), record))) > 1e3 * INVARIANCE_TOL


def test_structural_rank_with_h_free_is_one_short_by_the_common_scaling(record):
    pv = ParameterVector(PAPER, FREE_ALL, dict(TABLE1, h=0.004))
    w = _w(pv, pv.base, record)
    pts = random_points(pv, w, record.u, record.dt, 3, seed=1)
    st = structural_analysis(pv, pts, record.u, record.dt)
    assert st.rank == pv.dim - 1 and st.ranks == (pv.dim - 1,) * 3
    (d,) = st.null_directions
    assert d["key"] == "common_scaling"
    v = np.array([d["loadings"][n] for n in pv.names])
    scaled = {"m", "J_bc", "J_s", "K_theta_theta", "K_theta_psi", "K_psi_theta", "K_psi_psi",
              "D_theta", "D_psi"}  # fmt: skip
    expected = np.array([1.0 if n in scaled else 0.0 for n in pv.names]) / 3.0
    assert np.max(np.abs(v - expected)) < SUBSPACE_TOL
    basis = st.null_basis[:, 0]
    assert abs(abs(basis @ expected) - 1.0) < SUBSPACE_TOL  # the raw SVD null vector too
    lo, hi = st.gap()
    assert lo < st.rtol < hi


def test_structural_null_space_with_h_fixed_at_zero_is_two_dimensional(record):
    pv = ParameterVector(PAPER, FREE_H0, dict(TABLE1, h=0.0))
    w = _w(pv, pv.base, record)
    pts = random_points(pv, w, record.u, record.dt, 3, seed=2)
    st = structural_analysis(pv, pts, record.u, record.dt)
    assert st.rank == pv.dim - 2
    derived = np.column_stack([v for _, v, _ in analytic_null_directions(pv, w)])
    q, _ = np.linalg.qr(derived)
    sines = np.linalg.svd(st.null_basis - q @ (q.T @ st.null_basis), compute_uv=False)
    assert np.max(sines) < SUBSPACE_TOL
    assert [d["key"] for d in st.null_directions] == ["common_scaling", "rc_m_Jbc_trade"]
    leaks = {c["name"]: c["null_leak"] for c in st.combinations}
    assert leaks["m g r_c / M11 [1/s^2]"] < SUBSPACE_TOL and leaks["J_s / M11"] < SUBSPACE_TOL
    assert leaks["m (r_c^2 + h^2) / M11"] > 1e-3  # identified only through h != 0


def test_fisher_information_equals_hessian_at_zero_residual():
    rec = synthetic_experiment(duration=2.0, seed=7, noise_std=(0.0, 0.0))
    pv = ParameterVector(PAPER, ("J_s", "K_theta_theta", "K_psi_psi", "D_theta"), dict(TABLE1),
                         include_x0=False)  # fmt: skip
    res = WhitenedResiduals(pv, rec.u, rec.y, rec.dt, np.array([0.01, 0.02]),
                            np.array([0.5, 0.8]), x0=np.array([-0.5, 0.0, 0.0, 0.0]))  # fmt: skip
    w = pv.from_model(TABLE1)
    fim = fisher_information(res, w)
    f = (fim.eigenvectors * fim.eigenvalues) @ fim.eigenvectors.T
    hess = np.asarray(jax.hessian(lambda v: 0.5 * jnp.sum(res(v) ** 2))(jnp.asarray(w)))
    assert np.linalg.norm(f - hess) / np.linalg.norm(hess) < HESSIAN_RTOL


@pytest.mark.slow
def test_profiles_classify_identifiable_practical_and_structural():
    rec = synthetic_experiment(duration=2.0, seed=3, noise_std=(0.05, 0.05))
    x0 = np.array([-0.5, 0.0, 0.0, 0.0])
    # J_s: weak on a 2 s record with 0.05 rad noise -> bounded on one side only.
    pv = ParameterVector(PAPER, ("J_s", "K_theta_theta", "D_theta"), dict(TABLE1), include_x0=False)
    fit = fit_likelihood(pv, rec.u, rec.y, rec.dt, [pv.from_model(TABLE1)], error="iid", x0=x0)
    prof = {p.name: p for p in profile_coordinates(pv, fit, prior_mean=pv.from_model(TABLE1),
                                                    prior_sd=np.full(pv.dim, 2.0))}  # fmt: skip
    assert prof["K_theta_theta"].classification == "identifiable"
    lo, hi = prof["K_theta_theta"].ci95
    assert lo < np.log(TABLE1["K_theta_theta"]) < hi
    assert prof["J_s"].classification == "practically_non_identifiable"
    assert np.max(prof["J_s"].delta) > THRESHOLD_95  # rises ...
    assert (prof["J_s"].lower is None) != (prof["J_s"].upper is None)  # ... on one side only

    # With r_c fixed, the scaled group has exactly one null direction: flat profiles.
    free = ("m", "J_bc", "J_s", "K_theta_theta", "K_theta_psi", "K_psi_theta", "K_psi_psi",
            "D_theta", "D_psi")  # fmt: skip
    pv2 = ParameterVector(PAPER, free, dict(TABLE1), include_x0=False)
    fit2 = fit_likelihood(pv2, rec.u, rec.y, rec.dt, [pv2.from_model(TABLE1)], error="iid", x0=x0)
    st = structural_analysis(pv2, [fit2.w], rec.u, rec.dt, x0=x0)
    prof2 = profile_coordinates(pv2, fit2, prior_mean=pv2.from_model(TABLE1),
                                prior_sd=np.full(pv2.dim, 2.0), null_basis=st.null_basis)  # fmt: skip
    k = next(p for p in prof2 if p.name == "K_theta_theta")
    assert k.classification == "structurally_non_identifiable" and k.ci95 is None


def test_contraction_along_a_null_direction_is_zero_and_reads_a_posterior(tmp_path, record):
    import arviz as az

    pv = ParameterVector(PAPER, FREE_ALL, dict(TABLE1, h=0.004))
    w = _w(pv, pv.base, record)
    res = WhitenedResiduals(pv, record.u, record.y, record.dt, np.array([0.005, 0.005]))
    fim = fisher_information(res, w)
    prior_sd = np.r_[np.full(len(pv.free), 2.0), np.full(4, 0.1)]
    prior_sd[pv.names.index("h")] = 0.01
    f = (fim.eigenvectors * fim.eigenvalues) @ fim.eigenvectors.T
    cov = np.linalg.inv(f + np.diag(prior_sd**-2.0))
    (v,) = [vec for key, vec, _ in analytic_null_directions(pv, w) if key == "common_scaling"]
    per, (along,) = contraction(cov, prior_sd, [v])
    assert abs(along) < NULL_CONTRACTION_TOL
    assert per[pv.names.index("theta0")] > 0.9

    rng = np.random.default_rng(0)
    draws = {n: rng.normal(size=(2, 500)) * 0.1 + (0.0 if n == "h" else 1.0) for n in pv.names}
    draws = {n: (np.exp(d) if pv.is_log(n) else d) for n, d in draws.items()}
    got = draws_in_w(az.from_dict(posterior=draws).posterior, pv)
    assert got.shape == (1000, pv.dim)
    assert np.allclose(np.std(got, axis=0), 0.1, rtol=0.1)


def test_a_posterior_contracts_against_the_prior_it_was_sampled_under():
    """The sampler's prior spreads the inertia-scaled parameters along the common scale far
    more than their declared priors taken one by one (README, "Posterior"), so a posterior
    that the data leave spread along that null direction looked *wider than its prior*
    against the declared priors, and the cross-check failed it as unconverged (contraction
    -10.4 on a 10 s record).  Against its file's prior draws (the joint prior; the initial
    state, which that group lacks, at its declared prior) it does not contract there, and a
    coordinate the data fix still contracts."""
    from heli_uq.identifiability.contraction import MIN_PRIOR_DRAWS, sampled_prior_cov
    from heli_uq.identifiability.cross_check import CONTRACTION_LOW, CONTRACTION_WIDER

    pv = ParameterVector(PAPER, FREE_ALL, dict(TABLE1, h=0.004))
    rng = np.random.default_rng(1)
    declared = np.r_[np.full(len(pv.free), 0.5), np.full(4, 0.1)]  # sd in w
    declared[pv.names.index("h")] = 0.01
    scaled = [n for n in pv.free if pv.is_log(n)]
    common = np.ones(pv.dim) * 0.0
    common[[pv.names.index(n) for n in scaled]] = 1.0 / np.sqrt(len(scaled))
    n = 2000
    scale = rng.normal(0.0, 2.0, n)  # the common scale's own prior: sd 2 in log

    def group(spread):  # draws (in w) -> a posterior or prior group by name
        w = spread + np.outer(scale, common) * np.sqrt(len(scaled))
        return az.from_dict(posterior={name: (np.exp(w[:, j]) if pv.is_log(name) else w[:, j])[None]
                                       for j, name in enumerate(pv.names)
                                       if not name.endswith("0")}).posterior  # fmt: skip

    prior = group(rng.normal(size=(n, pv.dim)) * declared)
    post_spread = rng.normal(size=(n, pv.dim)) * declared * 0.3  # the data narrow every ratio
    posterior = np.asarray(post_spread + np.outer(scale, common) * np.sqrt(len(scaled)))
    cov_post = np.cov(posterior, rowvar=False)

    _, (against_declared,) = contraction(cov_post, declared, [common])
    assert against_declared < CONTRACTION_WIDER  # the false alarm
    cov = sampled_prior_cov(prior, pv, declared)
    per, (along,) = contraction(cov_post, declared, [common], prior_cov=cov)
    assert abs(along) < CONTRACTION_LOW  # a null direction the data leave alone
    theta0 = pv.names.index("theta0")  # not in the prior group: its declared variance
    assert cov[theta0, theta0] == pytest.approx(declared[theta0] ** 2)
    assert per[theta0] > 0.5 and per[pv.names.index("h")] > 0.5
    thin = group(rng.normal(size=(n, pv.dim)) * declared).isel(draw=slice(MIN_PRIOR_DRAWS - 1))
    assert sampled_prior_cov(thin, pv, declared) is None  # too few draws: the declared priors


@pytest.mark.slow
def test_cli_identifiability_writes_report(tmp_path, capsys):
    rec = synthetic_experiment(duration=2.0, seed=3, noise_std=(0.02, 0.02))
    csv = rec.to_csv(tmp_path / "rec.csv")
    out = tmp_path / "ident"
    code = main(["identifiability", "--data", str(csv), "--free", "m,J_bc,J_s,K_theta_theta,"
                 "K_theta_psi,K_psi_theta,K_psi_psi,D_theta,D_psi", "--error", "iid",
                 "--points", "2", "--quiet", "--out", str(out)])  # fmt: skip
    assert code == 0
    text = capsys.readouterr().out
    assert "structural rank 12 of 13" in text and "common_scaling" in text
    r = json.loads((out / "identifiability.json").read_text())
    assert r["structural"]["rank"] == 12 and r["structural"]["n_parameters"] == 13
    assert set(r["practical"]["profiles"]) == set(r["parameters"])
    assert r["practical"]["profiles"]["D_psi"]["classification"] == "structurally_non_identifiable"
    assert r["practical"]["profiles"]["theta0"]["classification"] == "identifiable"
    assert abs(r["bayesian"]["contraction_along_null_directions"]["common_scaling"]) < 0.1
    md = (out / "identifiability.md").read_text()
    assert "common_scaling" in md and "Cross-check" in md
    for fig in r["figures"]:
        assert (out / fig).stat().st_size > 10_000


@pytest.mark.parametrize("argv, message", [
    (["--free", "m,bogus"], "bogus"),
    (["--posterior", "nope/posterior.nc"], "no such file"),
    (["--points", "0"], "--points"),
])  # fmt: skip
def test_cli_identifiability_bad_input_is_one_line(tmp_path, capsys, argv, message):
    rec = synthetic_experiment(duration=1.0, seed=3)
    csv = rec.to_csv(tmp_path / "rec.csv")
    code = main(["identifiability", "--data", str(csv), *argv, "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and message in err and len(err.splitlines()) == 1


def _gp_model(length_scale=0.15):
    from heli_uq.model import build_model

    return build_model([{"effect": "gp_torque", "axis": "yaw", "length_scale": length_scale}])


def test_a_models_specification_leaves_out_what_it_took_from_a_record():
    # a GP adapted to two spans holds different voltage pairs, but is the model a user gave
    rec = synthetic_experiment(duration=20.0, seed=3, inputs="rig_steps")
    a = _gp_model().adapted(rec.u[:800], rec.y[:800], rec.dt, rec.u)
    b = _gp_model().adapted(rec.u[:1500], rec.y[:1500], rec.dt, rec.u[:1500])
    assert a.describe() != b.describe()
    assert a.specification() == b.specification() == _gp_model().specification()
    assert _gp_model(0.3).specification() != a.specification()
    assert a.describe()["effects"][0]["reference"] and "reference" not in a.specification()["effects"][0]


def test_cli_identifiability_refuses_a_posterior_of_another_model_in_one_line(tmp_path, capsys):
    import arviz as az

    rec = synthetic_experiment(duration=1.0, seed=3)
    csv = rec.to_csv(tmp_path / "rec.csv")
    adapted = _gp_model().adapted(rec.u, rec.y, rec.dt)
    idata = az.from_dict(posterior={"m": np.ones((1, 4))})
    idata.posterior.attrs["model"] = json.dumps(adapted.describe())
    idata.to_netcdf(tmp_path / "posterior.nc")
    other = tmp_path / "gp.json"
    other.write_text(json.dumps({"effects": [{"effect": "gp_torque", "axis": "yaw", "length_scale": 0.3}]}))
    code = main(["identifiability", "--data", str(csv), "--model-file", str(other), "--posterior",
                 str(tmp_path / "posterior.nc"), "--out", str(tmp_path / "o")])  # fmt: skip
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1
    assert '"length_scale": 0.15' in err and '"length_scale": 0.3' in err


@pytest.mark.slow
def test_cli_identifiability_reads_a_gp_posterior_on_the_model_it_was_fitted_with(tmp_path, capsys):
    """The path a user takes: a GP model's posterior, then its identifiability report with
    the same ``--effects``.  The posterior's model is adapted to its training window (its
    voltage pairs, here one fitted and one new), the user's is not; until the thirty-sixth
    session this was always refused.  The report runs on the posterior's model, so its
    parameters are the posterior's and its Bayesian part reads its draws.  The posterior
    is written as ``heli-uq sample --effects yaw:gp_torque --train 0:2 --test 2:3`` writes
    its model (the draws: small spreads around the start values, not a sampler's)."""
    from heli_uq.model import X0_NAMES, build_model
    from heli_uq.probability import make_problem

    rec = synthetic_experiment(duration=3.0, seed=4, noise_std=(0.003, 0.008))
    csv = rec.to_csv(tmp_path / "rec.csv")
    model = make_problem(rec, (0.0, 2.0), (2.0, 3.0), model=build_model(["yaw:gp_torque"]), error="iid").model
    centre = {**model.start_values(), **dict(zip(X0_NAMES, [*rec.y[0], 0.0, 0.0], strict=True))}
    rng = np.random.default_rng(0)
    spread = {n: 0.01 * rng.standard_normal((2, 10)) for n in centre}
    draws = {n: v * np.exp(spread[n]) if v > 0 else v + spread[n] for n, v in centre.items()}
    # a prior group as 'sample' writes it: 500 draws of the model parameters, none of x0
    wide = {n: 0.5 * rng.standard_normal((1, 500)) for n in model.start_values()}
    prior = {n: centre[n] * np.exp(wide[n]) if centre[n] > 0 else centre[n] + wide[n] for n in wide}
    idata = az.from_dict(posterior=draws, prior=prior)
    idata.posterior.attrs["model"] = json.dumps(model.describe())
    idata.to_netcdf(tmp_path / "posterior.nc")
    out = tmp_path / "ident"
    assert main(["identifiability", "--data", str(csv), "--effects", "yaw:gp_torque", "--posterior",
                 str(tmp_path / "posterior.nc"), "--points", "1", "--quiet", "--out", str(out)]) == 0, \
        capsys.readouterr().err  # fmt: skip
    r = json.loads((out / "identifiability.json").read_text())
    assert {n for n in r["parameters"] if n.startswith("gp_")} == {"gp_tau_yaw", "gp_f_0_yaw", "gp_z_1_yaw"}
    # measured against the prior it was sampled under (its file's prior group), and the
    # report says the posterior failed its health checks (ESS of 2 x 10 draws)
    assert r["bayesian"]["source"].startswith("MCMC draws of the given posterior, against its file's "
                                              "prior draws")  # fmt: skip
    assert "(UNCONVERGED: " in r["bayesian"]["source"]
    assert "bulk ESS" in r["bayesian"]["source"] and "WARNING: UNCONVERGED" in capsys.readouterr().err


def test_cli_identifiability_refuses_a_posterior_of_other_data_in_one_line(tmp_path, capsys):
    """A posterior names the data it was sampled on (its training window and their sha256):
    a report on another record, or on a window without that span, is refused in one line;
    on the same record, with a window that holds the span, the check passes."""
    from heli_uq.identifiability.report import check_posterior_data
    from heli_uq.probability import make_problem
    from heli_uq.probability.problem import training_data

    sampled = synthetic_experiment(duration=2.0, seed=3)
    other = synthetic_experiment(duration=2.0, seed=4)
    idata = az.from_dict(posterior={"m": np.ones((1, 4))})
    idata.posterior.attrs.update({"model": json.dumps(PAPER.describe()), "source": "a.csv",
                                  **training_data(make_problem(sampled, (0.0, 1.0), error="iid"))})
    idata.to_netcdf(tmp_path / "posterior.nc")
    check_posterior_data(idata.posterior, sampled)  # passes: no error
    check_posterior_data(idata.posterior, sampled.window(0.0, 1.5))
    for rec, window, why in ((other, [], "this record's samples there differ"),
                             (sampled, ["--window", "0.5:2"], "this record does not hold that window")):
        csv = rec.to_csv(tmp_path / "rec.csv")
        code = main(["identifiability", "--data", str(csv), *window, "--posterior",
                     str(tmp_path / "posterior.nc"), "--out", str(tmp_path / "o")])  # fmt: skip
        err = capsys.readouterr().err.strip()
        assert code == 2 and len(err.splitlines()) == 1, err
        assert "sampled on 0-1 s of a.csv" in err and why in err, err


#: Relative tolerance of a sample variance from PRECISION_DRAWS draws (its sd is sqrt(2/n) = 0.6 %).
VARIANCE_RTOL = 0.03
PRECISION_DRAWS = 50_000


def test_laplace_draws_of_an_ill_conditioned_precision_have_its_inverse_as_covariance():
    """The report's Laplace draws come from ``F + prior precision`` without inverting it.
    Inverted, a network model's (condition ~1e16) gave a covariance numpy called "not
    positive semi-definite", and draws from it.  Here the precision of a rank-one Fisher
    matrix of size 1e12 plus a unit prior: along the data direction the variance is
    1 / (1e12 + 1), across it 1."""
    import warnings

    from heli_uq.identifiability.fisher import precision_draws

    rng = np.random.default_rng(0)
    q, _ = np.linalg.qr(rng.standard_normal((4, 4)))
    data, other = q[:, 0], q[:, 1:]
    precision = 1e12 * np.outer(data, data) + np.eye(4)
    mean = np.array([1.0, -2.0, 0.5, 3.0])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        draws = precision_draws(mean, precision, PRECISION_DRAWS, seed=1)
    centred = draws - mean
    np.testing.assert_allclose(np.var(centred @ data), 1.0 / (1e12 + 1.0), rtol=VARIANCE_RTOL)
    np.testing.assert_allclose(np.var(centred @ other, axis=0), 1.0, rtol=VARIANCE_RTOL)
    np.testing.assert_allclose(draws.mean(axis=0), mean, atol=5 * np.sqrt(1.0 / PRECISION_DRAWS))
    # a general precision: the draws' covariance is its inverse
    a = rng.standard_normal((4, 4))
    precision = a @ a.T + 0.5 * np.eye(4)
    cov = np.cov(precision_draws(np.zeros(4), precision, PRECISION_DRAWS, seed=2), rowvar=False)
    np.testing.assert_allclose(cov @ precision, np.eye(4), atol=0.05)


def test_a_posterior_wider_than_its_prior_fails_the_cross_check():
    """Conditioning on data narrows a Gaussian prior in every direction: a contraction
    below CONTRACTION_WIDER (the helper's unconverged posterior of another record gave
    -6.19 along the common scaling) disagrees, on a null direction and on a coordinate,
    while Monte Carlo noise just below zero does not."""
    from types import SimpleNamespace

    from heli_uq.identifiability.cross_check import CONTRACTION_WIDER, cross_check

    structural = {"null_directions": [{"key": "common_scaling", "loadings": {"a": 0.7, "b": 0.7}}]}
    profiles = [SimpleNamespace(name=n, flat=True, classification="structurally_non_identifiable",
                                lower=None, upper=None) for n in ("a", "b")]  # fmt: skip

    def agree(c):
        rows = cross_check(["a", "b"], structural, profiles, np.array([c, 0.0]), np.array([c]))
        return [r["agree"] for r in rows], rows[0]["detail"]

    assert agree(-0.05)[0] == [True, True, True]
    flags, detail = agree(CONTRACTION_WIDER - 0.01)
    assert flags == [False, False, True] and "wider than the prior" in detail
