"""The paper's tables as plain values, the state names, and parameter files.

``TABLE2`` (nominal values) and ``TABLE1`` (the paper's fit) are read off the
declarations of the mechanics and the linear torque (their ``default`` and ``start``),
so they are written down once.  All values are SI: lengths in m, masses in kg, inertias
in kg m^2, gains in N m/V, damping in N m s/rad.  The state order everywhere is
``(theta, psi, omega_theta, omega_psi)`` [rad, rad, rad/s, rad/s].
"""

from __future__ import annotations

import json
import math
import os
import pathlib

from heli_uq.errors import ParameterError
from heli_uq.model.terms.linear_torque import LINEAR_TORQUE_PARAMETERS
from heli_uq.model.terms.rigid_body import MECHANICS_PARAMETERS

__all__ = ["TABLE1", "TABLE2", "TABLE3_X0", "RIG_FIT", "RIG_FIT_X0", "STATE_NAMES", "X0_NAMES",
           "load_params_json", "parse_x0"]  # fmt: skip

_BASE = MECHANICS_PARAMETERS + LINEAR_TORQUE_PARAMETERS
#: Paper Table 2 (nominal values).
TABLE2: dict[str, float] = {p.name: float(p.default) for p in _BASE}
#: Paper Table 1 (the paper's fitted values).  The paper reports V = 1.137 with its own fitted
#: initial state; with x0 = (first measured angles, zero rates) this package gets V = 0.552.
TABLE1: dict[str, float] = {p.name: float(p.start) for p in _BASE}
STATE_NAMES: tuple[str, ...] = ("theta", "psi", "omega_theta", "omega_psi")
#: Names of the initial-state entries in results: ``theta0, psi0, omega_theta0, omega_psi0``.
X0_NAMES: tuple[str, ...] = tuple(f"{s}0" for s in STATE_NAMES)
#: Paper Table 3: theta=pi/4 rad, psi=0, omega_theta=-0.1 rad/s, omega_psi=0.1 rad/s.
#: The paper's model fitted to the rig record (MAP, iid errors, training window 0-91 s;
#: the common inertia scale at its prior): base parameters of rig-like synthetic records
#: (``rig_fit.json`` beside this module: parameters [SI] and initial state).
_RIG = json.loads((pathlib.Path(__file__).with_name("rig_fit.json")).read_text(encoding="utf-8"))
RIG_FIT: dict[str, float] = dict(_RIG["parameters"])
#: Initial state of that fit ``(theta, psi, omega_theta, omega_psi)`` [rad, rad/s].
RIG_FIT_X0: tuple[float, float, float, float] = tuple(_RIG["x0"])
TABLE3_X0: tuple[float, float, float, float] = (math.pi / 4, 0.0, -0.1, 0.1)


def load_params_json(path: str | os.PathLike, model=None, *, complete: bool = True) -> dict[str, float]:
    """Read a flat JSON object ``{"m": 0.72, "F_c_yaw": 0.004, ...}`` of parameter values.

    Missing names take the model's defaults (Table 2 for the mechanics, "no effect" for
    effects), unless ``complete`` is False.

    Parameters
    ----------
    path : path
    model : HeliModel, optional
        The model whose parameters the file sets (default: the paper's model).
    complete : bool
        True (default): every parameter of the model, for a simulation.  False: the file's
        names only (checked all the same), e.g. a MAP start, whose missing names take the
        model's start values: an effect's "no effect" default can lie on a bound of its
        support (a friction level of 0), where a fit cannot start.

    Raises
    ------
    ParameterError
        Missing file, invalid JSON, not an object, an unknown name or a value outside
        its parameter's support (the message names the file and the parameter).
    """
    from heli_uq.io import read_json_object
    from heli_uq.model.heli_model import HeliModel

    model = HeliModel() if model is None else model
    path = os.fspath(path)
    raw = read_json_object(path, "parameter")
    for name, value in raw.items():  # a file holds one number per name, not a batch
        if isinstance(value, (list, dict)):
            raise ParameterError(f"{path}: parameter {name!r}: expected a number, found {value!r}")
    full = model.complete(raw, where=path)
    return {k: float(v) for k, v in full.items() if complete or k in raw}


def parse_x0(text: str) -> tuple[float, float, float, float]:
    """Parse ``"theta,psi,omega_theta,omega_psi"`` (rad, rad, rad/s, rad/s).

    Raises
    ------
    ParameterError
        Not four comma-separated finite numbers.
    """
    parts = [p.strip() for p in str(text).split(",")]
    if len(parts) != 4:
        raise ParameterError(
            f"x0: expected 4 comma-separated numbers theta,psi,omega_theta,omega_psi, "
            f"found {len(parts)} in {text!r}"
        )
    try:
        vals = tuple(float(p) for p in parts)
    except ValueError:
        raise ParameterError(f"x0: expected numbers, found {text!r}") from None
    if not all(math.isfinite(v) for v in vals):
        raise ParameterError(f"x0: values must be finite, found {text!r}")
    return vals  # type: ignore[return-value]
