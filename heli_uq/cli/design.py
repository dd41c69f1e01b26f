"""``heli-uq design``: a voltage staircase within the rig's limits that is most informative about
the identifiable parameters (or tells two rival models apart) (:func:`heli_uq.design.design`)."""

from __future__ import annotations

from heli_uq.cli.options import Formatter, add_model_options, model_from_args, out_dir, positive_float
from heli_uq.errors import ParameterError

__all__ = ["add_parser", "cmd_design"]


def _pair(text: str, option: str, sep: str = ":") -> tuple[float, float]:
    try:
        lo, hi = (float(v) for v in text.split(sep))
    except ValueError:
        raise ParameterError(f"{option}: expected LOW{sep}HIGH, found {text!r}") from None
    return lo, hi


def cmd_design(args) -> int:
    import json
    import math

    from heli_uq.design import SEARCH_BUDGETS, DesignPrior, Rivals, StaircaseBounds, design
    from heli_uq.design.information import DEFAULT_NOISE, DESIGN_X0, check_noise

    bounds = StaircaseBounds(positive_float(args.duration, "--duration"), args.dt,
                             (_pair(args.u_theta, "--u-theta"), _pair(args.u_psi, "--u-psi")),
                             _pair(args.segment, "--segment"),
                             tuple(math.radians(v) for v in _pair(args.pitch, "--pitch")))  # fmt: skip
    sigma = None if args.noise is None else check_noise(_pair(args.noise, "--noise", ","))
    draws = SEARCH_BUDGETS[args.budget].draws
    prior = rivals = None
    given = [flag for flag, on in (("--effects", args.effects), ("--model-file", args.model_file),
                                   ("--model hybrid", args.model == "hybrid")) if on]  # fmt: skip
    source = "--discovery" if args.discovery is not None else "--posterior" if args.posterior else None
    if given and source:
        raise ParameterError(f"{' and '.join(given)} with {source}: the models come from {source}; "
                             "give one of them")  # fmt: skip
    if args.discovery is not None:
        if args.posterior is not None:
            raise ParameterError("--discovery and --posterior: give one of them, not both")
        rivals = Rivals.from_discovery(args.discovery, sigma=DEFAULT_NOISE if sigma is None else sigma,
                                       x0=DESIGN_X0, dt=bounds.dt)  # fmt: skip
    elif args.posterior is not None:
        prior = DesignPrior.from_posterior(args.posterior, draws=draws, sigma=sigma, dt=bounds.dt,
                                           seed=args.seed)  # fmt: skip
    else:
        prior = DesignPrior.default(model_from_args(args), sigma=DEFAULT_NOISE if sigma is None else sigma,
                                    dt=bounds.dt, seed=args.seed)  # fmt: skip
    out = out_dir(args.out)
    published = _published(args.compare_with)
    summary = design(out, bounds, prior=prior, rivals=rivals, published=published,
                     budget=args.budget, seed=args.seed)  # fmt: skip
    pub = summary["baselines"]["published"]
    print(json.dumps({"value": summary["value"], "unit": summary["unit"],
                      "published": pub["value"], "random_median": summary["baselines"]["random"]["median"],
                      "volume_ratio_vs_published": summary["volume_ratio_vs_published"]}))  # fmt: skip
    print(f"wrote {out / 'design.csv'}, design.json, design.png")
    return 0


def _published(spec: str):
    """The record whose input is the baseline; ``None`` (said in design.json) when the real
    record is asked for by default and is not available."""
    from heli_uq.data import load_data
    from heli_uq.errors import DataFormatError

    if spec == "none":
        return None
    try:
        return load_data(spec)
    except DataFormatError:
        if spec != "experimental":
            raise
        return None


def add_parser(subparsers):
    p = subparsers.add_parser(
        "design",
        help="propose a voltage staircase that identifies the parameters best",
        description=(
            "Search a voltage staircase within the rig's limits that maximises the expected\n"
            "information gain about the model's parameters (Bayesian D-optimality on the\n"
            "whitened Fisher information, with the current posterior as prior, averaged over\n"
            "its draws; directions no experiment can identify add nothing), or, with\n"
            "--discovery, the expected log Bayes factor between the two best candidate\n"
            "models of a discovery run.  Compares it with the published profile (the first\n"
            "DURATION seconds of the rig record) and with random staircases.\n\n"
            "Writes DIR/design.csv (published format: the voltages and the predicted angles),\n"
            "DIR/design.json (criterion, baselines, gains, segments) and DIR/design.png."
        ),
        epilog=(
            "budgets: quick (24 random staircases, 60 hill-climb steps, 2 posterior draws);\n"
            "  full (100, 500, 8)\n\n"
            "examples:\n"
            "  heli-uq design --duration 60 --out out/design\n"
            "  heli-uq design --posterior out/run/posterior.nc --budget full --out out/design\n"
            "  heli-uq design --discovery out/disc --duration 30 --out out/discriminate"
        ),
        formatter_class=Formatter,
    )  # fmt: skip
    p.add_argument("--posterior", metavar="posterior.nc", default=None,
                   help="prior of the design: a posterior of 'heli-uq sample' or 'run' (default: "
                        "the package's priors, linearised at a fit of the rig record)")  # fmt: skip
    p.add_argument("--discovery", metavar="DIR", default=None,
                   help="discriminate the two best candidates of this 'heli-uq discover' output")
    add_model_options(p)
    p.add_argument("--duration", default="60", metavar="S", help="experiment length [s] (default: 60)")
    p.add_argument("--dt", type=float, default=0.01, help="sample time [s] (default: 0.01)")
    p.add_argument("--u-theta", default="1.22:1.47", metavar="LO:HI",
                   help="pitch voltage range [V] (default: about the rig record's levels, 1.21-1.47)")
    p.add_argument("--u-psi", default="0.45:1.6", metavar="LO:HI",
                   help="yaw voltage range [V] (default: about the rig record's levels, 0.48-1.57)")
    p.add_argument("--segment", default="3:14", metavar="MIN:MAX",
                   help="segment lengths [s] (default: the rig record's 3:14)")
    p.add_argument("--pitch", default="-60:0", metavar="LO:HI",
                   help="envelope [deg] the predicted pitch must keep at every prior draw "
                        "(default: -60:0, arm below horizontal; the rig record stays in -39:-4); write "
                        "--pitch=-50:-5 when LOW is negative")
    p.add_argument("--noise", default=None, metavar="SD_THETA,SD_PSI",
                   help="measurement noise sd [rad] (default: the posterior's, else 0.003,0.008)")
    p.add_argument("--compare-with", default="experimental", metavar="experimental|FILE.csv|none",
                   help="record whose input is the baseline (default: the rig record, skipped "
                        "with a note when it is not available)")  # fmt: skip
    p.add_argument("--budget", choices=["quick", "full"], default="quick", help="effort (default: quick)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default: 0)")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")
    p.set_defaults(handler=cmd_design)
    return p
