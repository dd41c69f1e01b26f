"""Accuracy of the fixed-step RK4 solver vs its substeps, per named effect, on the rig's inputs.

For each named effect (:data:`heli_uq.model.EFFECTS`) on one axis (``--axis``, default
yaw), at its documented smoothing (the term's default options, e.g. ``omega_s`` =
0.002 rad/s for ``coulomb_friction``), with representative values (:data:`EFFECT_VALUES`)
and the paper's Table 1 for the other parameters, simulate the rig record's voltages
(``--seconds`` from its start, default the full 131 s) from the first measured angles at
rest, and report

* the max angle error [rad] of :func:`heli_uq.simulation.simulate` against the adaptive
  stiff reference :func:`heli_uq.simulation.reference_solve` (diffrax Kvaerno5, rtol = atol
  = 1e-10 unless ``--rtol``), i.e. :func:`heli_uq.simulation.reference.solver_error`, for
  1, 2, 4, 8 and 16 RK4 substeps per sample and at ``default_substeps(model, values, dt,
  margin=2.0, thetas=reference pitch)`` (the margin the MAP stage used until 2026-11-28;
  it now covers the stiffness of the Laplace draws);
* the wall time [ms] of one jitted forward solve at each substep count (median of
  ``--repeats`` calls after compilation) and of the reference solve [s].

The paper's model without effects is the first row (baseline).  Prints markdown tables,
writes ``studies/results/substep_convergence.json`` and the log-log figure
``studies/figures/substep_convergence.png`` (error vs substeps per effect, with the
1e-4 rad tolerance of the posterior study).  Usage::

    python studies/substep_convergence.py [--axis yaw|pitch] [--seconds 131]
        [--effects coulomb_friction,deadband] [--substeps 1,2,4,8,16]

A full-record run of the stiff friction reference takes minutes; ``--seconds 10`` is a
quick check.  Errors level off at the reference's own error: at rtol = atol = 1e-10 it is
~1.2e-8 rad after 10 s of the record (against the DOP853 reference of
``tests/reference.py``, rtol 1e-11, for the paper's model, where RK4 with 4 substeps is
within 1.4e-11 rad), far below the 1e-4 rad tolerance; ``--rtol 1e-12`` lowers it to
~3e-10 rad at a higher cost.
"""

from __future__ import annotations

import argparse
import json
import math
import pathlib
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np
from matplotlib.ticker import NullLocator

from heli_uq.data import load_data
from heli_uq.errors import ParameterError
from heli_uq.figure import new_figure, save_figure
from heli_uq.io import atomic_write_text
from heli_uq.model import AXES, EFFECTS, TABLE1, build_model
from heli_uq.output.posterior_study import SOLVER_TOL
from heli_uq.simulation import default_substeps, reference_solve, simulate
from heli_uq.simulation.reference import REFERENCE_RTOL

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from _study import FIGURES, RESULTS, provenance  # noqa: E402

#: Representative values of each effect's parameters, by bare name [SI]:
#: dead band 0.3 V, Coulomb level 0.004 N m, drag 0.02 N m s^2/rad^2, spring 0.004 N m/rad
#: relaxed at 0.4 rad, quadratic thrust 0.01 N m/V^2, constant torque 0.002 N m.
EFFECT_VALUES = {
    "deadband": {"delta": 0.3},
    "coulomb_friction": {"F_c": 0.004},
    "quadratic_drag": {"c": 0.02},
    "torsional_spring": {"k": 0.004, "psi_0": 0.4},
    "quadratic_thrust": {"k_q": 0.01},
    "torque_offset": {"T_0": 0.002},
}
#: Label of the paper's model (no effect), the baseline row.
BASELINE = "none"
#: Substep counts compared.
SUBSTEPS = (1, 2, 4, 8, 16)
#: Margin of the stiffness-based substep count (the MAP stage used 2 until 2026-11-28; it
#: now covers the Laplace draws, :data:`heli_uq.inference.substeps.TAIL_DRAWS`).
MARGIN = 2.0
#: Timed forward solves per substep count (median reported).
REPEATS = 5


def _model_and_values(effect: str, axis: str):
    """The model with one effect on ``axis`` (default options) and its parameter values."""
    if effect == BASELINE:
        return build_model([]), dict(TABLE1)
    model = build_model([f"{axis}:{effect}"])
    values = {f"{bare}_{axis}": v for bare, v in EFFECT_VALUES[effect].items()}
    return model, {**TABLE1, **values}


