"""Prior predictive check: what the priors say about a record before they see it.

The first step of a Bayesian workflow (Gabry et al. 2019; Gelman et al. 2020, Sec. 2.4):
simulate data from the priors alone and compare with the record.  Every free parameter,
the initial state and the error scales are drawn from their priors (a :class:`PriorSet`,
in physical units and independently: the product of priors that the sampling coordinates
of :mod:`heli_uq.probability.coordinates` reparameterise), each draw is simulated once
over the whole span with the problem's model and substeps
(:func:`~heli_uq.output.inference_data.simulate_draws`, the posterior's code path), and
the record is set against the draws:

* ``failed``: share of draws whose solve fails (the posterior gives them no mass);
* ``substeps``, ``stiffness``: the solver's substeps, raised to cover the stiffest draw
  up to :data:`~heli_uq.simulation.stiffness.MAX_SUBSTEPS`, and the draws still past RK4's
  stability limit (:func:`~heli_uq.simulation.stiffness.stiffness_check`; noted);
* ``unphysical``: share whose pitch leaves +-90 deg or whose states blow up, failed
  draws included (:func:`heli_uq.simulation.physical.unphysical_draws`);
* ``coverage90``: per window and angle, the share of the record's samples inside the
  prior predictive 90 % band of the draws that solve;
* ``p_values``: for the statistics ``T`` = mean and sd of each angle over the training
  window, the share of solved draws whose replicated record (simulation plus error-model
  noise) has ``T`` below the record's (a prior predictive p-value: near 0 or 1, the priors
  put the record in their tail).

:data:`NOTE_RULES` turn these into notes (``summary["notes"]``).  A prior check does not
fail a run: priors that are wide by design miss-cover nothing and spread far, and a note
tells a user where to look before sampling.  Results: ``prior.nc`` (InferenceData with
the groups ``prior``, ``prior_predictive``, ``observed_data``, ``constant_data``),
``summary.json``, ``bands.png``.
"""

from __future__ import annotations

import json
import pathlib
import time

import arviz as az
import numpy as np

from heli_uq.data.record import Experiment
from heli_uq.errors import ParameterError
from heli_uq.io import atomic_write_text
from heli_uq.model.heli_model import HeliModel
from heli_uq.model.tables import X0_NAMES
from heli_uq.output.health import COVERAGE90_RANGE
from heli_uq.output.inference_data import save_netcdf, simulate_draws
from heli_uq.output.plots import plot_bands, save_figure
from heli_uq.probability.priors import OUTPUTS, PriorSet
from heli_uq.probability.problem import make_problem
from heli_uq.simulation.physical import unphysical_draws
from heli_uq.simulation.stiffness import MAX_SUBSTEPS, stiffness_check, substeps_covering

__all__ = ["prior_draws", "prior_predictive_check", "NOTE_RULES"]

#: Share of draws that fail the solver above which a note is given.
FAILED_NOTE = 0.05
#: Share of unphysical draws (pitch beyond +-90 deg) above which a note is given.
UNPHYSICAL_NOTE = 0.25
#: Coverage of the record by the prior's 90 % band below which a note is given: a prior
#: at the truth covers 90 % up to sampling error, a wider one more (the posterior's
#: lower bound too, :data:`heli_uq.output.health.COVERAGE90_RANGE`; no upper bound here).
COVERAGE_NOTE = COVERAGE90_RANGE[0]
#: Prior predictive p-values outside ``[P_TAIL, 1 - P_TAIL]`` are notes.
P_TAIL = 0.01
#: Solved draws drawn one by one over the bands of ``bands.png``.
EXAMPLES = 8
#: The thresholds of the notes, as stored in ``summary.json``.
NOTE_RULES = {"failed_above": FAILED_NOTE, "unphysical_above": UNPHYSICAL_NOTE,
              "coverage90_below": COVERAGE_NOTE, "p_value_tail": P_TAIL}  # fmt: skip


