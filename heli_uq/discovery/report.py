"""The refit of the chosen model and the outputs of a discovery run.

* ``discovery.json``: exactly the keys ``effect, axis, parameters, gap_before, gap_after,
  candidates, decision, added``.  The gap records hold ``rmse_theta, rmse_psi`` [rad],
  ``V`` [rad^2] and ``coverage90_theta, coverage90_psi`` per window: ``{"train": ...,
  "test": ...}`` when a split was given, else ``{"window": ...}``.  *After* is the NUTS
  posterior of the chosen model; *before* the base model's NUTS posterior (``full``) or
  its Laplace approximation at the MAP (``quick``; without a split refitted on the whole
  record from its fit on the fitting window, as a known fit: ``FitTask(refit=True)``).
* ``report.md``; ``bands_before.png``, ``bands_after.png``, ``residuals.png``,
  ``candidates.png``; ``refit/`` (``posterior.nc``, ``summary.json`` of the refit).
"""

from __future__ import annotations

import json
import pathlib
import time

import numpy as np

from heli_uq.discovery.budget import label as budget_label
from heli_uq.discovery.candidates import FitTask, fitted_predictive, model_priors
from heli_uq.discovery.candidates_figure import candidates_figure
from heli_uq.discovery.report_page import gap_warnings, report_page, tie_text
from heli_uq.discovery.score import gain_text, gap_metrics, gap_text
from heli_uq.figure import save_figure
from heli_uq.io import atomic_write_text, strict_json
from heli_uq.model import build_model
from heli_uq.output import plot_bands, sample_posterior

__all__ = ["write_outputs", "DISCOVERY_KEYS"]

#: Share of the time target left that the base model's NUTS posterior may use when a refit
#: follows.  The refit is the run's result and the stiffer model: on a pitch friction record
#: (full budget, 2026-11-28) the base posterior used 24 of its 27 min at half, and the
#: refit, left 30 min, could keep only 111 draws per chain.
BEFORE_SHARE = 1.0 / 3.0
#: Seconds a budget with a time target (:attr:`~heli_uq.discovery.budget.Budget.minutes`)
#: keeps for the posterior-predictive simulations, figures and files after its last NUTS
#: run stops sampling.
OUTPUT_SECONDS = 30.0
#: The keys of ``discovery.json``, in order.
DISCOVERY_KEYS = ("effect", "axis", "parameters", "gap_before", "gap_after", "candidates",
                  "decision", "added")  # fmt: skip


def _gap(y_sim, y_pred, y_obs, masks: dict) -> dict:
    return {w: gap_metrics(y_sim[:, m], y_pred[:, m], y_obs[m]) for w, m in masks.items()}


def _masks(n: int, windows: dict, split: bool) -> dict:
    out = {}
    for w, (a, b) in windows.items():
        m = np.zeros(n, bool)
        m[a:b] = True
        out[w if split else "window"] = m
    return out


def _posterior(record, model, train, test, out, cost, seed, guess, time_limit=None, priors=()):
    """NUTS posterior of ``model`` (MAP warm-started from ``guess``, the model's fit on the
    fitting window): ``(idata, summary, y_sim, y_pred, y_obs, t)``.  ``time_limit`` [s]:
    see :func:`heli_uq.output.sample_posterior`; ``priors``: see
    :attr:`~heli_uq.discovery.candidates.FitTask.priors`.

    With a split the posterior is conditioned on the fitting window itself, where ``guess``
    is already the multi-start MAP of the same model, so it is the only start (more
    starts cost a stiff model minutes and find nothing better); on a single window the
    posterior also sees the scoring part, and the budget's starts are tried too.

    A run saved in ``out`` with the same settings (an interrupted discovery, or a finished
    one run again) is continued, not sampled afresh.
    """
    starts = 1 if test is not None else cost.n_starts
    idata, summary = sample_posterior(record, out, model=model, train=train, test=test, sampler="nuts",
                                      error="iid", priors=model_priors(model, priors), chains=cost.chains,
                                      warmup=cost.warmup, draws=cost.samples, seed=seed, progress=False,
                                      max_tree_depth=cost.max_tree_depth, n_starts=starts,
                                      adapt_mass_matrix=cost.adapt_mass_matrix,
                                      guesses=(guess,), time_limit=time_limit,
                                      max_draws=cost.max_samples, resume="auto")  # fmt: skip
    pp = idata.posterior_predictive
    y_sim = np.asarray(pp["y_sim"]).reshape((-1,) + pp["y_sim"].shape[2:])
    y_pred = np.asarray(pp["y_pred"]).reshape((-1,) + pp["y_pred"].shape[2:])
    cd = idata.constant_data
    return idata, summary, y_sim, y_pred, np.asarray(cd["y_obs"]), np.asarray(cd["time"])


