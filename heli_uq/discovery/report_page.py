"""``report.md`` of a discovery run, the page a person reads first: the decision, where
the base model fails, what was tried and by how much it won, the before/after gap and
the refit's health (:func:`report_page`), and the warnings when the refitted model
predicts a window worse than the base (:func:`gap_warnings`)."""

from __future__ import annotations

import pathlib

import numpy as np

from heli_uq.data import unseen_inputs
from heli_uq.discovery.score import GAP_KEYS, MARGIN_CRPS_FRACTION, MARGIN_SE
from heli_uq.discovery.screen import screen_text
from heli_uq.model import AXES
from heli_uq.simulation.stiffness import edge_text

__all__ = ["report_page", "gap_warnings", "parameter_text", "tie_text", "CLOSER_V_FRACTION",
           "TIE_EVIDENCE_NATS"]

#: A first-step candidate whose held-out V is below this fraction of the base model's but
#: whose held-out score is negative is named in the report (closer, yet overconfident).
CLOSER_V_FRACTION = 0.8


def parameter_text(name: str, p: dict) -> str:
    """``"F_c = 0.0207 [0.0061, 0.043] N m"`` from a ``discovery.json`` parameter entry, and
    ``"; F_c / M22(theta_ref) = 0.8 [0.5, 1.1] (N m) / (kg m^2), what the record identifies"``
    when it has ``per_inertia``; a parameter the run's priors fix is given at its value and
    said to be fixed."""
    unit = "" if p["unit"] == "1" else f" {p['unit']}"  # dimensionless: no unit
    if p.get("fixed"):
        return f"{name} = {p['mean']:.4g}{unit}, fixed by the run's priors"
    text = f"{name} = {p['mean']:.4g} [{p['ci95'][0]:.4g}, {p['ci95'][1]:.4g}]{unit}"
    if "per_inertia" in p:
        r = p["per_inertia"]
        r_unit = "" if r["unit"] == "1" else f" {r['unit']}"
        text += (f"; {name} / {r['inertia']} = {r['mean']:.4g} [{r['ci95'][0]:.4g}, {r['ci95'][1]:.4g}]"
                 f"{r_unit}, what the record identifies")  # fmt: skip
    return text


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



#: A tie decided by less than this [nats] of log evidence is a Bayes factor under e, "not
#: worth more than a bare mention" (Kass and Raftery 1995): the record does not tell the
#: rivals apart.
TIE_EVIDENCE_NATS = 1.0
_TIE_BY = {"evidence": "the whole record's evidence (the fitting window's Laplace evidence and the "
                       "held-out log score)",
           "support": "the fitting window's log posterior at the MAP, less a BIC penalty per parameter, "
                      "and the held-out log score"}


def tie_text(step: dict) -> str:
    """How a step's tie was broken (``step["tied"]``, ``step["tie_break"]``, see
    :func:`heli_uq.discovery.decide.choose`), as a clause."""
    tb = step.get("tie_break") or {}
    text = (f"tied on held-out blocks with {', '.join(step['tied'])}; "
            f"{_TIE_BY.get(tb.get('by'), 'the fitting window')} decided")  # fmt: skip
    if "margin" in tb:
        text += f", by {tb['margin']:.2f} nats"
        if tb.get("by") == "evidence" and tb["margin"] < TIE_EVIDENCE_NATS:
            text += " (a Bayes factor under e: this record cannot tell them apart)"
    return text


def _fmt_gap(g: dict) -> str:
    return " | ".join(f"{g[k]:.3f}" if "rmse" in k or k == "V" else f"{g[k]:.0%}" for k in GAP_KEYS)


def _crps_better(c: dict) -> bool:
    """The candidate's held-out CRPS beats the current model's by :data:`MARGIN_SE` SE."""
    return c.get("crps_gain") is not None and c["crps_gain"] > MARGIN_SE * c["crps_gain_se"]


def _crps_per_sample(c: dict, n_scored: int) -> tuple[float, float] | None:
    """The candidate's CRPS gain and its SE per held-out sample [rad], or None (a fit stored
    before the CRPS was kept)."""
    if c.get("crps_gain") is None:
        return None
    return c["crps_gain"] / n_scored, c["crps_gain_se"] / n_scored


