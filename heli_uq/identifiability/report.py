"""The identifiability report: structural, practical and Bayesian views, cross-checked.

:func:`identifiability_report` runs, on one record:

1. a maximum-likelihood fit of ``w`` (:class:`~heli_uq.identifiability.structural.ParameterVector`:
   log of each free positive parameter, ``h``, the initial state) under the chosen error
   model (:mod:`heli_uq.identifiability.fisher`);
2. **structural**: rank and named null space of the output sensitivities at the fit and
   at random points (:mod:`heli_uq.identifiability.structural`);
3. **practical**: Fisher information at the fit and a profile likelihood of every
   coordinate, classified (:mod:`heli_uq.identifiability.profiles`);
4. **Bayesian**: prior-to-posterior contraction ``1 - var_post / var_prior`` per coordinate
   and along each null direction, from a given ``posterior.nc`` or, without one, from
   the Gaussian (Laplace) approximation ``(F + P)^-1`` with ``P`` the prior precision;
5. a **cross-check** of the three views, listing where they disagree and why
   (:mod:`heli_uq.identifiability.cross_check`);

and writes ``identifiability.json``, ``identifiability.md`` and the figures to a directory.
Priors are the package's (:class:`heli_uq.probability.PriorSet`): their central ``PRIOR_RANGE_SD``-sigma
range is the range the profiles explore.
"""

from __future__ import annotations

import json
import math
import pathlib
import time

import jax
import jax.numpy as jnp
import numpy as np

from heli_uq.data.record import Experiment
from heli_uq.errors import ParameterError
from heli_uq.identifiability.contraction import contraction, draws_in_w, sampled_prior_cov
from heli_uq.identifiability.cross_check import cross_check
from heli_uq.identifiability.fisher import fisher_information, fit_likelihood, precision_draws
from heli_uq.identifiability.profiles import THRESHOLD_95, classify, profile_likelihood
from heli_uq.identifiability.structural import ParameterVector, random_points, structural_analysis
from heli_uq.inference import least_squares_fit, start_parameters
from heli_uq.io import atomic_write_text
from heli_uq.log import progress_log
from heli_uq.model.heli_model import HeliModel
from heli_uq.model.prior import Prior
from heli_uq.model.tables import X0_NAMES
from heli_uq.probability.likelihood import loss_v
from heli_uq.probability.priors import PriorSet, RecordStart
from heli_uq.probability.problem import data_sha256, make_problem

__all__ = ["identifiability_report", "prior_moments", "check_posterior_data", "profile_coordinates",
           "PRIOR_RANGE_SD"]  # fmt: skip

#: Half-width of the explored prior range, in prior standard deviations (of the log for log-normals).
PRIOR_RANGE_SD = 2.0

#: Draws of the Laplace approximation used for the pair plot.
LAPLACE_DRAWS = 4000


