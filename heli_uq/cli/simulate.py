"""``heli-uq simulate``: simulate a model on Table 3 conditions or a record's inputs."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from heli_uq.cli.options import (
    EFFECTS_HELP,
    Formatter,
    add_model_options,
    model_from_args,
    out_dir,
    positive_float,
)
from heli_uq.errors import ParameterError

__all__ = ["add_parser", "cmd_simulate", "simulate_to_files", "momenta", "SIMULATION_COLUMNS"]

PROG = "heli-uq"
#: Header of ``simulation.csv``.
SIMULATION_COLUMNS = ("t", "theta", "psi", "omega_theta", "omega_psi", "p_theta", "p_psi")
#: Default sample time [s] and duration [s] of ``--inputs table3``.
TABLE3_DT = 0.01
TABLE3_T_END = 10.0
RECORD_KEYWORDS = ("experiment", "experimental")
#: Peak memory per sample of ``simulate`` [bytes]: states, momenta, the CSV text and the
#: figure (measured: 1e6 samples of table3 peak at 1.13 GB, 1e3 samples at 0.48 GB).
SIMULATE_BYTES_PER_SAMPLE = 700


def momenta(params, ys) -> np.ndarray:
    """Generalized momenta ``p = M(theta) v``, shape (N, 2) [kg m^2/s], for states (N, 4)."""
    import jax
    import jax.numpy as jnp

    from heli_uq.model.terms.rigid_body import mass_matrix

    p = {k: jnp.asarray(v) for k, v in params.items()}
    ys = jnp.asarray(ys, dtype=jnp.float64)
    mass = jax.vmap(mass_matrix, in_axes=(None, 0))(p, ys[:, 0])  # (N, 2, 2)
    return np.asarray(jnp.einsum("nij,nj->ni", mass, ys[:, 2:]))


def _x0(text):
    from heli_uq.model.tables import parse_x0

    try:
        return parse_x0(text)
    except ParameterError as exc:
        raise ParameterError(f"--{exc}") from None


def _write_csv_atomic(path: Path, header: tuple[str, ...], rows: np.ndarray) -> Path:
    """Write *rows* (2-D float array) with *header*, shortest round-trip floats, atomically."""
    from heli_uq.io import atomic_write_text

    lines = [",".join(header)]
    lines.extend(",".join(repr(float(v)) for v in row) for row in rows)
    return atomic_write_text(path, "\n".join(lines) + "\n")


def _check_size(n: int, t_end: float, dt: float) -> None:
    """Refuse up front a grid that would not fit in memory or exceeds the solver's limit
    (one line with the memory it would need)."""
    from heli_uq.io import format_bytes, require_memory
    from heli_uq.simulation.solver import MAX_SAMPLES

    what = f"--t-end {t_end:g} s with --dt {dt:g} s ({n:.3g} samples)"
    hint = "shorten --t-end or raise --dt"
    require_memory(n * SIMULATE_BYTES_PER_SAMPLE, what, hint)
    if n > MAX_SAMPLES:
        need = format_bytes(n * SIMULATE_BYTES_PER_SAMPLE)
        raise ParameterError(f"{what} exceeds the limit of {MAX_SAMPLES:,} samples per simulation "
                             f"(about {need} of memory); {hint}")  # fmt: skip


def _simulation_inputs(args):
    """Resolve ``--inputs``/``--x0``/``--t-end``/``--dt`` into ``(u, dt, x0, record)``."""
    from heli_uq.model.tables import TABLE3_X0

    spec = args.inputs
    if spec.strip().lower() == "table3":
        dt = TABLE3_DT if args.dt is None else positive_float(args.dt, "--dt")
        t_end = TABLE3_T_END if args.t_end is None else positive_float(args.t_end, "--t-end")
        n = round(t_end / dt) + 1
        _check_size(n, t_end, dt)
        if n < 2:
            raise ParameterError(
                f"--t-end {t_end:g} s with --dt {dt:g} s gives fewer than 2 samples"
            )
        x0 = TABLE3_X0 if args.x0 is None else _x0(args.x0)
        return np.zeros((n, 2)), dt, x0, None

    from heli_uq.data import load_data

    if args.dt is not None:
        raise ParameterError(
            "--dt applies only to --inputs table3; a record is simulated on its own sample time"
        )
    record = load_data("experimental" if spec.strip().lower() in RECORD_KEYWORDS else spec)
    if args.t_end is not None:
        t_end = positive_float(args.t_end, "--t-end")
        if t_end > record.duration + 1e-9 * record.dt:
            raise ParameterError(
                f"--t-end {t_end:g} s: beyond the end of {record.source}, "
                f"which covers {record.duration:g} s"
            )
        record = record.window(float(record.t[0]), float(record.t[0]) + t_end)
        if record.t.size < 2:  # as for table3: one sample is no simulation
            raise ParameterError(f"--t-end {t_end:g} s of {record.source} (sample time {record.dt:g} s; "
                                 f"a record is truncated to t < S) gives fewer than 2 samples")  # fmt: skip
    if args.x0 is None:
        x0 = (float(record.y[0, 0]), float(record.y[0, 1]), 0.0, 0.0)
    else:
        x0 = _x0(args.x0)
    return record.u, record.dt, x0, record


def simulate_to_files(out: Path, params: dict, x0, u, dt: float, *, model=None, record=None,
                      params_label: str = "defaults") -> tuple[int, str]:  # fmt: skip
    """Simulate and write ``out/simulation.csv`` and ``out/simulation.png``.

    Returns ``(status, message)``: status 0 with a one-line summary (ending in
    ``UNPHYSICAL: ...`` when the trajectory leaves the physical range, which the figure's
    title also says), or 1 with the reason when the simulation diverged (nothing written).
    """
    from heli_uq.model.heli_model import HeliModel
    from heli_uq.output.plots import plot_simulation, save_figure
    from heli_uq.probability.likelihood import loss_v
    from heli_uq.simulation.physical import physical_range
    from heli_uq.simulation.solver import RESULTS, solve
    from heli_uq.simulation.stiffness import MAX_SUBSTEPS, capped_substeps, count_text, default_substeps

    model = HeliModel() if model is None else model
    params = {k: float(v) for k, v in model.complete(params).items()}
    need = default_substeps(model, params, dt, margin=2.0)
    substeps = min(need, MAX_SUBSTEPS)
    sol = solve(params, x0, u, dt, model=model, substeps=substeps)
    if not bool(sol.ok):
        kind = "non-finite states" if int(sol.result) == RESULTS.nonfinite else "blow-up"
        stiff = (f"; the model is too stiff for the solver: {count_text(need)} substeps per sample needed, "
                 f"{MAX_SUBSTEPS} at most") if need > MAX_SUBSTEPS else ""  # fmt: skip
        return 1, (f"simulation diverged for these parameters ({kind}; parameters {params_label}, "
                   f"x0={tuple(float(v) for v in x0)}{stiff}); nothing written")  # fmt: skip
    capped_substeps(need, "the model")  # a solve at the cap is kept, with a warning
    ts = np.asarray(sol.ts, dtype=float)
    if record is not None:
        ts = ts + float(record.t[0])
    ys = np.asarray(sol.ys, dtype=float)
    unphysical = physical_range(ys).describe(ts)
    p = momenta(params, ys)
    for name in ("simulation.csv", "simulation.png"):  # both or neither: no partial output
        if (out / name).is_dir():
            raise ParameterError(f"{out / name}: a directory where the output file goes; give another --out")
    csv_path = _write_csv_atomic(out / "simulation.csv", SIMULATION_COLUMNS,
                                 np.column_stack([ts, ys, p]))  # fmt: skip
    source = "Table 3 (zero voltages)" if record is None else Path(record.source).name
    title = f"Simulation ({model.label}): inputs {source}, parameters {params_label}"
    if unphysical:
        title = f"{unphysical}\n{title}"
    png_path = save_figure(plot_simulation(ts, ys, p, title=title, data=record), out / "simulation.png")
    summary = (f"simulated {ys.shape[0]} samples (dt = {dt:g} s, t = {ts[0]:g}..{ts[-1]:g} s, "
               f"{substeps} RK4 substeps) -> {csv_path}, {png_path}")  # fmt: skip
    if record is not None:
        summary += f"; loss V = {float(loss_v(ys, record.y)):.6g} rad^2"
    if unphysical:
        summary += f"; {unphysical}"
    return 0, summary


def cmd_simulate(args) -> int:
    from heli_uq.model.tables import load_params_json

    model = model_from_args(args)
    params = {} if args.params is None else load_params_json(args.params, model)
    u, dt, x0, record = _simulation_inputs(args)
    out = out_dir(args.out)
    label = Path(args.params).name if args.params else "defaults (Table 2)"
    status, message = simulate_to_files(out, params, x0, u, dt, model=model, record=record,
                                        params_label=label)  # fmt: skip
    print(message if status == 0 else f"{PROG}: {message}", file=sys.stdout if status == 0 else sys.stderr)
    return status


def add_parser(subparsers):
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
            "exit status: 0 ok, 1 the simulation diverged, 2 bad input, 70 an internal error\n"
            "  (a bug), 130 interrupted\n\n"
            "examples:\n"
            "  heli-uq simulate --inputs table3 --out out/table3\n"
            "  heli-uq simulate --inputs experiment --params fit.json --t-end 30 --out out/exp\n"
            "  heli-uq simulate --inputs table3 --x0=-0.5,0,0,0 --out out/neg\n"
            "  heli-uq simulate --inputs experiment --effects yaw:coulomb_friction \\\n"
            "      --params fit.json --out out/friction\n\n" + EFFECTS_HELP
        ),
        formatter_class=Formatter,
    )
    p.add_argument("--inputs", required=True, metavar="table3|experiment|FILE.csv",
                   help="where the input voltages [V] come from (required; see 'inputs' below)")
    add_model_options(p)
    p.add_argument("--params", metavar="FILE.json", default=None,
                   help="JSON object of parameter names to SI values, e.g. "
                        '{"m": 0.72, "h": 0.001, "F_c_yaw": 0.004}; missing names take their '
                        "defaults: Table 2, and 'no effect' for effects (default: all defaults)")
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
    p.set_defaults(handler=cmd_simulate)
    return p