def prior_draws(problem, n: int, seed: int = 0) -> dict:
    """``n`` joint draws from the prior of ``problem`` (its parameters' as the samplers use
    it, :meth:`~heli_uq.probability.Problem.draw_parameters`), in the layout of a sampler's
    samples with one chain: ``{parameter: (1, n)}`` for every free model parameter,
    ``{theta0, psi0, omega_theta0, omega_psi0: (1, n)}``, ``sigma`` (1, n, 2) [rad] and,
    for AR(1) errors, ``tau`` [s] and ``rho`` (1, n, 2); with a timing error ``timing``
    [s] (1, n, 2)."""
    rng = np.random.default_rng(seed)
    priors: PriorSet = problem.priors
    out = problem.draw_parameters(rng, (1, n))
    for name, prior in zip(X0_NAMES, problem.x0_priors()):
        out[name] = prior.sample(rng, (1, n))

    def per_output(kind):  # (1, n, 2) draws of the error-model parameter ``kind``
        return np.stack([priors.noise[f"{kind}_{o}"].sample(rng, (1, n)) for o in OUTPUTS], axis=-1)

    out["sigma"] = per_output("sigma")
    if problem.ar1:
        out["tau"] = per_output("tau")
        out["rho"] = np.exp(-problem.dt / out["tau"])
    if problem.timing:
        out["timing"] = per_output("timing")
    return out


def _covering_substeps(problem, samples: dict):
    """``(problem, stiffness)``: the problem with the substeps that cover the stiffest
    draw (at most :data:`~heli_uq.simulation.stiffness.MAX_SUBSTEPS`), and
    :func:`~heli_uq.simulation.stiffness.stiffness_check` of the draws at them (None
    without stiff terms)."""
    n = samples["sigma"].shape[1]
    draws = {k: np.ravel(samples[k]) if p.free else np.full(n, p.a) for k, p in problem.priors.params.items()}
    thetas = problem.y[: problem.n_train, 0]

    def check(substeps: int):
        return stiffness_check(problem.model, draws, substeps, problem.dt, thetas=thetas)

    first = check(problem.substeps)
    if first is None:
        return problem, None
    need = substeps_covering([first["rate_max"]], problem.dt)
    problem = problem.with_substeps(min(MAX_SUBSTEPS, max(problem.substeps, need)))
    return problem, check(problem.substeps)


def _coverage(band, y_obs, windows: dict) -> dict:
    inside = (band[0] <= y_obs) & (y_obs <= band[1])
    return {w: {o: float(np.mean(inside[a:b, j])) for j, o in enumerate(OUTPUTS)}
            for w, (a, b) in windows.items()}  # fmt: skip


def _p_values(y_rep, y_obs, n_train: int) -> dict:
    sim, obs = y_rep[:, :n_train].astype(float), y_obs[:n_train]
    out = {}
    for stat, f in (("mean", np.mean), ("sd", np.std)):
        drawn, seen = f(sim, axis=1), f(obs, axis=0)
        out.update({f"{stat}_{o}": float(np.mean(drawn[:, j] < seen[j])) for j, o in enumerate(OUTPUTS)})
    return out


def _notes(summary: dict) -> list[str]:
    notes = []
    if summary["failed"] > FAILED_NOTE:
        notes.append(f"{100 * summary['failed']:.0f} % of the prior draws fail the solver")
    stiff = summary["stiffness"]
    if stiff is not None and stiff["beyond"] > 0:
        share = 100 * stiff["beyond"] / stiff["of"]
        notes.append(f"{share:.0f} % of the prior draws are stiffer than RK4 follows at "
                     f"{summary['substeps']} substeps: their simulations may be wrong")  # fmt: skip
    if summary["unphysical"] > UNPHYSICAL_NOTE:
        notes.append(f"{100 * summary['unphysical']:.0f} % of the prior draws leave the physical range "
                     "(pitch beyond +-90 deg): the priors allow motions the rig cannot make")  # fmt: skip
    for w, cov in summary["coverage90"].items():
        for o, c in cov.items():
            if c < COVERAGE_NOTE:
                notes.append(f"the prior's 90 % band covers {100 * c:.0f} % of the {w} window's {o}: "
                             "the record lies outside what the priors expect")  # fmt: skip
    for k, p in summary["p_values"].items():
        if not P_TAIL <= p <= 1.0 - P_TAIL:
            notes.append(f"prior predictive p-value of the training window's {k.replace('_', ' of ')}: "
                         f"{p:.3f} (the record is in the priors' tail)")  # fmt: skip
    return notes


