"""The refit of the chosen model and the outputs of a discovery run.

* ``discovery.json``: exactly the keys ``effect, axis, parameters, gap_before, gap_after,
  candidates, decision, added``.  The gap records hold ``rmse_theta, rmse_psi`` [rad],
  ``V`` [rad^2] and ``coverage90_theta, coverage90_psi`` per window: ``{"train": ...,
  "test": ...}`` when a split was given, else ``{"window": ...}``.  *After* is the NUTS
  posterior of the chosen model; *before* the base model's NUTS posterior (``full``) or
  its Laplace approximation at the MAP (``quick``).
* ``report.md``; ``bands_before.png``, ``bands_after.png``, ``residuals.png``,
  ``candidates.png``; ``refit/`` (``posterior.nc``, ``summary.json`` of the refit).
"""

from __future__ import annotations

import json
import pathlib
import time

import numpy as np

from heli_uq.data import unseen_inputs
from heli_uq.discovery.candidates import FitTask, fitted_predictive
from heli_uq.discovery.candidates_figure import candidates_figure
from heli_uq.discovery.score import GAP_KEYS, gap_metrics, gap_text
from heli_uq.figure import save_figure
from heli_uq.io import atomic_write_text
from heli_uq.model import build_model
from heli_uq.output import parameter_summary, plot_bands, sample_posterior

__all__ = ["write_outputs", "gap_warnings", "DISCOVERY_KEYS"]

#: A first-step candidate whose held-out V is below this fraction of the base model's but
#: whose held-out score is negative is named in the report (closer, yet overconfident).
CLOSER_V_FRACTION = 0.8
#: Share of the time target left that the base model's NUTS posterior may use when a refit
#: follows.  The refit is the run's result and the stiffer model: on a pitch friction record
#: (full budget, 2026-11-28) the base posterior used 24 of its 27 min at half, and the
#: refit, left 30 min, could keep only 111 draws per chain.
BEFORE_SHARE = 1.0 / 3.0
#: Seconds a budget with a time target (:attr:`~heli_uq.discovery.workflow.Budget.minutes`)
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


def _posterior(record, model, train, test, out, cost, seed, guess, time_limit=None):
    """NUTS posterior of ``model`` (MAP warm-started from ``guess``, the model's fit on the
    fitting window): ``(idata, summary, y_sim, y_pred, y_obs, t)``.  ``time_limit`` [s]:
    see :func:`heli_uq.output.sample_posterior`.

    With a split the posterior is conditioned on the fitting window itself, where ``guess``
    is already the multi-start MAP of the same model, so it is the only start (more
    starts cost a stiff model minutes and find nothing better); on a single window the
    posterior also sees the scoring part, and the budget's starts are tried too.
    """
    starts = 1 if test is not None else cost.n_starts
    idata, summary = sample_posterior(record, out, model=model, train=train, test=test, sampler="nuts",
                                      error="iid", chains=cost.chains, warmup=cost.warmup,
                                      draws=cost.samples, seed=seed, progress=False,
                                      max_tree_depth=cost.max_tree_depth, n_starts=starts,
                                      adapt_mass_matrix=cost.adapt_mass_matrix,
                                      guesses=(guess,), time_limit=time_limit,
                                      max_draws=cost.max_samples)  # fmt: skip
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
        for k in ("score_per_sample", "passes", "support", "supported", "tied", "chosen_by", "held_out",
                  "fit", "laplace", "seconds", "reused", "error"):
            if k in r:
                row[k] = r[k]
        out.append(row)
    return out


def _effect_parameters(summary_params: dict, effect: str) -> dict:
    """``{bare name: {mean, ci95, unit}}`` of the parameters of ``effect`` (``"axis:kind"``)."""
    names = [par.name for par in build_model([effect]).effects[0].parameters()]
    return {summary_params[n]["bare"]: {k: summary_params[n][k] for k in ("mean", "ci95", "unit")}
            for n in names if n in summary_params}  # fmt: skip