def _candidate_rows(rows: list[dict]) -> list[dict]:
    out = []
    for r in rows:
        kinds = [e.split(":")[1] for e in r["added"]]
        axes = sorted({e.split(":")[0] for e in r["added"]})
        row = {"effect": "+".join(kinds), "axis": "+".join(axes), "score": r["score"],
               "score_se": r["score_se"], "step": r["step"], "model": r["effect"]}  # fmt: skip
        for k in ("score_per_sample", "passes", "support", "supported", "crps_gain", "crps_gain_se",
                  "crps_gain_fraction", "log_evidence", "tied", "chosen_by", "tie_break", "held_out",
                  "fit", "laplace", "seconds", "reused", "carried", "error", "skipped"):
            if k in r:
                row[k] = r[k]
        out.append(row)
    return out


def _effect_parameters(summary_params: dict, effect: str, priors=()) -> dict:
    """``{bare name: {mean, ci95, unit, per_inertia}}`` of the parameters of ``effect``
    (``"axis:kind"``; ``per_inertia`` for a torque-type parameter, see
    :func:`~heli_uq.output.parameter_summary`);
    one the run's ``priors`` fix (``(name, Prior)`` pairs) is reported at its value, with
    ``"fixed": true`` and a zero-width interval (the tilt offered at ``a = 1``)."""
    fixed = {name: prior.a for name, prior in priors if prior.kind == "fixed"}
    out = {}
    for par in build_model([effect]).effects[0].parameters():
        if par.name in summary_params:
            out[par.bare] = {k: summary_params[par.name][k] for k in ("mean", "ci95", "unit", "per_inertia")
                             if k in summary_params[par.name]}  # fmt: skip
        elif par.name in fixed:
            value = float(fixed[par.name])
            out[par.bare] = {"mean": value, "ci95": [value, value], "unit": par.unit, "fixed": True}
    return out


def write_outputs(out: pathlib.Path, *, record, base_effects, added, base, base_fit, where, ranking,
                  rows, steps, cost, budget, seed, full, refit, chosen_map, fit_window, score_window,
                  n_scored, say, t_start, priors=(), criterion="log") -> dict:  # fmt: skip
    """Refit, compare and write every output (module docstring); returns ``discovery.json``.
    ``criterion``: the name of the held-out score that decided
    (:data:`~heli_uq.discovery.score.CRITERIA`)."""
    search_seconds = time.perf_counter() - t_start
    train, test = refit
    split = test is not None
    base_model = build_model(base_effects)
    # before
    if full:
        say("NUTS posterior of the base model (before); its times count from its own start")
        share = BEFORE_SHARE if added else 1.0  # of the time target left: the refit needs the rest
        _, _, bs, bp, by, bt = _posterior(record, base_model, train, test, out / "before", cost, seed,
                                          base_fit.params, _time_left(cost, t_start, share),
                                          priors)  # fmt: skip
        problem_windows = _windows_from(bt, train, test)
    else:
        fitted = base_fit if split else fitted_predictive(
            FitTask(record, train, None, tuple(base_effects), (base_fit.params,), seed, 1, cost.draws,
                    cost.newton_steps, priors=priors, refit=True))  # fmt: skip
        bs, bp, by, bt = fitted.y_sim, fitted.y_pred, fitted.start.problem.y, fitted.start.problem.t
        problem_windows = fitted.start.problem.windows()
    before_masks = _masks(len(bt), problem_windows, split)
    gap_before = _gap(bs, bp, by, before_masks)
    # after
    effects = list(base_effects) + list(added)
    if added:
        say(f"NUTS posterior of the chosen model ({build_model(effects).label}); its times count "
            "from its own start")
        idata, summary, as_, ap, ay, at = _posterior(record, build_model(effects), train, test,
                                                     out / "refit", cost, seed, chosen_map,
                                                     _time_left(cost, t_start), priors)  # fmt: skip
        masks_after = _masks(len(at), _windows_from(at, train, test), split)
        gap_after = _gap(as_, ap, ay, masks_after)
        params = summary["parameters"]
        health = summary.get("health", {"ok": summary.get("converged"), "warnings": []})
    else:
        as_, ap, ay, at, gap_after, params, health = bs, bp, by, bt, gap_before, {}, None
        masks_after = before_masks
    first = added[0] if added else None
    result = {
        "effect": first.split(":")[1] if first else "none",
        "axis": first.split(":")[0] if first else None,
        "parameters": _effect_parameters(params, first, priors) if first else {},
        "gap_before": gap_before, "gap_after": gap_after,
        "candidates": _candidate_rows(rows),
        "decision": _decision(added, rows, steps, gap_before, gap_after, criterion, n_scored, health),
        "added": [{"effect": e.split(":")[1], "axis": e.split(":")[0],
                   "parameters": _effect_parameters(params, e, priors)} for e in added],
    }  # fmt: skip
    assert tuple(result) == DISCOVERY_KEYS
    # the file and the return value: a score of -inf (no draw of a candidate simulates) is
    # null, as JSON has no Infinity; the report and figure read the numbers as they are
    raw, result = result, strict_json(result)
    atomic_write_text(out / "discovery.json", json.dumps(result, indent=1, allow_nan=False))
    title = f"{pathlib.Path(str(record.source)).name}"
    save_figure(plot_bands(bt, bp, by, **_plot_masks(before_masks, split),
                           coverage=_coverage(gap_before),
                           title=f"Before: {base_model.label} ({'NUTS' if full else 'Laplace'})"
                                 f" - {title}"), out / "bands_before.png")  # fmt: skip
    flags = ", ".join((health or {}).get("flags", [])) if added else ""
    save_figure(plot_bands(at, ap, ay, **_plot_masks(masks_after, split), coverage=_coverage(gap_after),
                           health=flags,
                           title=f"After: {build_model(effects).label} (NUTS) - {title}"),
                out / "bands_after.png")  # fmt: skip
    save_figure(candidates_figure(raw["candidates"], n_scored, criterion), out / "candidates.png")
    whole = {"before": gap_metrics(bs, bp, by), "after": gap_metrics(as_, ap, ay)}
    seconds = (time.perf_counter() - t_start, search_seconds)
    page = report_page(raw, where, ranking, steps, base, budget_label(budget), fit_window, score_window,
                       n_scored, health, whole, seconds, record, base_model.label, priors, criterion)
    atomic_write_text(out / "report.md", page)
    say(f"done: {result['decision']}")
    return result


