"""Command line interface ``heli-uq`` (also ``python -m heli_uq.cli``).

Subcommands::

    heli-uq run [--data experimental|synthetic|FILE.csv] [--out DIR]
    heli-uq simulate --inputs table3|experiment|FILE.csv [--params P.json] [--x0 ...]
                     [--t-end S] [--dt S] --out DIR
    heli-uq data show experimental|FILE.csv [--window a:b] --out DIR
    heli-uq sample --data experimental|FILE.csv [--train a:b --test c:d] ... --out DIR
    heli-uq identifiability --data experimental|FILE.csv [--window a:b] [--free NAMES]
                            [--posterior DIR/posterior.nc] --out DIR

Adding a subcommand is one ``_add_<name>(subparsers)`` function that builds its parser
and sets ``handler=<function(args) -> int>``, plus one entry in :data:`_SUBCOMMANDS`.

Exit codes: 0 success, 1 the simulation failed (diverged), 2 bad input or usage (any
:class:`~heli_uq.errors.HeliUQError`, an output that cannot be written, or an argparse
usage error).  Errors are reported as one line ``heli-uq: error: <message>`` on stderr.
"""

from __future__ import annotations

import os

# Let independent MCMC chains run as parallel host devices, spread over the CPU cores (this
# must precede JAX's start-up; 8 devices cover the usual 4 chains on any machine).
if "xla_force_host_platform_device_count" not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = (
        os.environ.get("XLA_FLAGS", "")
        + f" --xla_force_host_platform_device_count={max(8, os.cpu_count() or 1)}"
    ).strip()

import argparse
import math
import sys
from pathlib import Path

import numpy as np

from heli_uq import _jax_config  # noqa: F401  (float64 before any array exists)
from heli_uq.errors import HeliUQError, ParameterError

__all__ = ["main", "build_parser", "SIMULATION_COLUMNS"]

PROG = "heli-uq"
#: Header of ``simulation.csv``.
SIMULATION_COLUMNS = ("t", "theta", "psi", "omega_theta", "omega_psi", "p_theta", "p_psi")
#: Default sample time [s] and duration [s] of ``--inputs table3``.
TABLE3_DT = 0.01
TABLE3_T_END = 10.0
_RECORD_KEYWORDS = ("experiment", "experimental")


class _Formatter(argparse.RawDescriptionHelpFormatter):
    """Keep the line breaks of descriptions/epilogs (defaults are spelled out in each help)."""


# --------------------------------------------------------------------------- helpers


def _check_positive(args, names) -> None:
    """One clear error for the first of the integer options ``names`` that is not > 0."""
    for name in names:
        if getattr(args, name) <= 0:
            raise ParameterError(f"--{name}: expected a positive integer, found {getattr(args, name)}")


def _out_dir(path: str) -> Path:
    """Create the output directory if missing (OSError propagates: exit 2)."""
    out = Path(path)
    out.mkdir(parents=True, exist_ok=True)
    return out