def prior_predictive_check(record: Experiment, out_dir, *, model: HeliModel | None = None, train=None,
                           test=None, priors: PriorSet | None = None, error: str = "iid",
                           draws: int = 1000, seed: int = 0, log=None):  # fmt: skip
    """Prior predictive check of a model and its priors on a record (module docstring).

    Parameters
    ----------
    record : Experiment
    out_dir : path
        Receives ``prior.nc``, ``summary.json`` and ``bands.png``.
    model, train, test, priors, error
        As for :func:`heli_uq.probability.make_problem`.
    draws : int
        Prior draws, each simulated once over the whole span.
    seed : int
    log : callable, optional

    Raises
    ------
    ParameterError
        ``draws`` below 1, or what :func:`~heli_uq.probability.make_problem` refuses.

    Returns
    -------
    (arviz.InferenceData, dict)
        The draws and their predictive angles; the summary (module docstring) with
        ``notes``.
    """
    if isinstance(draws, bool) or not isinstance(draws, int | np.integer) or draws < 1:
        raise ParameterError(f"draws: expected an integer >= 1, found {draws!r}")
    t0 = time.perf_counter()
    out = pathlib.Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    problem = make_problem(record, train, test, model=model, priors=priors, error=error)
    samples = prior_draws(problem, draws, seed)
    problem, stiffness = _covering_substeps(problem, samples)
    _, y_sim, y_pred = simulate_draws(problem, samples, np.arange(draws), seed=seed, want_ll=False)
    failed = ~np.all(np.isfinite(y_sim), axis=(1, 2))
    solved = ~failed
    windows = problem.windows()
    summary = {"sampler": "prior", "draws": int(draws), "error_model": problem.error,
               "model": problem.model.describe(), "model_label": problem.model.label,
               "failed": float(np.mean(failed)),
               "unphysical": float(np.mean(unphysical_draws(y_sim))),
               "substeps": problem.substeps, "stiffness": stiffness}  # fmt: skip
    if np.any(solved):
        band = np.quantile(y_pred[solved], [0.05, 0.95], axis=0)
        summary["coverage90"] = _coverage(band, problem.y, windows)
        summary["p_values"] = _p_values(y_pred[solved], problem.y, problem.n_train)
    else:
        summary["coverage90"], summary["p_values"] = {}, {}
    summary["notes"], summary["note_rules"] = _notes(summary), NOTE_RULES
    summary["wall_s"] = time.perf_counter() - t0

    masks = problem.masks()
    idata = az.from_dict(
        prior={k: v for k, v in samples.items()},
        prior_predictive={"y_pred": y_pred[None], "y_sim": y_sim[None]},
        observed_data={"y": problem.y[: problem.n_train]},
        constant_data={"u": problem.u, "y_obs": problem.y, "train_mask": masks["train"],
                       "test_mask": masks["test"]},
        coords={"time": problem.t, "time_train": problem.t[: problem.n_train], "output": list(OUTPUTS),
                "input": ["u_theta", "u_psi"]},
        dims={"y_pred": ["time", "output"], "y_sim": ["time", "output"], "sigma": ["output"],
              "tau": ["output"], "rho": ["output"], "timing": ["output"],
              "y": ["time_train", "output"], "u": ["time", "input"],
              "y_obs": ["time", "output"], "train_mask": ["time"], "test_mask": ["time"]},
    )  # fmt: skip
    idata.prior.attrs.update({"model": json.dumps(problem.model.describe()),
                              "priors": json.dumps(problem.priors.to_json()), "error_model": problem.error,
                              "source": problem.source, "substeps": problem.substeps})  # fmt: skip
    save_netcdf(idata, out / "prior.nc")
    atomic_write_text(out / "summary.json", json.dumps(summary, indent=1))
    cov = summary["coverage90"] or None
    fig = plot_bands(problem.t, y_pred[solved] if np.any(solved) else y_pred, problem.y,
                     train_mask=masks["train"], test_mask=masks["test"], coverage=cov,
                     band="prior predictive", examples=y_sim[solved][:EXAMPLES],
                     title=(f"Prior predictive ({draws} draws, {100 * summary['failed']:.0f} % failed, "
                            f"{100 * summary['unphysical']:.0f} % unphysical; {problem.model.label}): "
                            f"{pathlib.Path(problem.source).name}"))  # fmt: skip
    save_figure(fig, out / "bands.png")
    if log is not None:
        log(f"prior predictive: {draws} draws in {summary['wall_s']:.0f} s; " + (
            "; ".join(summary["notes"]) if summary["notes"] else "no notes"))  # fmt: skip
    return idata, summary
