"""``heli-uq run``: the package's main job end to end."""

from __future__ import annotations

import logging
from pathlib import Path

from heli_uq.cli.data import show_record
from heli_uq.cli.options import (
    Formatter,
    add_model_options,
    add_trust_options,
    check_positive,
    model_from_args,
    out_dir,
    report_health,
    result_line,
)
from heli_uq.cli.simulate import simulate_to_files
from heli_uq.errors import HeliUQError, ParameterError

__all__ = ["add_parser", "cmd_run", "RUN_TRAIN_FRACTION"]

PROG = "heli-uq"
#: ``run``: the posterior's training window is this fraction of the record (0-91 s of the
#: 131 s rig record, as in the calibration study); the rest is the test window.
RUN_TRAIN_FRACTION = 91.0 / 131.0
#: ``run``: draws of the prior predictive check before the posterior.
PRIOR_DRAWS = 500


def _record_for_run(spec: str, out: Path):
    """The record of ``run``; falls back to the synthetic default when the real one is
    not available."""
    from heli_uq.data import load_data
    from heli_uq.simulation.synthetic import synthetic_experiment

    if spec != "synthetic":
        try:
            return load_data(spec)
        except HeliUQError as exc:
            if spec != "experimental":
                raise
            print(f"{PROG}: the real record is not available ({exc}); "
                  "using the embedded synthetic default instead")
    path = out / "synthetic_record.csv"
    synthetic_experiment(seed=0, duration=60.0).to_csv(path)
    from heli_uq.data import read_record

    return read_record(path)


#: ``run``'s NUTS settings beyond the command's options (those of ``sample``'s defaults).
RUN_NUTS = {"max_tree_depth": 8, "adapt_mass_matrix": True}


def _check_posterior(record, model, args, train, test, out: Path) -> None:
    """Refuse, before any stage writes, draws that cannot fit in memory and a ``--resume``
    that the saved run cannot take (another record, model or setting): a refused resume
    must leave the directory as the run it holds wrote it."""
    from heli_uq.inference import TARGET_ACCEPT, resume_obstacle
    from heli_uq.inference.draw_memory import check_draws_memory
    from heli_uq.probability.problem import make_problem

    problem = make_problem(record, train, test, model=model, error="iid")
    check_draws_memory(problem, args.chains * args.draws,
                       f"draws: {args.chains} chains x {args.draws} draws")  # fmt: skip
    if not args.resume:
        return
    if args.nn_posterior == "last-layer":
        raise ParameterError("--resume: a last-layer network run trains its hidden layers again, so "
                             "it cannot continue saved draws; run the command without --resume")  # fmt: skip
    why = resume_obstacle(problem, out / "posterior", chains=args.chains, warmup=args.warmup,
                          draws=args.draws, seed=args.seed, target_accept=TARGET_ACCEPT,
                          **RUN_NUTS)  # fmt: skip
    if why == "nothing to resume":
        raise ParameterError(f"--resume: nothing to resume in {out / 'posterior'}; run the command "
                             "without --resume")  # fmt: skip
    if why is not None:
        raise ParameterError(f"--resume: the run in {out / 'posterior'} cannot be continued: {why}; give "
                             "its settings, or run the command without --resume")  # fmt: skip


