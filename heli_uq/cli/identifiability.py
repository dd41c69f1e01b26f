"""``heli-uq identifiability``: structural, practical and Bayesian identifiability report."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from heli_uq.cli.options import (
    EFFECTS_HELP,
    Formatter,
    add_model_options,
    add_prior_options,
    model_from_args,
    out_dir,
    priors_from_args,
)
from heli_uq.errors import ParameterError

__all__ = ["add_parser", "cmd_identifiability"]


def cmd_identifiability(args) -> int:
    from heli_uq.data import load_data, parse_window
    from heli_uq.identifiability import identifiability_report
    from heli_uq.identifiability.report import check_posterior_data
    from heli_uq.output import check_health, convergence
    from heli_uq.output.health import format_warnings
    from heli_uq.output.inference_data import load_posterior

    model = model_from_args(args)
    priors = priors_from_args(args, model)
    record = load_data(args.data)
    if args.window is not None:
        record = record.window(*parse_window(args.window))
    free = None
    if args.free is not None:
        free = [n.strip() for n in args.free.split(",") if n.strip()]
    base = {}
    if args.params is not None:
        from heli_uq.model.tables import load_params_json

        base.update(load_params_json(args.params, model))
    for name, prior in priors.params.items():
        if not prior.free:
            base[name] = prior.a
    posterior, posterior_prior, note = None, None, None
    if args.posterior is not None:
        if not Path(args.posterior).is_file():
            raise ParameterError(f"--posterior {args.posterior}: no such file")
        idata, post_model = load_posterior(args.posterior)
        check_posterior_data(idata.posterior, record, where=f"--posterior {args.posterior}")
        if json.dumps(post_model.specification(), sort_keys=True) != json.dumps(model.specification(),
                                                                               sort_keys=True):  # fmt: skip
            raise ParameterError(f"--posterior {args.posterior}: sampled for the model "
                                 f"{json.dumps(post_model.specification()['effects'])}, this report is "
                                 f"for {json.dumps(model.specification()['effects'])}; give the same "
                                 "--effects or --model-file")  # fmt: skip
        # the posterior's own model: its terms hold what they took from the posterior's record
        # (a GP's pairs over the whole span, a network's input scaling), so its draws map
        model, posterior = post_model, idata.posterior
        posterior_prior = idata.prior if "prior" in idata.groups() else None
        health = check_health(convergence(idata))
        if not health["ok"]:  # reported, as by 'sample': the user decides
            print(format_warnings(health), file=sys.stderr)
            note = (f"{', '.join(health['flags'])}: {'; '.join(health['warnings'])}; its "
                    "contraction is not to be trusted")  # fmt: skip
    out = out_dir(args.out)
    result = identifiability_report(
        record, out, model=model, free=free, base=base, priors=priors, posterior=posterior,
        posterior_prior=posterior_prior, error=args.error, n_points=args.points, seed=args.seed,
        posterior_note=note,
    )  # fmt: skip
    st = result["structural"]
    classes = {}
    for name, prof in result["practical"]["profiles"].items():
        classes.setdefault(prof["classification"], []).append(name)
    print(f"structural rank {st['rank']} of {st['n_parameters']}; null directions: "
          + (", ".join(d["key"] for d in st["null_directions"]) or "none"))
    for cls, names in classes.items():
        print(f"{cls}: {', '.join(names)}")
    print(f"wrote {out / 'identifiability.md'}, identifiability.json and "
          f"{len(result['figures'])} figures in {result['timings']['total_s']:.0f} s")
    return 0


def add_parser(subparsers):
    p = subparsers.add_parser(
        "identifiability",
        help="structural, practical and Bayesian identifiability report",
        description=(
            "Identifiability of a model's parameters (the paper's Table 2, plus any\n"
            "--effects) and the initial state on a record:\n"
            "structural (rank and named null space of the output sensitivities at the fit\n"
            "and at random points), practical (Fisher information, profile likelihoods,\n"
            "classification) and Bayesian (prior-to-posterior contraction from --posterior,\n"
            "else from the Laplace approximation), cross-checked.\n\n"
            "Writes DIR/identifiability.md, DIR/identifiability.json and PNG figures."
        ),
        epilog=(
            "examples:\n"
            "  heli-uq identifiability --data experimental --out out/ident\n"
            "  heli-uq identifiability --data experimental --fix h=0 --out out/ident_h0\n"
            "  heli-uq identifiability --data rec.csv --window 0:20 \\\n"
            "      --free K_theta_theta,D_theta,J_s --posterior out/post/posterior.nc --out out/i\n"
            "  heli-uq identifiability --data rec.csv --effects yaw:coulomb_friction --out out/f\n\n"
            + EFFECTS_HELP
        ),
        formatter_class=Formatter,
    )
    add_model_options(p)
    p.add_argument("--data", default="experimental", metavar="experimental|FILE.csv",
                   help="record (default: experimental)")
    p.add_argument("--window", metavar="A:B", default=None,
                   help="use only A <= t < B [s] of the record (default: all)")
    p.add_argument("--free", metavar="NAMES", default=None,
                   help="comma-separated free parameters (default: all with a non-fixed prior);"
                        " the others are fixed at --params / start values (Table 1)")
    p.add_argument("--params", metavar="P.json", default=None,
                   help="values of the fixed parameters and first start of the fit (default:"
                        " the start values, Table 1 for the paper's parameters; names missing"
                        " from the file keep them)")
    p.add_argument("--posterior", metavar="posterior.nc", default=None,
                   help="posterior of 'heli-uq sample' for the Bayesian view (default: Laplace)")
    p.add_argument("--error", choices=["iid", "ar1"], default="iid",
                   help="residual model of the likelihood, noise estimated at the fit (default:"
                        " iid; with ar1 on the rig record yaw's rho -> 1 and yaw levels carry"
                        " almost no information)")
    p.add_argument("--points", type=int, default=5,
                   help="points of the structural analysis: the fit + random ones (default: 5)")
    add_prior_options(p)
    p.add_argument("--seed", type=int, default=0, help="random seed (default: 0)")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")
    p.set_defaults(handler=cmd_identifiability)
    return p