def prior_moments(pv: ParameterVector, priors: PriorSet,
                  start: RecordStart) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Exact prior mean and sd of every coordinate of ``w``.

    Each free parameter's prior must be written in ``w``'s coordinate of it (log for
    positive parameters: log-normal or half-normal; identity otherwise: normal); initial
    state: the :class:`~heli_uq.probability.PriorSet` entries, their defaults from the
    record's ``start``.

    Raises
    ------
    ParameterError
        A fixed or otherwise incompatible prior on a free coordinate.
    """
    mean, sd = [], []
    for n in pv.free:
        p = priors.params[n]
        if p.kind == "fixed":
            raise ParameterError(f"free {n}: its prior is fixed; free parameters need a prior")
        if p.transform != ("log" if pv.is_log(n) else "identity"):
            raise ParameterError(f"{n}: the report analyses it in "
                                 f"{'log' if pv.is_log(n) else 'linear'} coordinates and needs a "
                                 f"prior written there, found {p.describe()}")  # fmt: skip
        m, s_ = p.coordinate_moments()
        mean.append(m)
        sd.append(s_)
    if pv.include_x0:
        for n in X0_NAMES:
            p = priors.x0_prior(n, start)
            if not p.free:
                raise ParameterError(f"{n}: its prior is fixed; the report needs a normal prior")
            mean.append(p.a)
            sd.append(p.b)
    return np.asarray(mean), np.asarray(sd)


def check_posterior_data(posterior, record: Experiment, where: str = "posterior") -> None:
    """Refuse a posterior computed from other data than ``record``'s: the samples of its
    training window (attributes ``train_s``, ``train_sha256`` of ``posterior.nc``) must be
    in ``record`` with the same values.  A posterior without them (written before they
    were) is not checked.

    Raises
    ------
    ParameterError
        Naming ``where``, the posterior's record and window, and what differs.
    """
    attrs = posterior.attrs
    if "train_sha256" not in attrs:
        return
    a, b = json.loads(attrs["train_s"])
    t, dt = np.asarray(record.t), float(record.dt)
    i0 = int(np.searchsorted(t, a - 0.5 * dt))
    n = int(round((b - a) / dt))
    covered = i0 + n <= len(t) and abs(t[min(i0, len(t) - 1)] - a) < 0.5 * dt
    if covered:
        part = slice(i0, i0 + n)
        if data_sha256(record.u[part], record.y[part], t[part]) == attrs["train_sha256"]:
            return
    why = ("this record does not hold that window" if not covered
           else "this record's samples there differ")  # fmt: skip
    raise ParameterError(f"{where}: sampled on {a:g}-{b:g} s of {attrs.get('source', 'a record')}, and "
                         f"{why} ({record.source}); give the record it was sampled on, with a window "
                         "that holds that span")


#: Starts of the least-squares stage: the base values, Table 2, and perturbations of the base.
N_STARTS = 3


def _least_squares_starts(record, pv: ParameterVector, priors: PriorSet, seed: int) -> list:
    """Starts of the likelihood fit from the posterior workflow's robust least-squares stage.

    :func:`heli_uq.inference.least_squares_fit` (Levenberg-Marquardt in the identifiable
    sampling coordinates, iid residual scales) from ``pv.base``, the model's defaults
    and ``N_STARTS - 2`` log-normal (sd 0.3) perturbations of ``pv.base``; the fits are
    returned as ``w``, best paper loss V first.  The record has local optima (V = 14.9
    from Table 1 alone, 0.11 from the best start), so one start is not enough.
    """
    fixed = {n: Prior("fixed", float(pv.base[n])) for n in pv.model.names if n not in pv.free}
    problem = make_problem(record, model=pv.model, priors=priors.updated(pv.model, fixed),
                           error="iid", substeps=pv.substeps)  # fmt: skip
    coords = problem.coords
    fit = least_squares_fit(problem)
    alternative = {n: p.default for n, p in zip(pv.model.names, pv.model.parameters())
                   if p.prior.support[0] < p.default < p.prior.support[1]}  # fmt: skip
    guesses = start_parameters(pv.free, pv.base, N_STARTS, seed, alternative=alternative,
                               linear=[n for n in pv.free if not pv.is_log(n)])  # fmt: skip
    x_guess = np.array([record.y[0, 0], record.y[0, 1], 0.0, 0.0])
    out = []
    for params in guesses:
        z, x0, _ = fit(coords.from_physical(params), x_guess)
        phys = {n: float(v) for n, v in coords.to_physical(z).items()}
        ys = np.asarray(problem.solve(phys, np.asarray(x0)).ys)
        v = float(loss_v(ys, record.y))
        if np.isfinite(v):
            out.append((v, pv.from_model(phys, np.asarray(x0))))
    out.sort(key=lambda item: item[0])
    return [w for _, w in out]


def _profile_bounds(j, prior_mean, prior_sd, w_hat):
    lo = prior_mean[j] - PRIOR_RANGE_SD * prior_sd[j]
    hi = prior_mean[j] + PRIOR_RANGE_SD * prior_sd[j]
    pad = 0.1 * prior_sd[j]
    return min(lo, w_hat[j] - pad), max(hi, w_hat[j] + pad)


def profile_coordinates(pv: ParameterVector, fit, prior_mean, prior_sd, null_basis=None, *,
                        fim=None, log=None) -> list:  # fmt: skip
    """Profile and classify every coordinate of ``w`` around a likelihood fit
    (:class:`~heli_uq.identifiability.fisher.LikelihoodFit`).

    Each profile explores the prior range ``prior_mean +- PRIOR_RANGE_SD * prior_sd``
    (widened to contain the fit); its first step is the Cramér-Rao standard error,
    capped at an eighth of the range.  ``null_basis`` (P, k) is the structural null space
    at the fit, or any set of null vectors spanning it (used for warm starts and to tell
    structural from practical flatness).
    """
    fim = fisher_information(fit.residuals, fit.w) if fim is None else fim
    jac = np.asarray(jax.jacfwd(fit.residuals)(jnp.asarray(fit.w)))
    null_basis = np.zeros((pv.dim, 0)) if null_basis is None else np.asarray(null_basis)
    profiles = []
    for j, name in enumerate(pv.names):
        bounds = _profile_bounds(j, prior_mean, prior_sd, fit.w)
        se = fim.standard_errors[j]
        step0 = min(se if np.isfinite(se) else np.inf, (bounds[1] - bounds[0]) / 8)
        values, costs = profile_likelihood(fit.residuals, fit.w, fit.cost, j, bounds, step0, jac,
                                           null_basis)  # fmt: skip
        loading = float(np.max(np.abs(null_basis[j]))) if null_basis.size else 0.0
        profiles.append(classify(name, values, costs, bounds, loading, center=fit.w[j]))
        if log is not None:
            log(f"  {name:14s} {profiles[-1].classification}")
    return profiles


def identifiability_report(record: Experiment, out_dir, *, model: HeliModel | None = None,
                           free=None, base=None, priors: PriorSet | None = None, posterior=None,
                           posterior_prior=None, error: str = "iid", n_points: int = 5, seed: int = 0,
                           substeps=None, posterior_note: str | None = None, log=None) -> dict:  # fmt: skip
    """Run the whole report on ``record`` and write it to ``out_dir``; returns the JSON dict.

    Parameters
    ----------
    record : Experiment
    out_dir : path
    model : HeliModel, optional
        Default: the paper's model.
    free : sequence of str, optional
        Free model parameters (default: every one whose prior is not fixed, i.e. all but g
        for the paper's model).
    base : mapping, optional
        Values of the fixed parameters and the first start of the fit (default: the
        model's start values, Table 1 for the mechanics).
    priors : PriorSet, optional
        Default: the model's declared priors.
    posterior : xarray.Dataset, optional
        The ``posterior`` group of a ``posterior.nc`` for the Bayesian view (the CLI reads
        it with :func:`heli_uq.output.load_posterior`); without it the Laplace
        approximation.  It must come from ``record``'s data (:func:`check_posterior_data`).
    posterior_prior : xarray.Dataset, optional
        The same file's ``prior`` group: the posterior's contraction is measured against
        it (:func:`sampled_prior_cov`); without it, against the declared priors.
    error : {"iid", "ar1"}
    n_points : int
        Points of the structural analysis (the fit and ``n_points - 1`` random ones).
    substeps : int, optional
        RK4 substeps per sample (default: from the model's stiffness at ``base``).
    posterior_note : str, optional
        Said after the Bayesian view's source, e.g. that the posterior failed its health
        checks (the CLI's, from :func:`heli_uq.output.check_health`).
    """
    from heli_uq.identifiability import figures as figs
    from heli_uq.simulation.stiffness import default_substeps

    t_start = time.perf_counter()
    if posterior is not None:
        check_posterior_data(posterior, record)
    log = progress_log(log, __name__)
    out = pathlib.Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    model = (HeliModel() if model is None else model).adapted(record.u, record.y, record.dt)  # GP pairs
    priors = PriorSet.default(model) if priors is None else priors.completed(model)
    base = {**model.start_values(), **(base or {})}
    if free is None:
        free = [n for n in model.names if priors.params[n].free]
    if isinstance(n_points, bool) or not isinstance(n_points, int) or n_points < 1:
        raise ParameterError(f"points: expected a positive integer, found {n_points!r}")
    if substeps is None:
        substeps = default_substeps(model, base, record.dt, margin=2.0, thetas=record.y[:, 0])
    pv = ParameterVector(model, tuple(free), base, substeps=substeps)
    u, y, dt = np.asarray(record.u), np.asarray(record.y), float(record.dt)
    prior_mean, prior_sd = prior_moments(pv, priors, RecordStart.of(y, dt, u))
    timings = {}
    t0 = time.perf_counter()
    log(f"fitting {pv.dim} coordinates to {record.n} samples ({error} errors) ...")
    starts = _least_squares_starts(record, pv, priors, seed)[:1]
    fit = fit_likelihood(pv, u, y, dt, starts, error=error)
    timings["fit_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    log(f"structural analysis at {n_points} points ...")
    linear_sd = {n: 0.5 * priors.params[n].coordinate_moments()[1] for n in pv.free
                 if not pv.is_log(n)}  # fmt: skip
    points = random_points(pv, fit.w, u, dt, n_points, seed=seed, linear_sd=linear_sd)
    st = structural_analysis(pv, points, u, dt)
    timings["structural_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    log("Fisher information and profiles ...")
    fim = fisher_information(fit.residuals, fit.w)
    named = [np.array([d["loadings"][n] for n in pv.names]) for d in st.null_directions]
    null_vectors = np.column_stack(named + [st.null_basis]) if named else st.null_basis
    profiles = profile_coordinates(pv, fit, prior_mean, prior_sd, null_vectors, fim=fim, log=log)
    timings["practical_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    null_vectors = [np.array([d["loadings"][n] for n in pv.names]) for d in st.null_directions]
    prior_cov = None
    if posterior is not None:
        draws = draws_in_w(posterior, pv)
        prior_cov = None if posterior_prior is None else sampled_prior_cov(posterior_prior, pv, prior_sd)
        source = ("MCMC draws of the given posterior, against "
                  + ("its file's prior draws (the prior it was sampled under; the initial state's "
                     "declared prior)" if prior_cov is not None
                     else "the declared priors (its file has no usable prior draws)")
                  + (f" ({posterior_note})" if posterior_note else ""))  # fmt: skip
    else:
        draws = precision_draws(fit.w, _fisher_matrix(fim) + np.diag(1.0 / prior_sd**2), LAPLACE_DRAWS, seed)
        source = "Laplace approximation (F + prior precision)^-1 at the fit (no posterior given)"
    cov_post = np.cov(draws, rowvar=False)
    per, along = contraction(cov_post, prior_sd, null_vectors, prior_cov=prior_cov)
    corr_post = np.corrcoef(draws, rowvar=False)
    timings["bayesian_s"] = time.perf_counter() - t0

    structural = {
        "rank": st.rank, "n_parameters": st.n_parameters,
        "ranks_at_points": list(st.ranks), "rank_rtol": st.rtol,
        "gap": dict(zip(("largest_zero", "smallest_nonzero"), st.gap())),
        "null_directions": [{"key": d["key"], "loadings": d["loadings"],
                             "description": d["description"], "distance": d["distance"]}
                            for d in st.null_directions],
        "weakest_direction": st.weakest,
        "identifiable_combinations": st.combinations,
    }  # fmt: skip
    checks = cross_check(pv.names, structural, profiles, per, along)
    result = {
        "model": model.describe(), "model_label": model.label, "substeps": pv.substeps,
        "parameters": list(pv.names),
        "coordinates": {n: ("log" if pv.is_log(n) else "linear") for n in pv.names},
        "record": {"source": str(record.source), "n": int(record.n), "dt": dt,
                   "t0": float(record.t[0]), "t1": float(record.t[-1])},
        "error_model": {"kind": error, "sigma": np.asarray(fit.residuals.sigma).tolist(),
                        "rho": None if fit.residuals.rho is None
                        else np.asarray(fit.residuals.rho).tolist()},
        "fit": {"w": fit.w.tolist(), "neg_log_lik": fit.cost + fit.residuals.log_scale_sum(),
                "loss_v": fit.loss_v, "start_costs": list(fit.start_costs)},
        "structural": structural,
        "practical": {
            "fim_eigenvalues": fim.eigenvalues.tolist(),
            "fim_eigenvectors": fim.eigenvectors.tolist(),
            "condition_number": fim.condition_number,
            "fim_rank": fim.rank,
            "cramer_rao_se": {n: _finite(v) for n, v in zip(pv.names, fim.standard_errors)},
            "threshold": THRESHOLD_95,
            "profiles": {p.name: {"classification": p.classification, "ci95": p.ci95,
                                  "lower": p.lower, "upper": p.upper, "flat": p.flat,
                                  "max_delta": _finite(np.max(p.delta)),
                                  "bounds": list(p.bounds), "values": p.values.tolist(),
                                  "delta": [_finite(v) for v in p.delta]}
                         for p in profiles},
        },
        "bayesian": {"source": source,
                     "contraction": {n: float(c) for n, c in zip(pv.names, per)},
                     "contraction_along_null_directions": {
                         d["key"]: float(c) for d, c in zip(st.null_directions, along)},
                     "posterior_correlation": corr_post.tolist()},
        "cross_check": checks,
        "timings": dict(timings, total_s=time.perf_counter() - t_start),
    }  # fmt: skip

    short = "MCMC posterior" if posterior is not None else "Laplace approximation"
    figures = figs.write_report_figures(out, pv, st, fim, profiles, draws, corr_post, per,
                                        short, fit.w)  # fmt: skip
    result["figures"] = [f.name for f in figures]
    result["timings"]["total_s"] = time.perf_counter() - t_start
    atomic_write_text(out / "identifiability.json", json.dumps(result, indent=1))
    from heli_uq.identifiability.text import markdown_report

    atomic_write_text(out / "identifiability.md", markdown_report(result))
    return result


def _fisher_matrix(fim) -> np.ndarray:
    v, lam = fim.eigenvectors, fim.eigenvalues
    return (v * lam) @ v.T


def _finite(x):
    x = float(x)
    return x if math.isfinite(x) else None
