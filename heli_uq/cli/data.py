"""``heli-uq data show``: plot a record and print its summary."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from heli_uq.cli.options import Formatter, out_dir

__all__ = ["add_parser", "show_record"]


def show_record(exp, out: Path) -> str:
    """Write ``out/data.png`` of a record; returns the one-line summary."""
    from heli_uq.output.plots import plot_experiment, save_figure

    png_path = save_figure(plot_experiment(exp), out / "data.png")
    u_lo, u_hi = exp.u.min(axis=0), exp.u.max(axis=0)
    y_lo, y_hi = np.degrees(exp.y.min(axis=0)), np.degrees(exp.y.max(axis=0))
    return (
        f"{Path(exp.source).name}: N = {exp.n} samples, dt = {exp.dt:g} s, "
        f"t = {exp.t[0]:g}..{exp.t[0] + exp.duration:g} s ({exp.duration:g} s); "
        f"u_theta {u_lo[0]:.4g}..{u_hi[0]:.4g} V, u_psi {u_lo[1]:.4g}..{u_hi[1]:.4g} V, "
        f"theta {y_lo[0]:.4g}..{y_hi[0]:.4g} deg, psi {y_lo[1]:.4g}..{y_hi[1]:.4g} deg "
        f"-> {png_path}"
    )


def _cmd_data_show(args) -> int:
    from heli_uq.data import load_data, parse_window

    exp = load_data(args.source)
    if args.window is not None:
        exp = exp.window(*parse_window(args.window))
    print(show_record(exp, out_dir(args.out)))
    return 0


def add_parser(subparsers):
    p = subparsers.add_parser(
        "data",
        help="inspect rig records",
        description="Inspect rig records (CSV: u_theta [V], u_psi [V], theta [rad], "
                    "psi [rad], dt [s] in the first data row).",
        formatter_class=Formatter,
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
        formatter_class=Formatter,
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
    return show
