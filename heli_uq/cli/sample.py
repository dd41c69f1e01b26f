"""``heli-uq sample``: the posterior of a model given a record (NUTS or emcee)."""

from __future__ import annotations

import json
import pathlib

from heli_uq.cli.options import (
    EFFECTS_HELP,
    Formatter,
    add_model_options,
    add_prior_options,
    add_trust_options,
    check_positive,
    model_from_args,
    out_dir,
    priors_from_args,
    report_health,
    result_line,
)
from heli_uq.errors import ParameterError

__all__ = ["add_parser", "cmd_sample", "SAMPLE_ERROR_MODELS"]

#: ``--error`` choices: :data:`heli_uq.probability.noise.ERROR_MODELS`, spelled out so that
#: parsing the command line imports no JAX.
SAMPLE_ERROR_MODELS = ("iid", "ar1", "iid+timing", "ar1+timing")


def cmd_sample(args) -> int:
    import numpyro

    from heli_uq.data import load_data, parse_window
    from heli_uq.inference import TARGET_ACCEPT
    from heli_uq.model import load_params_json
    from heli_uq.output.posterior_study import sample_posterior

    check_positive(args, ("chains", "warmup", "draws", "max_tree_depth"))
    if args.time_limit is not None and not args.time_limit > 0:
        raise ParameterError(f"--time-limit: expected minutes > 0, found {args.time_limit:g}")
    if args.time_limit is not None and args.sampler != "nuts":
        raise ParameterError(f"--time-limit: NUTS only, found --sampler {args.sampler}")
    if args.max_draws is not None and (args.sampler != "nuts" or not args.max_draws > args.draws):
        raise ParameterError(f"--max-draws: NUTS only and more than --draws ({args.draws}), found "
                             f"{args.max_draws} with --sampler {args.sampler}")  # fmt: skip
    if args.target_accept is not None and (args.sampler != "nuts" or not 0.0 < args.target_accept < 1.0):
        raise ParameterError(f"--target-accept: NUTS only and in (0, 1), found {args.target_accept:g} "
                             f"with --sampler {args.sampler}")  # fmt: skip
    target_accept = TARGET_ACCEPT if args.target_accept is None else args.target_accept
    if args.sampler == "nuts":
        # One XLA host device per chain, so numpyro runs the chains in parallel; only
        # effective before JAX's backend starts (always so when run as a program).
        numpyro.set_host_device_count(args.chains)
    model = model_from_args(args)
    priors = priors_from_args(args, model)
    guesses = [] if args.init is None else [load_params_json(_init_file(args.init), model, complete=False)]
    record = load_data(args.data)
    if args.window is not None:
        record = record.window(*parse_window(args.window))
    train = parse_window(args.train) if args.train else None
    test = parse_window(args.test) if args.test else None
    if test is not None and train is None:
        raise ParameterError("--test needs --train (the test window follows the training window)")
    out = out_dir(args.out)
    _refuse_the_other_kind(out, args.sampler == "prior")
    if args.sampler == "prior":
        return _prior_check(args, record, model, priors, train, test, out)
    idata, summary = sample_posterior(
        record, out, model=model, train=train, test=test, sampler=args.sampler, error=args.error,
        priors=priors, chains=args.chains, warmup=args.warmup, draws=args.draws,
        seed=args.seed, resume=args.resume, progress=not args.no_progress,
        walkers=args.walkers, adapt_mass_matrix=args.adapt_mass_matrix == "on",
        target_accept=target_accept, network_posterior=args.nn_posterior or "full",
        max_tree_depth=args.max_tree_depth, guesses=guesses,
        time_limit=None if args.time_limit is None else 60.0 * args.time_limit,
        max_draws=args.max_draws,
    )  # fmt: skip
    keys = ("rhat_max", "ess_bulk_min", "ess_tail_min", "divergences", "rmse", "coverage90",
            "rmse_test", "coverage90_test", "solver_error_rad", "wall_s", "rhat_max_network_torque",
            "rhat_max_network_weights")  # fmt: skip
    print(result_line(summary, keys))
    from heli_uq.output.network import is_network_weight

    effect_names = {p.name for term in model.effects for p in term.parameters()
                    if not is_network_weight(p.name)}  # fmt: skip
    effects = {n: v for n, v in summary["parameters"].items() if n in effect_names}
    if effects:
        print("effect parameters (mean, 95 % interval): " + "; ".join(
            f"{n} = {v['mean']:.4g} [{v['ci95'][0]:.4g}, {v['ci95'][1]:.4g}] {v['unit']}"
            for n, v in effects.items()))  # fmt: skip
    _name_state_networks(args, model, idata, out, summary,
                         train or (float(record.t[0]), float(record.t[0] + record.duration)))
    print(f"wrote {out / 'posterior.nc'}, summary.csv, summary.json, bands.png, map.json (--init {out})")
    return report_health(summary, args.strict)


