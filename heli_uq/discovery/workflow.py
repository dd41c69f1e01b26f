"""``discover``: locate the gap, learn the missing torque, name the effect, refit, compare.

Steps (the module of each in parentheses):

1. **Windows.**  With ``train`` and ``test`` the candidates are fitted on ``train`` and
   scored on ``test``, and the refit uses ``train``.  Without, the fits use the first
   :data:`FIT_FRACTION` of the window and are scored on the rest (leave-future-out), and
   the refit uses the whole window.
2. **Locate** (:mod:`~heli_uq.discovery.locate`): the base model's MAP and Laplace
   predictive; where the data leave the 90 % band, by axis, input segment and state; and
   on which axes its residuals are white noise (:mod:`~heli_uq.discovery.screen`).
3. **Learn** (:mod:`~heli_uq.discovery.implied`, :mod:`~heli_uq.discovery.sindy`): the
   torque the data imply, regressed with pysindy on every candidate effect's feature;
   the ranking orders the candidates and gives start values.
4. **Name** (:mod:`~heli_uq.discovery.candidates`, :mod:`~heli_uq.discovery.score`):
   every candidate effect (each effect of the vocabulary on each axis, not yet in the
   model; one that acts only on axes with white residuals is listed, not fitted, unless
   the budget's ``screen`` is off) is added to the current model, fitted and scored on held-out blocks (its
   predictive: the Laplace draws resampled by importance weights, or the plug-in at the
   MAP where Pareto k rejects them); with two
   or more effects still allowed, pairs too: of the :attr:`Budget.pair_top` singles that
   fit the fitting window best and the best single by held-out score, and of each of the
   :attr:`Budget.pair_anchors` best with every other single the fitting window supports
   (:func:`~heli_uq.discovery.decide.pairs_to_fit`; single effects can be weak alone and
   strong together, as friction and a torque offset on the rig's yaw).  A pair starts
   from its members' MAPs and nests the better member; the pair fits that hold the
   single chosen at a step are that step's successor's singles and are not fitted again
   (:mod:`~heli_uq.discovery.nesting`).
   A candidate nests the current model, so when one fits the fitting window much
   better (:data:`~heli_uq.discovery.nesting.RESTART_NATS`), the current model is refitted
   once from its values;
   if that finds a better basin (a stiff hidden effect can trap the base fit: a pitch
   friction record left the base at pitch RMSE 1.5 rad), the candidates that fit worse
   than the refitted current model are fitted again from it (the others already sit in a
   basin at least as good).
   The fits are independent Dask tasks (:mod:`~heli_uq.discovery.rounds`) and are saved
   as they finish, so a rerun with the same output directory reuses them.
5. **Decide** (:mod:`~heli_uq.discovery.decide`).  The best model beats the current one if
   its score difference exceeds both :data:`~heli_uq.discovery.score.MARGIN_SE` standard
   errors and :data:`~heli_uq.discovery.score.MARGIN_PER_SAMPLE` nats per held-out sample
   (calibrated on records without a hidden effect, ``studies/discovery_confusion.py``).
   With ``score="crps"`` the held-out CRPS decides instead, with its margin
   :data:`~heli_uq.discovery.score.MARGIN_CRPS_FRACTION` of the current model's CRPS
   (:class:`~heli_uq.discovery.score.Criterion`).  Single effects that the best one does
   not beat by that margin are *tied* with it (effects can act alike on a record: a dead
   band below every voltage used is a torque offset); the whole record's evidence (the
   fitting window's Laplace evidence and the held-out log score) breaks the tie, and the
   report names the rivals and says by how much.  A
   model must also be *supported* by the fitting window (its log posterior at the MAP,
   less a BIC penalty per parameter, above the current model's): an effect fitted to
   nothing can widen the predictive band and so score on held-out blocks where the
   current model is far off.
   Among models that pass, one more effect must again pass the margin against the smaller
   model (parsimony).  With ``max_effects > 1`` the step repeats from the chosen model
   until nothing passes.
6. **Refit** the chosen model with NUTS (:func:`heli_uq.output.sample_posterior`) and
   report the gap before and after.  Its draws are saved as they are made, and a rerun
   with the same output directory and settings continues them (``resume="auto"``), so an
   interrupted discovery loses at most a chunk of draws; the base fit is made again
   (seconds to a minute).
"""