def write_outputs(out: pathlib.Path, *, record, base_effects, added, base, base_fit, where, ranking,
                  rows, steps, cost, budget, seed, full, refit, chosen_map, fit_window, score_window,
                  n_scored, say, t_start) -> dict:  # fmt: skip
    """Refit, compare and write every output (module docstring); returns ``discovery.json``."""
    search_seconds = time.perf_counter() - t_start
    train, test = refit
    split = test is not None
    base_model = build_model(base_effects)
    # before
    if full:
        say("NUTS posterior of the base model (before); its times count from its own start")
        share = BEFORE_SHARE if added else 1.0  # of the time target left: the refit needs the rest
        _, _, bs, bp, by, bt = _posterior(record, base_model, train, test, out / "before", cost, seed,
                                          base_fit.params, _time_left(cost, t_start, share))  # fmt: skip
        problem_windows = _windows_from(bt, train, test)
    else:
        fitted = base_fit if split else fitted_predictive(
            FitTask(record, train, None, tuple(base_effects), (base_fit.params,), seed, 1, cost.draws,
                    cost.newton_steps))  # fmt: skip
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
                                                     _time_left(cost, t_start))  # fmt: skip
        masks_after = _masks(len(at), _windows_from(at, train, test), split)
        gap_after = _gap(as_, ap, ay, masks_after)
        params = parameter_summary(idata, build_model(effects))
        health = summary.get("health", {"ok": summary.get("converged"), "warnings": []})
    else:
        as_, ap, ay, at, gap_after, params, health = bs, bp, by, bt, gap_before, {}, None
        masks_after = before_masks
    first = added[0] if added else None
    result = {
        "effect": first.split(":")[1] if first else "none",
        "axis": first.split(":")[0] if first else None,
        "parameters": _effect_parameters(params, first) if first else {},
        "gap_before": gap_before, "gap_after": gap_after,
        "candidates": _candidate_rows(rows),
        "decision": _decision(added, rows, steps, gap_before, gap_after),
        "added": [{"effect": e.split(":")[1], "axis": e.split(":")[0],
                   "parameters": _effect_parameters(params, e)} for e in added],
    }  # fmt: skip
    assert tuple(result) == DISCOVERY_KEYS
    atomic_write_text(out / "discovery.json", json.dumps(result, indent=1))
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
    save_figure(candidates_figure(result["candidates"], n_scored), out / "candidates.png")
    label = budget if isinstance(budget, str) else repr(budget)
    whole = {"before": gap_metrics(bs, bp, by), "after": gap_metrics(as_, ap, ay)}
    seconds = (time.perf_counter() - t_start, search_seconds)
    atomic_write_text(out / "report.md", _report(result, where, ranking, steps, base, label, fit_window,
                                                 score_window, n_scored, health, whole, seconds,
                                                 record))  # fmt: skip
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


def gap_warnings(before: dict, after: dict) -> list[str]:
    """What the refitted model predicts worse than the base: one sentence per window whose
    V (the mean squared error of the posterior-mean simulation, both angles) grew.

    A candidate is chosen on Laplace draws at its MAP; the NUTS refit can land elsewhere
    (an unconverged chain, a second mode), and an added effect must not be reported as a
    fix when the refitted model fits the record worse.

    Parameters
    ----------
    before, after : dict
        Gap records ``{window: {rmse_theta, rmse_psi, V, ...}}`` (module docstring).
    """
    out = []
    for w in before:
        if after[w]["V"] > before[w]["V"]:
            out.append(f"the refitted model predicts the {w} window worse than the base: V "
                       f"{before[w]['V']:.4g} -> {after[w]['V']:.4g} rad^2 (RMSE pitch "
                       f"{before[w]['rmse_theta']:.3f} -> {after[w]['rmse_theta']:.3f}, yaw "
                       f"{before[w]['rmse_psi']:.3f} -> {after[w]['rmse_psi']:.3f} rad)")  # fmt: skip
    return out


