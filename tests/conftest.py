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
# keyed by the program, JAX version and flags, so a stale entry is never used.
jax.config.update("jax_compilation_cache_dir",
                  str(pathlib.Path(__file__).resolve().parents[1] / ".pytest_cache" / "jax"))
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)

REPO = pathlib.Path(__file__).resolve().parents[1]
_SHARED_DATA = REPO.parent / "shared" / "data"
if "HELI_UQ_DATA" not in os.environ and _SHARED_DATA.is_dir():
    os.environ["HELI_UQ_DATA"] = str(_SHARED_DATA)


def pytest_collection_modifyitems(config, items):
    """Slow tests first, each group of tests kept in its order.  ``--dist loadgroup`` hands
    tests to the workers in collection order, so a long test collected last would run
    while the other worker sits idle; started first, the many short tests fill the end."""
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)


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