def _crps_text(c: dict, n_scored: int) -> str:
    """``", CRPS 0.246 ± 0.089 rad per sample lower"`` (empty without a CRPS gain)."""
    per = _crps_per_sample(c, n_scored)
    if per is None:
        return ""
    return f", CRPS {abs(per[0]):.3g} ± {per[1]:.2g} rad per sample {'lower' if per[0] > 0 else 'higher'}"


def _closer_lines(candidates: list[dict], base_score: dict, n_scored: int,
                  criterion: str = "log") -> list[str]:  # fmt: skip
    """A paragraph on the first-step candidates whose held-out score is below the base's
    although they predict better by another measure: their held-out mean simulation is much
    closer to the data (V below :data:`CLOSER_V_FRACTION` of the base's), or their CRPS is
    lower by :data:`~heli_uq.discovery.score.MARGIN_SE` SE.  Their bands are narrower than
    their misses.  ``criterion``: the score that decided (``"log"`` or ``"crps"``)."""
    closer = [c for c in candidates if c.get("step") == 1 and c.get("score") is not None and c["score"] < 0
              and (c["held_out"]["V"] < CLOSER_V_FRACTION * base_score["V"] or _crps_better(c))]  # fmt: skip
    if not closer:
        return []
    names = "; ".join(f"{c['effect']} ({c['axis']}): V {c['held_out']['V']:.3g} against the base's "
                      f"{base_score['V']:.3g} rad^2, score {c['score']:+.0f} nats{_crps_text(c, n_scored)}"
                      for c in closer)  # fmt: skip
    crps = ""
    if any(map(_crps_better, closer)):
        which = "them" if all(map(_crps_better, closer)) else "those it beats by 2 SE"
        decides = (", and decides here (`--score crps`)." if criterion == "crps" else
                   "; the log density decides (`--score crps` lets the CRPS decide, with its own margin "
                   "calibrated on records without a hidden effect).")  # fmt: skip
        crps = (" The CRPS, a proper score that charges a miss by its size rather than by its square "
                f"in units of the band, prefers {which}{decides}")
    return ["", f"**Closer, yet scored below the base:** {names}. Their mean simulation is nearer the "
            "held-out data, but their predictive bands are narrower than their misses, and the log "
            "predictive density penalises a confident miss more than the base model's wider band." + crps]


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


def _crps_cell(c: dict, n_scored: int) -> str:
    """``"+0.246 ± 0.089"`` per sample [rad], or ``"–"`` (a fit stored before the CRPS was kept)."""
    per = _crps_per_sample(c, n_scored)
    return "–" if per is None else f"{per[0]:+.3g} ± {per[1]:.2g}"


def _fit_seconds(row: dict) -> str:
    """The fit-time cell of a candidate row: its seconds, or the step it was fitted in
    when it was carried from an earlier step's pairs."""
    return f"step {row['carried']}" if row.get("carried") else f"{row['seconds']:.0f}"


def _reused_text(candidates: list[dict]) -> str:
    """A sentence when candidate fits were reused from an earlier run in the same directory
    (the minutes above then do not include them)."""
    n = sum(bool(c.get("reused")) for c in candidates)
    if not n:
        return ""
    spent = sum(c["seconds"] for c in candidates if c.get("reused") and c.get("seconds") is not None)
    fitted = sum(not c.get("skipped") for c in candidates)
    return (f" {n} of {fitted} candidate fits were reused from an earlier run in this "
            f"directory; the minutes above exclude them (they took {spent / 60:.1f} worker-minutes "
            "then).")


def _model_lines(base_label, priors) -> list[str]:
    """The base model and the priors changed in every model fitted (nothing if neither)."""
    if base_label is None and not priors:
        return []
    text = f"Base model: {base_label}." if base_label else ""
    if priors:
        text += (" Priors changed from the defaults, in every model fitted that has the parameter "
                 "(base, candidates, refit): "
                 + ", ".join(f"`{n}`: {p.describe()}" for n, p in priors) + ".")  # fmt: skip
    return [text.strip(), ""]


def _criterion_text(criterion: str) -> str:
    """Which of the two scores decided (the parenthesis of the candidates table's legend)."""
    if criterion == "log":
        return "(a second proper score, reported; the log density decides)."
    return (f"(**the CRPS decides**, `--score crps`: *passes* means a CRPS lower than the current "
            f"model's by {MARGIN_CRPS_FRACTION:.1%} of it and by {MARGIN_SE:g} SE; the rows are "
            "ordered by it, and the log density is reported).")


