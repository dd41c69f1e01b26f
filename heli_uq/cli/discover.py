"""``heli-uq discover``: where a model and a record disagree, the missing named effect, and the
refitted model (:func:`heli_uq.discovery.discover`)."""

from __future__ import annotations

import dataclasses
import json

from heli_uq.cli.options import EFFECTS_HELP, Formatter, add_prior_options, out_dir, prior_changes_from_args
from heli_uq.errors import ParameterError

__all__ = ["add_parser", "cmd_discover"]


def cmd_discover(args) -> int:
    import numpyro

    from heli_uq.data import load_data, parse_window
    from heli_uq.discovery import BUDGETS, candidate_effects, discover
    from heli_uq.model import build_model
    from heli_uq.model.spec import split_effects

    if args.max_effects < 1:
        raise ParameterError(f"--max-effects: expected an integer >= 1, found {args.max_effects}")
    changes = {}
    if args.cold_starts is not None:
        if args.cold_starts < 0:
            raise ParameterError(f"--cold-starts: expected an integer >= 0, found {args.cold_starts}")
        changes["cold_starts"] = args.cold_starts
    if args.fit_all:
        changes["screen"] = False
    budget = dataclasses.replace(BUDGETS[args.budget], **changes) if changes else args.budget
    base = split_effects(args.base_effects, where="--base-effects")
    build_model(base, where="--base-effects")
    candidates = split_effects(args.candidates, where="--candidates") or None
    if args.candidates is not None and not candidates:
        raise ParameterError(f"--candidates: expected AXIS:EFFECT,..., found {args.candidates!r}")
    if candidates and not candidate_effects(base, candidates):
        raise ParameterError(f"--candidates: every one ({', '.join(candidates)}) is in the base model "
                             "already (--base-effects): nothing to try")  # fmt: skip
    # prior options name parameters of the base model or of a candidate effect
    every = build_model(base + candidate_effects(base, candidates), where="--candidates")
    priors = prior_changes_from_args(args, every)
    numpyro.set_host_device_count(BUDGETS[args.budget].chains)
    record = load_data(args.data)
    window = parse_window(args.window) if args.window else None
    train = parse_window(args.train) if args.train else None
    test = parse_window(args.test) if args.test else None
    if (train is None) != (test is None):
        raise ParameterError("--train and --test go together (fit on one, score on the other)")
    if window is not None and train is not None:
        raise ParameterError("--window cannot be combined with --train/--test")
    out = out_dir(args.out)
    result = discover(record, out, window=window, train=train, test=test, base_effects=base,
                      budget=budget, max_effects=args.max_effects, seed=args.seed,
                      scheduler=args.scheduler, candidates=candidates, priors=priors,
                      score=args.score)  # fmt: skip
    print(json.dumps({k: result[k] for k in ("effect", "axis", "parameters")}))
    print(f"wrote {out / 'discovery.json'}, report.md, bands_before.png, bands_after.png, "
          "residuals.png, candidates.png")  # fmt: skip
    return 0