def _time_left(cost, t_start: float, share: float = 1.0) -> float | None:
    """``share`` of the seconds the budget's time target leaves a NUTS posterior of a run
    started at ``t_start`` (``time.perf_counter``), less :data:`OUTPUT_SECONDS`; None
    without a target."""
    if cost.minutes is None:
        return None
    return share * max(0.0, 60.0 * cost.minutes - (time.perf_counter() - t_start) - OUTPUT_SECONDS)


def _windows_from(t, train, test) -> dict:
    t = np.asarray(t)
    out = {"train": (0, int(np.searchsorted(t, train[1] - 1e-9)))}
    if test is not None:
        out["test"] = (int(np.searchsorted(t, test[0] - 1e-9)), len(t))
    return out


def _plot_masks(masks: dict, split: bool) -> dict:
    if split:
        return {"train_mask": masks["train"], "test_mask": masks["test"]}
    return {"train_mask": masks["window"], "test_mask": None}


def _coverage(gap: dict) -> dict:
    return {w: {"theta": g["coverage90_theta"], "psi": g["coverage90_psi"]} for w, g in gap.items()}


def _decision(added, rows, steps, before, after, criterion="log", n_scored=1, health=None) -> str:
    """The one-sentence ``decision`` of ``discovery.json``; ``health``: the refit's
    health record (``summary.json``), whose failure the sentence states, with the first
    reason: the parameters' intervals come from that posterior."""
    w = "test" if "test" in before else "window"
    where = "the test window" if w == "test" else "the whole window"
    if not added:
        best = next((r for r in rows if r.get("score") is not None), None)
        if best is None and rows and all(r.get("skipped") for r in rows):
            return ("none: the base model's residuals are white noise on every axis a candidate acts on, "
                    f"so none of the {len(rows)} candidates was fitted (report.md, section 1).")  # fmt: skip
        why = (f"; the best, {best['effect']}, scored {gain_text(best, criterion, n_scored)} on held-out "
               "blocks" if best else "")  # fmt: skip
        if best and best.get("passes") and not best.get("supported"):
            return (f"none: no candidate effect both beats the base model by the calibrated margin and is "
                    f"supported by the fitting window{why}, above the margin, but its fitting-window log "
                    f"posterior at the MAP, less a BIC penalty per parameter, is {-best['support']:.0f} "
                    "nats below the base model's.")  # fmt: skip
        margin = "the calibrated margin" + (" of the held-out CRPS" if criterion == "crps" else "")
        return f"none: no candidate effect beats the base model by {margin}{why}."
    names = " and ".join(f"{e.split(':')[1]} on {e.split(':')[0]}" for e in added)
    tie = f" ({tie_text(steps[0])})" if steps[0].get("tied") else ""
    worse = gap_warnings(before, after)
    if health is not None and health.get("ok") is False:
        why = (health.get("warnings") or ["see refit/summary.json"])[0]
        worse.append(f"the NUTS refit failed its health checks ({why}; refit/summary.json), so its "
                     "intervals and coverage are not to be trusted")  # fmt: skip
    warn = f" Warning: {'; '.join(worse)}." if worse else ""
    return (f"Added {names}: held-out score {gain_text(steps[0], criterion, n_scored)} over the base at "
            f"the first step{tie}; on {where} "
            f"{gap_text(before[w], after[w])}.{warn}")  # fmt: skip
