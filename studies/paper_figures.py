"""The paper's simulation figures (Figs. 4-6, 9-11) and its Tables 1-3, from the library.

* **Figs. 4-6** (paper Sec. 2.7-2.9): the ODE form ``(x, v)`` of the model
  (:class:`heli_uq.HeliModel` as vector field) against the momentum/DAE form ``(x, p)``
  (:func:`heli_uq.model.momentum_vector_field`, ``p = M(x) v`` solved for ``v`` at every
  evaluation), both with diffrax Dopri8 at rtol = atol = 1e-12, at the Table 2 nominal
  parameters, the Table 3 initial state (:data:`heli_uq.model.TABLE3_X0`) and the Table 3
  voltages ``u_theta = u_psi = 0 V`` (:data:`TABLE3_U`).  Fig. 4 angles, Fig. 5 angular
  velocities, Fig. 6 momenta (the ODE form's as ``M(theta) v``).  The largest absolute
  difference of the two forms is recorded: it checks that they give one solution.
* **Figs. 7-8** compare with the "RS model" of Sharma (2020), which this package does not
  implement: out of scope.
* **Figs. 9-10**: the rig record's voltages and angles (``heli_uq.load_data("experimental")``;
  if the record is unavailable, the embedded synthetic record, seed 0, 60 s, and the title
  and the JSON line say so).
* **Fig. 11**: the paper's Table 1 fit simulated on the record's inputs (RK4 on the
  sample grid, from the first measured angles at rest), with the loss V of paper Eq. 1.
  The paper's own Fig. 11 shows the *nominal* (Table 2) parameters; that figure is
  written too (``paper_fig11_table2.png``, its pitch leaves the data's range and the
  angle axis is clipped).
* **Tables 1-3** as one markdown file: Table 2 (unit, nominal value, the package's default
  prior of every base parameter), Table 1 (the paper's fit next to the posterior mean and
  95 % interval of the stored full-record NUTS run, ``--summary``), Table 3 (initial
  state and voltages).

Figures go to ``studies/figures/paper_fig*.png``, the tables to
``studies/results/paper_tables.md``, one JSON line per run to
``studies/results/paper_figures.jsonl``.  Usage::

    python studies/paper_figures.py [--t1 10] [--points 1001] [--summary PATH]
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import time

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import diffrax  # noqa: E402
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
from _study import FIGURES, RESULTS, append_jsonl, provenance  # noqa: E402

import heli_uq  # noqa: E402
from heli_uq.figure import new_figure, save_figure  # noqa: E402
from heli_uq.io import read_json_object  # noqa: E402
from heli_uq.model import TABLE1, TABLE2, TABLE3_X0, HeliModel, momentum_vector_field  # noqa: E402
from heli_uq.model.terms.rigid_body import mass_matrix, pitch_inertia  # noqa: E402
from heli_uq.output import plot_experiment, plot_simulation  # noqa: E402

#: Paper Table 3 (App. B): the motor voltages of the Sec. 2.9 simulations,
#: ``(u_theta, u_psi)`` [V], held constant.  The package keeps only the initial state.
TABLE3_U = (0.0, 0.0)
#: The ODE and DAE forms must agree to this (largest absolute difference over angles [rad],
#: rates [rad/s] and momenta [kg m^2/s]) for the run to count as a check passed.
ODE_DAE_TOLERANCE = 1e-8
#: Tolerances of the adaptive solves of Figs. 4-6.
SOLVER_TOL = 1e-12
#: The stored full-record NUTS run whose posterior Table 1 is compared with.
DEFAULT_SUMMARY = pathlib.Path(__file__).resolve().parent / "results" / "nuts_iid_full_issue9.summary.json"


def _diffrax_solve(field, z0, args, t1: float, n: int):
    """States at ``n`` equally spaced times in ``[0, t1]`` (Dopri8, tight tolerances)."""
    sol = diffrax.diffeqsolve(
        diffrax.ODETerm(field), diffrax.Dopri8(), 0.0, t1, None, z0, args,
        stepsize_controller=diffrax.PIDController(rtol=SOLVER_TOL, atol=SOLVER_TOL, dtmin=None),
        saveat=diffrax.SaveAt(ts=jnp.linspace(0.0, t1, n)), max_steps=500_000,
    )  # fmt: skip
    return np.asarray(sol.ts), sol.ys


def ode_and_dae(t1: float, n: int) -> dict:
    """Both forms at Table 2 / Table 3: times, angles, rates and momenta of each."""
    model = HeliModel()
    p = model.complete(TABLE2)
    u = jnp.asarray(TABLE3_U, dtype=jnp.float64)
    x0 = jnp.asarray(TABLE3_X0, dtype=jnp.float64)
    ts, ode = _diffrax_solve(model, x0, (p, u), t1, n)
    z0 = jnp.concatenate([x0[:2], mass_matrix(p, x0[0]) @ x0[2:]])
    _, dae = _diffrax_solve(momentum_vector_field, z0, (model, p, u), t1, n)
    p_ode = jax.vmap(lambda y: mass_matrix(p, y[0]) @ y[2:])(ode)
    v_dae = jax.vmap(lambda z: jnp.linalg.solve(mass_matrix(p, z[0]), z[2:]))(dae)
    out = {"t": ts,
           "ode": {"x": np.asarray(ode[:, :2]), "v": np.asarray(ode[:, 2:]), "p": np.asarray(p_ode)},
           "dae": {"x": np.asarray(dae[:, :2]), "v": np.asarray(v_dae),
                   "p": np.asarray(dae[:, 2:])}}  # fmt: skip
    out["max_abs_diff"] = {k: float(np.max(np.abs(out["ode"][k] - out["dae"][k]))) for k in ("x", "v", "p")}
    return out


#: (key, file, title, (pitch label, yaw label), unit, scale to the plotted unit)
_FIGS = (
    ("x", "paper_fig4_angles.png", "Fig. 4: pitch and yaw angles",
     (r"pitch angle $\theta$", r"yaw angle $\psi$"), "deg", 180.0 / np.pi, "rad"),
    ("v", "paper_fig5_rates.png", "Fig. 5: pitch and yaw angular velocities",
     (r"pitch rate $\omega_\theta$", r"yaw rate $\omega_\psi$"), "rad/s", 1.0, "rad/s"),
    ("p", "paper_fig6_momenta.png", "Fig. 6: pitch and yaw angular momenta",
     (r"pitch momentum $p_\theta$", r"yaw momentum $p_\psi$"), "kg m$^2$/s", 1.0, "kg m$^2$/s"),
)  # fmt: skip


def plot_forms(sol: dict, key, title, labels, unit, scale, diff_unit):
    """One paper figure: pitch and yaw panels, ODE form solid, DAE form dashed."""
    fig = new_figure((8.0, 6.0))
    axes = fig.subplots(2, 1, sharex=True)
    t = sol["t"]
    for j, ax in enumerate(axes):
        ode, dae = sol["ode"][key][:, j], sol["dae"][key][:, j]
        ax.plot(t, scale * ode, color="C0", lw=2.5, alpha=0.6, label="ODE form (x, v)")
        ax.plot(t, scale * dae, color="k", lw=1.2, ls="--", label="DAE form (x, p)")
        diff = float(np.max(np.abs(ode - dae)))
        ax.set_title(f"{labels[j]}   (max |ODE - DAE| = {diff:.1e} {diff_unit})", loc="left",
                     fontsize="medium")  # fmt: skip
        ax.set_ylabel(f"{labels[j].split()[-1]} [{unit}]")
        ax.grid(True, alpha=0.4)
        ax.legend(loc="best", fontsize="small")
    axes[-1].set_xlabel("time $t$ [s]")
    u = ", ".join(f"{v:g}" for v in TABLE3_U)
    fig.suptitle(f"{title}\nTable 2 parameters, Table 3 initial state, u = ({u}) V", fontsize="medium")
    fig.tight_layout()
    return fig


def load_record():
    """``(record, fallback note or "")``: the rig record, else the synthetic record."""
    try:
        return heli_uq.load_data("experimental"), ""
    except heli_uq.HeliUQError as exc:
        print(f"rig record not available ({exc}); using the synthetic record (seed 0, 60 s)")
        return heli_uq.synthetic_experiment(seed=0, duration=60.0), f"rig record unavailable ({exc})"


def simulate_on_record(params, exp):
    """States (N, 4) and momenta (N, 2) of ``params`` on the record's inputs, from the first
    measured angles at rest; and V (paper Eq. 1) [rad^2]."""
    x0 = jnp.array([exp.y[0, 0], exp.y[0, 1], 0.0, 0.0])
    ys = heli_uq.simulate(params, x0, exp.u, exp.dt)
    p = HeliModel().complete(params)
    mom = jax.vmap(lambda y: mass_matrix(p, y[0]) @ y[2:])(ys)
    return np.asarray(ys), np.asarray(mom), float(heli_uq.loss_v(ys, exp.y))


def _fmt(x) -> str:
    return "-" if x is None else f"{x:.4g}"


def tables_markdown(summary_path: pathlib.Path) -> str:
    """Tables 1-3 as markdown, generated from the package (and the stored posterior)."""
    pars = HeliModel().parameters()
    lines = ["# Paper Tables 1-3 next to the package",
             "",
             "Generated by `studies/paper_figures.py`; do not edit.  All values in SI units.",
             "",
             "## Table 2: nominal parameters and the package's default priors",
             "",
             "| parameter | unit | paper nominal (Table 2) | package default | package prior | description |",
             "| --- | --- | --- | --- | --- | --- |"]  # fmt: skip
    for par in pars:
        lines.append(f"| `{par.name}` | {par.unit} | {_fmt(TABLE2[par.name])} | {_fmt(par.default)} | "
                     f"{par.prior.describe()} | {par.description} |")  # fmt: skip
    try:
        summary = read_json_object(str(summary_path), "posterior summary")
        post, note = summary.get("parameters", {}), ""
    except heli_uq.HeliUQError as exc:
        summary, post, note = {}, {}, f"posterior summary unavailable ({exc})"
    lines += ["", "## Table 1: the paper's fit and the package's posterior on the full record", ""]
    if summary:
        v = summary.get("windows", {}).get("train", {}).get("loss_v_posterior_mean_sim")
        lines.append(f"Posterior: `{summary_path.name}` ({summary.get('sampler')}, "
                     f"{summary.get('chains')} chains x {summary.get('draws')} draws, "
                     f"error model {summary.get('error_model')}, model {summary.get('model_label')}, "
                     f"R-hat max {summary.get('rhat_max')}, divergences {summary.get('divergences')}, "
                     f"V of the posterior-mean simulation {_fmt(v)} rad^2).")  # fmt: skip
    else:
        lines.append(note)
    lines += ["",
              "| parameter | unit | paper fit (Table 1) | posterior mean | posterior sd | 95 % interval "
              "| Table 1 inside |",
              "| --- | --- | --- | --- | --- | --- | --- |"]  # fmt: skip
    for par in pars:
        q = post.get(par.name)
        if q is None:
            why = "fixed" if not par.prior.free else "not in the summary"
            lines.append(f"| `{par.name}` | {par.unit} | {_fmt(TABLE1[par.name])} | {why} | - | - | - |")
            continue
        lo, hi = q["ci95"]
        inside = "yes" if lo <= TABLE1[par.name] <= hi else "**no**"
        lines.append(f"| `{par.name}` | {par.unit} | {_fmt(TABLE1[par.name])} | {_fmt(q['mean'])} | "
                     f"{_fmt(q['sd'])} | [{_fmt(lo)}, {_fmt(hi)}] | {inside} |")  # fmt: skip
    names = {par.name for par in pars}
    ratios = {k: q for k, q in post.items() if k not in names}  # e.g. ratios to the inertia
    for key, q in ratios.items():
        lo, hi = q["ci95"]
        lines.append(f"| `{key}` | {q.get('unit', '')} | - | {_fmt(q['mean'])} | {_fmt(q['sd'])} | "
                     f"[{_fmt(lo)}, {_fmt(hi)}] | - |")  # fmt: skip
    m11 = float(pitch_inertia(TABLE1))
    lines += ["",
              "The angles depend on masses, inertias, gains and damping only through their "
              "ratios to the pitch inertia `M11 = J_bc + m (r_c^2 + h^2)`: the common scale is "
              f"not identified (the summary lists `{summary.get('unidentified_coordinates', '?')}` "
              "as unidentified), so the marginal intervals above are wide (they carry the prior's "
              "spread along the common scale) and 'Table 1 inside' compares values whose common "
              "scale is arbitrary.  "
              + ("The rows below the base parameters are the summary's other entries.  " if ratios else
                 "The summary holds no posterior of those ratios (only the marginals above); "
                 "the ratio of two posterior means is not the posterior mean of the ratio, so "
                 "none is given here.  ")
              + f"For reference, Table 1 has M11 = {m11:.4g} kg m^2."]  # fmt: skip
    lines += ["", "## Table 3: operating conditions of the Sec. 2.9 simulations", "",
              "| quantity | value | unit |", "| --- | --- | --- |"]
    units = {"theta": "rad", "psi": "rad", "omega_theta": "rad/s", "omega_psi": "rad/s"}
    for name, value in zip(heli_uq.STATE_NAMES, TABLE3_X0, strict=True):
        lines.append(f"| `{name}(0)` | {value:.6g} | {units[name]} |")
    for name, value in zip(("u_theta", "u_psi"), TABLE3_U, strict=True):
        lines.append(f"| `{name}(t)` | {value:g} | V |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--t1", type=float, default=10.0, help="end of the Figs. 4-6 solves [s]")
    parser.add_argument("--points", type=int, default=1001, help="saved times in [0, t1]")
    parser.add_argument("--summary", type=pathlib.Path, default=DEFAULT_SUMMARY,
                        help="posterior summary.json of a full-record NUTS run (Table 1)")
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    FIGURES.mkdir(parents=True, exist_ok=True)
    RESULTS.mkdir(parents=True, exist_ok=True)
    written = []

    sol = ode_and_dae(args.t1, args.points)
    diff = sol["max_abs_diff"]
    worst = max(diff.values())
    print(f"ODE vs DAE, max |difference|: angles {diff['x']:.2e} rad, rates {diff['v']:.2e} rad/s, "
          f"momenta {diff['p']:.2e} kg m^2/s")  # fmt: skip
    for key, name, title, labels, unit, scale, diff_unit in _FIGS:
        fig = plot_forms(sol, key, title, labels, unit, scale, diff_unit)
        written.append(save_figure(fig, FIGURES / name))

    exp, fallback = load_record()
    fig = plot_experiment(exp)
    if fallback:
        fig.suptitle(f"Figs. 9-10: SYNTHETIC record (seed 0), the rig record is unavailable\n"
                     f"{exp.n} samples, dt = {exp.dt:g} s", color="firebrick")  # fmt: skip
        fig.tight_layout()
    else:
        fig.suptitle(f"Figs. 9-10: the rig record, {exp.n} samples, dt = {exp.dt:g} s")
    written.append(save_figure(fig, FIGURES / "paper_fig9_10_record.png"))
    source = "SYNTHETIC record (seed 0, 60 s)" if fallback else "rig record"
    v = {}
    for table, what, params, name in (
            ("Table 1", "the paper's fit, cf. its Figs. 12-13", TABLE1, "paper_fig11_table1.png"),
            ("Table 2", "nominal, as in the paper's own Fig. 11", TABLE2,
             "paper_fig11_table2.png")):  # fmt: skip
        ys, mom, v[table] = simulate_on_record(params, exp)
        reach = np.degrees(np.max(np.abs(ys[:, 0])))
        fig = plot_simulation(exp.t, ys, mom, data=exp, note=f"|pitch| reaches {reach:.3g} deg",
                              title=f"Fig. 11: {table} parameters ({what})\non the inputs of the "
                                    f"{source}, from its first measured angles at rest\n"
                                    f"V (Eq. 1) = {v[table]:.4g} rad$^2$")  # fmt: skip
        written.append(save_figure(fig, FIGURES / name))
        print(f"V({table}) on the {source} = {v[table]:.6g} rad^2")

    tables = RESULTS / "paper_tables.md"
    tables.write_text(tables_markdown(args.summary), encoding="utf-8")
    written.append(tables)
    row = {"study": "paper_figures", "t1_s": args.t1, "points": args.points,
           "ode_dae_max_abs_diff": worst, "ode_dae_max_abs_diff_by_quantity": diff,
           "ode_dae_tolerance": ODE_DAE_TOLERANCE, "ode_dae_agree": bool(worst < ODE_DAE_TOLERANCE),
           "table3_u": list(TABLE3_U), "record": str(exp.source), "record_fallback": fallback or None,
           "loss_v_table1": v["Table 1"], "loss_v_table2": v["Table 2"],
           "posterior_summary": str(args.summary), "files": [p.name for p in written],
           **provenance(__file__, argv, time.perf_counter() - t0)}  # fmt: skip
    print(f"wrote {', '.join(p.name for p in written)}")
    print(f"wrote {append_jsonl(RESULTS / 'paper_figures.jsonl', row)}")
    if not row["ode_dae_agree"]:
        print(f"ODE and DAE forms differ by {worst:.2e} > {ODE_DAE_TOLERANCE:g}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
