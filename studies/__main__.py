"""Run the studies at one size: ``python -m studies run --size quick|paper [--only NAME ...]``.

Every study of :data:`STUDIES` is one or more commands (a study script, or ``heli-uq``);
each runs in its own process (a fresh JAX per study), one after another, and a failed
study is reported without stopping the rest.  ``quick`` runs each at a smoke size (a few
minutes in all, into ``studies/quick/``, which git ignores) to check that it still works;
``paper`` runs the sizes whose results are stored in ``studies/results/`` and
``studies/figures/`` (hours on 2 cores; the full outputs of ``heli-uq sample`` and
``discover``, posteriors of tens of MB, go to ``studies/runs/``, which git ignores: their
summaries are what ``studies/results/`` keeps).  Every run appends one line per study (command,
exit status, wall time, versions) to ``<root>/results/studies_<size>.jsonl``.

``python -m studies list`` prints the table of studies with what each shows.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import pathlib
import subprocess
import sys
import time

HERE = pathlib.Path(__file__).resolve().parent
REPO = HERE.parent
#: Output root of each size (the study scripts read it from ``HELI_UQ_STUDY_ROOT``).
ROOTS = {"quick": HERE / "quick", "paper": HERE}
PY = sys.executable
CLI = [PY, "-m", "heli_uq.cli"]


@dataclasses.dataclass(frozen=True)
class Study:
    """A study: ``shows`` what it establishes (paper figure, table or challenge in brackets);
    ``quick`` and ``paper`` are lists of commands, ``{root}`` in an argument is the output
    root of the size; ``needs_record``: it reads the rig record."""

    name: str
    shows: str
    quick: tuple
    paper: tuple
    needs_record: bool = True  # reads the rig record (HELI_UQ_DATA or the download)


def _script(name, *args):
    return (PY, str(HERE / f"{name}.py"), *args)


STUDIES = (
    Study("paper_figures", "ODE vs DAE forms at Table 3, the record and Table 1 on it, Tables 1-3 (Figs. 4-6, 9-11)",
          (_script("paper_figures"),), (_script("paper_figures"),), needs_record=False),
    Study("bench_simulate", "forward solve and gradient cost vs scipy LSODA, accuracy vs DOP853 (speed)",
          (_script("bench_simulate", "--repeats", "5"),), (_script("bench_simulate", "--repeats", "50"),)),
    Study("substep_convergence", "RK4 substeps per named effect vs the stiff reference (Sec. 5 challenge 4)",
          (_script("substep_convergence", "--seconds", "10", "--repeats", "2"),),
          (_script("substep_convergence"),)),
    Study("identifiability", "structural rank, Fisher information, profiles, contraction (Table 2; challenges 2a-2b)",
          ((*CLI, "identifiability", "--data", "experimental", "--window", "0:20", "--points", "2",
            "--out", "{root}/results/identifiability_quick"),),
          ((*CLI, "identifiability", "--data", "experimental", "--out", "{root}/results/identifiability_full"),)),
    Study("posterior_split", "NUTS posterior, bands and coverage on train 0-91 s / test 91-131 s (Figs. 4-9; challenge 2c)",
          ((*CLI, "sample", "--data", "experimental", "--train", "0:14", "--test", "14:20", "--error", "iid",
            "--chains", "2", "--warmup", "100", "--draws", "100", "--quiet", "--out", "{root}/results/posterior_quick"),),
          ((*CLI, "sample", "--data", "experimental", "--train", "0:91", "--test", "91:131", "--error", "iid",
            "--chains", "4", "--warmup", "1000", "--draws", "1000", "--quiet", "--out", "{root}/runs/posterior_split"),)),
    Study("effects_on_rig", "every named effect on the rig record, MAP V and intervals (challenge 3a)",
          (_script("effects_on_rig", "--window", "0:20", "--axes", "yaw", "--effects", "torque_offset",
                   "--starts", "1", "--out", "{root}/results/effects_on_rig.jsonl"),),
          (_script("effects_on_rig", "--starts", "2", "--out", "{root}/results/effects_on_rig.jsonl"),)),
    Study("effect_recovery", "hidden effects recovered by NUTS, truth inside the 95 % interval (challenge 3a)",
          (_script("effect_recovery", "--effects", "torque_offset", "--truths", "table1", "--seconds", "10",
                   "--warmup", "100", "--draws", "100", "--out", "{root}/results/effect_recovery.jsonl"),),
          (_script("effect_recovery", "--out", "{root}/results/effect_recovery.jsonl"),), needs_record=False),
    Study("discovery_confusion", "discover on records with one hidden effect or none: the confusion table (challenge 3b)",
          (_script("discovery_confusion", "--cases", "none", "--seconds", "30", "--scheduler", "serial",
                   "--candidates", "yaw:torque_offset", "--out", "{root}/results/discovery_confusion.jsonl"),),
          (_script("discovery_confusion"),), needs_record=False),
    Study("discover_rig", "what discover names on the rig record, before/after gap (Sec. 4.3; challenge 3b)",
          ((*CLI, "discover", "experimental", "--train", "0:21", "--test", "21:30", "--scheduler", "serial",
            "--candidates", "yaw:torque_offset", "--quiet", "--out", "{root}/results/discover_rig_quick"),),
          ((*CLI, "discover", "experimental", "--train", "0:91", "--test", "91:131", "--max-effects", "2",
            "--quiet", "--out", "{root}/runs/discover_rig"),)),
    Study("hybrid_rig", "FNN(u), FNN(u,x,v) trained as in the paper vs its V (Sec. 4; Figs. 14-17; challenge 2d)",
          (_script("hybrid_rig", "--networks", "u", "--hidden", "4", "--train", "0:14", "--test", "14:20"),),
          (_script("hybrid_rig"),)),
    Study("sbc_scaling", "SBC wall time with 1 and 2 Dask workers, fresh compilation caches (scale-out)",
          (_script("sbc_scaling", "--replicates", "1", "--duration", "1.5", "--draws", "20",
                   "--out", "{root}/results/sbc_scaling.jsonl"),),
          (_script("sbc_scaling", "--out", "{root}/results/sbc_scaling.jsonl"),), needs_record=False),
    Study("hybrid_posterior", "Bayesian hybrids (FNN(u), FNN(u,x,v), recovered equation) vs mechanistic on train/test (Sec. 4; challenge 2d)",
          (_script("hybrid_posterior", "--train", "0:14", "--test", "14:20", "--rows", "mechanistic", "u", "equation",
                   "--hidden", "2", "--chains", "2", "--warmup", "50", "--draws", "50",
                   "--runs", "{root}/runs/hybrid_posterior", "--figures", "{root}/figures",
                   "--out", "{root}/results/hybrid_posterior.jsonl"),),
          (_script("hybrid_posterior", "--nn-posterior", "last-layer", "--chains", "2", "--warmup", "250",
                   "--draws", "250", "--rows", "mechanistic", "effect", "u", "equation"),
           _script("hybrid_posterior", "--nn-posterior", "last-layer", "--chains", "2", "--warmup", "250",
                   "--draws", "250", "--rows", "u", "--project", "none"))),
    Study("stiction_rig", "yaw friction + offset with and without stiction on the rig split (MAP, held-out window)",
          (_script("stiction_rig", "--train", "0:6", "--test", "6:9", "--out", "{root}/results/stiction_rig.jsonl",
                   "--figure", "{root}/figures/stiction_rig.png"),),
          (_script("stiction_rig"),)),
    Study("thrust_tilt_rig", "does the rig's yaw torque fall off with pitch as cos θ (the geometry)? A profile of the tilt "
          "on the rig split (MAP, held-out window)",
          (_script("thrust_tilt_rig", "--train", "0:6", "--test", "6:9", "--grid", "0,1",
                   "--out", "{root}/results/thrust_tilt_rig.jsonl", "--figure", "{root}/figures/thrust_tilt_rig.png"),),
          (_script("thrust_tilt_rig"),)),
    Study("bench_hybrid", "log-density gradient of FNN(u)/FNN(u,x,v) hybrids vs the mechanistic model (speed, challenge 2d)",
          (_script("bench_hybrid", "--window", "0:10", "--repeats", "3", "--out", "{root}/results/bench_hybrid.jsonl"),),
          (_script("bench_hybrid"),)),
    Study("bench_nuts_trace", "tracing and compiling the NUTS kernel with the potential plain vs jitted (speed)",
          (_script("bench_nuts_trace", "--seconds", "0.5", "--repeats", "1",
                   "--out", "{root}/results/bench_nuts_trace.jsonl"),),
          (_script("bench_nuts_trace"),), needs_record=False),
    Study("hybrid_unseen_pairs", "does the hybrid's network band widen at voltage pairs the training window never holds?",
          (_script("hybrid_unseen_pairs", "--seconds", "6", "--hidden", "2", "--chains", "1", "--warmup", "10",
                   "--draws", "10", "--runs", "{root}/runs/hybrid_unseen_pairs", "--figures", "{root}/figures",
                   "--out", "{root}/results/hybrid_unseen_pairs.jsonl"),),
          (_script("hybrid_unseen_pairs"),), needs_record=False),
    Study("hybrid_state_network", "does projecting the linear physics out of FNN(u, x, v) help its posterior, "
          "and which effect of the table did it learn?",
          (_script("hybrid_state_network", "--seconds", "6", "--chains", "1", "--warmup", "10", "--draws", "10",
                   "--check-named",
                   "--runs", "{root}/runs/hybrid_state_network",
                   "--out", "{root}/results/hybrid_state_network.jsonl"),),
          (_script("hybrid_state_network"),), needs_record=False),
    Study("emcee_dimension", "emcee's autocorrelation time against the dimension (mechanistic, FNN(u) h=2, h=4): its limit",
          (_script("emcee_dimension", "--seconds", "3", "--steps", "40", "--out", "{root}/results/emcee_dimension.jsonl"),),
          (_script("emcee_dimension"),), needs_record=False),
    Study("bench_memory", "peak memory and wall time of default NUTS and emcee runs (speed)",
          (_script("bench_memory", "--window", "0:10", "--sampler", "nuts", "--chains", "1", "--warmup", "50",
                   "--draws", "50", "--out", "{root}/results/bench_memory.jsonl"),),
          (_script("bench_memory", "--out", "{root}/results/bench_memory.jsonl"),)),
    Study("bench_stiffness", "the stiffness check over a run's draws, all at once vs one call per draw (speed)",
          (_script("bench_stiffness", "--draws", "2000", "--angles", "500", "--baseline-draws", "200",
                   "--out", "{root}/results/bench_stiffness.jsonl"),),
          (_script("bench_stiffness"),), needs_record=False),
    Study("bench_cache", "the compilation cache's minimum compile time: a second record's run at 1 s vs 0 s (speed)",
          (_script("bench_cache", "--commands", "sample", "--out", "{root}/results/bench_cache.jsonl"),),
          (_script("bench_cache"),), needs_record=False),
    Study("bench_samplers", "NUTS vs emcee, ESS per second on one log density",
          (_script("bench_samplers", "--window", "0:10", "--chains", "2", "--warmup", "100", "--draws", "100"),),
          (_script("bench_samplers"),)),
    Study("sbc", "simulation-based calibration of the NUTS posterior: ranks and coverage (challenge 2b)",
          (_script("sbc", "--replicates", "4", "--duration", "2", "--chains", "1", "--warmup", "100",
                   "--draws", "50", "--h-sd", "0", "--x0-prior", "generator", "--out", "{root}/results/sbc_quick"),
           _script("sbc", "--out", "{root}/results/sbc_quick", "--plot", "--fig", "{root}/figures/sbc_quick.png")),
          (_script("sbc", "--replicates", "100", "--h-sd", "0", "--chains", "1", "--warmup", "200", "--draws", "100",
                   "--x0-prior", "generator", "--out", "{root}/results/sbc_v2"),
           _script("sbc", "--out", "{root}/results/sbc_v2", "--plot", "--fig", "{root}/figures/sbc_ranks_v2.png")), needs_record=False),
    Study("design_gain", "designed staircase vs published profile and random staircases: posterior volume (challenge 1b)",
          (_script("design_gain", "--duration", "20", "--truths", "3", "--random", "5"),),
          (_script("design_gain", "--duration", "60", "--truths", "8", "--random", "20", "--budget", "full"),)),
    Study("notebooks", "the executed notebooks (quickstart, bands, identifiability, discovery, hybrid)",
          ((PY, str(REPO / "notebooks" / "execute.py"), "--size", "small", "--out-dir", "{root}/notebooks"),),
          ((PY, str(REPO / "notebooks" / "execute.py"), "--size", "full"),), needs_record=False),
)


def _provenance(size: str, wall_s: float) -> dict:
    """The fields of every study's result line (:func:`studies._study.provenance`, with the
    machine's reference time) and the commit."""
    from studies._study import provenance

    git = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO, capture_output=True, text=True)
    return {**provenance("__main__.py", ["run", "--size", size], wall_s),
            "commit": git.stdout.strip() or None}


