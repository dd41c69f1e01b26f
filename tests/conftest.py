"""Test configuration: float64 JAX and the location of the real rig record."""

import os
import pathlib

# isort: off
import heli_uq  # noqa: F401  (first: its JAX settings act only if JAX is not imported yet)
import jax
import pytest
# isort: on

jax.config.update("jax_enable_x64", True)
# Many tests compile the same programs (one NUTS kernel per run, a resumed run, the CLI):
# a persistent XLA cache shared by the test processes compiles each once.  Entries are
# keyed by the program, JAX version and flags, so a stale entry is never used.  Every
# program is kept, however fast it compiled: most compile in well under a second, thousands
# of them, and tests, workers and the CLI's subprocesses compile many of them again.
jax.config.update("jax_compilation_cache_dir",
                  str(pathlib.Path(__file__).resolve().parents[1] / ".pytest_cache" / "jax"))
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)

# A test that meets a bug sees its traceback, not the CLI's one-line internal error
# (inherited by the CLI's subprocesses too).
os.environ.setdefault("HELI_UQ_TRACEBACK", "1")

REPO = pathlib.Path(__file__).resolve().parents[1]
_SHARED_DATA = REPO.parent / "shared" / "data"
if "HELI_UQ_DATA" not in os.environ and _SHARED_DATA.is_dir():
    os.environ["HELI_UQ_DATA"] = str(_SHARED_DATA)


#: Seconds the longest groups and tests took in CI (``--durations``, 2026-11-29, a cold
#: JAX cache on the 2 cores): they are handed out first, longest first, so that none starts
#: near the end while the other worker sits idle (longest-processing-time-first
#: scheduling); slow tests before the others, each part in this order.  Only the order
#: depends on these numbers; a stale entry costs a little balance, nothing else.
LONGEST_SECONDS = {
    "discover_30s": 170, "hybrid_posterior": 120, "trap_record": 91, "cli_1s_record": 89,
    "cli_record": 85, "test_every_effect_runs_through_every_stage": 77, "sbc_run": 56,
    "full_nuts_run": 47, "nuts_run": 44,
    "test_emcee_at_defaults_stays_under_the_memory_cap": 37,
    "test_a_dead_band_between_voltage_levels_is_reached_from_the_grid_start": 30,
    "test_training_learns_a_hidden_smooth_torque": 27, "test_hidden_effect_is_recovered": 22,
    # not marked slow: first among the others
    "test_tail_substeps_cover_the_laplace_draws_of_a_friction_posterior": 27,
    "test_commands_keep_compiled_programs_on_disk": 17,
    "test_training_rejects_steps_that_blow_up_the_model": 15,
}  # fmt: skip


def _expected_seconds(item) -> float:
    group = item.get_closest_marker("xdist_group")
    key = group.args[0] if group and group.args else item.originalname
    return LONGEST_SECONDS.get(key, 0.0)


def pytest_collection_modifyitems(config, items):
    """Slow tests first, the longest of them first (:data:`LONGEST_SECONDS`), each group of
    tests kept in its order.  ``--dist loadgroup`` hands tests to the workers in
    collection order, so a long test collected last would run while the other worker sits
    idle; started first, the many short tests fill the end."""
    for item in items:  # a long test is a slow one too (pyproject's markers): -m "not slow" drops it
        if item.get_closest_marker("long") and not item.get_closest_marker("slow"):
            item.add_marker(pytest.mark.slow)
    items.sort(key=lambda item: (item.get_closest_marker("slow") is None, -_expected_seconds(item)))


#: The fixed-step solver's angle error [rad] against the adaptive reference (issue goal).
SOLVER_TOL = 1e-4


def assert_solver_follows_the_reference(model, values: dict, seed: int, substeps: int = 2) -> None:
    """On 30 s of rig-like voltage steps (21 random levels held 1.5 s, from ``seed``) the
    fixed-step solution of ``model`` at ``values`` is within :data:`SOLVER_TOL` of diffrax's
    Kvaerno5, and the model's terms move the angles by more than 100x that from the
    paper's model at Table 1."""
    import numpy as np

    from heli_uq.model import TABLE1
    from heli_uq.simulation import reference_solve
    from heli_uq.simulation.reference import solver_error

    rng = np.random.default_rng(seed)
    u = np.repeat(rng.uniform([1.25, 0.45], [1.42, 1.6], size=(21, 2)), 150, axis=0)[:3000]
    x0 = [-0.5, 0.3, 0.0, 0.0]
    ref = reference_solve(values, x0, u, 0.01, model=model)
    plain = reference_solve(TABLE1, x0, u, 0.01)
    assert np.max(np.abs(ref[:, :2] - plain[:, :2])) > 100 * SOLVER_TOL
    assert solver_error(values, x0, u, 0.01, model=model, substeps=substeps, reference=ref) <= SOLVER_TOL


# Shared synthetic posterior problem (compiling the model is the expensive part, so the
# emcee and NUTS tests share one problem and one MAP start).
SYNTHETIC_NOISE = 0.003  # rad: the true residual sd of the shared synthetic record


@pytest.fixture(scope="session")
def synthetic_problem():
    from heli_uq.probability import make_problem
    from heli_uq.simulation import synthetic_experiment

    record = synthetic_experiment(duration=4.0, seed=1, noise_std=(SYNTHETIC_NOISE,) * 2)
    return make_problem(record, error="iid")


@pytest.fixture(scope="session")
def synthetic_start(synthetic_problem):
    from heli_uq.inference import prepare_start

    return prepare_start(synthetic_problem, n_starts=1, seed=0)
