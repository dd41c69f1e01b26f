"""Benchmark the simulator on the full rig record against scipy's LSODA, in one run.

Prints ratios and appends one JSON line to ``--out`` (default
``studies/results/bench_simulate.jsonl``).  Usage::

    python studies/bench_simulate.py [--repeats 20] [--out FILE]

Measured on the record's own inputs (13,100 samples, dt = 0.01 s, zero-order hold)
with the paper's Table 1 ("fitted-looking") parameters:

* forward: ``jax.jit(simulate)`` vs ``scipy.integrate.solve_ivp(method="LSODA",
  rtol=1e-6)`` with the same held inputs (one call, t_eval on the grid);
* gradient: ``jax.jit(jax.grad(V))`` of the paper's loss (Eq. 1) wrt all 12
  parameters and the initial state, relative to the forward solve;
* a batch of 8 parameter sets under ``jax.vmap`` (forward and gradient);
* accuracy: max angle error vs a DOP853 reference (rtol 1e-11) restarted at each switch.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import pathlib
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np
from scipy.integrate import solve_ivp

import heli_uq
from heli_uq.data import load_data

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "tests"))
from reference import reference_solution, vector_field  # noqa: E402


def _median_ms(fn, repeats):
    jax.block_until_ready(fn())
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        times.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(times))


def _lsoda(params, x0, u, dt):
    n = len(u)

    def rhs(t, y):
        return vector_field(t, y, params, u[min(int(t / dt), n - 1)])

    t = np.arange(n) * dt
    return solve_ivp(rhs, (0.0, t[-1]), x0, method="LSODA", rtol=1e-6, t_eval=t).y.T


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default="experimental", help="record: 'experimental' or CSV path")
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--out", default="studies/results/bench_simulate.jsonl")
    args = ap.parse_args(argv)

    exp = load_data(args.data)
    u, y, dt = jnp.asarray(exp.u), jnp.asarray(exp.y), exp.dt
    params = dict(heli_uq.TABLE1)
    x0 = jnp.array([exp.y[0, 0], exp.y[0, 1], 0.0, 0.0])

    fwd = jax.jit(lambda p, x: heli_uq.simulate(p, x, u, dt))
    loss = lambda p, x: heli_uq.loss_v(heli_uq.simulate(p, x, u, dt), y)  # noqa: E731
    grad = jax.jit(jax.grad(loss, argnums=(0, 1)))
    grad_plain = jax.jit(
        jax.grad(lambda p, x: heli_uq.loss_v(
            heli_uq.simulate(p, x, u, dt, gradients="autodiff"), y), argnums=(0, 1))
    )  # fmt: skip
    scales = jnp.linspace(0.95, 1.05, 8)
    batch = {k: v * scales for k, v in params.items()}
    fwd8 = jax.jit(jax.vmap(lambda p: heli_uq.simulate(p, x0, u, dt)))
    grad8 = jax.jit(jax.vmap(jax.grad(lambda p: loss(p, x0))))

    t_fwd = _median_ms(lambda: fwd(params, x0), args.repeats)
    t_grad = _median_ms(lambda: grad(params, x0), args.repeats)
    t_grad_plain = _median_ms(lambda: grad_plain(params, x0), max(3, args.repeats // 4))
    t_fwd8 = _median_ms(lambda: fwd8(batch), args.repeats)
    t_grad8 = _median_ms(lambda: grad8(batch), max(3, args.repeats // 4))
    x0n, un = np.asarray(x0), np.asarray(u)
    lsoda_times = []
    for _ in range(5):
        t0 = time.perf_counter()
        ls = _lsoda(params, x0n, un, dt)
        lsoda_times.append(time.perf_counter() - t0)
    t_lsoda = 1e3 * float(np.median(lsoda_times))

    ref = reference_solution(params, x0n, un, dt)
    ours = np.asarray(fwd(params, x0))
    err = float(np.max(np.abs(ours[:, :2] - ref[:, :2])))
    err_lsoda = float(np.max(np.abs(ls[:, :2] - ref[:, :2])))
    record = {
        "benchmark": "simulate_full_record",
        "n_samples": int(len(u)),
        "dt_s": dt,
        "forward_ms": t_fwd,
        "lsoda_ms": t_lsoda,
        "speedup_vs_lsoda": t_lsoda / t_fwd,
        "grad_ms": t_grad,
        "grad_over_forward": t_grad / t_fwd,
        "grad_plain_autodiff_ms": t_grad_plain,
        "vmap8_forward_ms": t_fwd8,
        "vmap8_forward_per_set_ms": t_fwd8 / 8,
        "vmap8_grad_ms": t_grad8,
        "max_angle_error_rad": err,
        "lsoda_max_angle_error_rad": err_lsoda,
        "loss_v_table1": float(loss(params, x0)),
        "jax": jax.__version__,
        "cpu_count": os.cpu_count(),
        "time": time.strftime("%Y-%m-%dT%H:%M:%S"),
    }
    print(f"forward (jit, RK4, 1 step/sample): {t_fwd:8.2f} ms   LSODA rtol=1e-6: {t_lsoda:8.2f} ms"
          f"   speed-up x{t_lsoda / t_fwd:.1f}")
    print(f"grad of V (discrete adjoint):      {t_grad:8.2f} ms   = {t_grad / t_fwd:.1f} x forward"
          f"   (plain reverse-mode: {t_grad_plain:.1f} ms = {t_grad_plain / t_fwd:.1f} x)")
    print(f"vmap over 8 parameter sets:        forward {t_fwd8:.2f} ms ({t_fwd8 / 8:.2f} ms/set),"
          f" grad {t_grad8:.2f} ms ({t_grad8 / 8:.2f} ms/set)")
    print(f"accuracy vs DOP853 rtol 1e-11: max angle error {err:.2e} rad (LSODA: {err_lsoda:.2e})")
    out = pathlib.Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with open(out, "a", encoding="utf-8") as fh:
        fh.write(json.dumps(record) + "\n")
    print(f"wrote {out}")
    return 0 if math.isfinite(err) else 1


if __name__ == "__main__":
    raise SystemExit(main())
