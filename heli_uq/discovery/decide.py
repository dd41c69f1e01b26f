"""Decide between candidate models: rank them by held-out score, pick the singles to pair,
break ties, choose what to add (step 5 of :mod:`heli_uq.discovery.workflow`).

A model beats the current one if the deciding :class:`~heli_uq.discovery.score.Criterion`
(the held-out log density by default, or the CRPS) says so
(:func:`~heli_uq.discovery.score.passes`): its block-score difference exceeds the
calibrated margin and is significant.  Single effects
the best one does not beat by that rule are *tied* with it (effects can act alike on a
record: a dead band below every voltage used is a torque offset); the whole record's
evidence breaks the tie: the fitting window's Laplace evidence times the held-out
window's predictive density, ``log p(y_fit) + log p(y_held | y_fit)`` (for stored fits
without the evidence, the log posterior at the MAP less a BIC penalty per parameter in its
place).  A pair must beat the best single by the same rule.

A model is added only if the fitting window *supports* it too: its log posterior at the
MAP, less a BIC penalty per parameter, exceeds the current model's (``supported``). An
effect fitted to nothing (on the rig record a yaw spring of stiffness 3e-5 N m/rad, its
MAP the base model's) can still score above the margin on held-out blocks where the
current model is far off, because its free parameters (the spring's rest angle, its NUTS
95 % interval [-5.1, 5.8] rad) widen the predictive band; that gain is the band's, not the
effect's (2026-11-28: +163 +- 66 nats, 0.04 per held-out sample, for the spring whose
fitting-window log posterior gained nothing).
"""

from __future__ import annotations

import itertools

import numpy as np

from heli_uq.discovery.score import CRPS, LOG_DENSITY, Criterion, compare

__all__ = ["rank", "pairs_to_fit", "choose"]


def rank(results: dict, reference: dict, n_scored: int, n_fit: int,
         criterion: Criterion = LOG_DENSITY) -> list[dict]:  # fmt: skip
    """Candidates with their score difference to ``reference`` and its SE [nats], best
    first by ``criterion``; ``passes``: they beat ``reference`` by its margin;
    ``support``: their BIC-penalised fitting-window log posterior less ``reference``'s
    [nats] (:func:`_training_support`), ``supported``: it is positive; ``crps_gain``,
    ``crps_gain_se``: how much lower their held-out CRPS is than ``reference``'s, summed
    over the blocks [rad] (positive: better; None for a stored fit made before the CRPS
    was kept), ``crps_gain_fraction``: that over ``reference``'s CRPS."""
    rows, floor = [], _training_support(reference, n_fit)
    for key, res in results.items():
        if "error" in res:
            rows.append({"effect": key, "score": None, "score_se": None, "error": res["error"]})
            continue
        diff, se = compare(res["block_scores"], reference["block_scores"])
        support = _training_support(res, n_fit) - floor
        crps = _crps_gain(res, reference)
        rows.append({"effect": key, "score": diff, "score_se": se,
                     "score_per_sample": diff / n_scored,
                     "passes": criterion.passes(res, reference, n_scored),
                     "held_out": res["score"], "fit": res["fit"], "map_value": res["map_value"],
                     "log_evidence": res.get("log_evidence"),
                     "laplace": res.get("laplace"), "seconds": res["seconds"],
                     "support": float(support), "supported": bool(support > 0),
                     "crps_gain": crps[0], "crps_gain_se": crps[1], "crps_gain_fraction": crps[2],
                     "reused": bool(res.get("reused")),
                     **({"carried": res["carried"]} if res.get("carried") else {})})  # fmt: skip
    rows.sort(key=lambda r: np.inf if r.get(criterion.rank_key) is None else -r[criterion.rank_key])
    return rows


def _crps_gain(result: dict, reference: dict) -> tuple[float | None, float | None, float | None]:
    """``(reference's CRPS - result's, its SE, that gain over reference's CRPS)`` over
    the blocks [rad, rad, 1] (:func:`~heli_uq.discovery.score.compare` of the negated
    block CRPS; the fraction is what :data:`~heli_uq.discovery.score.MARGIN_CRPS_FRACTION`
    bounds); ``(None, None, None)`` when either lacks it or a block is not scored."""
    if "block_crps" not in result or "block_crps" not in reference:
        return None, None, None
    gain, se = CRPS.gain(result, reference)
    total = float(np.sum(reference["block_crps"]))
    if not (np.isfinite(gain) and np.isfinite(se) and total > 0):
        return None, None, None
    return gain, se, gain / total


def pairs_to_fit(rows: list[dict], top: int, anchors: int) -> list[tuple[str, str]]:
    """Pairs of singles to fit, each once, in a fixed order.

    Every pair among the ``top`` singles that fit the fitting window best (lowest V of the
    mean simulation) and the best single by held-out score; and each of the ``anchors``
    best-fitting singles with every other single the fitting window supports over the
    current model (``supported`` of :func:`rank`).  A good pair can hold a member that is
    weak alone: an effect can help in-sample and extrapolate badly alone (friction on the
    rig's yaw), or explain only part of the gap (a synthetic record hiding yaw drag and a
    pitch dead band: the dead band fitted 2nd best alone, the drag 5th of 12, and the
    pairs among the top 3 missed it, 2026-11-28).  A single the fitting window does not
    support (a pitch effect on a record whose gap is yaw) is not worth a pair fit of its
    own.  Failed singles are never paired.
    """
    ok = [r for r in rows if r["score"] is not None]
    fitted = sorted(ok, key=lambda r: r["fit"]["V"])
    by_fit = [r["effect"] for r in fitted]
    members = by_fit[:top]
    if ok and ok[0]["effect"] not in members:
        members.append(ok[0]["effect"])
    pairs = list(itertools.combinations(members, 2))
    supported = [r["effect"] for r in fitted if r["supported"]]
    for a in by_fit[:anchors]:
        pairs += [(a, b) for b in supported if b != a]
    seen, out = set(), []
    for a, b in pairs:
        if frozenset((a, b)) not in seen:
            seen.add(frozenset((a, b)))
            out.append((a, b))
    return out


