"""The real rig record: a local copy named by ``HELI_UQ_DATA``, else a checked download (pooch).

The record ``Lab-Helicopter_Experimental-data.csv`` is published by SciML/HelicopterSciML.jl
(MIT licence) and is never part of this repository.
"""

from __future__ import annotations

import os
from pathlib import Path

from heli_uq.data.csv_read import read_record
from heli_uq.data.record import Experiment
from heli_uq.errors import DataFormatError

__all__ = [
    "DATA_ENV_VAR",
    "EXPERIMENTAL_FILENAME",
    "EXPERIMENTAL_SHA256",
    "EXPERIMENTAL_URL",
    "load_experimental",
    "load_data",
]

EXPERIMENTAL_FILENAME = "Lab-Helicopter_Experimental-data.csv"
EXPERIMENTAL_URL = (
    "https://raw.githubusercontent.com/SciML/HelicopterSciML.jl/"
    "cd75a43cde8e7ec9a09bc349b058aaa98a67d2c2/data/" + EXPERIMENTAL_FILENAME
)
EXPERIMENTAL_SHA256 = "d569026eb9d26a1d668249cfdd1c2b713ff015a181845e9b983a45e505464fd8"
DATA_ENV_VAR = "HELI_UQ_DATA"


def load_experimental(*, data_dir: str | os.PathLike | None = None) -> Experiment:
    """Load the real rig record (13,100 samples at dt = 0.01 s).

    The file is looked up in, in order: *data_dir*; the directory named by the
    environment variable ``HELI_UQ_DATA``; else it is downloaded once (sha256 checked)
    into pooch's cache directory for ``heli_uq``.  Local copies are read without a
    checksum.

    Parameters
    ----------
    data_dir : str or path-like, optional
        Directory containing ``Lab-Helicopter_Experimental-data.csv``.

    Returns
    -------
    Experiment

    Raises
    ------
    DataFormatError
        If the file is missing in the given directory, cannot be downloaded, or is
        malformed.
    """
    if data_dir is None and os.environ.get(DATA_ENV_VAR):
        data_dir = os.environ[DATA_ENV_VAR]
        if not (Path(data_dir) / EXPERIMENTAL_FILENAME).is_file():
            raise DataFormatError(
                f"{DATA_ENV_VAR}={data_dir}: no file {EXPERIMENTAL_FILENAME} in that directory "
                f"(unset {DATA_ENV_VAR} to download it from {EXPERIMENTAL_URL})"
            )
    if data_dir is not None:
        return read_record(Path(data_dir) / EXPERIMENTAL_FILENAME)

    import pooch

    logger = pooch.get_logger()
    level = logger.level
    logger.setLevel("WARNING")  # no "Downloading ..." line before our own message
    try:
        path = pooch.retrieve(
            EXPERIMENTAL_URL,
            known_hash=f"sha256:{EXPERIMENTAL_SHA256}",
            fname=EXPERIMENTAL_FILENAME,
            path=pooch.os_cache("heli_uq"),
            progressbar=False,
        )
    except Exception as exc:  # network, permission or checksum failure
        # The useful sentence first; the library's reason (often a long urllib3 chain)
        # only by its kind.
        raise DataFormatError(
            f"the rig record could not be downloaded ({_short_reason(exc)}): set {DATA_ENV_VAR} "
            f"to a directory containing {EXPERIMENTAL_FILENAME} (from {EXPERIMENTAL_URL})"
        ) from exc
    finally:
        logger.setLevel(level)
    return read_record(path)


def _short_reason(exc: BaseException) -> str:
    """``"offline or host not found: ConnectionError"``-style summary of a download error."""
    text = f"{type(exc).__name__}: {exc}"
    if any(k in text for k in ("NameResolution", "Name or service", "resolve", "ConnectionError",
                               "Max retries", "Network is unreachable", "timed out")):  # fmt: skip
        return f"no network connection ({type(exc).__name__})"
    if "hash" in text.lower() or "sha256" in text.lower():
        return "the downloaded file's sha256 does not match"
    return type(exc).__name__


def load_data(spec: str) -> Experiment:
    """Load a record from ``"experimental"`` (the real record) or a CSV path.

    Parameters
    ----------
    spec : str
        The keyword ``"experimental"`` or a path to an existing CSV file.

    Returns
    -------
    Experiment

    Raises
    ------
    DataFormatError
        If *spec* is neither the keyword nor an existing file, or the file is malformed.
    """
    if str(spec).strip().lower() == "experimental":
        return load_experimental()
    if Path(spec).is_file():
        return read_record(spec)
    raise DataFormatError(
        f"unknown data source {spec!r}: expected 'experimental' or the path of an existing "
        f"CSV file"
    )
