"""Which fits nest which, between the rounds of a discovery run
(:mod:`heli_uq.discovery.workflow`): a candidate model is the current model plus effects,
so with those effects switched off it *is* the current model, and a pair is either of its
members with the other member's effect off.  These rules say when a fit can stand for
another (kept, carried into the next step) and where a fit starts from.
"""

from __future__ import annotations

import numpy as np

from heli_uq.discovery.candidates import NESTED_SLACK_NATS

__all__ = ["RESTART_NATS", "nested_guess", "beyond", "pair_start", "carried", "model_key"]

#: A candidate whose fitting-window log posterior beats the current model's by more than
#: this [nats] triggers one refit of the current model from the candidate's values.
RESTART_NATS = 10.0


def nested_guess(results: dict, current_res: dict, current_map: dict) -> dict | None:
    """The current model's parameters at the MAP of the candidate that fits the fitting
    window best, if that candidate beats the current MAP by more than
    :data:`RESTART_NATS`, else None.

    A candidate nests the current model (its effect at zero is the current model), so a
    much better candidate fit can mean the current MAP sits in a poor basin (a stiff
    hidden effect can trap the base model's optimiser); refitting the current model from
    the candidate's values finds out.  Not so when the current fit is pinned at the
    solver's limit and that candidate is not (``solver_edge``): the candidate's effect
    does what the current model imitated by damping, so its lead is the effect's, and the
    current model's basins along the limit differ by what the solver allows (on a pitch
    friction record such a restart gained 353 nats there and cost 5 of 13.5 min, to refit
    the eleven other candidates for the same answer).
    """
    fitted = [r for r in results.values() if "error" not in r and np.isfinite(r["map_value"])]
    if not fitted:
        return None
    best = min(fitted, key=lambda r: r["map_value"])
    if best["map_value"] >= current_res["map_value"] - RESTART_NATS:
        return None
    if current_res.get("solver_edge") and not best.get("solver_edge"):
        return None
    return {k: v for k, v in best["map"].items() if k in current_map}


def beyond(results: dict, current_res: dict) -> dict:
    """The candidate fits whose MAP is at least as good as the current model's (after a
    restart found it a better basin): they are kept.  A candidate nests the current model,
    so one that fits worse than it sits in a poorer basin and is refitted from it; one
    that fits as well or better is not helped by that start."""
    return {k: r for k, r in results.items()
            if "error" not in r and r["map_value"] <= current_res["map_value"]}  # fmt: skip


def pair_start(a: dict, b: dict) -> tuple[dict, dict]:
    """``(guess, member)`` of the pair of two fitted singles ``a`` and ``b``: its start,
    ``a``'s MAP with ``b``'s own parameters at ``b``'s MAP, and the member with the
    better MAP, which the pair nests (with the other effect off it *is* that member).
    The pair's fit falls back to that member's MAP with the other effect switched off
    when it ends more than :data:`~heli_uq.discovery.candidates.NESTED_SLACK_NATS` above it
    (:func:`~heli_uq.discovery.candidates.fitted_predictive`).

    The members' MAPs already come from their own warm starts (the rig fit's among them),
    so a pair needs no more.  Measured on a 131 s record hiding yaw friction and pitch
    drag (rig_steps, seed 87, 2026-11-28), against the earlier three starts (this one,
    the current MAP with both effects probed, the rig fit) nesting the current model:
    friction + pitch offset 38 -> 20 s and friction + pitch drag 64 -> 18 s to the same
    MAP; friction + yaw spring 96 -> 52 s, where the old fit ended 32,000 (in the
    discovery run) and 108,000 nats (in this measurement) above friction alone, its
    fallback being the base model with both effects off, which went stiff at 16
    substeps, and the new one 15 nats above it (the spring's prior terms)."""
    guess = {**a["map"], **{k: v for k, v in b["map"].items() if k not in a["map"]}}
    return guess, min(a, b, key=lambda r: r["map_value"])


def carried(results: dict, current: list[str], current_res: dict, step: int) -> dict:
    """This step's fits that are the next step's singles, keyed as those: models of the new
    ``current`` plus one effect (a pair holding the chosen single), whose MAP is no worse
    than ``current_res``'s by more than :data:`~heli_uq.discovery.candidates.NESTED_SLACK_NATS`
    (they nest it; one that fits worse sits in a poorer basin and is fitted again from the
    new current model).  The same model on the same windows is not fitted twice: on a
    two-effect record (2026-11-28, yaw dead band + pitch spring) step 2 refitted 4 of its
    11 singles that step 1 had fitted as pairs."""
    out = {}
    for key, r in results.items():
        effects = key.split("+")
        extra = [e for e in effects if e not in current]
        if ("error" not in r and len(extra) == 1 and len(effects) == len(current) + 1
                and r["map_value"] <= current_res["map_value"] + NESTED_SLACK_NATS):
            out[model_key(current + extra)] = {**r, "reused": False, "carried": step}
    return out


def model_key(effects) -> str:
    return "+".join(effects) if effects else "base"
