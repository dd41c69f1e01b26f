"""Memory stays bounded: emcee at its default settings (4 ensembles x 2000 steps, ~36
walkers: 144,000 kept draws) on a short window, measured in a child process."""

import json
import subprocess
import sys

import pytest

from heli_uq.simulation import synthetic_experiment

#: Peak resident memory [MB] a default emcee run on a short window may use (the issue's
#: goal for the full record is 4 GB; this run's draws are as many as on the full record).
MEMORY_CAP_MB = 2500

_CHILD = """
import resource, subprocess, sys
code = subprocess.call(sys.argv[1:])
print(code, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024)
"""


@pytest.mark.slow
def test_emcee_at_defaults_stays_under_the_memory_cap(tmp_path):
    record = synthetic_experiment(duration=1.0, seed=8, noise_std=(0.005, 0.005))
    csv = record.to_csv(tmp_path / "rec.csv")
    out = tmp_path / "post"
    cmd = [sys.executable, "-m", "heli_uq.cli", "sample", "--sampler", "emcee", "--error", "iid",
           "--data", str(csv), "--no-progress", "--out", str(out)]  # fmt: skip
    result = subprocess.run([sys.executable, "-c", _CHILD, *cmd], capture_output=True, text=True,
                            timeout=1500)  # fmt: skip
    code, peak_mb = result.stdout.strip().splitlines()[-1].split()
    assert int(code) == 0, result.stderr[-2000:]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["sampler"] == "emcee" and summary["chains"] == 4
    assert summary["draws"] >= 100_000 // 4  # all kept draws are in the posterior
    assert float(peak_mb) <= MEMORY_CAP_MB, f"peak RSS {float(peak_mb):.0f} MB"