def _positive_float(text: str, option: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise ParameterError(f"{option}: expected a number of seconds, found {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise ParameterError(f"{option}: expected a finite number > 0, found {text!r}")
    return value


def _write_csv_atomic(path: Path, header: tuple[str, ...], rows: np.ndarray) -> Path:
    """Write *rows* (2-D float array) with *header*, shortest round-trip floats, atomically."""
    from heli_uq.io import atomic_write_text

    lines = [",".join(header)]
    lines.extend(",".join(repr(float(v)) for v in row) for row in rows)
    return atomic_write_text(path, "\n".join(lines) + "\n")


def momenta(params, ys) -> np.ndarray:
    """Generalized momenta ``p = M(theta) v``, shape (N, 2) [kg m^2/s], for states (N, 4)."""
    import jax
    import jax.numpy as jnp

    from heli_uq.dynamics import closed_form_mass_matrix
    from heli_uq.params import HeliParams

    hp = HeliParams.from_mapping(params)
    ys = jnp.asarray(ys, dtype=jnp.float64)
    mass = jax.vmap(closed_form_mass_matrix, in_axes=(None, 0))(hp, ys[:, 0])  # (N, 2, 2)
    return np.asarray(jnp.einsum("nij,nj->ni", mass, ys[:, 2:]))


# --------------------------------------------------------------------------- simulate


def _simulation_inputs(args):
    """Resolve ``--inputs``/``--x0``/``--t-end``/``--dt`` into ``(u, dt, x0, record)``."""
    from heli_uq.params import TABLE3_X0, parse_x0

    spec = args.inputs
    if spec.strip().lower() == "table3":
        dt = TABLE3_DT if args.dt is None else _positive_float(args.dt, "--dt")
        t_end = TABLE3_T_END if args.t_end is None else _positive_float(args.t_end, "--t-end")
        n = round(t_end / dt) + 1
        if n < 2:
            raise ParameterError(
                f"--t-end {t_end:g} s with --dt {dt:g} s gives fewer than 2 samples"
            )
        x0 = TABLE3_X0 if args.x0 is None else parse_x0(args.x0)
        return np.zeros((n, 2)), dt, x0, None

    from heli_uq.data import load_data

    if args.dt is not None:
        raise ParameterError(
            "--dt applies only to --inputs table3; a record is simulated on its own sample time"
        )
    record = load_data("experimental" if spec.strip().lower() in _RECORD_KEYWORDS else spec)
    if args.t_end is not None:
        t_end = _positive_float(args.t_end, "--t-end")
        if t_end > record.duration + 1e-9 * record.dt:
            raise ParameterError(
                f"--t-end {t_end:g} s: beyond the end of {record.source}, "
                f"which covers {record.duration:g} s"
            )
        record = record.window(float(record.t[0]), float(record.t[0]) + t_end)
    if args.x0 is None:
        x0 = (float(record.y[0, 0]), float(record.y[0, 1]), 0.0, 0.0)
    else:
        x0 = parse_x0(args.x0)
    return record.u, record.dt, x0, record


def _cmd_simulate(args) -> int:
    from heli_uq.objectives import loss_v
    from heli_uq.params import TABLE2, load_params_json
    from heli_uq.plots import plot_simulation, save_figure
    from heli_uq.simulate import RESULTS, solve

    params = dict(TABLE2) if args.params is None else load_params_json(args.params)
    u, dt, x0, record = _simulation_inputs(args)
    out = _out_dir(args.out)

    sol = solve(params, x0, u, dt)
    if not bool(sol.ok):
        kind = "non-finite states" if int(sol.result) == RESULTS.nonfinite else "blow-up"
        print(
            f"{PROG}: simulation diverged for these parameters ({kind}; parameters "
            f"{args.params or 'Table 2'}, x0={tuple(float(v) for v in x0)}); nothing written",
            file=sys.stderr,
        )
        return 1
    ts = np.asarray(sol.ts, dtype=float)
    if record is not None:
        ts = ts + float(record.t[0])
    ys = np.asarray(sol.ys, dtype=float)
    p = momenta(params, ys)

    csv_path = _write_csv_atomic(out / "simulation.csv", SIMULATION_COLUMNS,
                                 np.column_stack([ts, ys, p]))
    source = "Table 3 (zero voltages)" if record is None else Path(record.source).name
    param_name = Path(args.params).name if args.params else "Table 2"
    title = f"Simulation: inputs {source}, parameters {param_name}"
    png_path = save_figure(plot_simulation(ts, ys, p, title=title, data=record),
                           out / "simulation.png")

    summary = (
        f"simulated {ys.shape[0]} samples (dt = {dt:g} s, t = {ts[0]:g}..{ts[-1]:g} s) "
        f"-> {csv_path}, {png_path}"
    )
    if record is not None:
        summary += f"; loss V = {float(loss_v(ys, record.y)):.6g} rad^2"
    print(summary)
    return 0


def _add_simulate(subparsers) -> None:
    p = subparsers.add_parser(
        "simulate",
        help="simulate the helicopter and write simulation.csv and simulation.png",
        description=(
            "Simulate the 2-DOF helicopter (fixed-step RK4, zero-order-held voltages).\n\n"
            "Writes DIR/simulation.csv with columns\n"
            "  t [s], theta [rad], psi [rad], omega_theta [rad/s], omega_psi [rad/s],\n"
            "  p_theta [kg m^2/s], p_psi [kg m^2/s]\n"
            "and DIR/simulation.png (angles in degrees, velocities, momenta; the measured\n"
            "angles are overlaid when the inputs come from a record)."
        ),
        epilog=(
            "inputs:\n"
            "  table3        zero voltages, x0 = Table 3 (pi/4, 0, -0.1, 0.1), on a grid\n"
            "                of --dt up to --t-end (N = round(t_end/dt) + 1 samples)\n"
            "  experiment    the voltages of the real rig record (13,100 samples, dt 0.01 s);\n"
            "                found via $HELI_UQ_DATA or downloaded once\n"
            "  FILE.csv      any record in the published format (u_theta [V], u_psi [V],\n"
            "                theta [rad], psi [rad], dt [s] in the first data row)\n"
            "  For records, x0 defaults to (first theta, first psi, 0, 0), the record's\n"
            "  sample time is used, and the loss V = mean((theta - theta_d)^2 +\n"
            "  (psi - psi_d)^2) [rad^2] is printed.\n\n"
            "exit status: 0 ok, 1 the simulation diverged, 2 bad input\n\n"
            "examples:\n"
            "  heli-uq simulate --inputs table3 --out out/table3\n"
            "  heli-uq simulate --inputs experiment --params fit.json --t-end 30 --out out/exp\n"
            "  heli-uq simulate --inputs table3 --x0=-0.5,0,0,0 --out out/neg"
        ),
        formatter_class=_Formatter,
    )
    p.add_argument("--inputs", required=True, metavar="table3|experiment|FILE.csv",
                   help="where the input voltages [V] come from (required; see 'inputs' below)")
    p.add_argument("--params", metavar="FILE.json", default=None,
                   help="JSON object of Table 2 parameter names to SI values, e.g. "
                        '{"m": 0.72, "h": 0.001}; missing names take Table 2 values '
                        "(default: Table 2)")
    p.add_argument("--x0", metavar="THETA,PSI,OMEGA_THETA,OMEGA_PSI", default=None,
                   help="initial state [rad, rad, rad/s, rad/s]; write --x0=-0.5,0,0,0 when "
                        "the first value is negative (default: Table 3 for table3, "
                        "the record's first angles and zero velocities for records)")
    p.add_argument("--t-end", metavar="S", default=None,
                   help=f"duration [s] (default: {TABLE3_T_END:g} for table3, the whole "
                        "record for records; records are truncated to t < S)")
    p.add_argument("--dt", metavar="S", default=None,
                   help=f"sample time [s], only for table3 (default: {TABLE3_DT})")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="output directory (created if missing)")
    p.set_defaults(handler=_cmd_simulate)


# --------------------------------------------------------------------------- data


def _cmd_data_show(args) -> int:
    from heli_uq.data import load_data, parse_window
    from heli_uq.plots import plot_experiment, save_figure

    exp = load_data(args.source)
    if args.window is not None:
        exp = exp.window(*parse_window(args.window))
    out = _out_dir(args.out)
    png_path = save_figure(plot_experiment(exp), out / "data.png")
    u_lo, u_hi = exp.u.min(axis=0), exp.u.max(axis=0)
    y_lo, y_hi = np.degrees(exp.y.min(axis=0)), np.degrees(exp.y.max(axis=0))
    print(
        f"{Path(exp.source).name}: N = {exp.n} samples, dt = {exp.dt:g} s, "
        f"t = {exp.t[0]:g}..{exp.t[0] + exp.duration:g} s ({exp.duration:g} s); "
        f"u_theta {u_lo[0]:.4g}..{u_hi[0]:.4g} V, u_psi {u_lo[1]:.4g}..{u_hi[1]:.4g} V, "
        f"theta {y_lo[0]:.4g}..{y_hi[0]:.4g} deg, psi {y_lo[1]:.4g}..{y_hi[1]:.4g} deg "
        f"-> {png_path}"
    )
    return 0


def _add_data(subparsers) -> None:
    p = subparsers.add_parser(
        "data",
        help="inspect rig records",
        description="Inspect rig records (CSV: u_theta [V], u_psi [V], theta [rad], "
                    "psi [rad], dt [s] in the first data row).",
        formatter_class=_Formatter,
    )
    sub = p.add_subparsers(title="commands", dest="data_command", required=True,
                           metavar="COMMAND")
    show = sub.add_parser(
        "show",
        help="plot a record (voltages and angles) and print a summary",
        description=(
            "Plot a record as DIR/data.png: input voltages [V] (steps) and measured angles\n"
            "[deg] vs time [s]; print N, dt, duration and the ranges of every column."
        ),
        epilog=(
            "examples:\n"
            "  heli-uq data show experimental --out out/data\n"
            "  heli-uq data show experimental --window 90:131 --out out/val\n"
            "  heli-uq data show my_record.csv --out out/mine"
        ),
        formatter_class=_Formatter,
    )
    show.add_argument("source", metavar="experimental|FILE.csv",
                      help="the real rig record ($HELI_UQ_DATA or downloaded once) or a CSV "
                           "record in the published format")
    show.add_argument("--window", metavar="A:B", default=None,
                      help="only samples with A <= t < B [s]; 'A:' runs to the end "
                           "(default: the whole record)")
    show.add_argument("--out", required=True, metavar="DIR",
                      help="output directory (created if missing)")
    show.set_defaults(handler=_cmd_data_show)


# --------------------------------------------------------------------------- run


def _record_for_run(spec: str, out: Path) -> str:
    """A record path (or keyword) for ``run``; fall back to the synthetic default offline."""
    from heli_uq.data import load_data, synthetic_experiment

    if spec != "synthetic":
        try:
            load_data(spec)
            return spec
        except HeliUQError as exc:
            if spec != "experimental":
                raise
            print(f"{PROG}: the real record is not available ({exc}); "
                  "using the embedded synthetic default instead")
    path = out / "synthetic_record.csv"
    synthetic_experiment(seed=0, duration=60.0).to_csv(path)
    return str(path)


#: ``run``: the posterior's training window is this fraction of the record (0-91 s of the
#: 131 s rig record, as in the issue's calibration study); the rest is the test window.
RUN_TRAIN_FRACTION = 91.0 / 131.0


def _cmd_run(args) -> int:
    """The main job: show the record, simulate Table 3 and the record (Tables 2 and 1), then
    the posterior (NUTS, iid errors) with a train/test split and its bands."""
    import json

    import numpyro

    from heli_uq.params import TABLE1

    _check_positive(args, ("chains", "warmup", "draws"))
    numpyro.set_host_device_count(args.chains)  # before the first JAX computation
    out = _out_dir(args.out)
    record = _record_for_run(args.data, out)
    ns = argparse.Namespace
    status = _cmd_data_show(ns(source=record, window=None, out=str(out / "data")))
    status |= _cmd_simulate(ns(inputs="table3", params=None, x0=None, t_end=None, dt=None,
                               out=str(out / "table3")))
    table1 = out / "table1_params.json"
    table1.write_text(json.dumps(TABLE1, indent=1), encoding="utf-8")
    for name, params in (("record_table1", str(table1)), ("record_table2", None)):
        print(f"[{name}] ", end="")
        code = _cmd_simulate(ns(inputs=record, params=params, x0=None, t_end=None, dt=None,
                                out=str(out / name)))
        status |= code if name == "record_table1" else 0  # Table 2 may diverge: reported only
    status |= _run_posterior(record, out / "posterior", args)
    print(f"main job finished; figures and tables in {out}")
    return status


def _run_posterior(record_spec: str, out: Path, args) -> int:
    """The ``run`` job's posterior stage: NUTS on the first RUN_TRAIN_FRACTION of the record."""
    import json

    from heli_uq.data import load_data
    from heli_uq.workflow import sample_posterior

    record = load_data(record_spec)
    t0, t_end = float(record.t[0]), float(record.t[0]) + record.duration
    split = round(t0 + RUN_TRAIN_FRACTION * record.duration, 2)
    print(f"[posterior] NUTS, iid errors, train {t0:g}:{split:g} s, test {split:g}:{t_end:g} s, "
          f"{args.chains} chains x ({args.warmup} + {args.draws})")
    _, summary = sample_posterior(
        record, out, train=(t0, split), test=(split, t_end), error="iid", chains=args.chains,
        warmup=args.warmup, draws=args.draws, seed=args.seed, progress=not args.no_progress,
    )  # fmt: skip
    keys = ("rhat_max", "ess_bulk_min", "divergences", "coverage90", "coverage90_test", "wall_s")
    print(json.dumps({k: summary[k] for k in keys if k in summary}))
    print(f"wrote {out / 'posterior.nc'}, summary.json, bands.png")
    return 0


def _add_run(subparsers) -> None:
    p = subparsers.add_parser(
        "run",
        help="the main job end to end: record figure, Table 3 and record simulations, posterior",
        description=(
            "Run the package's main job end to end and write everything under DIR:\n"
            "  DIR/data/data.png                      the record (voltages, angles)\n"
            "  DIR/table3/simulation.{csv,png}        nominal model, Table 3 conditions\n"
            "  DIR/record_table1/simulation.{csv,png} the record's inputs, paper Table 1\n"
            "  DIR/record_table2/simulation.{csv,png} the record's inputs, Table 2\n"
            "  DIR/posterior/{posterior.nc,summary.json,summary.csv,bands.png}\n"
            "      NUTS posterior (iid errors) on the first 91/131 of the record, bands\n"
            "      with the rest held out (6.5 min on the rig record, 2 cores)\n"
            "The real record is used when available ($HELI_UQ_DATA or a checked\n"
            "download); otherwise the embedded synthetic default (seed 0) is used."
        ),
        formatter_class=_Formatter,
    )
    p.add_argument("--data", default="experimental", metavar="experimental|synthetic|FILE.csv",
                   help="record to use (default: experimental, falling back to synthetic)")
    p.add_argument("--out", default="out", metavar="DIR",
                   help="output directory (default: out)")
    p.add_argument("--chains", type=int, default=4, help="NUTS chains (default: 4)")
    p.add_argument("--warmup", type=int, default=500,
                   help="warm-up iterations per chain (default: 500)")
    p.add_argument("--draws", type=int, default=500, help="kept draws per chain (default: 500)")
    p.add_argument("--seed", type=int, default=0, help="seed of the posterior (default: 0)")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(handler=_cmd_run)


# --------------------------------------------------------------------------- sample


def _priors_from_args(args):
    from heli_uq.priors import default_priors, load_priors_json, parse_prior_option, update_priors

    priors = default_priors() if args.priors is None else load_priors_json(args.priors)
    changes = dict(parse_prior_option(text) for text in (args.prior or []))
    for text in args.fix or []:
        name, prior = parse_prior_option(text)
        if prior.kind != "fixed":
            raise ParameterError(f"--fix: expected NAME=VALUE, found {text!r}")
        changes[name] = prior
    return update_priors(priors, changes, where="--prior/--fix")


def _cmd_sample(args) -> int:
    import json

    import numpyro

    from heli_uq.data import load_data, parse_window
    from heli_uq.workflow import sample_posterior

    _check_positive(args, ("chains", "warmup", "draws"))
    from heli_uq.inference import TARGET_ACCEPT

    if args.target_accept is None:
        args.target_accept = TARGET_ACCEPT
    if not 0.0 < args.target_accept < 1.0:
        raise ParameterError(f"--target-accept: expected a number in (0, 1), found {args.target_accept}")
    if args.sampler == "nuts":
        # One XLA host device per chain, so numpyro runs the chains in parallel; only
        # effective before JAX's backend starts (always so when run as a program).
        numpyro.set_host_device_count(args.chains)
    record = load_data(args.data)
    if args.window is not None:
        record = record.window(*parse_window(args.window))
    train = parse_window(args.train) if args.train else None
    test = parse_window(args.test) if args.test else None
    if test is not None and train is None:
        raise ParameterError("--test needs --train (the test window follows the training window)")
    priors = _priors_from_args(args)
    out = _out_dir(args.out)
    _, summary = sample_posterior(
        record, out, train=train, test=test, sampler=args.sampler, error=args.error,
        priors=priors, chains=args.chains, warmup=args.warmup, draws=args.draws,
        seed=args.seed, resume=args.resume, progress=not args.no_progress,
        walkers=args.walkers, adapt_mass_matrix=args.adapt_mass_matrix == "on",
        target_accept=args.target_accept,
    )  # fmt: skip
    keys = ("rhat_max", "ess_bulk_min", "ess_tail_min", "divergences", "rmse", "coverage90",
            "rmse_test", "coverage90_test", "wall_s")  # fmt: skip
    print(json.dumps({k: summary[k] for k in keys if k in summary}))
    print(f"wrote {out / 'posterior.nc'}, summary.csv, summary.json, bands.png")
    return 0


def _add_sample(subparsers) -> None:
    p = subparsers.add_parser(
        "sample",
        help="Bayesian posterior (NUTS or emcee) with predictive bands and diagnostics",
        description=(
            "Sample the posterior of the mechanistic model given a record.\n\n"
            "Writes DIR/posterior.nc (arviz InferenceData), DIR/summary.csv,\n"
            "DIR/summary.json (R-hat, ESS, divergences, RMSE, 90 % coverage per window,\n"
            "wall time) and DIR/bands.png; draws are saved in DIR/chunks as they come.\n"
            "Both samplers start from a multi-start MAP; NUTS uses a dense mass matrix\n"
            "started from the Laplace covariance, in identifiable coordinates."
        ),
        epilog=(
            "priors (defaults: see heli_uq.priors): --prior m=lognormal:0.5:1.0,\n"
            "  --prior h=normal:0:0.01, --fix h=0, or --priors FILE.json with\n"
            '  {"m": {"lognormal": [0.5, 1.0]}, "h": {"fixed": 0}}\n\n'
            "examples:\n"
            "  heli-uq sample --data experimental --train 0:91 --test 91:131 --out out/post\n"
            "  heli-uq sample --data experimental --window 0:30 --sampler emcee --out out/em"
        ),
        formatter_class=_Formatter,
    )
    p.add_argument("--model", choices=["mechanistic"], default="mechanistic",
                   help="model to sample (default: mechanistic)")
    p.add_argument("--sampler", choices=["nuts", "emcee"], default="nuts",
                   help="sampler (default: nuts)")
    p.add_argument("--data", default="experimental", metavar="experimental|FILE.csv",
                   help="record (default: experimental)")
    p.add_argument("--window", metavar="A:B", default=None,
                   help="use only A <= t < B [s] of the record (default: all)")
    p.add_argument("--train", metavar="A:B", default=None,
                   help="training window [s] (default: the whole (windowed) record)")
    p.add_argument("--test", metavar="C:D", default=None,
                   help="held-out test window [s], after the training window")
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
                        " heli_uq.inference.TARGET_ACCEPT = 0.95); raise towards 0.99 if a short"
                        " or low-noise record gives divergences (smaller steps, longer trees)")
    p.add_argument("--walkers", type=int, default=None,
                   help="emcee walkers per ensemble (default: 2 * dim + 2)")
    p.add_argument("--error", choices=["iid", "ar1"], default="ar1",
                   help="residual model per output (default: ar1)")
    p.add_argument("--priors", metavar="FILE.json", default=None, help="prior overrides file")
    p.add_argument("--prior", action="append", metavar="NAME=KIND:A:B",
                   help="override one prior (repeatable)")
    p.add_argument("--fix", action="append", metavar="NAME=VALUE",
                   help="fix a parameter (repeatable), e.g. --fix h=0")
    p.add_argument("--seed", type=int, default=0, help="random seed (default: 0)")
    p.add_argument("--resume", action="store_true",
                   help="continue an interrupted run from DIR/chunks")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")
    p.set_defaults(handler=_cmd_sample)


