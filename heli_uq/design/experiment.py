"""``design``: propose a voltage staircase, compare it with the published profile and random
staircases, and write ``design.csv``, ``design.json`` and ``design.png``."""

from __future__ import annotations

import dataclasses
import json
import math
import pathlib
import time
from collections.abc import Callable

import numpy as np

from heli_uq.data.record import Experiment
from heli_uq.design.discrimination import Rivals
from heli_uq.design.figures import plot_design
from heli_uq.design.information import DesignPrior, InformationGain
from heli_uq.design.search import SEARCH_BUDGETS, search_staircase
from heli_uq.design.staircase import StaircaseBounds
from heli_uq.errors import ParameterError
from heli_uq.figure import save_figure
from heli_uq.io import atomic_write_text
from heli_uq.log import progress_log

__all__ = ["design", "DESIGN_KEYS"]

#: Keys of ``design.json``.
DESIGN_KEYS = ("criterion", "unit", "value", "baselines", "gain_over_published",
               "gain_over_random_median", "volume_ratio_vs_published", "prior", "bounds",
               "budget", "seed", "segments", "seconds")  # fmt: skip

_CRITERIA = {
    "information": ("expected information gain (Bayesian D-optimality on the whitened Fisher "
                    "information, averaged over posterior draws)", "nats"),
    "discrimination": ("expected log Bayes factor between two rival models (T-optimality, "
                       "fits held fixed)", "nats"),
}  # fmt: skip


def design(out, bounds: StaircaseBounds, *, prior: DesignPrior | None = None,
           rivals: Rivals | None = None, published: Experiment | None = None,
           budget: str = "quick", seed: int = 0,
           log: Callable[[str], None] | None = None) -> dict:  # fmt: skip
    """Search a staircase within ``bounds`` that maximises the criterion, and write the results.

    Parameters
    ----------
    out : path
        Output directory (exists).
    bounds : StaircaseBounds
    prior : DesignPrior, optional
        For the information criterion (the default, with :meth:`DesignPrior.default`).
    rivals : Rivals, optional
        Two fitted models: the discrimination criterion instead.
    published : Experiment, optional
        A record whose first ``bounds.duration`` seconds of input are the baseline (the
        published profile); skipped (and said so in ``design.json``) when shorter.
    budget : {"quick", "full"}
    seed : int

    Returns
    -------
    dict
        The content of ``design.json`` (keys :data:`DESIGN_KEYS`).
    """
    t0 = time.perf_counter()
    log = progress_log(log, __name__)
    out = pathlib.Path(out)
    effort = SEARCH_BUDGETS[budget]
    if rivals is not None:
        rivals = dataclasses.replace(rivals, pitch=bounds.pitch)
        kind, value_of = "discrimination", rivals.value
        source, sigma, x0 = rivals.source, rivals.sigma, rivals.x0
    else:
        prior = prior or DesignPrior.default(dt=bounds.dt, seed=seed)
        gain = InformationGain(prior, bounds.dt, bounds.pitch)
        kind, value_of = "information", gain.value
        source, sigma, x0 = prior.source, prior.sigma, prior.x0
    log(f"criterion: {kind}; prior: {source}")
    result = search_staircase(value_of, bounds, budget=effort, seed=seed, log=log)
    u = result.best.inputs()
    baselines = {"random": _random_summary(result.random_values)}
    u_pub, why = _published_inputs(published, bounds)
    pub = value_of(u_pub) if u_pub is not None else None
    if pub is not None and not math.isfinite(pub):
        pub, why = None, ("the published profile is infeasible here (failed simulation or pitch outside "
                          "the envelope)")
    baselines["published"] = {"value": pub, **({"skipped": why} if why else {})}
    gain_pub = None if pub is None else result.value - pub
    summary = {
        "criterion": {"name": kind, "definition": _CRITERIA[kind][0]},
        "unit": _CRITERIA[kind][1], "value": result.value, "baselines": baselines,
        "gain_over_published": gain_pub,
        "gain_over_random_median": result.value - baselines["random"]["median"],
        "volume_ratio_vs_published": (math.exp(-gain_pub) if kind == "information"
                                      and gain_pub is not None else None),
        "prior": {"source": source, "sigma_rad": list(map(float, sigma)),
                  "x0": list(map(float, x0))},
        "bounds": bounds.to_json(), "budget": {"name": budget, **vars(effort)}, "seed": seed,
        "segments": result.best.segments(bounds.dt),
    }  # fmt: skip
    if kind == "information":
        summary["shrinkage"] = {"design": gain.shrinkage(u).tolist()}
        if u_pub is not None:
            summary["shrinkage"]["published"] = gain.shrinkage(u_pub).tolist()
        y_pred = np.asarray(gain.angles(prior.center, u)[0])
        curves = {"design": y_pred}
    else:
        y_pred = rivals.a.angles(u, bounds.dt, x0)[0]
        curves = {rivals.a.name: y_pred, rivals.b.name: rivals.b.angles(u, bounds.dt, x0)[0]}
    summary["seconds"] = time.perf_counter() - t0
    _write(out, bounds, u, y_pred, summary)
    save_figure(plot_design(bounds.dt, u, u_pub, curves, summary), out / "design.png")
    return summary


def _random_summary(values: np.ndarray) -> dict:
    finite = values[np.isfinite(values)]
    return {"n": int(values.size), "feasible": int(finite.size),
            "median": float(np.median(finite)), "best": float(finite.max())}  # fmt: skip


def _published_inputs(record: Experiment | None, bounds: StaircaseBounds):
    """``(u, None)``: the first ``bounds.n`` inputs of ``record``; or ``(None, why)``."""
    if record is None:
        return None, "no published record given (set HELI_UQ_DATA to compare with it)"
    if not math.isclose(record.dt, bounds.dt, rel_tol=1e-9):
        raise ParameterError(f"published record: dt = {record.dt:g} s, the design's is {bounds.dt:g} s")
    if record.n < bounds.n:
        return None, f"{record.source} covers {record.duration:g} s, shorter than the design"
    return np.asarray(record.u[: bounds.n]), None


def _write(out: pathlib.Path, bounds: StaircaseBounds, u, y_pred, summary: dict) -> None:
    """``design.csv`` (published format; the angles are the predicted ones) and ``design.json``."""
    t = np.arange(bounds.n) * bounds.dt
    Experiment(t, u, y_pred, bounds.dt, source="heli-uq design").to_csv(out / "design.csv")
    atomic_write_text(out / "design.json", json.dumps(summary, indent=1, allow_nan=False) + "\n")