def _decision(added, rows, steps, before, after) -> str:
    w = "test" if "test" in before else "window"
    where = "the test window" if w == "test" else "the whole window"
    if not added:
        best = next((r for r in rows if r.get("score") is not None), None)
        why = (f"; the best, {best['effect']}, scored {best['score']:+.0f} ± {best['score_se']:.0f} "
               f"nats on held-out blocks") if best else ""  # fmt: skip
        if best and best.get("passes") and not best.get("supported"):
            return (f"none: no candidate effect both beats the base model by the calibrated margin and is "
                    f"supported by the fitting window{why}, above the margin, but its fitting-window log "
                    f"posterior at the MAP, less a BIC penalty per parameter, is {-best['support']:.0f} "
                    "nats below the base model's.")  # fmt: skip
        return f"none: no candidate effect beats the base model by the calibrated margin{why}."
    names = " and ".join(f"{e.split(':')[1]} on {e.split(':')[0]}" for e in added)
    tied = steps[0].get("tied") or []
    tie = (f" (tied on held-out blocks with {', '.join(tied)}; the fitting window decided)"
           if tied else "")  # fmt: skip
    worse = gap_warnings(before, after)
    warn = f" Warning: {'; '.join(worse)}." if worse else ""
    return (f"Added {names}: held-out score +{steps[0]['score']:.0f} ± {steps[0]['score_se']:.0f} nats "
            f"over the base at the first step{tie}; on {where} "
            f"{gap_text(before[w], after[w])}.{warn}")  # fmt: skip


def _fmt_gap(g: dict) -> str:
    return " | ".join(f"{g[k]:.3f}" if "rmse" in k or k == "V" else f"{g[k]:.0%}" for k in GAP_KEYS)


def _closer_lines(candidates: list[dict], base_score: dict) -> list[str]:
    """A paragraph on the first-step candidates whose held-out mean simulation is much closer
    to the data than the base model's (V below :data:`CLOSER_V_FRACTION` of its) but whose
    held-out score is below the base's: their bands are narrower than their misses."""
    closer = [c for c in candidates if c.get("step") == 1 and c.get("score") is not None and c["score"] < 0
              and c["held_out"]["V"] < CLOSER_V_FRACTION * base_score["V"]]  # fmt: skip
    if not closer:
        return []
    names = "; ".join(f"{c['effect']} ({c['axis']}): V {c['held_out']['V']:.3g} against the base's "
                      f"{base_score['V']:.3g} rad^2, score {c['score']:+.0f} nats"
                      for c in closer)  # fmt: skip
    return ["", f"**Closer, yet scored below the base:** {names}. Their mean simulation is nearer the "
            "held-out data, but their predictive bands are narrower than their misses, and the log "
            "predictive density penalises a confident miss more than the base model's wider band."]


def _unseen_lines(record, fit_window, score_window) -> list[str]:
    """A paragraph on the scored samples whose voltage pair the fitting window never holds
    (none when the two windows are the same or every pair is seen)."""
    if tuple(fit_window) == tuple(score_window):
        return []
    scored = np.asarray(record.window(*score_window).u)
    new = unseen_inputs(record.window(*fit_window).u, scored)
    if not new.any():
        return []
    pairs = len(np.unique(scored[new], axis=0))
    return ["", f"The scored window holds **{pairs} voltage pair(s) the fitting window never holds**, "
            f"{new.mean():.0%} of its samples: there a score measures extrapolation in the inputs "
            "(a gain error or an input nonlinearity is not constrained by the fit)."]


def _reused_text(candidates: list[dict]) -> str:
    """A sentence when candidate fits were reused from an earlier run in the same directory
    (the minutes above then do not include them)."""
    n = sum(bool(c.get("reused")) for c in candidates)
    if not n:
        return ""
    spent = sum(c["seconds"] for c in candidates if c.get("reused") and c.get("seconds") is not None)
    return (f" {n} of {len(candidates)} candidate fits were reused from an earlier run in this "
            f"directory; the minutes above exclude them (they took {spent / 60:.1f} worker-minutes "
            "then).")