def _white_lines(white) -> list[str]:
    """The screen's finding (:mod:`~heli_uq.discovery.screen`): per axis, white or not."""
    if not white:
        return []
    said = ", ".join(f"{axis} **{'white' if white[axis]['white'] else 'not white'}**" for axis in AXES)
    return ["", f"Residuals of the base model: {said} ({screen_text(white)}; white at p >= "
            f"{white['p_white']:g} on both windows). A candidate that acts only on white axes is "
            "not fitted: nothing is left there for a torque to explain."]  # fmt: skip


def _edge_lines(edge) -> list[str]:
    """The base fit pinned at the solver's limit (:func:`~heli_uq.simulation.stiffness.damping_edge`)."""
    return [] if not edge else ["", f"**The base fit is pinned by the solver:** {edge_text(edge)}."]


def report_page(result, where, ranking, steps, base, budget, fit_window, score_window, n_scored, health,
                whole, seconds, record, base_label=None, priors=(), criterion="log") -> str:  # fmt: skip
    """The text of ``report.md``.  ``seconds``: the whole run's and the search's (base
    fit, candidates, decision) [s]; ``base_label``: the base model's; ``priors``: pairs
    ``(name, Prior)`` changed from the defaults in every model fitted that has the name;
    ``criterion``: the name of the held-out score that decided (``"log"`` or ``"crps"``)."""
    total, search = seconds
    lines = [f"# Discovery report: {pathlib.Path(str(record.source)).name}", "",
             f"**Decision.** {result['decision']}", "",
             f"Budget `{budget}`, {total / 60:.1f} min: {search / 60:.1f} min to fit and score the "
             f"candidates, {(total - search) / 60:.1f} min for the NUTS posterior and these outputs. "
             f"Candidates fitted on {fit_window[0]:g}-"
             f"{fit_window[1]:g} s and scored on {score_window[0]:g}-{score_window[1]:g} s "
             f"({n_scored} samples in input-segment blocks).{_reused_text(result['candidates'])}", "",
             *_model_lines(base_label, priors),
             "## 1. Where the base model fails", "",
             f"Worst axis: **{where['axis']}** (held-out RMSE / the data's noise scale there, from "
             f"successive differences: pitch {where['error_ratio']['theta']:.1f}, yaw "
             f"{where['error_ratio']['psi']:.1f}).",
             *_white_lines(where.get("white")), *_edge_lines(where.get("solver_edge")), "",
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
              "passes the margin and this is positive. *Fit* gives *step N* for a model fitted as "
              "a pair at step N and not fitted again. *CRPS gain*: how much lower the held-out "
              "CRPS is than the current model's, per sample, with its SE [rad] "
              + _criterion_text(criterion), "",
              "| step | effect | axis | score [nats] | SE | per sample | passes | support [nats] | "
              "CRPS gain [rad] | held-out RMSE pitch / yaw [rad] | held-out V | Pareto k (ESS) | fit [s] |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for c in result["candidates"]:
        if c.get("score") is None:
            why = c["skipped"] if c.get("skipped") else f"failed: {c.get('error')}"
            lines.append(f"| {c['step']} | {c['effect']} | {c['axis']} | {why} | | | | | | | | | |")
            continue
        held, imp = c["held_out"], c.get("laplace") or {}
        k = f"{imp['pareto_k']:.2f} ({imp['ess']:.0f})" if imp else "–"
        k += " *MAP*" if imp.get("predictive") == "map" else ""
        lines.append(f"| {c['step']} | {c['effect']} | {c['axis']} | {c['score']:+.0f} | {c['score_se']:.0f} "
                     f"| {c['score_per_sample']:+.3f} | {'yes' if c['passes'] else 'no'} | "
                     f"{c['support']:+.0f} | {_crps_cell(c, n_scored)} | "
                     f"{held['rmse_theta']:.3f} / {held['rmse_psi']:.3f} | {held['V']:.3f} | {k} | "
                     f"{_fit_seconds(c)} |")  # fmt: skip
    lines += _closer_lines(result["candidates"], base["score"], n_scored, criterion)
    lines += ["", "## 4. Steps", ""]
    for s in steps:
        what = ", ".join(s["added"]) if s["added"] else s.get("decision", "")
        if s.get("tied"):
            what += f" ({tie_text(s)}; no rival beats the other by the margin)"
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
            lines += [f"- {a['effect']} ({a['axis']}): {parameter_text(name, p)}"
                      for name, p in a["parameters"].items()]
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