def _forward(model, values, x0, u, dt, substeps: int, repeats: int):
    """States (N, 4) of one jitted forward solve and its median wall time [ms]."""
    f = jax.jit(lambda p, x: simulate(p, x, u, dt, model=model, substeps=substeps))
    ys = jax.block_until_ready(f(values, x0))
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(f(values, x0))
        times.append(time.perf_counter() - t0)
    return np.asarray(ys), 1e3 * float(np.median(times))


def _angle_error(ys, ref) -> float | None:
    """Max angle error [rad] (as ``solver_error``); None if the solve is not finite."""
    err = float(np.max(np.abs(ys[:, :2] - ref[:, :2])))
    return err if math.isfinite(err) else None


def study_effect(effect: str, axis: str, record, substeps, *, repeats: int, rtol: float) -> dict:
    """Errors and timings of one effect (module docstring); ``rtol``: the reference's
    relative and absolute tolerance."""
    model, values = _model_and_values(effect, axis)
    u, dt = jnp.asarray(record.u), float(record.dt)
    x0 = jnp.array([record.y[0, 0], record.y[0, 1], 0.0, 0.0])
    label = model.effects[0].label if model.effects else "paper model (no effect)"
    out = {"effect": effect, "axis": None if effect == BASELINE else axis,
           "model": model.describe(), "label": label,
           "values": {k: v for k, v in values.items() if k not in TABLE1}}  # fmt: skip
    t0 = time.perf_counter()
    try:
        ref = reference_solve(values, x0, u, dt, model=model, rtol=rtol, atol=rtol)
    except ParameterError as exc:
        out.update(reference_error=str(exc), reference_s=time.perf_counter() - t0)
        return out
    out["reference_s"] = time.perf_counter() - t0
    out["stiffness_rate_per_s"] = model.stiffness(model.complete(values), ref[:, 0])
    n_default = default_substeps(model, values, dt, margin=MARGIN, thetas=ref[:, 0])
    out["default_substeps"] = n_default
    counts = sorted(set(substeps) | {n_default})
    errors, times = {}, {}
    for n in counts:
        ys, ms = _forward(model, values, x0, u, dt, n, repeats)
        errors[n], times[n] = _angle_error(ys, ref), ms
    out["substeps"] = list(substeps)
    out["max_angle_error_rad"] = [errors[n] for n in substeps]
    out["forward_ms"] = [times[n] for n in substeps]
    out["default_error_rad"] = errors[n_default]
    out["default_forward_ms"] = times[n_default]
    return out


def _fmt(err) -> str:
    return "diverged" if err is None else f"{err:.1e}"


def print_tables(rows: list, substeps) -> None:
    """Markdown tables: errors [rad] and forward times [ms] per substep count."""
    head = " | ".join(f"{n}" for n in substeps)
    sep = " | ".join("---" for _ in substeps)
    print(f"\nmax angle error [rad] vs reference, by RK4 substeps per sample "
          f"(tolerance {SOLVER_TOL:g} rad)\n")
    print(f"| effect | {head} | default (margin {MARGIN:g}) | reference [s] |")
    print(f"| --- | {sep} | --- | --- |")
    for r in rows:
        if "reference_error" in r:
            print(f"| {r['label']} | reference failed: {r['reference_error']} |")
            continue
        errs = " | ".join(_fmt(e) for e in r["max_angle_error_rad"])
        print(f"| {r['label']} | {errs} | {_fmt(r['default_error_rad'])} at "
              f"{r['default_substeps']} | {r['reference_s']:.1f} |")
    print("\nwall time of one forward solve [ms] (jit, median)\n")
    print(f"| effect | {head} | default |")
    print(f"| --- | {sep} | --- |")
    for r in rows:
        if "reference_error" in r:
            continue
        ms = " | ".join(f"{t:.1f}" for t in r["forward_ms"])
        print(f"| {r['label']} | {ms} | {r['default_forward_ms']:.1f} at {r['default_substeps']} |")