def _report(result, where, ranking, steps, base, budget, fit_window, score_window, n_scored, health,
            whole, seconds, record) -> str:  # fmt: skip
    """``seconds``: the whole run's and the search's (base fit, candidates, decision) [s]."""
    total, search = seconds
    lines = [f"# Discovery report: {pathlib.Path(str(record.source)).name}", "",
             f"**Decision.** {result['decision']}", "",
             f"Budget `{budget}`, {total / 60:.1f} min: {search / 60:.1f} min to fit and score the "
             f"candidates, {(total - search) / 60:.1f} min for the NUTS posterior and these outputs. "
             f"Candidates fitted on {fit_window[0]:g}-"
             f"{fit_window[1]:g} s and scored on {score_window[0]:g}-{score_window[1]:g} s "
             f"({n_scored} samples in input-segment blocks).{_reused_text(result['candidates'])}", "",
             "## 1. Where the base model fails", "",
             f"Worst axis: **{where['axis']}** (held-out RMSE / fitted error scale: pitch "
             f"{where['error_ratio']['theta']:.1f}, yaw {where['error_ratio']['psi']:.1f}).", "",
             "| window | RMSE pitch [rad] | outside 90 % pitch | RMSE yaw [rad] | outside 90 % yaw |",
             "|---|---|---|---|---|"]  # fmt: skip
    for w, m in where["windows"].items():
        lines.append(f"| {w} | {m['rmse_theta']:.3f} | {m['outside90_theta']:.0%} | {m['rmse_psi']:.3f} | "
                     f"{m['outside90_psi']:.0%} |")  # fmt: skip
    imp = base.get("laplace")
    if imp:
        how = ("its Laplace draws resampled by importance weights" if imp["predictive"] == "laplace" else
               "the plug-in predictive at its MAP (the importance weights of its Laplace draws rejected)")
        lines += ["", f"The base model's predictive band is {how}: Pareto k {imp['pareto_k']:.2f}, "
                  f"ESS {imp['ess']:.0f}."]  # fmt: skip
    worst = sorted(where["segments"], key=lambda s: -max(s["outside90_theta"], s["outside90_psi"]))[:5]
    lines += _unseen_lines(record, fit_window, score_window)
    lines += ["", "Input segments with the most misses (share outside the 90 % band):", "",
              "| t [s] | u_theta [V] | u_psi [V] | pitch | yaw |", "|---|---|---|---|---|"]
    lines += [f"| {s['t0']:.1f}-{s['t1']:.1f} | {s['u_theta']:.3f} | {s['u_psi']:.3f} | "
              f"{s['outside90_theta']:.0%} | {s['outside90_psi']:.0%} |" for s in worst]
    lines += ["", f"Misses of the {where['axis']} band vary most with: "
              + ", ".join(where["strongest_features"]) + " (`residuals.png`).", "",
              "## 2. The missing torque (sparse regression, pysindy)", "",
              "Inclusion probability of each candidate's feature in a bagged STLSQ fit of the "
              "torque the data imply (a ranking and start values only; the fits decide):", "",
              "| effect | inclusion | explained | implied parameters |", "|---|---|---|---|"]  # fmt: skip
    lines += [f"| {r['effect']} | {r['inclusion']:.2f} | {r['explained']:.3f} | "
              + ", ".join(f"{k} = {v:.3g}" for k, v in r["implied"].items()) + " |" for r in ranking]
    lines += ["", "## 3. Candidates (held-out score vs the current model)", "",
              "Each candidate's predictive is its Laplace approximation at the MAP, resampled by "
              "importance weights toward the posterior (ESS: their effective number); where Pareto k "
              "exceeds 0.7 the weights are not trusted and the predictive is the plug-in one at the "
              "MAP (marked *MAP*).", "",
              "*Support*: the fitting window's log posterior at the MAP, less 0.5 log(n) per "
              "parameter (BIC), minus the current model's [nats]; a candidate is added only if it "
              "passes the margin and this is positive.", "",
              "| step | effect | axis | score [nats] | SE | per sample | passes | support [nats] | "
              "held-out RMSE pitch / yaw [rad] | held-out V | Pareto k (ESS) | fit [s] |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for c in result["candidates"]:
        if c.get("score") is None:
            lines.append(f"| {c['step']} | {c['effect']} | {c['axis']} | failed: {c.get('error')} |"
                         " | | | | | | | |")  # fmt: skip
            continue
        held, imp = c["held_out"], c.get("laplace") or {}
        k = f"{imp['pareto_k']:.2f} ({imp['ess']:.0f})" if imp else "–"
        k += " *MAP*" if imp.get("predictive") == "map" else ""
        lines.append(f"| {c['step']} | {c['effect']} | {c['axis']} | {c['score']:+.0f} | {c['score_se']:.0f} "
                     f"| {c['score_per_sample']:+.3f} | {'yes' if c['passes'] else 'no'} | "
                     f"{c['support']:+.0f} | "
                     f"{held['rmse_theta']:.3f} / {held['rmse_psi']:.3f} | {held['V']:.3f} | {k} | "
                     f"{c['seconds']:.0f} |")  # fmt: skip
    lines += _closer_lines(result["candidates"], base["score"])
    lines += ["", "## 4. Steps", ""]
    for s in steps:
        what = ", ".join(s["added"]) if s["added"] else s.get("decision", "")
        if s.get("tied"):
            what += (f" (tied on held-out blocks with {', '.join(s['tied'])}: no rival beats the other "
                     "by the margin; the fitting window's log posterior at the MAP, less a BIC "
                     "penalty per parameter, decided)")  # fmt: skip
        lines.append(f"- step {s['step']}: {what}")
    lines += ["", "## 5. Before and after", "",
              "| window | model | RMSE pitch [rad] | RMSE yaw [rad] | V [rad^2] | 90 % pitch | 90 % yaw |",
              "|---|---|---|---|---|---|---|"]  # fmt: skip
    for w in result["gap_before"]:
        lines.append(f"| {w} | before | {_fmt_gap(result['gap_before'][w])} |")
        lines.append(f"| {w} | after | {_fmt_gap(result['gap_after'][w])} |")
    if len(result["gap_before"]) > 1:
        lines.append(f"| whole span | before | {_fmt_gap(whole['before'])} |")
        lines.append(f"| whole span | after | {_fmt_gap(whole['after'])} |")
    if result["added"]:
        lines += ["", "Added parameters (NUTS posterior mean, 95 % interval):", ""]
        for a in result["added"]:
            for name, p in a["parameters"].items():
                lines.append(f"- {a['effect']} ({a['axis']}): {name} = {p['mean']:.4g} "
                             f"[{p['ci95'][0]:.4g}, {p['ci95'][1]:.4g}] {p['unit']}")  # fmt: skip
        worse = gap_warnings(result["gap_before"], result["gap_after"])
        if worse:
            lines += ["", "**Warning: the gap did not shrink.**", ""] + [f"- {w}" for w in worse]
        if health is not None and not health.get("ok", True):
            lines += ["", "**Warning: the NUTS refit failed its health checks** (`refit/summary.json`):", ""]
            lines += [f"- {w}" for w in health.get("warnings", [])]
        if health is not None and health.get("notes"):
            lines += ["", "Notes on the NUTS refit:", ""] + [f"- {n}" for n in health["notes"]]
    lines += ["", "Figures: `residuals.png`, `candidates.png`, `bands_before.png`, `bands_after.png`.", ""]
    return "\n".join(lines)
