"""The Bayesian hybrid model end to end: ``heli-uq sample --model hybrid`` on a synthetic
record with a hidden input nonlinearity (a quadratic yaw thrust) gives a posterior whose
network torque, stored on the record's voltage pairs, recovers that nonlinearity's curve
within its band; so does the posterior of a Gaussian-process torque (``gp_torque``, centred
form), which converges; convergence is reported on the torque and, separately, on the
weights; bad network options fail in one line; a network that blows up is a rejected
proposal."""

import json

import arviz as az
import jax.numpy as jnp
import numpy as np
import pytest

from heli_uq.cli import main
from heli_uq.inference.density import log_density_setup
from heli_uq.model import RIG_FIT, RIG_FIT_X0, build_model, model_from_description
from heli_uq.probability import make_problem
from heli_uq.simulation import synthetic_experiment

#: The hidden nonlinearity: a quadratic yaw thrust k_q u_psi |u_psi| [N m/V^2].
K_Q = 0.05
#: Pairs whose truth must lie inside the network torque's central 90 % interval.
COVERED_FRACTION = 0.8
#: Correlation of the posterior-mean network acceleration with the truth over the pairs.
CURVE_CORRELATION = 0.9
#: A short record of random 0.5-3 s voltage steps: many distinct voltage pairs.
SECONDS = 20.0


def _truth_record():
    model = build_model([{"effect": "quadratic_thrust", "axis": "yaw"}])
    values = {**RIG_FIT, "k_q_yaw": K_Q}
    rec = synthetic_experiment(values, RIG_FIT_X0, duration=SECONDS, inputs="steps", seed=5,
                               noise_std=(0.003, 0.008), model=model)  # fmt: skip
    return rec, model, values


#: The long tier's NUTS run over every weight (2 chains): at 2 x (100 + 100), the size CI
#: could afford, R-hat on the torque was 1.17; at this size 1.06 (measured 2026-11-26).
LONG_WARMUP, LONG_DRAWS = 400, 300
#: The chains must agree on the network's acceleration to this R-hat (Gelman's classic
#: 1.1): the strict 1.01 of the health checks is not reached at this size, and the run is
#: flagged UNCONVERGED (its trees fill depth 8); with the mass fixed (plain log coordinates,
#: before 2026-11-26) the same run stood at 1.9.
RHAT_TORQUE_LONG = 1.1


# Session scope: ``--dist loadgroup`` sends both tests to one worker, but not necessarily
# one after the other, and a module fixture would be computed again after other modules.
@pytest.fixture(scope="session")
def hybrid_run(tmp_path_factory):
    rec, model, values = _truth_record()
    tmp = tmp_path_factory.mktemp("hybrid")
    path = rec.to_csv(tmp / "rec.csv")
    out = tmp / "out"
    # every inertia free: the identifiable coordinates integrate the common scale out, and
    # the record fixes the network's torque over the yaw inertia, an acceleration
    code = main(["sample", "--data", str(path), "--model", "hybrid", "--nn-posterior", "full",
                 "--hidden", "2", "--error", "iid", "--chains", "2", "--warmup", str(LONG_WARMUP),
                 "--draws", str(LONG_DRAWS), "--no-progress", "--out", str(out)])  # fmt: skip
    return code, out, rec, model, values


@pytest.mark.slow
@pytest.mark.long
@pytest.mark.xdist_group("hybrid_posterior")
def test_hybrid_posterior_recovers_the_hidden_curve(hybrid_run):
    """The network's yaw acceleration (its torque over each draw's yaw inertia) against
    the truth's part orthogonal to the gains: inside the 90 % band at most voltage pairs,
    and the posterior mean follows its shape."""
    from heli_uq.output.network import axis_inertia

    code, out, rec, model, values = hybrid_run
    assert code == 0
    idata = az.from_netcdf(out / "posterior.nc")
    torque = np.asarray(idata.posterior["nn_torque_yaw"])
    accel = torque.reshape(-1, torque.shape[-1]) / axis_inertia(idata, "yaw")[:, None]
    ut = np.asarray(idata.posterior["nn_point_yaw_u_theta"])
    up = np.asarray(idata.posterior["nn_point_yaw_u_psi"])
    pairs, counts = np.unique(rec.u, axis=0, return_counts=True)
    assert sorted(zip(ut, up)) == sorted(map(tuple, pairs))
    # the truth's acceleration at the pairs (at the reference pitch axis_inertia uses), minus
    # its weighted fit on (u_theta, u_psi): the part a network projected off the linear gains
    # can hold (independent of the package's projection)
    _assert_curve_recovered(accel, _projected_truth(model, values, idata, ut, up, pairs, counts))