def cmd_run(args) -> int:
    """The main job: show the record, simulate Table 3 and the record (Tables 2 and 1), check
    the priors against the record, then the posterior (NUTS, iid errors) with a train/test
    split and its bands."""
    import numpyro

    from heli_uq.model.tables import TABLE1, TABLE3_X0
    from heli_uq.output.posterior_study import sample_posterior
    from heli_uq.output.prior_check import prior_predictive_check

    check_positive(args, ("chains", "warmup", "draws"))
    numpyro.set_host_device_count(args.chains)  # before the first JAX computation
    model = model_from_args(args)
    out = out_dir(args.out)
    record = _record_for_run(args.data, out)
    t0, t_end = float(record.t[0]), float(record.t[0]) + record.duration
    split = round(t0 + RUN_TRAIN_FRACTION * record.duration, 2)
    _check_posterior(record, model, args, (t0, split), (split, t_end), out)
    print(show_record(record, out_dir(out / "data")))
    import numpy as np

    n3 = round(10.0 / 0.01) + 1
    status, message = simulate_to_files(out_dir(out / "table3"), {}, TABLE3_X0, np.zeros((n3, 2)), 0.01,
                                        params_label="Table 2")  # fmt: skip
    print(message)
    x0 = (float(record.y[0, 0]), float(record.y[0, 1]), 0.0, 0.0)
    for name, params, label in (("record_table1", TABLE1, "Table 1"), ("record_table2", {}, "Table 2")):
        code, message = simulate_to_files(out_dir(out / name), params, x0, record.u, record.dt,
                                          record=record, params_label=label)  # fmt: skip
        print(f"[{name}] {message}")
        status |= code if name == "record_table1" else 0  # Table 2 may diverge: reported only
    _, prior = prior_predictive_check(record, out / "prior", model=model, train=(t0, split),
                                      test=(split, t_end), error="iid", draws=PRIOR_DRAWS,
                                      seed=args.seed)  # fmt: skip
    print(f"[prior] prior predictive check, {PRIOR_DRAWS} draws: {100 * prior['failed']:.0f} % fail the "
          f"solver, {100 * prior['unphysical']:.0f} % unphysical -> {out / 'prior'}/bands.png"
          + "".join(f"\n[prior] note: {n}" for n in prior["notes"]))  # fmt: skip
    logging.getLogger(__name__).info(
        f"[posterior] NUTS, iid errors, {model.label}, train {t0:g}:{split:g} s, test "
        f"{split:g}:{t_end:g} s, {args.chains} chains x ({args.warmup} + {args.draws})")
    post = out / "posterior"
    _, summary = sample_posterior(
        record, post, model=model, train=(t0, split), test=(split, t_end), error="iid",
        chains=args.chains, warmup=args.warmup, draws=args.draws, seed=args.seed,
        progress=not args.no_progress, resume=args.resume,
        network_posterior=args.nn_posterior or "full", **RUN_NUTS,
    )  # fmt: skip
    keys = ("rhat_max", "ess_bulk_min", "ess_tail_min", "divergences", "coverage90", "coverage90_test",
            "wall_s")
    print(result_line(summary, keys))
    print(f"wrote {post / 'posterior.nc'}, summary.json, bands.png")
    print(f"main job finished; figures and tables in {out}")
    health = report_health(summary, args.strict)  # printed whatever the status
    return status or health


def add_parser(subparsers):
    p = subparsers.add_parser(
        "run",
        help="the main job end to end: record figure, Table 3 and record simulations, posterior",
        description=(
            "Run the package's main job end to end and write everything under DIR:\n"
            "  DIR/data/data.png                      the record (voltages, angles)\n"
            "  DIR/table3/simulation.{csv,png}        nominal model, Table 3 conditions\n"
            "  DIR/record_table1/simulation.{csv,png} the record's inputs, paper Table 1\n"
            "  DIR/record_table2/simulation.{csv,png} the record's inputs, Table 2\n"
            "  DIR/prior/{prior.nc,summary.json,bands.png}\n"
            "      prior predictive check: 500 draws from the priors, simulated and\n"
            "      set against the record (notes on failed, unphysical or conflicting\n"
            "      draws)\n"
            "  DIR/posterior/{posterior.nc,summary.json,summary.csv,bands.png}\n"
            "      NUTS posterior (iid errors) of the model (the paper's, or with\n"
            "      --effects) on the first 91/131 of the record, bands with the rest\n"
            "      held out\n"
            "The real record is used when available ($HELI_UQ_DATA or a checked\n"
            "download); otherwise the embedded synthetic default (seed 0) is used.\n"
            "Simulations that leave the physical range (|pitch| > 90 deg, blow-ups) are\n"
            "reported as UNPHYSICAL; failed health checks of the posterior as a warning\n"
            "block (see 'heli-uq sample --help').\n\n"
            "exit status: 0 ok, 1 the Table 1 simulation diverged, 2 bad input or a refused\n"
            "--resume, 3 a failed health check under --strict, 70 an internal error (a bug),\n"
            "130 interrupted"
        ),
        formatter_class=Formatter,
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
    add_model_options(p, sampled=True)
    add_trust_options(p)
    p.add_argument("--no-progress", action="store_true",
                   help="no progress lines (they go to stderr, rewritten in place on a terminal,"
                        " every 30 s otherwise)")
    p.set_defaults(handler=cmd_run)
    return p