#: The file that marks a directory as a posterior run's, and as a prior check's.
KIND_FILES = {False: "posterior.nc", True: "prior.nc"}


def _refuse_the_other_kind(out: pathlib.Path, prior: bool) -> None:
    """A prior check and a posterior run write summary.json and bands.png under the same
    names: into a directory that holds the other's results, one would leave the other's
    files beside its own, and the directory would describe two runs."""
    other = out / KIND_FILES[not prior]
    if other.is_file():
        kind = "posterior run" if prior else "prior check"
        raise ParameterError(f"--out {out}: holds a {kind}'s results ({other.name}); this run would "
                             "replace its summary.json and bands.png and leave its other files: "
                             "give another --out")  # fmt: skip


def _init_file(path: str) -> pathlib.Path:
    """``--init``: a parameter file, or the ``--out`` directory of an earlier run (its
    :data:`~heli_uq.output.posterior_study.MAP_FILE`)."""
    from heli_uq.output.posterior_study import MAP_FILE

    given = pathlib.Path(path)
    if not given.is_dir():
        return given
    if not (given / MAP_FILE).is_file():
        raise ParameterError(f"--init {path}: a directory without {MAP_FILE} (expected a parameter "
                             "file, or the --out directory of a 'heli-uq sample' run that found its MAP)")
    return given / MAP_FILE


def _prior_words(args) -> list[str]:
    """The run's ``--priors``, ``--prior`` and ``--fix`` as command-line words."""
    words = ["--priors", args.priors] if args.priors is not None else []
    for flag, values in (("--prior", args.prior), ("--fix", args.fix)):
        for v in values or []:
            words += [flag, v]
    return words


def _name_state_networks(args, model, idata, out, summary: dict, window) -> None:
    """For a network of the states: which effects of the table it learned
    (:func:`heli_uq.discovery.network_effects.network_effects_of`), printed and stored in
    summary.json as ``network_effects``, and the ``discover`` command that checks the named
    effects on held-out blocks of the training ``window`` ``(a, b)`` [s]."""
    from heli_uq.discovery.network_check import check_line
    from heli_uq.discovery.network_effects import effects_sentence, network_effects_of, state_networks
    from heli_uq.model.spec import model_from_description
    from heli_uq.output.posterior_study import write_summary

    if not state_networks(model):
        return
    adapted = model_from_description(idata.posterior.attrs["model"])  # as adapted to the record
    summary["network_effects"] = {axis: network_effects_of(idata, adapted, axis)
                                  for axis in state_networks(model)}  # fmt: skip
    for axis, found in summary["network_effects"].items():
        print(effects_sentence(axis, found))
    line = check_line(args.data, summary["network_effects"], window, out / "check", model=model,
                      prior_options=_prior_words(args))  # fmt: skip
    if line:
        print(line)
    write_summary(out, summary)


def _prior_check(args, record, model, priors, train, test, out) -> int:
    from heli_uq.output.prior_check import prior_predictive_check

    if args.resume:
        raise ParameterError("--resume: a prior check saves nothing to resume; run it again")
    _, summary = prior_predictive_check(record, out, model=model, train=train, test=test, priors=priors,
                                        error=args.error, draws=args.draws, seed=args.seed)  # fmt: skip
    keys = ("draws", "failed", "unphysical", "coverage90", "p_values", "wall_s")
    print(json.dumps({k: summary[k] for k in keys}))
    for note in summary["notes"]:
        print(f"note: {note}")
    print(f"wrote {out / 'prior.nc'}, summary.json, bands.png")
    return 0