def _projected_truth(model, values, idata, ut, up, pairs, counts):
    """The truth's yaw acceleration at the pairs ``(ut, up)`` [rad/s^2] (its torque over
    ``M22`` at the reference pitch :func:`axis_inertia` uses), minus its weighted fit on
    ``(u_theta, u_psi)`` (weights: samples held): the part a torque projected off the
    linear gains can hold (independent of the package's projection)."""
    from heli_uq.model.terms.rigid_body import yaw_inertia
    from heli_uq.output.network import reference_pitch

    p = model.complete(values)
    term = model.effects[0]
    zero = jnp.zeros(2)
    m22 = float(yaw_inertia(values, reference_pitch(idata)))
    true = np.array([float(term(p, zero, zero, jnp.array([a, b]))[1]) for a, b in zip(ut, up)]) / m22
    w = np.array([counts[np.flatnonzero((pairs == [a, b]).all(1))[0]] for a, b in zip(ut, up)], float)
    basis = np.column_stack([ut, up])
    beta = np.linalg.lstsq(basis * np.sqrt(w)[:, None], true * np.sqrt(w), rcond=None)[0]
    return true - basis @ beta


def _assert_curve_recovered(accel, true_proj):
    """Draws ``accel`` (S, k) hold ``true_proj`` (k,) in their central 90 % at most pairs,
    and their mean follows its shape."""
    lo, hi = np.quantile(accel, [0.05, 0.95], axis=0)
    inside = (lo <= true_proj) & (true_proj <= hi)
    assert inside.mean() >= COVERED_FRACTION, (lo, hi, true_proj)
    assert np.corrcoef(accel.mean(0), true_proj)[0, 1] >= CURVE_CORRELATION


#: The GP posterior's size (2 chains): its centred form passes every health check at it
#: (at 2 x (300 + 300) only the tail ESS fell short, 286 < 400; the whitened form, at this
#: size, had 21 divergences in 2.6x the time: studies/notes/hybrid.md).
GP_WARMUP, GP_DRAWS = 300, 600


