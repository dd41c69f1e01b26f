"""Rig records: the :class:`Experiment` type, the published CSV format and the real record.

Layer 1 of the package (imports only :mod:`heli_uq.errors` and :mod:`heli_uq.io`).
Synthetic records need the simulator and live in :mod:`heli_uq.simulation`.
"""

from heli_uq.data.csv_read import read_record as read_record
from heli_uq.data.experimental import (
    DATA_ENV_VAR as DATA_ENV_VAR,
)
from heli_uq.data.experimental import (
    EXPERIMENTAL_FILENAME as EXPERIMENTAL_FILENAME,
)
from heli_uq.data.experimental import (
    EXPERIMENTAL_SHA256 as EXPERIMENTAL_SHA256,
)
from heli_uq.data.experimental import (
    EXPERIMENTAL_URL as EXPERIMENTAL_URL,
)
from heli_uq.data.experimental import load_data as load_data
from heli_uq.data.experimental import load_experimental as load_experimental
from heli_uq.data.inputs import unseen_inputs as unseen_inputs
from heli_uq.data.rates import evenly_spaced as evenly_spaced
from heli_uq.data.rates import initial_rates as initial_rates
from heli_uq.data.rates import measured_rates as measured_rates
from heli_uq.data.record import COLUMNS as COLUMNS
from heli_uq.data.record import HEADER as HEADER
from heli_uq.data.record import Experiment as Experiment
from heli_uq.data.record import parse_window as parse_window

__all__ = [
    "DATA_ENV_VAR", "EXPERIMENTAL_FILENAME", "EXPERIMENTAL_SHA256", "EXPERIMENTAL_URL",
    "load_data", "load_experimental", "COLUMNS", "HEADER", "Experiment", "parse_window",
    "read_record", "unseen_inputs", "measured_rates", "evenly_spaced", "initial_rates",
]  # fmt: skip