def add_parser(subparsers):
    p = subparsers.add_parser(
        "discover",
        help="find the missing physical effect, add it, refit, and show the gap shrink",
        description=(
            "Fit the base model, locate where the data leave its predictive band, regress the\n"
            "torque the data imply on the effects vocabulary (pysindy), fit every candidate\n"
            "effect (and pairs of the best) on the fitting window, rank them by held-out\n"
            "log predictive density (or CRPS) in input-segment blocks, add the winner if it beats the\n"
            "calibrated margin (else 'none'), refit with NUTS and compare before/after.\n\n"
            "Writes DIR/discovery.json, DIR/report.md, DIR/bands_before.png,\n"
            "DIR/bands_after.png, DIR/residuals.png, DIR/candidates.png, DIR/candidates/\n"
            "(each fit) and DIR/refit/ (posterior). Interrupted (Ctrl-C), the same command\n"
            "run again reuses the finished candidate fits and continues the refit's saved draws."
        ),
        epilog=(
            "budgets: quick (the base model: the rig fit + 2 MAP starts; each candidate: its\n"
            "  warm starts from the current fit; NUTS 2 x (150 + 350) in the Laplace metric; 10 min\n"
            "  target); full (the base: the rig fit + 4 starts; each candidate: + 1 cold start;\n"
            "  NUTS 4 x (1000 + 1000) with a dense mass matrix adapted, NUTS also for the base\n"
            "  model; 60 min target). A NUTS run still\n"
            "  sampling at the target stops with the draws made (at least 100 per chain)\n\n"
            "examples:\n"
            "  heli-uq discover experimental --train 0:91 --test 91:131 --max-effects 2 --out out/disc\n"
            "  heli-uq discover rec.csv --budget full --scheduler tcp://host:8786 --out out/rec\n"
            "  heli-uq discover experimental --train 0:91 --test 91:131 --base-effects \\\n"
            "      yaw:coulomb_friction,yaw:torque_offset,yaw:thrust_tilt --fix a_yaw=1 --out out/tilt\n"
            "  heli-uq discover experimental --train 0:91 --test 91:131 --base-effects \\\n"
            "      yaw:coulomb_friction,yaw:torque_offset --candidates yaw:thrust_tilt,yaw:stiction \\\n"
            "      --fix a_yaw=1 --out out/tilt_candidate   # a derived term offered at its fixed value\n"
            "  heli-uq discover experimental --train 0:91 --test 91:131 --score crps --cold-starts 1 \\\n"
            "      --candidates yaw:coulomb_friction,yaw:torque_offset --max-effects 2 --out out/crps\n\n"
            + EFFECTS_HELP
        ),
        formatter_class=Formatter,
    )  # fmt: skip
    p.add_argument("data", metavar="DATA", help="experimental, or a CSV in the published format")
    p.add_argument("--window", metavar="A:B", default=None,
                   help="use A <= t < B [s]; candidates are fitted on its first 70 %% and scored "
                        "on the rest (default: the whole record)")  # fmt: skip
    p.add_argument("--train", metavar="A:B", default=None, help="fitting window [s]")
    p.add_argument("--test", metavar="C:D", default=None, help="held-out scoring window [s]")
    p.add_argument("--base-effects", metavar="AXIS:EFFECT,...", default=None,
                   help="effects already in the base model (default: none)")
    p.add_argument("--candidates", metavar="AXIS:EFFECT,...", default=None,
                   help="effects to try (default: every effect of the vocabulary on each axis)")
    p.add_argument("--budget", choices=["quick", "full"], default="quick",
                   help="effort (default: quick)")
    p.add_argument("--cold-starts", type=int, default=None, metavar="N",
                   help="MAP starts of each candidate from the model's start values, besides "
                        "those next to the current fit (default: the budget's, quick 0, full 1)")  # fmt: skip
    p.add_argument("--fit-all", action="store_true",
                   help="fit every candidate; by default a candidate that acts only on axes where the "
                        "base model's residuals are white noise (Ljung-Box, lags to 1 s) is not fitted "
                        "and is listed as such")  # fmt: skip
    p.add_argument("--score", choices=["log", "crps"], default="log",
                   help="the held-out score that decides: the log predictive density (default), or "
                        "the CRPS, which charges a miss by its size, not its square, and so does not "
                        "prefer a wide band wrong everywhere to a narrow one wrong in one swing; both "
                        "are reported and calibrated on null records")  # fmt: skip
    p.add_argument("--max-effects", type=int, default=1,
                   help="most effects to add, greedily, pairs considered (default: 1)")
    add_prior_options(p)  # of the base model's or a candidate's parameters; in every model that has them
    p.add_argument("--seed", type=int, default=0, help="random seed (default: 0)")
    p.add_argument("--scheduler", default="local", metavar="local|serial|ADDRESS",
                   help="candidate fits on a Dask LocalCluster (default), in this process "
                        "(serial), or on the Dask scheduler at ADDRESS")  # fmt: skip
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")
    p.set_defaults(handler=cmd_discover, rerun_reuses="the finished candidate fits and the refit's draws")
    return p