from __future__ import annotations

import pathlib
import time

import numpy as np

from heli_uq.data import Experiment
from heli_uq.discovery.budget import BUDGETS, Budget
from heli_uq.discovery.candidates import FitTask, fitted_predictive, off_start, score_fitted, warm_starts
from heli_uq.discovery.decide import choose, pairs_to_fit, rank
from heli_uq.discovery.implied import base_features, effect_features, implied_torque
from heli_uq.discovery.locate import failed_draws, locate
from heli_uq.discovery.nesting import RESTART_NATS, beyond, carried, model_key, nested_guess, pair_start
from heli_uq.discovery.report import write_outputs
from heli_uq.discovery.rounds import CandidateStore, run_round
from heli_uq.discovery.score import CRITERIA, gain_text, gap_text
from heli_uq.discovery.screen import screen_text, screened
from heli_uq.discovery.sindy import rank_effects
from heli_uq.errors import ParameterError
from heli_uq.executor import check_scheduler
from heli_uq.log import progress_log
from heli_uq.model import AXES, EFFECTS, RIG_FIT, build_model
from heli_uq.probability import PriorSet, check_split
from heli_uq.simulation.stiffness import edge_text

__all__ = ["discover", "checked_priors", "cold_starts", "Budget", "BUDGETS", "FIT_FRACTION",
           "MIN_SECONDS"]  # fmt: skip

#: Fraction of the window the candidates are fitted on when no train/test split is given.
FIT_FRACTION = 0.7
#: Shortest window [s] discovery accepts (fitting and held-out part together).
MIN_SECONDS = 20.0


def _windows(record: Experiment, window, train, test):
    t0, t1 = float(record.t[0]), float(record.t[0] + record.duration)
    if (train is None) != (test is None):
        raise ParameterError("train, test: give both or neither")
    if train is not None:
        for name, (a, b) in (("train", train), ("test", test)):
            if not (t0 - 1e-9 <= a < b <= t1 + 1e-9):
                raise ParameterError(f"{name}: window {a:g}:{b:g} s is outside the record "
                                     f"({t0:g}:{t1:g} s)")  # fmt: skip
        check_split(train, test, record.dt)
        fit, score, refit = tuple(train), tuple(test), (tuple(train), tuple(test))
    else:
        a, b = window if window is not None else (t0, t1)
        if not (t0 - 1e-9 <= a < b <= t1 + 1e-9):
            raise ParameterError(f"window: {a:g}:{b:g} s is outside the record ({t0:g}:{t1:g} s)")
        cut = round(a + FIT_FRACTION * (b - a), 2)
        fit, score, refit = (a, cut), (cut, b), ((a, b), None)
    span = score[1] - fit[0]
    if span < MIN_SECONDS:
        raise ParameterError(f"window: {span:g} s is too short to fit and score models; discovery "
                             f"needs at least {MIN_SECONDS:g} s")  # fmt: skip
    return fit, score, refit


def candidate_effects(current: list[str], vocabulary=None) -> list[str]:
    """The effects a step may add to the model of the effects ``current``: those of
    ``vocabulary`` (``"axis:effect"`` strings; default every effect of the table on each
    axis) that it does not hold yet, in order."""
    have = set(current)
    pool = vocabulary or [f"{axis}:{kind}" for axis in AXES for kind in EFFECTS]
    return [e for e in pool if e not in have]


def cold_starts(n: int, current: list[str], effect: str, changes) -> int:
    """MAP starts from the model's start values for the candidate ``current + [effect]``:
    the budget's ``n``, and at least one if the run's prior ``changes`` fix every
    parameter the effect adds (a derived term offered at its derived value).  Such a
    candidate nests the current model at no parameter value, so the nested fallback's
    "effect off" start is its warm start again: on the rig's split the tilt at a = 1,
    started from the yaw friction + offset MAP, ended 228 nats below that pair on the
    fitting window (test yaw 1.146 rad); one cold start found the basin 109 nats above it
    (0.307 rad)."""
    new = set(build_model(current + [effect]).names) - set(build_model(current).names)
    fixed = {name for name, prior in changes if prior.kind == "fixed"}
    return max(n, 1) if new and new <= fixed else n