def plot(rows: list, path, *, axis: str, seconds: float, rtol: float):
    """Log-log error vs substeps per effect, the default count marked, the tolerance line."""
    fig = new_figure((7.5, 5.0))
    ax = fig.add_subplot(1, 1, 1)
    for i, r in enumerate(r for r in rows if "reference_error" not in r):
        color = f"C{i}"
        n = np.asarray(r["substeps"], dtype=float)
        e = np.asarray([np.nan if v is None else v for v in r["max_angle_error_rad"]], dtype=float)
        ax.loglog(n, e, "o-", color=color, label=r["label"])
        if r["default_error_rad"] is not None:
            ax.loglog([r["default_substeps"]], [r["default_error_rad"]], "*", color=color,
                      markersize=13, markeredgecolor="k")  # fmt: skip
    ax.axhline(SOLVER_TOL, color="k", ls="--", lw=1, label=f"tolerance {SOLVER_TOL:g} rad")
    ax.plot([], [], "*", color="0.5", markersize=13, markeredgecolor="k",
            label=f"default_substeps (margin {MARGIN:g})")  # fmt: skip
    ax.set_xlabel("RK4 substeps per sample interval (dt = 0.01 s)")
    ax.set_ylabel("max angle error vs adaptive reference [rad]")
    ax.set_xscale("log", base=2)
    ticks = sorted({n for r in rows for n in r.get("substeps", [])}
                   | {r["default_substeps"] for r in rows if "default_substeps" in r})
    ax.set_xticks(ticks, [str(n) for n in ticks])
    ax.xaxis.set_minor_locator(NullLocator())
    ax.set_title(f"Fixed-step RK4 vs adaptive reference (Kvaerno5, rtol = atol = {rtol:g}),\n"
                 f"one {axis} effect each, Table 1 otherwise, rig inputs 0-{seconds:g} s",
                 fontsize=10)  # fmt: skip
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8, loc="best")
    fig.tight_layout()
    return save_figure(fig, path)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default="experimental", help="record: 'experimental' or CSV path")
    ap.add_argument("--axis", choices=AXES, default="yaw", help="axis of every effect (default yaw)")
    ap.add_argument("--seconds", type=float, default=None,
                    help="use the first SECONDS of the record [s] (default: all of it)")
    ap.add_argument("--effects", default=",".join(k for k in EFFECTS if k in EFFECT_VALUES),
                    help="comma-separated effect names (default: every effect of the vocabulary "
                         "with values in EFFECT_VALUES)")
    ap.add_argument("--substeps", default=",".join(map(str, SUBSTEPS)),
                    help="comma-separated substep counts (default 1,2,4,8,16)")
    ap.add_argument("--repeats", type=int, default=REPEATS, help="timed forward solves per count")
    ap.add_argument("--rtol", type=float, default=REFERENCE_RTOL,
                    help=f"rtol = atol of the reference solve (default {REFERENCE_RTOL:g})")
    ap.add_argument("--out", default=str(RESULTS / "substep_convergence.json"))
    ap.add_argument("--fig", default=str(FIGURES / "substep_convergence.png"))
    args = ap.parse_args(argv)
    t_run = time.perf_counter()
    effects = [e.strip() for e in args.effects.split(",") if e.strip()]
    unknown = sorted(set(effects) - set(EFFECTS))
    if unknown:
        ap.error(f"--effects: unknown {', '.join(unknown)}; expected some of {', '.join(EFFECTS)}")
    lacking = sorted(set(effects) - set(EFFECT_VALUES))
    if lacking:
        ap.error(f"--effects: no representative values for {', '.join(lacking)}; add them to "
                 "EFFECT_VALUES in studies/substep_convergence.py")
    substeps = sorted({int(s) for s in args.substeps.split(",") if s.strip()})

    record = load_data(args.data)
    if args.seconds is not None:
        record = record.window(float(record.t[0]), float(record.t[0]) + args.seconds)
    rows = []
    for effect in [BASELINE, *effects]:
        row = study_effect(effect, args.axis, record, substeps, repeats=args.repeats,
                           rtol=args.rtol)
        rows.append(row)
        done = ("reference failed" if "reference_error" in row
                else f"default {row['default_substeps']} substeps: {_fmt(row['default_error_rad'])} rad")
        print(f"{row['label']}: {done}", flush=True)
    print_tables(rows, substeps)
    seconds = float(record.n * record.dt)
    result = {"study": "substep_convergence", "data": args.data, "axis": args.axis,
              "seconds": seconds, "n_samples": int(record.n), "dt_s": float(record.dt),
              "tolerance_rad": SOLVER_TOL, "margin": MARGIN, "reference_rtol_atol": args.rtol,
              "effects": rows}  # fmt: skip
    result.update(provenance(__file__, argv, time.perf_counter() - t_run))
    out = pathlib.Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out, json.dumps(result, indent=1))
    fig = plot(rows, args.fig, axis=args.axis, seconds=seconds, rtol=args.rtol)
    print(f"\nwrote {out} and {fig}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