def add_parser(subparsers):
    p = subparsers.add_parser(
        "sample",
        help="Bayesian posterior (NUTS or emcee) with predictive bands and diagnostics",
        description=(
            "Sample the posterior of a model (the paper's, or with --effects /\n"
            "--model-file) given a record.\n\n"
            "Writes DIR/posterior.nc (arviz InferenceData), DIR/summary.csv,\n"
            "DIR/summary.json (R-hat, ESS, divergences, parameters with 95 % intervals,\n"
            "RMSE, 90 % coverage per window, solver accuracy, wall time) and\n"
            "DIR/bands.png, DIR/map.json (the MAP's parameters, for --init or simulate\n"
            "--params); draws are saved in DIR/chunks as they come.  The model's\n"
            "description is stored in posterior.nc and summary.json.\n"
            "Both samplers start from a multi-start MAP; NUTS uses a dense mass matrix\n"
            "started from the Laplace covariance, in identifiable coordinates."
        ),
        epilog=(
            "priors (defaults: see heli_uq.probability.priors): --prior m=lognormal:0.5:1.0,\n"
            "  --prior h=normal:0:0.01, --fix h=0, or --priors FILE.json with\n"
            '  {"m": {"lognormal": [0.5, 1.0]}, "h": {"fixed": 0}}\n\n'
            "examples:\n"
            "  heli-uq sample --data experimental --train 0:91 --test 91:131 --out out/post\n"
            "  heli-uq sample --data experimental --window 0:30 --sampler emcee --out out/em\n"
            "  heli-uq sample --data experimental --sampler prior --draws 500 --error iid \\\n"
            "      --out out/prior\n"
            "  heli-uq sample --data rec.csv --effects yaw:coulomb_friction --error iid \\\n"
            "      --out out/friction\n"
            "  heli-uq sample --data rec.csv --effects yaw:coulomb_friction,yaw:stiction \\\n"
            "      --init out/friction --error iid --out out/stiction\n"
            "  heli-uq sample --data experimental --model hybrid --nn-inputs u --error iid \\\n"
            "      --target-accept 0.95 --train 0:91 --test 91:131 --out out/hybrid\n\n"
            "hybrid: R-hat and ESS are judged on the physical parameters and on the network's\n"
            "  torque (posterior variable nn_torque_<axis> at the training window's inputs;\n"
            "  for a network of u also nn_torque_<axis>_unseen at the voltage pairs only the\n"
            "  test window holds), not on the raw weights, whose sign and permutation\n"
            "  symmetries make them meaningless one by one (their worst R-hat is reported as\n"
            "  rhat_max_network_weights); summary.json's network_band_widths compares the\n"
            "  torque's band at the new pairs with the training pairs'.  A network of the\n"
            "  states (--nn-inputs u,x,v) is named by the effects table (network_effects in\n"
            "  summary.json, and one printed line: the effects it learned, or none, and the\n"
            "  input its torque depends on most); when it names effects, the heli-uq discover\n"
            "  command that checks them on held-out blocks of the training window is printed.\n\n"
            "health checks: R-hat, ESS, divergences, tree-depth saturation, collapsed step size,\n"
            "  MAP convergence, unphysical predictive simulations; failures are printed as a\n"
            "  warning block, stored in summary.json ('health') and named in bands.png's title.\n"
            "interrupt (Ctrl-C): stops within seconds, keeps the finished draws and prints the\n"
            "  command that continues them (--resume).\n"
            "exit status: 0 ok (health warnings only printed), 2 bad input or a refused\n"
            "  --resume, 3 a failed health check under --strict, 70 an internal error (a bug),\n"
            "  130 interrupted\n\n"
            + EFFECTS_HELP
        ),
        formatter_class=Formatter,
    )
    add_model_options(p, sampled=True)
    p.add_argument("--sampler", choices=["nuts", "emcee", "laplace", "prior"], default="nuts",
                   help="sampler (default: nuts); 'laplace': independent draws of the Laplace "
                        "approximation at the MAP, minutes instead of hours for a hybrid model, "
                        "trusted only when its Pareto k <= 0.7 (checked); 'prior': a prior "
                        "predictive check, --draws draws from the priors alone, simulated and set "
                        "against the record (DIR/prior.nc, summary.json with notes, bands.png)")
    p.add_argument("--data", default="experimental", metavar="experimental|FILE.csv",
                   help="record (default: experimental)")
    p.add_argument("--window", metavar="A:B", default=None,
                   help="use only A <= t < B [s] of the record (default: all)")
    p.add_argument("--train", metavar="A:B", default=None,
                   help="training window [s] (default: the whole (windowed) record)")
    p.add_argument("--test", metavar="C:D", default=None,
                   help="held-out test window [s], after the training window")
    p.add_argument("--init", metavar="FILE.json|DIR", default=None,
                   help="the first MAP start: parameter values as 'simulate --params' reads them"
                        " (missing names take the model's start values), or the --out DIR of an"
                        " earlier run (its map.json), e.g. the fit of a smaller model the new one"
                        " nests, whose own starts may land in a worse basin; the initial state"
                        " is fitted from the record as always")
    p.add_argument("--chains", type=int, default=4,
                   help="NUTS chains, or emcee ensembles (default: 4)")
    p.add_argument("--warmup", type=int, default=1000,
                   help="warm-up iterations per chain (emcee: burn-in steps) (default: 1000)")
    p.add_argument("--draws", type=int, default=1000,
                   help="kept draws per chain (emcee: steps per walker) (default: 1000)")
    p.add_argument("--adapt-mass-matrix", choices=["on", "off"], default="on",
                   help="NUTS: adapt a dense mass matrix in warm-up, in coordinates whitened by"
                        " the Laplace covariance (default: on); 'off' keeps the Laplace matrix")
    p.add_argument("--target-accept", type=float, default=None,
                   help="NUTS: target acceptance of step-size adaptation, in (0, 1) (default:"
                        " heli_uq.inference.TARGET_ACCEPT = 0.9); raise towards 0.99 if a short"
                        " or low-noise record gives divergences (smaller steps, longer trees)")
    p.add_argument("--max-tree-depth", type=int, default=8,
                   help="NUTS: at most 2^D - 1 leapfrog steps per draw (default: 8); a stiff"
                        " model (friction) can spend the whole tree on every draw, a lower D"
                        " bounds the cost per draw (summary.json reports the saturation)")
    p.add_argument("--time-limit", type=float, default=None, metavar="MIN",
                   help="NUTS: stop sampling after MIN minutes with the draws made (at least"
                        " 100 per chain; a warm-up that would leave no time for them is cut and"
                        " adapts the step size only); --resume later continues to --draws")
    p.add_argument("--max-draws", type=int, default=None, metavar="N",
                   help="NUTS: after --draws, go on a chunk at a time while R-hat or ESS fail"
                        " their checks, up to N draws per chain (and --time-limit)")
    p.add_argument("--walkers", type=int, default=None,
                   help="emcee walkers per ensemble (default: 2 * dim + 2)")
    p.add_argument("--error", choices=SAMPLE_ERROR_MODELS, default="ar1",
                   help="residual model per output (default: ar1, the conservative choice for"
                        " residuals correlated in time; 'heli-uq run' uses iid, which calibrates"
                        " the rig record's pitch and keeps the yaw level honest; '+timing' adds"
                        " a timing error whose sd grows with the simulated rate; see README)")
    add_prior_options(p)
    p.add_argument("--seed", type=int, default=0, help="random seed (default: 0)")
    add_trust_options(p)
    p.add_argument("--no-progress", action="store_true",
                   help="no progress lines (they go to stderr, rewritten in place on a terminal,"
                        " every 30 s otherwise)")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")
    p.set_defaults(handler=cmd_sample)
    return p
