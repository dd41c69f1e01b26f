"""Hidden-effect recovery with NUTS: does the posterior's 95 % interval hold the truth?

For each named effect (``--effects``) on an axis (``--axis``, default yaw) and each truth
of the paper's parameters (``--truths``: ``table1``, the paper's fit, and ``table2``, the
nominal values the priors are centred on), a record is simulated by the *adaptive stiff
reference solver* (diffrax Kvaerno5, :func:`heli_uq.simulation.reference_solve`: an
independent solver, not the fixed-step one the model uses) on a random voltage staircase in
the rig's ranges, with iid noise; the model with that effect is fitted with the package's
MAP and NUTS (iid errors), and the 95 % intervals of each effect parameter and of its ratio
to the axis inertia (what the angles identify; the parameter itself also carries the
unidentified common inertia scale, set by the priors) are compared with the truth.

One JSON line per case goes to ``--out`` (default ``studies/results/effect_recovery.jsonl``)
with the intervals, the coverage flags, R-hat and ESS of the effect parameters, the number
of divergences and the wall time.  Usage::

    python studies/effect_recovery.py [--seconds 30] [--chains 2 --warmup 400 --draws 400]
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import tempfile
import time

import arviz as az
import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from _study import RESULTS, append_jsonl, provenance  # noqa: E402

from heli_uq.inference import prepare_start, run_nuts  # noqa: E402
from heli_uq.model import EFFECTS, TABLE1, TABLE2, build_model  # noqa: E402
from heli_uq.model.terms.rigid_body import pitch_inertia, yaw_inertia  # noqa: E402
from heli_uq.probability import make_problem  # noqa: E402
from heli_uq.simulation import reference_solve, synthetic_experiment  # noqa: E402

#: Hidden values of each effect's parameters, by bare name [SI] (as in tests/test_effects.py).
EFFECT_VALUES = {
    "deadband": {"delta": 0.3}, "coulomb_friction": {"F_c": 0.004},
    "quadratic_drag": {"c": 0.02}, "torsional_spring": {"k": 0.004, "psi_0": 0.4},
    "quadratic_thrust": {"k_q": 0.01}, "torque_offset": {"T_0": 0.002},
}  # fmt: skip
TRUTHS = {"table1": TABLE1, "table2": TABLE2}
#: Voltage ranges of the staircase [V] (the rig record's) and hold time of a level [s].
U_RANGES = ((1.25, 1.42), (0.45, 1.6))
HOLD_S = 1.5
INTERVAL = (0.025, 0.975)
X0 = (-0.5, 0.3, 0.0, 0.0)


def staircase(seconds: float, dt: float, seed: int) -> np.ndarray:
    """Random voltage levels in :data:`U_RANGES`, each held :data:`HOLD_S`, shape (N, 2) [V]."""
    rng = np.random.default_rng(seed)
    n, hold = round(seconds / dt), round(HOLD_S / dt)
    levels = rng.uniform(*np.array(U_RANGES).T, size=(n // hold + 1, 2))
    return np.repeat(levels, hold, axis=0)[:n]


def recover(kind: str, axis: str, truth_name: str, args) -> dict:
    """Simulate, fit and sample one case; returns its JSON record."""
    model = build_model([f"{axis}:{kind}"])
    term = model.effects[0]
    truth = dict(TRUTHS[truth_name])
    truth.update({p.name: EFFECT_VALUES[kind][p.bare] for p in term.parameters()})
    if truth_name == "table2" and axis == "pitch":
        truth["h"] = 0.001  # h = 0 exactly sits on the prior's mode; keep it generic

    def reference(p, x0, u, dt):
        return reference_solve(p, x0, u, dt, model=model)

    t0 = time.perf_counter()
    record = synthetic_experiment(truth, X0, inputs=staircase(args.seconds, 0.01, args.seed),
                                  noise_std=(args.noise, args.noise), seed=args.seed,
                                  simulator=reference)  # fmt: skip
    problem = make_problem(record, model=model, error="iid")
    start = prepare_start(problem, seed=args.seed)
    with tempfile.TemporaryDirectory() as tmp:
        run = run_nuts(problem, tmp, chains=args.chains, warmup=args.warmup, draws=args.draws,
                       seed=args.seed, progress=False, start=start)  # fmt: skip
    s = run.samples
    theta_ref = problem.coords.yaw_theta_ref
    inertia = {"yaw": lambda p: yaw_inertia(p, theta_ref), "pitch": pitch_inertia}[axis]
    results = {}
    for par in term.parameters():
        cases = [(par.name, s[par.name], truth[par.name])]
        if par.scales_with_inertia:
            cases.append((f"{par.name}/M", s[par.name] / inertia(s), truth[par.name] / inertia(truth)))
        for label, draws, value in cases:
            lo, hi = np.quantile(np.ravel(draws), INTERVAL)
            results[label] = {"truth": float(value), "mean": float(np.mean(draws)),
                              "ci95": [float(lo), float(hi)], "covered": bool(lo <= value <= hi),
                              "rhat": float(az.rhat(np.asarray(draws))) if args.chains > 1 else None,
                              "ess_bulk": float(az.ess(np.asarray(draws)))}  # fmt: skip
    return {"effect": kind, "axis": axis, "truth": truth_name, "seconds": args.seconds,
            "noise": args.noise, "substeps": run.problem.substeps, "results": results,
            "divergences": int(np.sum(run.stats["diverging"])),
            "leapfrog_per_draw": float(np.mean(run.stats["num_steps"])),
            "map_seconds": start.map_seconds, "wall_s": time.perf_counter() - t0}  # fmt: skip


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    # the vocabulary's effects with hidden values here (a new effect needs one in EFFECT_VALUES)
    valued = sorted(k for k in EFFECTS if k in EFFECT_VALUES)
    ap.add_argument("--effects", nargs="+", default=valued, choices=valued)
    ap.add_argument("--axis", default="yaw", choices=["yaw", "pitch"])
    ap.add_argument("--truths", nargs="+", default=["table1", "table2"], choices=sorted(TRUTHS))
    ap.add_argument("--seconds", type=float, default=30.0, help="record length [s] (default 30)")
    ap.add_argument("--noise", type=float, default=0.005, help="noise sd [rad] (default 0.005)")
    ap.add_argument("--chains", type=int, default=2)
    ap.add_argument("--warmup", type=int, default=400)
    ap.add_argument("--draws", type=int, default=400)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--out", default=str(RESULTS / "effect_recovery.jsonl"))
    args = ap.parse_args(argv)
    import numpyro

    numpyro.set_host_device_count(args.chains)
    for truth in args.truths:
        for kind in args.effects:
            row = recover(kind, args.axis, truth, args)
            row.update(provenance(__file__, argv, row["wall_s"]))
            append_jsonl(args.out, row)
            flags = ", ".join(f"{k}: {'ok' if v['covered'] else 'MISSED'} "
                              f"({v['truth']:.3g} in [{v['ci95'][0]:.3g}, {v['ci95'][1]:.3g}])"
                              for k, v in row["results"].items())  # fmt: skip
            print(f"{truth} {args.axis}:{kind} ({row['wall_s']:.0f} s, {row['divergences']} div, "
                  f"{row['leapfrog_per_draw']:.1f} steps/draw): {flags}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
