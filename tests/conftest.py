"""Test configuration: float64 JAX and the location of the real rig record."""

import os
import pathlib

import jax

jax.config.update("jax_enable_x64", True)

REPO = pathlib.Path(__file__).resolve().parents[1]
_SHARED_DATA = REPO.parent / "shared" / "data"
if "HELI_UQ_DATA" not in os.environ and _SHARED_DATA.is_dir():
    os.environ["HELI_UQ_DATA"] = str(_SHARED_DATA)
