"""Benchmark the simulator on the full rig record against scipy's LSODA, in one run.

Prints medians and minima and appends one JSON line to ``--out`` (default
``studies/results/bench_simulate.jsonl``).  Usage::

    python studies/bench_simulate.py [--repeats 50] [--data experimental] [--out FILE]

Measured on the record's own inputs (13,100 samples, dt = 0.01 s, zero-order hold)
with the paper's Table 1 ("fitted-looking") parameters and ``x0`` = (first measured
angles, zero rates):

* forward: ``jax.jit(simulate)`` (RK4, one step per sample) vs
  ``scipy.integrate.solve_ivp(method="LSODA", rtol=1e-6)`` with the same held inputs
  (one call, ``t_eval`` on the grid);
* gradient: ``jax.jit(jax.grad(V))`` of the paper's loss (Eq. 1, [rad^2]) wrt every
  parameter and the initial state, through the discrete adjoint and through plain
  reverse-mode autodiff, relative to the forward solve (``grad / forward``);
* a batch of 8 parameter sets (Table 1 scaled by 0.95 ... 1.05) under ``jax.vmap``
  (forward and gradient);
* the same forward / gradient / ratio for models with one effect:
  ``yaw:coulomb_friction`` with ``F_c_yaw`` = 0.004 N m (stiff: at the substeps
  :func:`heli_uq.simulation.default_substeps` gives over the record's pitch angles, as
  :func:`heli_uq.probability.make_problem` does, and at 5) and ``yaw:torque_offset`` with
  ``T_0_yaw`` = 0.002 N m (smooth: 1 substep), and both motors' lags (``motor_lag``,
  ``tau`` = 0.3 s: a scan over the voltages before the solve, 1 substep); the gradient
  per substep relative to the mechanistic gradient, and for several substeps the forward
  against a baseline that unrolls each sample's substeps in one loop body (the scheme
  before 2026-11-25);
* accuracy: max angle error [rad] vs the DOP853 reference of ``tests/reference.py``
  (rtol 1e-11, restarted at each switch of the inputs).

Timing: every timed function is compiled and run once, then the functions are called
in turn (interleaved, the order rotated each round) ``--repeats`` times, so a slow
phase of a shared machine hits all of them alike; the JSON line keeps the median and
the minimum of each [ms].
"""

from __future__ import annotations

import argparse
import math
import pathlib
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np
from scipy.integrate import solve_ivp

import heli_uq
from heli_uq.data import load_data
from heli_uq.model import TABLE1, parse_effects
from heli_uq.simulation import default_substeps

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "tests"))
from _study import RESULTS, append_jsonl, provenance  # noqa: E402
from reference import reference_solution, vector_field  # noqa: E402

#: Rounds of the interleaved timing (each round calls every timed function once).
REPEATS = 50
#: Parameter sets of the vmap benchmark: Table 1 times these factors.
BATCH_SCALES = np.linspace(0.95, 1.05, 8)
#: LSODA's relative tolerance (the old study's choice).
LSODA_RTOL = 1e-6
#: The one-effect models: effects text, the effect parameter's value [N m] and whether
#: the substeps come from ``default_substeps`` (stiff) or are 1 (smooth).
EFFECT_CASES = (
    ("yaw:coulomb_friction", {"F_c_yaw": 0.004}, "default"),
    ("yaw:coulomb_friction", {"F_c_yaw": 0.004}, 5),
    ("yaw:torque_offset", {"T_0_yaw": 0.002}, 1),
    ("pitch:motor_lag,yaw:motor_lag", {"tau_pitch": 0.3, "tau_yaw": 0.3}, 1),
)


def nested_forward(model, u, dt, substeps):
    """The baseline of the substeps: states (N, 4) with each sample's ``substeps`` RK4 steps
    unrolled in one loop body (the simulator takes them as rows of their own)."""
    from heli_uq.simulation.solver import _rk4_step

    def run(p, x0):
        prepared = model.prepare(model.complete(p))

        def body(y, uk):
            y_next = y
            for _ in range(substeps):
                y_next = _rk4_step(model, prepared, y_next, uk, dt / substeps)[0]
            return y_next, y

        return jax.lax.scan(body, x0, u)[1]

    return jax.jit(run)


def _lsoda(params, x0, u, dt):
    """States (N, 4) by LSODA with the inputs held on each sample interval."""
    n = len(u)

    def rhs(t, y):
        return vector_field(t, y, params, u[min(int(t / dt), n - 1)])

    t = np.arange(n) * dt
    return solve_ivp(rhs, (0.0, t[-1]), x0, method="LSODA", rtol=LSODA_RTOL, t_eval=t).y.T


