"""Runs a user can trust (issue 13): the run manifest and resume, health checks, physical
range of simulations, memory limits, interrupts, bounded outputs, messages."""

import json

import numpy as np
import pytest

from heli_uq.errors import ParameterError
from heli_uq.inference import manifest as manifest_module
from heli_uq.inference.checkpoint import Checkpoint
from heli_uq.inference.manifest import differences, run_manifest
from heli_uq.model.spec import parse_effects
from heli_uq.probability import make_problem
from heli_uq.probability.priors import PriorSet, parse_prior_option
from heli_uq.simulation import synthetic_experiment

#: The NUTS settings of the base run of the manifest tests.
SETTINGS = dict(sampler="nuts", chains=2, warmup=50, draws=40, chunk=20, seed=0, max_tree_depth=8,
                target_accept=0.95, adapt_mass_matrix=True)  # fmt: skip


@pytest.fixture(scope="module")
def record():
    return synthetic_experiment(duration=3.0, seed=7)


def _priors_with(model, text):
    name, prior = parse_prior_option(text, option="--prior")
    return PriorSet.default(model).updated(model, {name: prior}, where="--prior")


def _variants(record):
    """``{setting name: manifest}`` of runs that differ from the base in that one setting."""
    base_problem = make_problem(record, (0.0, 2.0), (2.0, 3.0), error="iid")
    out = {k: run_manifest(base_problem, dict(SETTINGS, **{k: v})) for k, v in (
        ("seed", 2), ("chains", 4), ("warmup", 60), ("draws", 50), ("chunk", 10),
        ("target_accept", 0.9), ("max_tree_depth", 10), ("adapt_mass_matrix", False),
        ("sampler", "emcee"))}  # fmt: skip
    problems = {
        "train_s": make_problem(record, (0.0, 1.5), (2.0, 3.0), error="iid"),
        "test_s": make_problem(record, (0.0, 2.0), (2.5, 3.0), error="iid"),
        "error": make_problem(record, (0.0, 2.0), (2.0, 3.0), error="ar1"),
        "model": make_problem(record, (0.0, 2.0), (2.0, 3.0), error="iid",
                              model=parse_effects("yaw:torque_offset")),
        "priors": make_problem(record, (0.0, 2.0), (2.0, 3.0), error="iid",
                               priors=_priors_with(base_problem.model, "m=lognormal:0.5:1")),
    }  # fmt: skip
    shifted = synthetic_experiment(duration=3.0, seed=8)  # other values, same times
    problems["data_sha256"] = make_problem(shifted, (0.0, 2.0), (2.0, 3.0), error="iid")
    out.update({k: run_manifest(p, SETTINGS) for k, p in problems.items()})
    return run_manifest(base_problem, SETTINGS), out


def test_manifest_names_each_differing_setting(record):
    base, variants = _variants(record)
    assert differences(base, run_manifest(make_problem(record, (0.0, 2.0), (2.0, 3.0), error="iid"),
                                          SETTINGS)) == []  # fmt: skip
    for setting, other in variants.items():
        assert setting in differences(base, other), setting
    for key in ("data_sha256", "train_s", "test_s", "model", "priors", "error", "seed", "chains",
                "warmup", "draws", "target_accept", "versions"):  # fmt: skip
        assert key in base, key
    assert base["versions"]["jax"] and base["versions"]["numpyro"] and base["versions"]["heli_uq"]


def test_resume_refuses_each_mismatch_in_one_line(record, tmp_path):
    base, variants = _variants(record)
    checkpoint = Checkpoint(tmp_path / "chunks")
    with pytest.raises(ParameterError, match="^resume: nothing to resume"):
        checkpoint.resume_info(base)
    checkpoint.start_new({"map_value": 1.0}, base)
    assert checkpoint.resume_info(base) == {"map_value": 1.0}
    for setting, other in variants.items():
        with pytest.raises(ParameterError, match=f"^resume: .*{setting}") as err:
            checkpoint.resume_info(other)
        assert "\n" not in str(err.value)
    with pytest.raises(ParameterError, match=r"seed 0 -> 2, .*chains 2 -> 4|chains 2 -> 4.*seed 0 -> 2"):
        checkpoint.resume_info(dict(base, seed=2, chains=4))


def test_resume_refuses_other_library_versions(record, tmp_path, monkeypatch):
    problem = make_problem(record, (0.0, 2.0), (2.0, 3.0), error="iid")
    checkpoint = Checkpoint(tmp_path / "chunks")
    checkpoint.start_new({}, run_manifest(problem, SETTINGS))
    saved = json.loads((tmp_path / "chunks" / manifest_module.MANIFEST_FILE).read_text())
    assert saved == run_manifest(problem, SETTINGS)  # a human-readable, complete file
    real = manifest_module.library_versions()
    monkeypatch.setattr(manifest_module, "library_versions", lambda: dict(real, numpyro="0.0.1"))
    with pytest.raises(ParameterError, match="numpyro version"):
        checkpoint.resume_info(run_manifest(problem, SETTINGS))


def test_manifest_train_window_in_seconds(record):
    problem = make_problem(record, (0.5, 2.0), (2.0, 3.0), error="iid")
    m = run_manifest(problem, SETTINGS)
    np.testing.assert_allclose(m["train_s"], [0.5, 2.0])
    np.testing.assert_allclose(m["test_s"], [2.0, 3.0])