def _training_support(result: dict, n_fit: int) -> float:
    """Log posterior at the MAP on the fitting window, less ``0.5 log(n_fit)`` per fitted
    coordinate (a BIC penalty; a parameter fixed by the run's priors costs nothing) [nats]:
    the tie-break between held-out-equal candidates.  A stored fit without ``n_fitted``
    counts its MAP's entries."""
    n = result.get("n_fitted", len(result["map"]))
    return -float(result["map_value"]) - 0.5 * n * np.log(n_fit)


def _tie_break_values(tied: list[dict], results: dict, n_fit: int) -> tuple[str, list[float]]:
    """What breaks a tie among the rows ``tied``: ``("evidence", values)``, the whole
    record's log evidence of each when every tied fit has the fitting window's
    (``log_evidence`` [nats]), else ``("support", values)``, with the BIC-penalised log
    posterior (:func:`_training_support`; stored fits made before the evidence was kept) in
    its place.

    By the chain rule ``log p(y) = log p(y_fit) + log p(y_held | y_fit)``: the fitting
    window's evidence plus the held-out window's log predictive density, the sum of the
    fit's ``block_scores``.  Tied rivals differ on held-out blocks by less than the margin,
    but that difference is evidence too: on a staircase record hiding a pitch offset
    (seed 302, no split, 2026-12-06) the offset, a pitch spring and a pitch quadratic thrust
    were tied; the fitting window alone favoured the thrust by 2.0 nats over the offset,
    the held-out window the offset by 3.9 over the thrust, and the whole record the offset
    (by 1.9 over the thrust, 0.6 over the spring).

    Tied effects fit the data alike, so their log posteriors at the MAP differ mostly by
    the prior densities, which carry units: a dead band's ``delta`` [V] against an
    offset's ``T_0`` [N m] favours the offset by about ``log(1 / K)`` nats, ``K`` the
    motor's gain [N m/V] (measured: 2.2 and 2.3 nats on two records with a hidden yaw dead
    band, where the evidence favours the dead band by 0.25 and 0.05).  The evidence
    integrates the prior over the posterior's width, so it compares them in one unit."""
    fits = [results[r["effect"]] for r in tied]
    held = [float(np.sum(f["block_scores"])) for f in fits]
    if all("log_evidence" in f for f in fits):
        return "evidence", [float(f["log_evidence"]) + h for f, h in zip(fits, held)]
    return "support", [_training_support(f, n_fit) + h for f, h in zip(fits, held)]


def _break_ties(best: dict, passing: list[dict], results: dict, n_scored: int, n_fit: int,
                criterion: Criterion) -> dict:  # fmt: skip
    """Among the passing rows that ``best`` does not beat by the margin (``passes``), the
    one the whole record supports most (:func:`_tie_break_values`).  Every tied row gets
    ``tied: True``; the chosen one ``chosen_by: "whole-record evidence"`` if it is not
    ``best``, and ``tie_break``: ``{"by": "evidence" or "support", "margin": nats over
    the runner-up}`` (a margin under 1 nat is a Bayes factor under e: the record does not
    tell the rivals apart).  Held-out blocks alone cannot separate effects that act alike
    on the record (a dead band below every voltage used is a torque offset on the same
    motor's axes); the fitting window's evidence joins them, and the report names the
    rivals."""
    tied = [r for r in passing
            if r is best or not criterion.passes(results[best["effect"]], results[r["effect"]], n_scored)]
    if len(tied) == 1:
        return best
    by, values = _tie_break_values(tied, results, n_fit)
    order = np.argsort(values)[::-1]
    chosen = tied[order[0]]
    for r in tied:
        r["tied"] = True
    chosen["tie_break"] = {"by": by, "margin": float(values[order[0]] - values[order[1]])}
    if chosen is not best:
        chosen["chosen_by"] = "whole-record evidence"
    return chosen


def choose(rows: list[dict], results: dict, n_scored: int, n_fit: int, criterion: Criterion = LOG_DENSITY):
    """The row to add (module docstring) by ``criterion``, or None; ``rows`` as
    :func:`rank` orders them by the same criterion."""
    passing = [r for r in rows if r.get("passes") and r.get("supported")]
    if not passing:
        return None
    singles = [r for r in passing if len(r["added"]) == 1]
    best_single = _break_ties(singles[0], singles, results, n_scored, n_fit, criterion) if singles else None
    best_pair = next((r for r in passing if len(r["added"]) == 2), None)
    if best_pair is None:
        return best_single
    if best_single is None:
        return best_pair
    # the pair must beat the single by the margin too
    better = criterion.passes(results[best_pair["effect"]], results[best_single["effect"]], n_scored)
    return best_pair if better else best_single
