"""Options shared by several ``heli-uq`` commands: the model, the priors, common checks.

Core code raises errors that name its arguments (``effects: unknown effect ...``);
:func:`heli_uq.cli.main.main` turns the leading argument name into the option that set
it (``--effects: ...``).
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

from heli_uq.errors import ParameterError
from heli_uq.model.terms.neural_torque import DEFAULT_HIDDEN  # of --model hybrid's networks

__all__ = ["Formatter", "add_model_options", "model_from_args", "add_prior_options",
           "priors_from_args", "prior_changes_from_args", "check_positive", "out_dir",
           "positive_float", "EFFECTS_HELP", "add_trust_options", "report_health", "result_line",
           "EXIT_UNHEALTHY", "DEFAULT_HIDDEN"]  # fmt: skip

#: Exit status of a run whose health checks failed under ``--strict``.
EXIT_UNHEALTHY = 3


class Formatter(argparse.RawDescriptionHelpFormatter):
    """Keep the line breaks of descriptions/epilogs (defaults are spelled out in each help)."""


def _term_parameters(cls) -> str:
    """``name [unit], ...`` of a term's parameters (bare names for an effect), or why they
    cannot be listed: a term that cannot be built from its defaults breaks its own line of
    the help, not every command (the contract: :class:`heli_uq.model.terms.AbstractEffect`)."""
    try:
        term = cls()
        pars = term._declare() if hasattr(term, "_declare") else term.parameters()
    except Exception as exc:  # a broken term must not break the CLI
        return f"(cannot list its parameters: {type(exc).__name__}: {exc})"
    if len(pars) > 4:  # a network's or a GP's many values: their count
        return f"{len(pars)} parameters at its defaults"
    return ", ".join(f"{p.name} [{p.unit}]" for p in pars)


def _effects_help() -> str:
    """The effects vocabulary, then every other term, each with its parameters and
    :attr:`~heli_uq.model.terms.AbstractEffect.summary`, from :data:`~heli_uq.model.terms.TERMS`."""
    from heli_uq.model.terms import EFFECTS, TERMS

    lines = ["effects (AXIS:EFFECT, axes pitch and yaw; parameters named NAME_AXIS, e.g. F_c_yaw):"]
    for name, cls in EFFECTS.items():
        lines.append(f"  {name:18s} {_term_parameters(cls)}: {cls.summary}")
    lines.append("other terms (the same syntax; not discovery candidates unless given to "
                 "--candidates):")
    for name, cls in TERMS.items():
        if name not in EFFECTS:
            lines.append(f"  {name:18s} {_term_parameters(cls)}: {cls.summary}")
    return "\n".join(lines)


EFFECTS_HELP = _effects_help()


def add_model_options(p, *, sampled: bool = False) -> None:
    """``--effects``, ``--model-file`` and the hybrid model's ``--model``, ``--nn-inputs``,
    ``--hidden``, ``--nn-axes``; with ``sampled`` (a command that samples a posterior) also
    ``--nn-posterior``, which other commands would only ignore."""
    p.add_argument("--effects", metavar="AXIS:EFFECT,...", default=None,
                   help="named effects added to the paper's model, e.g. "
                        "yaw:coulomb_friction,yaw:torque_offset (default: none; see 'effects' "
                        "below)")
    p.add_argument("--model-file", metavar="MODEL.json", default=None,
                   help='the model as JSON, e.g. {"effects": ["yaw:deadband", {"effect": '
                        '"coulomb_friction", "axis": "yaw", "omega_s": 0.001}]}')
    p.add_argument("--model", choices=["mechanistic", "hybrid"], default="mechanistic",
                   help="'hybrid' adds a neural torque (tanh network) on each of --nn-axes to "
                        "the model of --effects/--model-file (default: mechanistic)")
    p.add_argument("--nn-inputs", choices=["u", "u,x,v"], default=None,
                   help="hybrid: the network's inputs, the voltages (u) or also the angles and "
                        "rates (u,x,v) (default: u)")
    p.add_argument("--hidden", type=int, default=None,
                   help=f"hybrid: hidden units per network (default: {DEFAULT_HIDDEN}; the paper "
                        "used 16; NUTS over every weight mixes at 2 on the rig record, not at 4)")
    if sampled:
        _add_network_posterior(p)
    p.add_argument("--nn-axes", default=None, metavar="yaw|pitch|pitch,yaw",
                   help="hybrid: the axes that get a network (default: yaw, the axis the "
                        "paper's network corrected)")


def _add_network_posterior(p) -> None:
    p.add_argument("--nn-posterior", choices=["full", "last-layer"], default=None,
                   help="hybrid: 'full' (default) samples every weight (2 units: 10 min for 4 "
                        "chains on 0-91 s of the rig record; wider networks saturate NUTS's "
                        "trees); 'last-layer' trains the network, fixes its "
                        "hidden layer and samples its output weights with the physics (fast and "
                        "converged, but its band holds the true curve less often)")


def model_from_args(args):
    """The :class:`~heli_uq.model.HeliModel` of ``--effects`` / ``--model-file``."""
    from heli_uq.model.spec import load_model_file, parse_effects

    if args.effects is not None and args.model_file is not None:
        raise ParameterError("--effects and --model-file: give one of them, not both")
    if args.model_file is not None:
        model = load_model_file(args.model_file)
    else:
        model = parse_effects(args.effects, where="--effects")
    return _with_networks(args, model)


def _with_networks(args, model):
    """``model`` plus the neural torques of ``--model hybrid`` (the projection also takes
    out the constant where the axis has a torque offset, which then owns it)."""
    from heli_uq.model.spec import build_model

    given = [f"--{n.replace('_', '-')}" for n in ("nn_inputs", "hidden", "nn_axes", "nn_posterior")
             if getattr(args, n, None) is not None]  # fmt: skip
    if getattr(args, "model", "mechanistic") != "hybrid":
        if given:
            raise ParameterError(f"{given[0]}: only with --model hybrid")
        return model
    hidden = DEFAULT_HIDDEN if args.hidden is None else args.hidden
    if isinstance(hidden, bool) or hidden < 1:
        raise ParameterError(f"--hidden: expected a positive integer, found {hidden}")
    axes = [a.strip() for a in (args.nn_axes or "yaw").split(",") if a.strip()]
    bad = [a for a in axes if a not in ("pitch", "yaw")]
    if bad or not axes or len(set(axes)) < len(axes):
        raise ParameterError(f"--nn-axes: expected pitch, yaw or pitch,yaw, found {args.nn_axes!r}")
    effects = model.describe()["effects"]
    have = {(e["effect"], e["axis"]) for e in effects}
    for axis in axes:
        if ("neural_torque", axis) in have:
            raise ParameterError(f"--nn-axes: the model already has a neural torque on {axis}")
        project = "1,u" if ("torque_offset", axis) in have else "u"
        effects.append({"effect": "neural_torque", "axis": axis, "inputs": args.nn_inputs or "u",
                        "hidden": hidden, "project": project})  # fmt: skip
    desc = model.describe()
    return build_model(effects, mechanics=desc.get("mechanics", "closed_form"),
                       linear_torque=desc.get("linear_torque", True), where="--model hybrid")


def add_prior_options(p) -> None:
    """``--priors``, ``--prior`` and ``--fix``."""
    p.add_argument("--priors", metavar="FILE.json", default=None,
                   help='prior overrides file, e.g. {"m": {"lognormal": [0.5, 1.0]}, "h": 0, '
                        '"F_c_yaw": {"halfnormal": [0.01]}}')
    p.add_argument("--prior", action="append", metavar="NAME=KIND:A:B",
                   help="override one prior (repeatable): lognormal:MEDIAN:SIGMA_LOG, "
                        "halfnormal:SCALE, normal:MEAN:SD, uniform:LOW:HIGH; names are model "
                        "parameters, theta0, psi0, omega_theta0, omega_psi0, sigma_theta, "
                        "sigma_psi, tau_theta, tau_psi, timing_theta, timing_psi")
    p.add_argument("--fix", action="append", metavar="NAME=VALUE",
                   help="fix a parameter (repeatable), e.g. --fix h=0")


def _option_changes(args) -> dict:
    """``{name: Prior}`` of ``--prior`` and ``--fix`` (a later option wins)."""
    from heli_uq.probability.priors import parse_prior_option

    changes = dict(parse_prior_option(text, option="--prior") for text in (args.prior or []))
    for text in args.fix or []:
        name, prior = parse_prior_option(text, option="--fix")
        if prior.kind != "fixed":
            raise ParameterError(f"--fix: expected NAME=VALUE, found {text!r}")
        changes[name] = prior
    return changes


def prior_changes_from_args(args, model) -> dict:
    """``{name: Prior}`` of ``--priors``, ``--prior`` and ``--fix``, checked against ``model``
    (each error names its file or option): the changes a run of several models applies
    to each (``heli-uq discover``)."""
    from heli_uq.probability.priors import load_priors_json

    priors_from_args(args, model)  # the checks
    return {**(load_priors_json(args.priors) if args.priors is not None else {}), **_option_changes(args)}


def priors_from_args(args, model):
    """The :class:`~heli_uq.probability.PriorSet` of the model with the options applied."""
    from heli_uq.probability.priors import PriorSet, load_priors_json

    priors = PriorSet.default(model)
    if args.priors is not None:
        priors = priors.updated(model, load_priors_json(args.priors), where=args.priors)
    return priors.updated(model, _option_changes(args), where="--prior/--fix")


def check_positive(args, names) -> None:
    """One clear error for the first of the integer options ``names`` that is not > 0."""
    for name in names:
        if getattr(args, name) <= 0:
            flag = "--" + name.replace("_", "-")
            raise ParameterError(f"{flag}: expected a positive integer, found {getattr(args, name)}")


def out_dir(path: str) -> Path:
    """Create the output directory if missing (OSError propagates: exit 2)."""
    if not str(path).strip():  # Path("") is the working directory
        raise ParameterError(f"--out: expected a directory, found {path!r}")
    out = Path(path)
    out.mkdir(parents=True, exist_ok=True)
    return out


def positive_float(text: str, option: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise ParameterError(f"{option}: expected a number of seconds, found {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise ParameterError(f"{option}: expected a finite number > 0, found {text!r}")
    return value


def add_trust_options(p) -> None:
    """``--resume`` and ``--strict`` of the commands that sample."""
    p.add_argument("--resume", action="store_true",
                   help="continue an interrupted run from DIR/chunks; refused (naming the "
                        "differences) unless every setting that determines the draws is the "
                        "same as in DIR/chunks/manifest.json, and when there is nothing to "
                        "resume")
    p.add_argument("--strict", action="store_true",
                   help=f"exit with status {EXIT_UNHEALTHY} when a health check fails "
                        "(R-hat, ESS, divergences, tree depth, step size, MAP convergence, "
                        "unphysical predictive simulations); without it they are warnings")


def result_line(summary: dict, keys) -> str:
    """The one JSON line a sampling command prints: ``ok`` (the health checks passed), the
    summary's ``keys`` it has, and ``draws_failed`` (``{window: "k of S"}``) when some
    predictive draws did not simulate, since the coverage and RMSE are then of the others."""
    line = {"ok": summary["health"]["ok"], **{k: summary[k] for k in keys if k in summary}}
    failed = {w: f"{c['draws_failed']} of {c['draws']}" for w, c in summary.get("windows", {}).items()
              if c.get("draws_failed")}  # fmt: skip
    if failed:
        line["draws_failed"] = failed
    return json.dumps(line)


def report_health(summary: dict, strict: bool) -> int:
    """Print the health notes and the warning block of a failed health check on stderr;
    the exit status (:data:`EXIT_UNHEALTHY` under ``strict``, else 0)."""
    import sys

    from heli_uq.output.health import format_warnings

    health = summary["health"]
    for note in health.get("notes", ()):
        print(f"note: {note}", file=sys.stderr)
    if health["ok"]:
        return 0
    print(format_warnings(health), file=sys.stderr)
    return EXIT_UNHEALTHY if strict else 0