def checked_priors(effects: list[str], priors) -> tuple:
    """``priors`` (``{name: Prior or JSON spec}``) checked against the model of every
    effect a run may add (names, supports), as sorted pairs ``(name, Prior)``.

    Raises
    ------
    ParameterError
        An unknown name, a value or prior outside its parameter's support.
    """
    every = build_model(effects)
    checked = PriorSet.default(every).updated(every, dict(priors or {}), where="priors")
    found = {**checked.params, **checked.x0, **checked.noise}
    return tuple((name, found[name]) for name in sorted(priors or {}))


def discover(record: Experiment, out_dir, *, window=None, train=None, test=None, base_effects=(),
             budget="quick", max_effects: int = 1, candidates=None, seed: int = 0,
             scheduler="local", priors=None, score="log", log=None) -> dict:  # fmt: skip
    """Run the discovery workflow (module docstring) and write its outputs to ``out_dir``.

    Parameters
    ----------
    record : Experiment
    out_dir : path
        Receives ``discovery.json``, ``report.md``, figures, ``candidates/`` (each fit)
        and ``refit/`` (the NUTS posterior of the chosen model).
    window : (float, float), optional
        Part of the record [s] (without ``train``/``test``).
    train, test : (float, float), optional
        Fitting and held-out windows [s].
    base_effects : sequence of str
        Effects ``"axis:kind"`` already in the base model.
    budget : {"quick", "full"} or Budget
    max_effects : int
        Most effects added (greedy steps, pairs considered).
    candidates : sequence of str, optional
        The effects ``"axis:kind"`` to try (default: every effect of the vocabulary on
        each axis).
    seed : int
    scheduler : {"local", "serial"} or address
        See :func:`heli_uq.executor.run_tasks`.
    priors : mapping, optional
        Changes to the default priors, ``{name: Prior or JSON spec}``
        (:meth:`~heli_uq.probability.PriorSet.updated`), applied to every model fitted
        that has the parameter: the base model, each candidate and the refits.  Names are
        parameters of the base model or of a candidate effect, e.g. ``{"a_yaw": 1.0}``
        fixes the tilt of a ``yaw:thrust_tilt`` base effect, or offers that effect as a
        candidate at its derived tilt, without a free parameter.
    score : {"log", "crps"}
        The held-out score that decides (:data:`~heli_uq.discovery.score.CRITERIA`): the
        log predictive density (default) or the CRPS; both are reported.  The fits do
        not depend on it, so a rerun with the same ``out_dir`` and the other score reuses
        them.
    log : callable, optional
        Progress messages (default: the ``logging`` INFO of this module, see :mod:`heli_uq.log`).

    Returns
    -------
    dict
        The content of ``discovery.json``.
    """
    t_start = time.perf_counter()
    log = progress_log(log, __name__)
    if not isinstance(budget, Budget) and budget not in BUDGETS:
        raise ParameterError(f"budget: expected one of {', '.join(BUDGETS)}, found {budget!r}")
    if score not in CRITERIA:
        raise ParameterError(f"score: expected one of {', '.join(CRITERIA)}, found {score!r}")
    criterion = CRITERIA[score]
    if not (isinstance(max_effects, int) and max_effects >= 1):
        raise ParameterError(f"max_effects: expected an integer >= 1, found {max_effects!r}")
    cost = budget if isinstance(budget, Budget) else BUDGETS[budget]
    check_scheduler(scheduler)  # an unreachable scheduler fails now, not after the base fit
    base_effects = list(base_effects)
    build_model(base_effects, where="base_effects")  # validates names
    vocabulary = None if candidates is None else list(candidates)
    if vocabulary is not None:
        discrepancy = [t.label for t in build_model(vocabulary, where="candidates").effects if t.record_keys]
        if discrepancy:  # no physical name to give, and no feature for the sparse regression
            raise ParameterError(f"candidates: {', '.join(discrepancy)} is a discrepancy term set up from "
                                 "the record, not a named effect; fit it with `heli-uq sample` (it may be "
                                 "in the base model)")  # fmt: skip
    changes = checked_priors(base_effects + candidate_effects(base_effects, vocabulary), priors)
    fit_w, score_w, (refit_train, refit_test) = _windows(record, window, train, test)
    out = pathlib.Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    store = CandidateStore(out)

    def task(effects, guesses=(), cold=cost.cold_starts, nests=None):
        """``nests``: the current fit ``(result, map)`` the candidate nests (its fallback)."""
        starts = len(guesses) + cold
        off, floor = (None, None) if nests is None else (off_start(nests[1], effects), nests[0]["map_value"])
        return FitTask(record, fit_w, score_w, tuple(effects), tuple(guesses), seed, starts,
                       cost.draws, cost.newton_steps, off, floor, changes)  # fmt: skip

    def elapsed():
        return f"[{time.perf_counter() - t_start:5.0f} s]"

    def say(msg):
        log(f"{elapsed()} {msg}")

    # 1-2. base fit and where it fails
    say(f"fitting the base model ({build_model(base_effects).label}) on {fit_w[0]:g}:{fit_w[1]:g} s")
    base_task = task(base_effects, (RIG_FIT,), cold=cost.n_starts)  # the rig's fit, then cold starts
    base_fit = fitted_predictive(base_task)
    failed = failed_draws(base_fit)  # none simulating: refused here, not scored as no misses
    base = score_fitted(base_fit, base_task)
    c, d = base_fit.start.problem.windows()["test"]
    n_scored = d - c  # held-out samples (the blocks tile the window)
    a, b = base_fit.start.problem.windows()["train"]
    n_fit = b - a
    where = locate(base_fit, out)
    white = where["white"]  # the screen of every step: the first base fit's (a restart keeps it)
    say(f"base model: held-out {gap_text(base['score'])}; worst axis: {where['axis']}"
        + (f" ({failed} of {len(base_fit.y_pred)} predictive draws fail to simulate: the numbers "
           "are of the others)" if failed else ""))  # fmt: skip
    say(f"residuals white on {' and '.join(a for a in AXES if white[a]['white']) or 'neither axis'} "
        f"({screen_text(white)})")  # fmt: skip
    if where.get("solver_edge"):
        say(f"base model: {edge_text(where['solver_edge'])}")

    # 3. the torque the data imply, and the sparse regression
    fw = record.window(*fit_w)
    model = build_model(base_effects)
    data = implied_torque(model, base_fit.params, fw.y, fw.u, record.dt)
    cands = {e: effect_features(model, base_fit.params, e, data)
             for e in candidate_effects(base_effects, vocabulary)}
    ranking = rank_effects(data.residual, base_features(model, base_fit.params, data), cands, seed=seed)
    implied = {r["effect"]: r["implied"] for r in ranking}
    say("sparse regression (pysindy) on the implied torque: "
        + ", ".join(f"{r['effect']} {r['inclusion']:.2f}" for r in ranking[:5]))  # fmt: skip

    # 4-5. name: greedy steps over singles and pairs
    current, current_res, current_map = list(base_effects), base, base_fit.params
    steps, all_rows = [], []
    restarted, kept = False, {}
    while len(current) - len(base_effects) < max_effects:
        singles = {}
        pool = candidate_effects(current, vocabulary)
        skipped = screened(pool, white) if cost.screen else {}
        if skipped:
            say(f"not fitting {len(skipped)} candidate(s) that act only on white axes: {', '.join(skipped)}")
        for e in pool:
            if e not in skipped and (key := model_key(current + [e])) not in kept:
                starts = warm_starts(current_map, current + [e], implied.get(e, {}))
                cold = cold_starts(cost.cold_starts, current, e, changes)
                singles[key] = task(current + [e], starts, cold=cold, nests=(current_res, current_map))
        fresh = run_round(singles, store, record, scheduler, say)
        results = {**kept, **fresh}  # disjoint: a kept candidate is not fitted again
        kept = {}
        if not restarted:
            restarted = True
            guess = nested_guess(results, current_res, current_map)
            if guess is not None:  # a candidate's MAP may lie in a better basin of the current model
                say("refitting the current model from the best candidate's MAP")
                again_task = task(current, (guess, current_map))
                try:
                    again_fit = fitted_predictive(again_task)
                    again = score_fitted(again_fit, again_task)
                except Exception as exc:  # noqa: BLE001 - like a failed candidate: keep the current fit
                    say(f"  the refit failed ({type(exc).__name__}: {exc}); keeping the current MAP")
                    again = {"map_value": np.inf}
                if again["map_value"] < current_res["map_value"] - RESTART_NATS:
                    kept = beyond(results, again)
                    say(f"the current model's MAP improved by "
                        f"{current_res['map_value'] - again['map_value']:.0f} nats; refitting "
                        f"from it the {len(results) - len(kept)} candidate(s) that fit worse than "
                        f"it (keeping {', '.join(kept) or 'none'})")  # fmt: skip
                    current_res, current_map = again, again["map"]
                    if not steps:
                        base_fit, base = again_fit, again
                        where = {**locate(base_fit, out), "white": white}
                    continue
        rows = rank(results, current_res, n_scored, n_fit, criterion)
        room = max_effects - (len(current) - len(base_effects))
        if room >= 2 and (cost.pair_top >= 2 or cost.pair_anchors >= 1):
            pairs = {}
            for a, b in pairs_to_fit(rows, cost.pair_top, cost.pair_anchors):
                effects = current + [a.split("+")[-1], b.split("+")[-1]]
                guess, member = pair_start(results[a], results[b])
                pairs[model_key(effects)] = task(effects, (guess,), nests=(member, member["map"]))
            pair_results = run_round(pairs, store, record, scheduler, say)
            results.update(pair_results)
            rows = rank(results, current_res, n_scored, n_fit, criterion)
        for r in rows:
            r["step"] = len(steps) + 1
            r["added"] = [e for e in r["effect"].split("+") if e not in current]
        all_rows += rows + [{"effect": model_key(current + [e]), "score": None, "score_se": None,
                             "skipped": why, "step": len(steps) + 1, "added": [e]}
                            for e, why in skipped.items()]  # fmt: skip
        choice = choose(rows, results, n_scored, n_fit, criterion)
        if choice is None:
            steps.append({"step": len(steps) + 1, "added": [],
                          "decision": "nothing passes the margin with the fitting window's support"})
            break
        added = choice["added"]
        steps.append({"step": len(steps) + 1, "added": added, "score": choice["score"],
                      "score_se": choice["score_se"], "crps_gain": choice["crps_gain"],
                      "crps_gain_se": choice["crps_gain_se"],
                      "tied": [r["effect"] for r in rows if r.get("tied") and r is not choice],
                      **({"tie_break": choice["tie_break"]} if "tie_break" in choice else {})})  # fmt: skip
        gain = gain_text(steps[-1], criterion.name, n_scored)
        say(f"step {len(steps)}: adding {', '.join(added)} (held-out score {gain})")
        current = current + added
        current_res = results[choice["effect"]]
        current_map = current_res["map"]
        restarted = False
        more = len(current) - len(base_effects) < max_effects  # another step follows
        kept = carried(results, current, current_res, len(steps)) if more else {}
        if kept:
            say(f"carrying {len(kept)} pair fit(s) of step {len(steps)} into step {len(steps) + 1}: "
                f"{', '.join(kept)}")  # fmt: skip

    added = current[len(base_effects):]
    # 6. refit and compare
    result = write_outputs(
        out, record=record, base_effects=base_effects, added=added, base=base, base_fit=base_fit,
        where=where, ranking=ranking, rows=all_rows, steps=steps, cost=cost, budget=budget,
        seed=seed, full=cost.nuts_before, refit=(refit_train, refit_test), chosen_map=current_map,
        fit_window=fit_w,
        score_window=score_w,
        n_scored=n_scored, say=say, t_start=t_start, priors=changes, criterion=criterion.name)  # fmt: skip
    return result