def run(size: str, only=(), root: pathlib.Path | None = None) -> int:
    """Run every study (or ``only`` these) at ``size``; returns the number that failed."""
    root = (root or ROOTS[size]).resolve()
    (root / "results").mkdir(parents=True, exist_ok=True)
    env = {**os.environ, "HELI_UQ_STUDY_ROOT": str(root), "MPLBACKEND": "Agg"}
    log = root / "results" / f"studies_{size}.jsonl"
    failed = 0
    for study in STUDIES:
        if only and study.name not in only:
            continue
        t0 = time.perf_counter()
        status = 0
        for cmd in getattr(study, size):
            cmd = [str(a).replace("{root}", str(root)) for a in cmd]
            print(f"[{study.name}] {' '.join(cmd)}", flush=True)
            status = subprocess.run(cmd, cwd=REPO, env=env).returncode
            if status:
                break
        wall = time.perf_counter() - t0
        failed += status != 0
        row = {"study": study.name, "size": size, "status": status, **_provenance(size, wall)}
        with open(log, "a", encoding="utf-8") as fh:
            fh.write(json.dumps(row) + "\n")
        print(f"[{study.name}] {'ok' if status == 0 else f'FAILED (exit {status})'} in {wall:.0f} s", flush=True)
    return failed


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m studies", description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="command", required=True)
    sub.add_parser("list", help="the studies and what each shows")
    sub.add_parser("table", help="rewrite the README's results table from the stored results")
    r = sub.add_parser("run", help="run the studies at one size")
    r.add_argument("--size", choices=tuple(ROOTS), default="quick")
    r.add_argument("--only", nargs="+", default=(), metavar="NAME", help="run only these studies")
    r.add_argument("--root", default=None, help="output root (default: studies/quick or studies/)")
    args = ap.parse_args(argv)
    if args.command == "table":
        from studies.results_table import README, write_readme

        write_readme()
        print(f"wrote the results table in {README}")
        return 0
    if args.command == "list":
        for s in STUDIES:
            print(f"{s.name:22s} {s.shows}")
        return 0
    unknown = sorted(set(args.only) - {s.name for s in STUDIES})
    if unknown:
        ap.error(f"unknown study {', '.join(unknown)}; see 'python -m studies list'")
    failed = run(args.size, args.only, pathlib.Path(args.root) if args.root else None)
    print(f"{failed} stud{'y' if failed == 1 else 'ies'} failed" if failed else "all studies ran")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
