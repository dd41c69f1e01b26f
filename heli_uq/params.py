"""Physical parameters of the helicopter (paper Table 2) and the initial state (Table 3).

All values are in SI units: lengths in m, masses in kg, inertias in kg m^2, torque
gains in N m / V, damping in N m / (rad/s).  The state order used everywhere in the
package is ``(theta, psi, omega_theta, omega_psi)`` in (rad, rad, rad/s, rad/s).
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from heli_uq.errors import ParameterError

__all__ = [
    "HeliParams",
    "PARAM_NAMES",
    "PARAM_UNITS",
    "PARAM_DESCRIPTIONS",
    "POSITIVE_PARAMS",
    "TABLE1",
    "TABLE2",
    "TABLE3_X0",
    "STATE_NAMES",
    "check_params",
    "load_params_json",
    "parse_x0",
]

#: Parameter names in canonical order, with (Table 2 value, unit, description).
_SPEC: dict[str, tuple[float, str, str]] = {
    "r_c": (0.015, "m", "distance from pivot to centre of mass along the body axis"),
    "h": (0.0, "m", "elevation of the body axis above the pivot"),
    "m": (0.5, "kg", "mass of the helicopter body"),
    "J_bc": (0.015, "kg m^2", "moment of inertia of the body about its centre of mass"),
    "J_s": (0.005, "kg m^2", "moment of inertia of the yaw shaft"),
    "g": (9.81, "m/s^2", "acceleration of gravity"),
    "K_theta_theta": (0.055, "N m/V", "pitch torque per pitch-motor volt"),
    "K_theta_psi": (0.005, "N m/V", "pitch torque per yaw-motor volt (enters with minus sign)"),
    "K_psi_theta": (0.15, "N m/V", "yaw torque per pitch-motor volt"),
    "K_psi_psi": (0.20, "N m/V", "yaw torque per yaw-motor volt (enters with minus sign)"),
    "D_theta": (0.01, "N m s/rad", "viscous friction in pitch"),
    "D_psi": (0.08, "N m s/rad", "viscous friction in yaw"),
}

PARAM_NAMES: tuple[str, ...] = tuple(_SPEC)
PARAM_UNITS: dict[str, str] = {k: v[1] for k, v in _SPEC.items()}
PARAM_DESCRIPTIONS: dict[str, str] = {k: v[2] for k, v in _SPEC.items()}
#: Paper Table 2 (nominal values).
TABLE2: dict[str, float] = {k: v[0] for k, v in _SPEC.items()}
#: Paper Table 1 (the paper's fitted values).  The paper reports V = 1.137 with its own fitted
#: initial state; with x0 = (first measured angles, zero rates) this package gets V = 0.552.
TABLE1: dict[str, float] = {
    "r_c": 0.022, "h": 0.001, "m": 0.72, "J_bc": 0.01, "J_s": 0.0017, "g": 9.81,
    "K_theta_theta": 0.105, "K_theta_psi": 0.0017, "K_psi_theta": 0.03, "K_psi_psi": 0.043,
    "D_theta": 0.014, "D_psi": 0.11,
}  # fmt: skip
#: Parameters that must be strictly positive (masses, inertias, gravity).
POSITIVE_PARAMS: tuple[str, ...] = ("m", "J_bc", "J_s", "g")
STATE_NAMES: tuple[str, ...] = ("theta", "psi", "omega_theta", "omega_psi")
#: Paper Table 3: theta=pi/4 rad, psi=0, omega_theta=-0.1 rad/s, omega_psi=0.1 rad/s.
TABLE3_X0: tuple[float, float, float, float] = (math.pi / 4, 0.0, -0.1, 0.1)


class HeliParams(eqx.Module):
    """The twelve Table 2 parameters as a JAX pytree (each leaf a scalar, SI units).

    Build it with :meth:`from_mapping` (missing names take Table 2 values) or
    :meth:`nominal`.  Leaves may be batched (e.g. under :func:`jax.vmap`).
    """

    r_c: jnp.ndarray
    h: jnp.ndarray
    m: jnp.ndarray
    J_bc: jnp.ndarray
    J_s: jnp.ndarray
    g: jnp.ndarray
    K_theta_theta: jnp.ndarray
    K_theta_psi: jnp.ndarray
    K_psi_theta: jnp.ndarray
    K_psi_psi: jnp.ndarray
    D_theta: jnp.ndarray
    D_psi: jnp.ndarray

    @classmethod
    def from_mapping(cls, values: Mapping | HeliParams | None = None) -> HeliParams:
        """Build from a mapping of Table 2 names to values; missing names take Table 2 values.

        Raises
        ------
        ParameterError
            If the mapping has a name that is not a Table 2 parameter.
        """
        if isinstance(values, HeliParams):
            return values
        values = dict(values or {})
        unknown = sorted(set(values) - set(PARAM_NAMES))
        if unknown:
            raise ParameterError(
                f"unknown parameter name(s) {unknown}; expected names from {list(PARAM_NAMES)}"
            )
        merged = {k: values.get(k, TABLE2[k]) for k in PARAM_NAMES}
        return cls(**{k: jnp.asarray(v, dtype=jnp.float64) for k, v in merged.items()})

    @classmethod
    def nominal(cls) -> HeliParams:
        """Paper Table 2 values."""
        return cls.from_mapping(TABLE2)

    def to_dict(self) -> dict[str, float]:
        """Plain ``{name: float}`` (requires unbatched, concrete leaves)."""
        return {k: float(getattr(self, k)) for k in PARAM_NAMES}

    def replace(self, **changes) -> HeliParams:
        """A copy with some parameters changed, e.g. ``p.replace(h=0.001)``."""
        return HeliParams.from_mapping({**{k: getattr(self, k) for k in PARAM_NAMES}, **changes})


def check_params(values: Mapping[str, float], *, where: str = "parameters") -> dict[str, float]:
    """Validate a concrete parameter mapping and fill missing names from Table 2.

    Parameters
    ----------
    values : mapping of str to float
        Names from :data:`PARAM_NAMES`.
    where : str
        Where the values came from (file name), used in error messages.

    Returns
    -------
    dict
        All twelve parameters as floats.

    Raises
    ------
    ParameterError
        Unknown name, non-number, non-finite value, or a non-positive mass/inertia/g.
    """
    out = dict(TABLE2)
    for name, value in values.items():
        if name not in _SPEC:
            raise ParameterError(
                f"{where}: unknown parameter {name!r}; expected one of {', '.join(PARAM_NAMES)}"
            )
        if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
            raise ParameterError(f"{where}: parameter {name!r} must be a number, found {value!r}")
        if not math.isfinite(float(value)):
            raise ParameterError(f"{where}: parameter {name!r} must be finite, found {value!r}")
        if name in POSITIVE_PARAMS and float(value) <= 0.0:
            raise ParameterError(
                f"{where}: parameter {name!r} ({PARAM_UNITS[name]}) must be > 0, found {value!r}"
            )
        out[name] = float(value)
    return out


def load_params_json(path: str | os.PathLike) -> dict[str, float]:
    """Read a flat JSON object ``{"m": 0.72, ...}``; missing names take Table 2 values.

    Raises
    ------
    ParameterError
        Missing file, invalid JSON, not an object, or any :func:`check_params` failure.
    """
    from heli_uq.io import read_json_object

    path = os.fspath(path)
    raw = read_json_object(path, "parameter")
    return check_params(raw, where=path)


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
            f"--x0: expected 4 comma-separated numbers theta,psi,omega_theta,omega_psi, "
            f"found {len(parts)} in {text!r}"
        )
    try:
        vals = tuple(float(p) for p in parts)
    except ValueError:
        raise ParameterError(f"--x0: expected numbers, found {text!r}") from None
    if not all(math.isfinite(v) for v in vals):
        raise ParameterError(f"--x0: values must be finite, found {text!r}")
    return vals  # type: ignore[return-value]