def interleaved_ms(fns: dict, repeats: int) -> dict[str, np.ndarray]:
    """Wall times [ms] of ``repeats`` calls of each function, interleaved.

    Each function is called once first (compilation, caches).  Then every round calls all
    of them, in an order rotated by one each round, each timed to
    ``jax.block_until_ready`` of its result.
    """
    names = list(fns)
    for name in names:
        jax.block_until_ready(fns[name]())
    times = {name: [] for name in names}
    for r in range(repeats):
        k = r % len(names)
        for name in names[k:] + names[:k]:
            t0 = time.perf_counter()
            jax.block_until_ready(fns[name]())
            times[name].append(time.perf_counter() - t0)
    return {name: 1e3 * np.asarray(t) for name, t in times.items()}


def _stats(ms: np.ndarray) -> dict:
    return {"median_ms": float(np.median(ms)), "min_ms": float(np.min(ms))}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default="experimental", help="record: 'experimental' or CSV path")
    ap.add_argument("--repeats", type=int, default=REPEATS,
                    help=f"interleaved timing rounds (default {REPEATS})")
    ap.add_argument("--out", default=str(RESULTS / "bench_simulate.jsonl"))
    args = ap.parse_args(argv)
    t_run = time.perf_counter()

    exp = load_data(args.data)
    u, y, dt = jnp.asarray(exp.u), jnp.asarray(exp.y), exp.dt
    params = dict(TABLE1)
    x0 = jnp.array([exp.y[0, 0], exp.y[0, 1], 0.0, 0.0])
    x0n, un = np.asarray(x0), np.asarray(u)

    def loss(p, x, **kw):
        return heli_uq.loss_v(heli_uq.simulate(p, x, u, dt, **kw), y)

    fwd = jax.jit(lambda p, x: heli_uq.simulate(p, x, u, dt))
    grad = jax.jit(jax.grad(loss, argnums=(0, 1)))
    grad_plain = jax.jit(jax.grad(lambda p, x: loss(p, x, gradients="autodiff"), argnums=(0, 1)))
    batch = {k: v * jnp.asarray(BATCH_SCALES) for k, v in params.items()}
    fwd8 = jax.jit(jax.vmap(lambda p: heli_uq.simulate(p, x0, u, dt)))
    grad8 = jax.jit(jax.vmap(jax.grad(lambda p: loss(p, x0))))
    fns = {
        "forward": lambda: fwd(params, x0),
        "grad": lambda: grad(params, x0),
        "grad_plain_autodiff": lambda: grad_plain(params, x0),
        "vmap8_forward": lambda: fwd8(batch),
        "vmap8_grad": lambda: grad8(batch),
        "lsoda": lambda: _lsoda(params, x0n, un, dt),
    }
    effects = {}
    for text, values, substeps in EFFECT_CASES:
        model = parse_effects(text)
        p_eff = {**params, **values}
        n_sub = (default_substeps(model, p_eff, dt, thetas=exp.y[:, 0]) if substeps == "default"
                 else substeps)  # fmt: skip
        key = f"{text} x{n_sub}"
        if key in effects:
            continue
        kw = {"model": model, "substeps": n_sub}
        f_e = jax.jit(lambda p, x, kw=kw: heli_uq.simulate(p, x, u, dt, **kw))
        g_e = jax.jit(jax.grad(lambda p, x, kw=kw: loss(p, x, **kw), argnums=(0, 1)))
        fns[f"{key}/forward"] = lambda f=f_e, p=p_eff: f(p, x0)
        fns[f"{key}/grad"] = lambda g=g_e, p=p_eff: g(p, x0)
        if n_sub > 1:
            fns[f"{key}/forward_nested"] = (lambda f=nested_forward(model, u, dt, n_sub), p=p_eff:
                                            f(p, x0))  # fmt: skip
        effects[key] = {"effects": text, "values": values, "substeps": n_sub}

    ms = interleaved_ms(fns, args.repeats)
    st = {name: _stats(v) for name, v in ms.items()}
    med = {name: s["median_ms"] for name, s in st.items()}
    low = {name: s["min_ms"] for name, s in st.items()}
    for key, case in effects.items():
        f, g, nested = f"{key}/forward", f"{key}/grad", f"{key}/forward_nested"
        case.update(forward_ms=med[f], forward_min_ms=low[f], grad_ms=med[g], grad_min_ms=low[g],
                    grad_over_forward=med[g] / med[f], grad_over_forward_min=low[g] / low[f],
                    grad_per_substep_over_grad=med[g] / case["substeps"] / med["grad"])
        if nested in med:  # the substeps as rows against the same steps unrolled per sample
            case.update(forward_nested_ms=med[nested], speedup_vs_nested=med[nested] / med[f])

    ls = _lsoda(params, x0n, un, dt)
    ref = reference_solution(params, x0n, un, dt)
    ours = np.asarray(fwd(params, x0))
    err = float(np.max(np.abs(ours[:, :2] - ref[:, :2])))
    err_lsoda = float(np.max(np.abs(ls[:, :2] - ref[:, :2])))
    record = {
        "benchmark": "simulate_full_record",
        "n_samples": int(len(u)),
        "dt_s": dt,
        "repeats": args.repeats,
        "timing": "interleaved, median (and *_min_ms minimum) over repeats",
        "forward_ms": med["forward"],
        "forward_min_ms": low["forward"],
        "lsoda_ms": med["lsoda"],
        "lsoda_min_ms": low["lsoda"],
        "speedup_vs_lsoda": med["lsoda"] / med["forward"],
        "grad_ms": med["grad"],
        "grad_min_ms": low["grad"],
        "grad_over_forward": med["grad"] / med["forward"],
        "grad_over_forward_min": low["grad"] / low["forward"],
        "grad_plain_autodiff_ms": med["grad_plain_autodiff"],
        "grad_plain_autodiff_min_ms": low["grad_plain_autodiff"],
        "vmap8_forward_ms": med["vmap8_forward"],
        "vmap8_forward_min_ms": low["vmap8_forward"],
        "vmap8_forward_per_set_ms": med["vmap8_forward"] / len(BATCH_SCALES),
        "vmap8_grad_ms": med["vmap8_grad"],
        "vmap8_grad_min_ms": low["vmap8_grad"],
        "effects": effects,
        "max_angle_error_rad": err,
        "lsoda_max_angle_error_rad": err_lsoda,
        "loss_v_table1": float(loss(params, x0)),
    }
    record.update(provenance(__file__, argv, time.perf_counter() - t_run))

    def row(label, name):
        return f"{label:34s} {med[name]:9.2f} ms (min {low[name]:9.2f})"

    print(f"{args.repeats} interleaved rounds; median (min) per call")
    print(row("forward (jit, RK4, 1 step/sample):", "forward"))
    print(row(f"LSODA rtol={LSODA_RTOL:g}:", "lsoda")
          + f"   speed-up x{med['lsoda'] / med['forward']:.1f}")
    print(row("grad of V (discrete adjoint):", "grad")
          + f"   grad / forward = {record['grad_over_forward']:.2f}"
          f" (min/min {record['grad_over_forward_min']:.2f})")
    print(row("grad of V (plain reverse mode):", "grad_plain_autodiff")
          + f"   = {med['grad_plain_autodiff'] / med['forward']:.1f} x forward")
    print(row("vmap over 8 sets, forward:", "vmap8_forward")
          + f"   ({record['vmap8_forward_per_set_ms']:.2f} ms/set)")
    print(row("vmap over 8 sets, grad:", "vmap8_grad")
          + f"   ({med['vmap8_grad'] / len(BATCH_SCALES):.2f} ms/set)")
    for key, case in effects.items():
        tag = f"{case['effects']} ({case['substeps']} substeps)"
        print(f"{tag:34s} forward {case['forward_ms']:8.2f} ms (min {case['forward_min_ms']:.2f}),"
              f" grad {case['grad_ms']:8.2f} ms (min {case['grad_min_ms']:.2f}),"
              f" grad / forward = {case['grad_over_forward']:.2f}"
              f" (min/min {case['grad_over_forward_min']:.2f}),"
              f" grad per substep / mechanistic grad = {case['grad_per_substep_over_grad']:.2f}")
        if "speedup_vs_nested" in case:
            print(f"{'':34s} forward with the substeps unrolled per sample {case['forward_nested_ms']:.2f}"
                  f" ms: rows of their own are x{case['speedup_vs_nested']:.1f} faster")
    print(f"accuracy vs DOP853 rtol 1e-11: max angle error {err:.2e} rad (LSODA: {err_lsoda:.2e})")
    out = append_jsonl(args.out, record)
    print(f"appended to {out}")
    return 0 if math.isfinite(err) else 1


if __name__ == "__main__":
    raise SystemExit(main())