def _cmd_identifiability(args) -> int:
    from heli_uq.data import load_data, parse_window
    from heli_uq.identifiability import identifiability_report
    from heli_uq.params import TABLE1, load_params_json

    record = load_data(args.data)
    if args.window is not None:
        record = record.window(*parse_window(args.window))
    priors = _priors_from_args(args)
    free = None
    if args.free is not None:
        free = [n.strip() for n in args.free.split(",") if n.strip()]
    base = dict(TABLE1)
    if args.params is not None:
        base.update(load_params_json(args.params))
    for name, prior in priors.items():
        if not prior.free:
            base[name] = prior.a
    if args.posterior is not None and not Path(args.posterior).is_file():
        raise ParameterError(f"--posterior {args.posterior}: no such file")
    out = _out_dir(args.out)
    result = identifiability_report(
        record, out, free=free, base=base, priors=priors, posterior=args.posterior,
        error=args.error, n_points=args.points, seed=args.seed,
        log=(lambda _msg: None) if args.quiet else print,
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


def _add_identifiability(subparsers) -> None:
    p = subparsers.add_parser(
        "identifiability",
        help="structural, practical and Bayesian identifiability report",
        description=(
            "Identifiability of the Table 2 parameters and the initial state on a record:\n"
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
            "      --free K_theta_theta,D_theta,J_s --posterior out/post/posterior.nc --out out/i"
        ),
        formatter_class=_Formatter,
    )
    p.add_argument("--data", default="experimental", metavar="experimental|FILE.csv",
                   help="record (default: experimental)")
    p.add_argument("--window", metavar="A:B", default=None,
                   help="use only A <= t < B [s] of the record (default: all)")
    p.add_argument("--free", metavar="NAMES", default=None,
                   help="comma-separated free parameters (default: all with a non-fixed prior);"
                        " the others are fixed at --params / Table 1 values")
    p.add_argument("--params", metavar="P.json", default=None,
                   help="values of the fixed parameters and first start of the fit (default:"
                        " Table 1; names missing from the file take Table 2 values)")
    p.add_argument("--posterior", metavar="posterior.nc", default=None,
                   help="posterior of 'heli-uq sample' for the Bayesian view (default: Laplace)")
    p.add_argument("--error", choices=["iid", "ar1"], default="iid",
                   help="residual model of the likelihood, noise estimated at the fit (default:"
                        " iid; with ar1 on the rig record yaw's rho -> 1 and yaw levels carry"
                        " almost no information)")
    p.add_argument("--points", type=int, default=5,
                   help="points of the structural analysis: the fit + random ones (default: 5)")
    p.add_argument("--priors", metavar="FILE.json", default=None, help="prior overrides file")
    p.add_argument("--prior", action="append", metavar="NAME=KIND:A:B",
                   help="override one prior (repeatable)")
    p.add_argument("--fix", action="append", metavar="NAME=VALUE",
                   help="fix a parameter (repeatable), e.g. --fix h=0")
    p.add_argument("--seed", type=int, default=0, help="random seed (default: 0)")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")
    p.set_defaults(handler=_cmd_identifiability)


# --------------------------------------------------------------------------- main

#: Parser builders of the subcommands, in the order shown by ``--help``.
_SUBCOMMANDS = (_add_run, _add_simulate, _add_data, _add_sample, _add_identifiability)


def build_parser() -> argparse.ArgumentParser:
    """The ``heli-uq`` argument parser with all subcommands."""
    parser = argparse.ArgumentParser(
        prog=PROG,
        description="Bayesian uncertainty quantification of a 2-DOF laboratory helicopter.\n"
                    "States (theta, psi, omega_theta, omega_psi) in rad and rad/s; voltages "
                    "in V;\nparameters in SI units (paper Table 2).",
        epilog="Run 'heli-uq COMMAND --help' for the options of a command.",
        formatter_class=_Formatter,
    )
    sub = parser.add_subparsers(title="commands", dest="command", required=True,
                                metavar="COMMAND")
    for add in _SUBCOMMANDS:
        add(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run ``heli-uq`` with *argv* (default ``sys.argv[1:]``); return the exit status."""
    args = build_parser().parse_args(argv)
    try:
        return int(args.handler(args))
    except (HeliUQError, OSError) as exc:
        if isinstance(exc, OSError) and exc.filename is not None and exc.strerror:
            message = f"{exc.filename}: {exc.strerror}"  # e.g. an --out that is a file
        else:
            message = " ".join(str(exc).split()) or type(exc).__name__
        print(f"{PROG}: error: {message}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