@pytest.mark.slow
@pytest.mark.long
def test_gp_torque_posterior_converges_and_recovers_the_hidden_curve(tmp_path):
    """The GP torque's yaw acceleration at the record's voltage pairs (``gp_torque_yaw``
    of the posterior), from each draw, against the truth's part orthogonal to the gains;
    and every health check passes (R-hat, ESS, no divergence)."""
    from heli_uq.output import sample_posterior
    from heli_uq.output.network import axis_inertia

    rec, model, values = _truth_record()
    gp_model = build_model([{"effect": "gp_torque", "axis": "yaw"}])
    idata, summary = sample_posterior(rec, tmp_path, model=gp_model, error="iid", chains=2,
                                      warmup=GP_WARMUP, draws=GP_DRAWS, progress=False)  # fmt: skip
    assert summary["health"]["flags"] == [], summary["health"]
    assert summary["divergences"] == 0
    # the posterior's GP torque at its voltage pairs (every pair is fitted: no test window),
    # checked against the term evaluated by hand at a few draws
    stored = idata.posterior["gp_torque_yaw"]
    ut, up = np.asarray(stored["gp_pair_yaw_u_theta"]), np.asarray(stored["gp_pair_yaw_u_psi"])
    assert np.asarray(stored["gp_pair_yaw_fitted"]).all()
    torque = np.asarray(stored).reshape(-1, stored.shape[-1])
    fitted = model_from_description(idata.posterior.attrs["model"])  # the adapted model
    term = fitted.effects[0]
    post = idata.posterior
    draws = {n: np.asarray(post[n]).ravel() for n in fitted.names if n in post}
    fixed = {n: v for n, v in fitted.complete(RIG_FIT).items() if n not in draws}
    for i in (0, torque.shape[0] // 2, torque.shape[0] - 1):
        prepared = fitted.prepare({**fixed, **{n: v[i] for n, v in draws.items()}})[1]
        by_hand = [float(term.torque(prepared, jnp.array([a, b]))) for a, b in zip(ut, up)]
        np.testing.assert_allclose(torque[i], by_hand, rtol=1e-9, atol=1e-12)
    accel = torque / axis_inertia(idata, "yaw")[:, None]
    pairs, counts = np.unique(rec.u, axis=0, return_counts=True)
    truth = _projected_truth(model, values, idata, ut, up, pairs, counts)
    _assert_curve_recovered(accel, truth)


@pytest.mark.slow
@pytest.mark.long
@pytest.mark.xdist_group("hybrid_posterior")
def test_hybrid_run_reports_convergence_on_the_torque_and_the_weights(hybrid_run):
    _, out, *_ = hybrid_run
    summary = json.loads((out / "summary.json").read_text())
    assert "rhat_max_network_torque" in summary and "rhat_max_network_weights" in summary
    assert summary["rhat_max"] >= summary["rhat_max_network_torque"]
    assert summary["rhat_max_network_torque"] <= RHAT_TORQUE_LONG
    worst = summary.get("worst_rhat_variable") or ""
    assert not worst.startswith(("nn_W_", "nn_b_", "nn_w_"))


#: Split R-hat of two chains that sample one distribution, with 500 draws each: at most
#: ~1.01 (Vehtari et al. 2021); of two chains 2 sd apart: far above.
RHAT_SAME, RHAT_APART = 1.02, 1.5


@pytest.mark.parametrize("torque_shift", [0.0, 2.0])
def test_convergence_is_judged_on_the_torque_not_the_weights(torque_shift):
    """Two chains in the two sign-mirrored modes of a network (hidden weight and output
    weight both flipped: the same torque): R-hat on the weights is huge, but it is reported
    beside the judged R-hat, not in it.  Where the chains' torques disagree
    (``torque_shift`` sd apart), the judged R-hat catches it."""
    import xarray as xr

    from heli_uq.output.diagnostics import convergence

    rng = np.random.default_rng(1)
    chains, draws, points = 2, 500, 3
    sign = np.array([1.0, -1.0])[:, None]
    torque = rng.normal(size=(chains, draws, points))
    torque[1] += torque_shift
    post = xr.Dataset({
        "K_psi_psi": (("chain", "draw"), rng.normal(size=(chains, draws))),
        "nn_W_0_0_yaw": (("chain", "draw"), sign * (1.0 + 0.1 * rng.normal(size=(chains, draws)))),
        "nn_w_0_yaw": (("chain", "draw"), sign * (0.5 + 0.1 * rng.normal(size=(chains, draws)))),
        "nn_torque_yaw": (("chain", "draw", "nn_point_yaw"), torque),
    }, attrs={"sampler_info": json.dumps({"sampler": "nuts", "max_tree_depth": 8})})  # fmt: skip
    stats = xr.Dataset({
        "diverging": (("chain", "draw"), np.zeros((chains, draws), bool)),
        "tree_depth": (("chain", "draw"), np.full((chains, draws), 3)),
        "n_steps": (("chain", "draw"), np.full((chains, draws), 7)),
        "energy": (("chain", "draw"), rng.normal(size=(chains, draws))),
    })
    out = convergence(az.InferenceData(posterior=post, sample_stats=stats))
    assert out["rhat_max_network_weights"] > RHAT_APART
    assert not (out["worst_rhat_variable"] or "").startswith(("nn_W_", "nn_b_", "nn_w_"))
    if torque_shift:
        assert out["rhat_max"] == out["rhat_max_network_torque"] > RHAT_APART
        assert not out["converged"]
    else:
        assert out["rhat_max"] < RHAT_SAME and out["rhat_max_network_torque"] < RHAT_SAME
        assert out["converged"]


@pytest.mark.parametrize("argv, needles", [
    (["--model", "hybrid", "--hidden", "0"], ["--hidden", "positive"]),
    (["--model", "hybrid", "--hidden", "100000"], ["hidden", "1..1024", "100000"]),
    (["--hidden", "4"], ["--hidden", "--model hybrid"]),
    (["--model", "hybrid", "--nn-axes", "roll"], ["--nn-axes", "roll"]),
])  # fmt: skip
def test_bad_network_options_fail_in_one_line(tmp_path, capsys, argv, needles):
    code = main(["sample", "--data", "experimental", *argv, "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err
    line = err.strip().splitlines()[-1]
    assert all(n in line for n in needles), line


def test_an_unknown_network_input_is_refused_by_the_parser(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["sample", "--model", "hybrid", "--nn-inputs", "u,x", "--out", str(tmp_path / "o")])
    assert exc.value.code == 2
    assert "--nn-inputs" in capsys.readouterr().err


def test_a_network_that_blows_up_is_a_rejected_proposal():
    """Huge output weights: the log density is far below the start's (1e6: a finite but
    hopeless misfit) or -inf (1e300: the solve overflows and fails), never NaN, so NUTS
    rejects the proposal instead of crashing."""
    rec, _, _ = _truth_record()
    model = build_model([{"effect": "neural_torque", "axis": "yaw", "hidden": 2}])
    problem = make_problem(rec.window(0.0, 5.0), model=model, error="iid")
    density = log_density_setup(problem)
    x = np.zeros(density.dim)
    good = float(density.potential_jit(x))
    sites = density.unravel(jnp.asarray(x))
    names = problem.coords.sampled_names
    def potential_with_output_weights(value):
        z = np.asarray(sites["z"]).copy()
        for i, n in enumerate(names):
            if "nn_w_" in n:
                z[i] = value
        return float(density.potential_jit(density.ravel({**sites, "z": jnp.asarray(z)})))

    assert np.isfinite(good)
    assert potential_with_output_weights(1e6) > good + 1e6
    assert potential_with_output_weights(1e300) == np.inf


def _fixed_mass_priors(model, values):
    from heli_uq.model.prior import Prior
    from heli_uq.probability import PriorSet

    return PriorSet.default(model).updated(model, {"m": Prior("fixed", values["m"])}, where="test")


#: Without the projection the yaw gain and the network's linear part must trade off at
#: least this strongly (correlation over draws; Laplace at the last layer's MAP).
TRADE_OFF_CORR = -0.5
#: A projected network's linear part, relative to the gain's sd: rounding only.
PROJECTED_LINEAR = 1e-9
#: The base model's V [rad^2] on the record from a good MAP: the noise floor is 7.3e-5, the
#: unmodelled quadratic thrust adds ~1e-4; the wrong basin the rig-fit start removes had 3.1.
BASE_V_MAX = 1e-3


@pytest.mark.slow
@pytest.mark.xdist_group("hybrid_posterior")  # one record and model: shared programs
def test_cli_hybrid_end_to_end_and_the_projection_removes_the_gain_network_trade_off(tmp_path):
    """``heli-uq sample --model hybrid`` at a tiny size (last layer, Laplace, the default
    projection) and the same hybrid without the projection, through the library.

    --nn-posterior last-layer: training from the base model's MAP lowers V, every hidden
    weight and bias is fixed at its trained value, the output weights stay free.

    The CLI run exits 0 and stores the network torque on a named grid of exactly the
    record's voltage pairs, its convergence beside the weights', and the bands figure.
    Without the projection the yaw gain K_psi_psi and the network's part along u_psi are
    anti-correlated over the draws and the gain's sd exceeds that of their sum (what the
    data fix); with it the network's linear part is zero and the gain carries the whole
    linear torque.

    The mass m is fixed at the truth (plain log coordinates).  With it, two cold starts of
    the base model's MAP both ended at V = 3.1 rad^2 on this record and the Laplace
    covariance came out non-finite; started from the rig fit too, the base fit is good and
    the last-layer posterior finite."""
    from heli_uq.output.last_layer import last_layer_setup
    from heli_uq.output.posterior_study import sample_posterior

    rec, _, values = _truth_record()
    path = rec.to_csv(tmp_path / "rec.csv")
    code = main(["sample", "--data", str(path), "--model", "hybrid", "--hidden", "2",
                 "--nn-posterior", "last-layer", "--sampler", "laplace", "--error", "iid",
                 "--fix", f"m={values['m']}", "--chains", "2", "--draws", "100", "--no-progress",
                 "--out", str(tmp_path / "u")])  # fmt: skip
    assert code == 0
    # the library half, step by step: the last layer's setup, then its posterior
    hybrid = build_model([{"effect": "neural_torque", "axis": "yaw", "hidden": 2, "project": "none"}])
    priors, guesses, info = last_layer_setup(rec, (0.0, SECONDS), None, model=hybrid, error="iid",
                                             priors=_fixed_mass_priors(hybrid, values))  # fmt: skip
    hidden = [n for n in hybrid.names if n.startswith(("nn_W_", "nn_b_"))]
    outputs = [n for n in hybrid.names if n.startswith("nn_w_")]
    assert hidden and outputs
    for n in hidden:  # fixed at the trained values, the MAP's first start
        assert not priors.params[n].free and priors.params[n].a == pytest.approx(guesses[0][n])
    assert all(priors.params[n].free for n in (*outputs, "J_s", "K_psi_psi"))
    sample_posterior(rec, tmp_path / "none", model=hybrid, priors=priors, guesses=guesses,
                     sampler="laplace", error="iid", chains=2, warmup=0, draws=100, progress=False,
                     n_starts=1)  # fmt: skip
    trade = {}
    for project in ("none", "u"):
        summary = json.loads((tmp_path / project / "summary.json").read_text())
        fit = info if project == "none" else summary["last_layer"]
        assert fit["v_base"] < BASE_V_MAX and fit["v_trained"] <= fit["v_base"]
        assert {"rhat_max_network_torque", "rhat_max_network_weights"} <= set(summary)
        post = az.from_netcdf(tmp_path / project / "posterior.nc").posterior
        assert "m" not in post and not any(n in post for n in hidden)  # fixed: not sampled
        assert all(n in post for n in outputs)
        assert np.all(np.isfinite(post["K_psi_psi"].values)) and float(post["K_psi_psi"].std()) > 0
        assert post["nn_torque_yaw"].dims == ("chain", "draw", "nn_point_yaw")
        stored = set(zip(post["nn_point_yaw_u_theta"].values, post["nn_point_yaw_u_psi"].values))
        assert stored == {tuple(q) for q in np.asarray(rec.u)}
        assert np.all(np.isfinite(post["nn_torque_yaw"].values))
        trade[project] = summary["gain_trade_off"]["yaw"]
        assert set(trade[project]) == {"u_theta", "u_psi"}
    assert (tmp_path / "u" / "bands.png").stat().st_size > 0
    free, projected = trade["none"]["u_psi"], trade["u"]["u_psi"]
    assert free["gain"] == "K_psi_psi"
    assert free["corr"] < TRADE_OFF_CORR
    assert free["sd_gain"] > free["sd_total"]
    for row in trade["u"].values():
        assert row["sd_linear"] <= PROJECTED_LINEAR * row["sd_gain"]
        assert np.isnan(row["corr"])  # undefined for a constant
    assert projected["sd_gain"] < free["sd_gain"]


def test_the_torque_at_voltage_pairs_the_training_window_never_holds():
    """A network of u is also stored at the span's voltage pairs outside the training window
    (``<axis>_unseen``): exactly the set difference of the pairs, and the same torque that
    the seen grid of a problem trained on the whole span gives at those pairs (with the
    term's input scaling and projection frozen at the split's, so it is one function)."""
    from heli_uq.output.network import UNSEEN, network_torques

    rec, _, _ = _truth_record()
    model = build_model([{"effect": "neural_torque", "axis": "yaw", "hidden": 2}])
    split = make_problem(rec, (0.0, 10.0), (10.0, SECONDS), model=model, error="iid")
    whole = make_problem(rec, (0.0, SECONDS), model=split.model, error="iid")
    rng = np.random.default_rng(3)
    names = [p.name for p in model.effects[0].parameters()]
    samples = {n: rng.normal(0.0, 0.5, size=(2, 3)) for n in names}
    samples["z"] = np.zeros((2, 3, 1))
    got = network_torques(split, samples)
    n = split.n_train
    train_pairs = {tuple(p) for p in np.asarray(rec.u)[:n]}
    test_pairs = {tuple(p) for p in np.asarray(rec.u)[n:len(split.u)]}
    torque, points = got["yaw" + UNSEEN]
    assert set(zip(points["u_theta"], points["u_psi"])) == test_pairs - train_pairs
    assert len(points["u_theta"]) > 0 and torque.shape == (2, 3, len(points["u_theta"]))
    ref, ref_points = network_torques(whole, samples)["yaw"]
    ref_pairs = list(zip(ref_points["u_theta"], ref_points["u_psi"]))
    columns = [ref_pairs.index(pair) for pair in zip(points["u_theta"], points["u_psi"])]
    np.testing.assert_allclose(torque, ref[..., columns], rtol=1e-12, atol=1e-15)
    assert "yaw" + UNSEEN not in network_torques(whole, samples)


#: Sampling error of the ratio of two median 90 % widths over 4000 Gaussian draws.
WIDTH_RATIO_TOL = 0.05


def test_band_widths_compare_seen_and_unseen_pairs():
    """Known draws of the network's angular acceleration, sd 0.01 rad/s^2 at the seen
    pairs and 0.03 at the unseen, stored as torques of draws whose yaw inertia varies
    (J_s over a factor of e): the widths are those of the acceleration (median 90 % width
    2 x 1.645 sd, ratio 3), not of the torque, which carries the unidentified inertia."""
    import xarray as xr

    from heli_uq.model.terms.rigid_body import yaw_inertia
    from heli_uq.output.network import band_widths

    rng = np.random.default_rng(0)
    shape = (2, 2000)
    j_s = RIG_FIT["J_s"] * np.exp(rng.normal(0.0, 1.0, size=shape))
    pitch = np.full(10, -0.5)
    inertia = np.asarray(yaw_inertia({**RIG_FIT, "J_s": j_s}, float(np.median(pitch))))[..., None]
    seen, unseen = ("chain", "draw", "nn_point_yaw"), ("chain", "draw", "nn_point_yaw_unseen")
    post = xr.Dataset({
        "J_s": (("chain", "draw"), j_s),
        "nn_torque_yaw": (seen, 0.01 * rng.normal(size=shape + (5,)) * inertia),
        "nn_torque_yaw_unseen": (unseen, 0.03 * rng.normal(size=shape + (3,)) * inertia),
    }, coords={"nn_point_yaw_u_psi": ("nn_point_yaw", np.arange(5.0)),
               "nn_point_yaw_unseen_u_psi": ("nn_point_yaw_unseen", np.arange(3.0))},
       attrs={"priors": json.dumps({k: RIG_FIT[k] for k in ("r_c", "h", "m", "J_bc", "g")})})  # fmt: skip
    constant = xr.Dataset({"y_obs": (("time", "output"), np.column_stack([pitch, pitch])),
                           "train_mask": ("time", np.ones(10, bool))})  # fmt: skip
    widths = band_widths(az.InferenceData(posterior=post, constant_data=constant), "yaw")
    assert widths["seen"]["n"] == 5 and widths["unseen"]["n"] == 3
    assert widths["seen"]["median"] == pytest.approx(2 * 1.645 * 0.01, rel=WIDTH_RATIO_TOL)
    assert widths["ratio"] == pytest.approx(3.0, rel=WIDTH_RATIO_TOL)
    no_unseen = az.InferenceData(posterior=post.drop_vars(["nn_torque_yaw_unseen",
                                                           "nn_point_yaw_unseen_u_psi"]),
                                 constant_data=constant)  # fmt: skip
    assert "ratio" not in band_widths(no_unseen, "yaw")
