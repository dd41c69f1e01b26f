"""What every notebook here starts with: its size and its record.

``HELI_UQ_NOTEBOOK_SIZE=small`` (the test suite) runs each notebook at a size that takes
about a minute; the default, ``full``, is the size a study would use.  The record is the
rig record (``HELI_UQ_DATA`` or a checked download), else the package's embedded
synthetic record, so every notebook runs offline.
"""

from __future__ import annotations

import os
import warnings

# numpyro's progress bars come from tqdm.auto, which warns in a kernel without ipywidgets.
warnings.filterwarnings("ignore", message="IProgress not found")

import numpyro  # noqa: E402

# One XLA host device per NUTS chain, so chains run in parallel: this must happen before
# JAX starts, which is why every notebook imports this module first (the ``heli-uq``
# commands do the same).
numpyro.set_host_device_count(4)

import heli_uq  # noqa: E402

#: "small" or "full" (the environment variable ``HELI_UQ_NOTEBOOK_SIZE``).
SIZE = os.environ.get("HELI_UQ_NOTEBOOK_SIZE", "full")
if SIZE not in ("small", "full"):
    raise SystemExit(f"HELI_UQ_NOTEBOOK_SIZE: expected small or full, found {SIZE!r}")
SMALL = SIZE == "small"


def rig_or_synthetic():
    """``(record, train, test)``: the rig record with the paper's split (0-91 s / 91-131 s),
    or the embedded synthetic record (seed 0, 60 s) split 70/30 when the rig record is
    not available."""
    try:
        record = heli_uq.load_data("experimental")
        print(f"record: the rig record ({record.n} samples)")
        return record, (0.0, 91.0), (91.0, 131.0)
    except heli_uq.HeliUQError as exc:
        print(f"rig record not available ({exc}); using the embedded synthetic record")
        record = heli_uq.synthetic_experiment(seed=0, duration=60.0)
        return record, (0.0, 42.0), (42.0, 60.0)


def shortened(record, train, test, seconds: float):
    """The first ``seconds`` of the record with the same train/test proportion (small size)."""
    cut = seconds * train[1] / test[1]
    return record.window(0.0, seconds), (0.0, cut), (cut, seconds)
