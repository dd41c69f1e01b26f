"""Discovery on rig-like records with a known hidden effect (or none): the confusion table.

Each case simulates a 131 s record (``--seconds``) with the *adaptive stiff reference
solver* (diffrax Kvaerno5, an independent solver, not the fixed-step one the fits use):
the base parameters of a fit of the rig record (:data:`heli_uq.model.RIG_FIT`), one
effect of the vocabulary hidden on one axis at the value in :data:`HIDDEN` (or none),
inputs a random staircase in the rig's voltage ranges held 3-14 s (``rig_steps``) or the
published profile (``published``, needs the rig record), iid noise 3 mrad on pitch and
8 mrad on yaw, quantised by a 4096-count encoder.  With ``--base-jitter S`` the base
parameters are not the rig fit's but each is multiplied by ``exp(S z)``, ``z ~ N(0, 1)``
drawn from the case's seed (``g`` and the pitch statics kept, :func:`jittered_base`): the
records held out from the package come from another fit of the rig, and discovery must
not depend on starting at the truth.  With ``--hidden-omega-s W`` a hidden Coulomb
friction is smoothed over ``W`` rad/s instead of the fitted term's width (another
simulator's friction law); with ``--hold MIN:MAX`` the staircase's levels are held
``MIN``-``MAX`` s instead of 3-14 s (another staircase: more and shorter input segments).
Then ``heli_uq.discovery.discover`` runs on it (``--budget``, train 0-91 s / test
91-131 s; ``--fix NAME=VALUE`` fixes a parameter in every model it fits).  A case of two
effects joined by ``+`` (``yaw:torque_offset+pitch:deadband``) hides both and runs with
``max_effects=2``.

Writes one JSON line per case to ``--out`` (default
``studies/results/discovery_confusion.jsonl``): the truth, what was named, whether each
hidden parameter's 95 % interval holds the truth (and, for a torque, whether the interval
of its ratio to its axis' inertia holds the truth's ratio: :func:`ratio_coverage`), the
best candidate's score and the wall time; then prints the confusion table (truth -> named)
of all lines in the file.  The margin of "none"
(:data:`heli_uq.discovery.score.MARGIN_PER_SAMPLE`) is checked against the ``none`` cases:
their best candidate's score per held-out sample is printed, and the candidate of largest
CRPS gain (``best_crps``: per sample, its SE ratio and its fraction of the base's CRPS,
what :data:`heli_uq.discovery.score.MARGIN_CRPS_FRACTION` is set from).  ``--score crps``
lets the CRPS decide (``heli-uq discover --score``).  Usage::

    python studies/discovery_confusion.py [--cases none yaw:coulomb_friction ...] [--seeds 1 2]
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import copy
import json
import pathlib
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from _study import RESULTS, append_jsonl, provenance  # noqa: E402

from heli_uq.data import load_data  # noqa: E402
from heli_uq.discovery import discover  # noqa: E402
from heli_uq.errors import ParameterError  # noqa: E402
from heli_uq.model import AXES, EFFECTS, RIG_FIT, RIG_FIT_X0, build_model  # noqa: E402
from heli_uq.model.terms.rigid_body import pitch_inertia, yaw_inertia  # noqa: E402
from heli_uq.probability.priors import parse_prior_option  # noqa: E402
from heli_uq.simulation import reference_solve, synthetic_experiment  # noqa: E402
from heli_uq.simulation.synthetic import ENCODER_QUANTUM, RIG_RANGES, step_inputs  # noqa: E402

#: ``make_record``'s ``start``: factors on the rig fit's initial state (angles, rates).
START_FACTORS = {"rig": np.ones(4), "rest": np.array([1.0, 1.0, 0.0, 0.0])}
#: Hidden value of each effect's parameters (bare names, SI), by axis.
HIDDEN = {
    "yaw": {"deadband": {"delta": 0.3}, "coulomb_friction": {"F_c": 0.012},
            "quadratic_drag": {"c": 0.1}, "torsional_spring": {"k": 0.01, "psi_0": 0.5},
            "quadratic_thrust": {"k_q": 0.02}, "torque_offset": {"T_0": -0.01},
            "thrust_tilt": {"a": 1.0}, "motor_lag": {"tau": 0.3},
            "cross_damping": {"D_x": 0.1}, "input_delay": {"d": 0.3},
            "axis_tilt": {"b_c": 0.02, "b_s": -0.015}},
    "pitch": {"deadband": {"delta": 0.3}, "coulomb_friction": {"F_c": 0.003},
              "quadratic_drag": {"c": 0.02}, "torsional_spring": {"k": 0.003, "psi_0": -0.5},
              "quadratic_thrust": {"k_q": 0.001}, "torque_offset": {"T_0": 0.002}},
}  # fmt: skip
#: Cases outside the effects table (``--cases yaw:thrust_tilt``, never by default): the
#: derived ``cos theta`` of the yaw torques, hidden at its derivation ``a = 1``; offered as a
#: candidate with ``--candidates yaw:thrust_tilt ... --fix a_yaw=1`` as on the rig record;
#: the yaw motor's lag at the rig's fitted 0.3 s, offered with ``--candidates yaw:motor_lag ...``;
#: a yaw torque of the pitch rate (``cross_damping``, 0.1 N m s/rad: a pitch rate of 0.2 rad/s
#: as large a torque as 0.18 V on the yaw motor), offered with ``--candidates yaw:cross_damping ...``;
#: a dead time of the yaw motor (``input_delay``, 0.3 s), offered with ``--candidates yaw:input_delay ...``;
#: a yaw axis tilted by 1.4 degrees (``axis_tilt``, ``b_c = 0.02``, ``b_s = -0.015`` rad),
#: offered with ``--candidates yaw:axis_tilt ...``.
EXTRA_CASES = ("yaw:thrust_tilt", "yaw:motor_lag", "yaw:cross_damping", "yaw:input_delay", "yaw:axis_tilt")
#: A record whose pitch leaves this range [rad] is refused: the real rig hits its stops
#: long before the body turns over (on the seed-3 staircase a pitch thrust k_q = 0.002
#: N m/V^2 already lifts it to 7.8 rad, 0.005 spins it through 170 rad).
PITCH_RANGE = (-np.pi / 2, np.pi / 2)
NOISE = (0.003, 0.008)


class ImplausibleRecord(ValueError):
    """The hidden effect drives the pitch outside :data:`PITCH_RANGE` (the case is skipped)."""


def jittered_base(seed: int, jitter: float) -> dict[str, float]:
    """:data:`RIG_FIT` with every parameter but ``g`` multiplied by ``exp(jitter z)``,
    ``z ~ N(0, 1)`` from ``seed`` (the identity at ``jitter = 0``), then both pitch gains
    rescaled so that ``K_theta_theta / (m r_c)`` is the rig fit's.

    Why the rescaling: at the rig's largest pitch voltage the thrust barely holds the
    body against gravity (``K_theta_theta u_theta`` vs ``m g r_c``, 0.051 vs 0.049 N m),
    so a 5 % spread of the parameters alone turns the pitch over on half the seeds.  Any
    fit of the rig record pins that ratio (the pitch statics), so another fit differs in
    the other directions.
    """
    z = np.random.default_rng([seed, 7919]).standard_normal(len(RIG_FIT))
    base = {k: v if k == "g" else float(v * np.exp(jitter * zk))
            for (k, v), zk in zip(RIG_FIT.items(), z)}  # fmt: skip
    statics = (base["m"] * base["r_c"]) / (RIG_FIT["m"] * RIG_FIT["r_c"])
    scale = statics * RIG_FIT["K_theta_theta"] / base["K_theta_theta"]
    for k in ("K_theta_theta", "K_theta_psi"):
        base[k] *= scale
    return base


def make_record(case: str, inputs: str, seed: int, seconds: float, hidden=HIDDEN, base_jitter=0.0,
                omega_s=None, hold=None, start="rig"):  # fmt: skip
    """The synthetic record of ``case`` (``"none"`` or ``"axis:effect"``) and its truth.

    ``hidden`` gives the hidden values (default :data:`HIDDEN`, same layout);
    ``base_jitter`` the log-normal spread of the base parameters (:func:`jittered_base`);
    ``omega_s`` [rad/s] the smoothing width of a hidden ``coulomb_friction`` (default the
    term's, which the candidates fit): another friction law than the fitted one;
    ``hold`` = ``(min, max)`` [s] the hold time of a ``rig_steps`` level (default the
    package's 3-14 s): another staircase than the package's own; ``start`` ``"rig"`` the
    rig fit's initial state (:data:`RIG_FIT_X0`, moving), ``"rest"`` its angles with both
    rates 0 (a record that starts still, whose initial rates' prior reads the start).
    """
    effects = [] if case == "none" else case.split("+")
    if omega_s is not None:
        effects = [{"effect": "coulomb_friction", "axis": e.split(":")[0], "omega_s": omega_s}
                   if e.endswith(":coulomb_friction") else e for e in effects]  # fmt: skip
    model = build_model(effects)
    truth = jittered_base(seed, base_jitter)
    for term in model.effects:
        truth.update({p.name: hidden[term.axis][term.kind][p.bare] for p in term.parameters()})

    def reference(p, x0, u, dt):
        return reference_solve(p, x0, u, dt, model=model)

    if inputs == "published":
        u = load_data("experimental").window(0, seconds).u
    elif hold is not None:  # own generator stream: the noise stream of `seed` is unchanged
        u = step_inputs(round(seconds / 0.01), 0.01, np.random.default_rng([seed, 104729]),
                        RIG_RANGES, hold)  # fmt: skip
    else:
        u = inputs
    x0 = np.asarray(RIG_FIT_X0, dtype=float) * START_FACTORS[start]
    rec = synthetic_experiment(truth, x0, duration=seconds, inputs=u, noise_std=NOISE,
                               seed=seed, simulator=reference, quantum=ENCODER_QUANTUM)  # fmt: skip
    lo, hi = rec.y[:, 0].min(), rec.y[:, 0].max()
    if lo < PITCH_RANGE[0] or hi > PITCH_RANGE[1]:
        raise ImplausibleRecord(f"{case} ({inputs}, seed {seed}): the pitch spans [{lo:.2f}, "
                                f"{hi:.2f}] rad, outside the rig's range {PITCH_RANGE}: hidden "
                                "values (or base jitter) too large")
    return rec, truth, model


def run_case(case: str, inputs: str, seed: int, args) -> dict:
    rec, truth, model = make_record(case, inputs, seed, args.seconds, args.hidden, args.base_jitter,
                                    args.hidden_omega_s, args.hold, args.start)  # fmt: skip
    split = 0.7 * args.seconds
    t0 = time.perf_counter()
    keep = args.keep and pathlib.Path(args.keep) / f"{case.replace(':', '_')}_{inputs}_{seed}"
    with contextlib.nullcontext(keep) if keep else tempfile.TemporaryDirectory() as tmp:
        windows = {} if args.no_split else {"train": (0.0, split), "test": (split, args.seconds)}
        res = discover(rec, tmp, **windows, budget=args.budget,
                       seed=seed, scheduler=args.scheduler, candidates=args.candidates,
                       max_effects=max(args.max_effects, len(model.effects)),
                       priors=dict(args.fix),
                       score=args.score)  # fmt: skip
    added = {f"{a['axis']}:{a['effect']}": a["parameters"] for a in res["added"]}
    named = "+".join(added) or "none"
    covered = {}
    if set(added) == set(case.split("+")):
        for term in model.effects:
            for p in term.parameters():
                if p.name in dict(args.fix):  # fixed by --fix: not estimated, not reported
                    continue
                found = added[f"{term.axis}:{term.kind}"][p.bare]
                ci = found["ci95"]
                covered[p.name] = {"truth": truth[p.name], "ci95": ci,
                                   "covered": ci[0] <= truth[p.name] <= ci[1],
                                   **ratio_coverage(found, truth, p.name, term.axis)}
    best = next((c for c in res["candidates"] if c.get("score") is not None), None)
    by_crps = max((c for c in res["candidates"] if c.get("crps_gain") is not None),
                  key=lambda c: c["crps_gain"], default=None)
    values = {p.name: truth[p.name] for term in model.effects for p in term.parameters()}
    return {"case": case, "inputs": inputs, "seed": seed, "hidden": values, "named": named,
            "correct": set(added) == set(case.split("+")) if added else case == "none",
            "covered": covered, "best": best and {k: best[k] for k in ("effect", "axis", "score",
                                                                        "score_se", "score_per_sample")},
            "best_crps": by_crps and crps_facts(by_crps),
            "gap_before": res["gap_before"], "gap_after": res["gap_after"], "decision": res["decision"],
            "budget": args.budget, "score": args.score, "discover_s": time.perf_counter() - t0,
            **({"base_jitter": args.base_jitter,
                "base": {k: truth[k] for k in RIG_FIT}} if args.base_jitter else {}),
            **({"hidden_omega_s": args.hidden_omega_s}
               if args.hidden_omega_s is not None else {}),
            **({"hold": list(args.hold)} if args.hold is not None else {}),
            **({"start": args.start} if args.start != "rig" else {}),
            **({"split": False} if args.no_split else {}),
            **({"fix": dict(args.fix)} if args.fix else {}),
            **({"max_effects": args.max_effects} if args.max_effects > 1 else {}),
            **({"refit": refit_facts(keep / "refit" / "summary.json")} if keep else {})}  # fmt: skip


def ratio_coverage(found: dict, truth: dict, name: str, axis: str) -> dict:
    """For a torque-type parameter, whether the 95 % interval of its ratio to its axis'
    inertia (``per_inertia``, the quantity the record identifies) holds the truth's ratio:
    ``{ratio_truth, ratio_ci95, ratio_covered}``, or ``{}`` if it has none.  Its interval in
    N m holds the truth as far as the common scale's prior does, and under the default
    priors that interval spans three decades (studies/notes/posterior.md, "Where the common
    scale lands"), so the ratio is the test of the fit."""
    if "per_inertia" not in found:
        return {}
    ratio = found["per_inertia"]
    inertia = (pitch_inertia(truth) if axis == "pitch" else yaw_inertia(truth, ratio["theta_ref"]))
    value = truth[name] / float(inertia)
    lo, hi = ratio["ci95"]
    return {"ratio_truth": value, "ratio_ci95": [lo, hi], "ratio_covered": bool(lo <= value <= hi)}


def crps_facts(c: dict) -> dict:
    """The candidate of largest held-out CRPS gain (a row of ``discovery.json``): its gain
    and SE per held-out sample [rad] (``crps_gain`` of :func:`heli_uq.discovery.decide.rank`
    over the held-out samples), their ratio, and its log score per sample [nats]: what a
    CRPS margin would be calibrated on."""
    n_scored = c["score"] / c["score_per_sample"]  # both per candidate; never 0 in practice
    return {"effect": c["effect"], "crps_gain_per_sample": c["crps_gain"] / n_scored,
            "crps_gain_se_per_sample": c["crps_gain_se"] / n_scored,
            "crps_z": c["crps_gain"] / c["crps_gain_se"] if c["crps_gain_se"] else None,
            "crps_gain_fraction": c.get("crps_gain_fraction"),
            "score_per_sample": c["score_per_sample"]}


def refit_facts(path: pathlib.Path) -> dict | None:
    """The NUTS refit's size, time and health from its ``summary.json`` (None if none)."""
    if not path.exists():
        return None
    s = json.loads(path.read_text())
    keys = ("chains", "warmup", "warmup_requested", "draws", "draws_requested", "adapt_mass_matrix",
            "substeps", "warmup_seconds", "wall_s", "rhat_max", "ess_bulk_min", "ess_tail_min",
            "divergences", "tree_depth_saturation", "mean_leapfrog_steps")
    return {k: s[k] for k in keys if k in s} | {"health": s.get("health")}


def confusion(path) -> str:
    rows = [json.loads(line) for line in pathlib.Path(path).read_text().splitlines() if line.strip()]
    table = collections.defaultdict(collections.Counter)
    for r in rows:
        table[r["case"]][r["named"]] += 1
    lines = ["| truth | named (count) | correct | 95 % intervals hold the truth | their ratios to the "
             "inertia hold the truth's | median time [s] |", "|---|---|---|---|---|---|"]
    for case in sorted(table):
        rs = [r for r in rows if r["case"] == case]
        cov = [c["covered"] for r in rs for c in r["covered"].values()]
        ratios = [c["ratio_covered"] for r in rs for c in r["covered"].values() if "ratio_covered" in c]
        times = sorted(r["discover_s"] for r in rs)
        lines.append(f"| {case} | " + ", ".join(f"{k} ({v})" for k, v in table[case].most_common())
                     + f" | {sum(r['correct'] for r in rs)}/{len(rs)} | "
                     + (f"{sum(cov)}/{len(cov)}" if cov else "-") + " | "
                     + (f"{sum(ratios)}/{len(ratios)}" if ratios else "-")
                     + f" | {times[len(times) // 2]:.0f} |")
    nulls = [r["best"]["score_per_sample"] for r in rows if r["case"] == "none" and r["best"]]
    if nulls:
        lines.append(f"\nnull records: best candidate's score per held-out sample "
                     f"{', '.join(f'{x:+.4f}' for x in nulls)} nats")  # fmt: skip
    crps = [r["best_crps"] for r in rows if r["case"] == "none" and r.get("best_crps")]
    if crps:
        gains = (f"{c['crps_gain_per_sample']:+.2e} rad ({c['crps_z']:+.1f} SE)" for c in crps)
        lines.append("null records: largest CRPS gain per held-out sample " + ", ".join(gains))
    return "\n".join(lines)


def hidden_value(text: str):
    """``"axis:effect:name=value"`` -> ``(axis, effect, name, value)``, checked against HIDDEN."""
    try:
        key, value = text.split("=")
        axis, kind, name = key.split(":")
        if name not in HIDDEN[axis][kind]:
            raise KeyError(name)
        return axis, kind, name, float(value)
    except (ValueError, KeyError) as err:
        raise argparse.ArgumentTypeError(f"{text!r}: expected AXIS:EFFECT:NAME=VALUE with a name of "
                                         f"HIDDEN ({err})") from None


def _fixed(text: str) -> tuple[str, float]:
    """``"NAME=VALUE"`` -> ``(name, value)``: a parameter fixed in every model discover fits
    (parsed as ``heli-uq discover --fix``)."""
    try:
        name, prior = parse_prior_option(text, option="--fix")
    except ParameterError as err:
        raise argparse.ArgumentTypeError(str(err)) from None
    if prior.kind != "fixed":
        raise argparse.ArgumentTypeError(f"--fix {text!r}: expected NAME=VALUE, e.g. a_yaw=1")
    return name, prior.a


def _hold(text: str) -> tuple[float, float]:
    """``"MIN:MAX"`` [s] -> ``(min, max)``, 0 < min <= max."""
    try:
        lo, hi = (float(x) for x in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected MIN:MAX in seconds") from None
    if not 0 < lo <= hi:
        raise argparse.ArgumentTypeError(f"{text!r}: expected 0 < MIN <= MAX")
    return lo, hi


def main(argv=None) -> int:
    # every effect of the vocabulary that HIDDEN gives a value on that axis (a new effect
    # joins the default cases when its value is added there)
    all_cases = ["none"] + [f"{a}:{k}" for a in AXES for k in EFFECTS if k in HIDDEN[a]]

    def case(text):  # "none", "axis:effect" or two of them joined by "+"
        parts = text.split("+")
        lacking = [x for x in parts if x.count(":") == 1 and x.split(":")[0] in HIDDEN
                   and x.split(":")[1] in EFFECTS and x.split(":")[1] not in HIDDEN[x.split(":")[0]]]
        if lacking:
            raise argparse.ArgumentTypeError(f"{text!r}: no hidden value for {', '.join(lacking)}; "
                                             "add one to HIDDEN in studies/discovery_confusion.py")
        known = set(parts) <= set(all_cases[1:]) | set(EXTRA_CASES) and len(set(parts)) == len(parts) <= 2
        if text != "none" and not known:
            raise argparse.ArgumentTypeError(f"{text!r}: expected none, axis:effect or two joined by +")
        return text

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="+", default=all_cases, type=case,
                    help="cases; two effects joined by + are hidden together (max_effects 2)")
    ap.add_argument("--inputs", nargs="+", default=["rig_steps"], choices=["rig_steps", "published"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[1])
    ap.add_argument("--seconds", type=float, default=131.0)
    ap.add_argument("--budget", default="quick", choices=["quick", "full"])
    ap.add_argument("--score", default="log", choices=["log", "crps"],
                    help="the held-out score that decides (heli-uq discover --score)")
    ap.add_argument("--scheduler", default="local")
    ap.add_argument("--candidates", nargs="+", default=None, metavar="AXIS:EFFECT",
                    help="effects to try (default: every effect on each axis)")
    ap.add_argument("--hidden", nargs="+", default=[], type=hidden_value, dest="overrides",
                    metavar="AXIS:EFFECT:NAME=VALUE",
                    help="hidden values other than HIDDEN's, e.g. pitch:torsional_spring:k=0.03")
    ap.add_argument("--fix", nargs="+", default=[], type=_fixed, metavar="NAME=VALUE",
                    help="parameters fixed in every model discover fits, e.g. a_yaw=1 (the tilt "
                         "offered at its derived value)")
    ap.add_argument("--base-jitter", type=float, default=0.0, metavar="S",
                    help="log-normal spread of the base parameters around the rig fit (0: the fit)")
    ap.add_argument("--hidden-omega-s", type=float, default=None, metavar="W",
                    help="smoothing width [rad/s] of a hidden coulomb_friction (default: the "
                         "fitted term's), e.g. 0.0002 for nearly exact stick-slip")
    ap.add_argument("--hold", type=_hold, default=None, metavar="MIN:MAX",
                    help="hold time [s] of a rig_steps level (default: the package's 3-14 s)")
    ap.add_argument("--start", choices=sorted(START_FACTORS), default="rig",
                    help="initial state: the rig fit's (rig, moving) or its angles at rest (rest)")
    ap.add_argument("--no-split", action="store_true",
                    help="no train/test split, as `heli-uq discover REC --out DIR` runs: the "
                         "candidates are fitted on the first 70 %% and scored on the rest, the "
                         "refit uses the whole record")
    ap.add_argument("--max-effects", type=int, default=1, metavar="N",
                    help="effects discover may add (at least the hidden count): 2 on a record "
                         "of one effect or none checks that the second step adds nothing")
    ap.add_argument("--quiet", action="store_true", help="no progress lines")
    ap.add_argument("--keep", default=None, metavar="DIR",
                    help="keep each record's discover outputs in DIR/CASE_INPUTS_SEED (default: "
                         "a temporary directory)")
    ap.add_argument("--out", default=str(RESULTS / "discovery_confusion.jsonl"))
    args = ap.parse_args(argv)
    args.hidden = copy.deepcopy(HIDDEN)  # the values run_case hides: HIDDEN with the overrides
    for axis, kind, name, value in args.overrides:
        args.hidden[axis][kind][name] = value
    import numpyro

    from heli_uq.log import configure_cli

    configure_cli(args.quiet)  # discover's progress lines on stdout

    numpyro.set_host_device_count(4)
    for seed in args.seeds:
        for inputs in args.inputs:
            for case in args.cases:
                try:
                    row = run_case(case, inputs, seed, args)
                except ImplausibleRecord as err:
                    print(f"skipped: {err}", flush=True)
                    continue
                row.update(provenance(__file__, argv, row["discover_s"]))
                append_jsonl(args.out, row)
                print(f"{case} ({inputs}, seed {seed}) -> {row['named']} in {row['discover_s']:.0f} s; "
                      f"{row['covered']}", flush=True)  # fmt: skip
    print(confusion(args.out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
