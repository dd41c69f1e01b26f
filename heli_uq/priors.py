"""Priors on the Table 2 parameters, the initial state and the error model.

One table (:func:`default_priors`) documents every default.  Users change any entry
(or fix a parameter) with :func:`update_priors`, from the CLI (``--prior``, ``--fix``)
or a JSON file (``--priors FILE``: ``{"m": {"lognormal": [0.5, 1.0]}, "h": {"fixed": 0}}``).

========================  ===========================  =====================================
quantity                  default prior                why
========================  ===========================  =====================================
r_c, m, J_bc, J_s,        log-normal, median Table 2,  a least-squares fit moves gains by up
K_*, D_* (positive)       sigma_log = 2.0              to ~15x (K_psi_theta 0.009 vs 0.15):
                                                       1.4 sigma; Table 1 lies within 1 sigma
h                         normal(0, 0.01 m)            allows 0, centimetre scale
g                         fixed 9.81 m/s^2             known
theta0, psi0              normal(first sample, 0.05)   rad; measurement noise is a few mrad
omega_theta0, omega_psi0  normal(0, 0.2)               rad/s; the rig starts nearly at rest
sigma (per output)        log-normal(0.05 rad, 1.5)    residual scale incl. model error
tau (AR(1), per output)   log-normal(0.5 s, 1.0)       correlation time of the residuals;
                                                       rho = exp(-dt / tau).  A prior on tau
                                                       (not a flat one on rho) keeps the
                                                       AR(1) from turning a misfit into a
                                                       random walk (rho -> 1, tau -> minutes)
========================  ===========================  =====================================
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Mapping

import jax.numpy as jnp
import numpy as np

from heli_uq.errors import ParameterError
from heli_uq.params import PARAM_NAMES, TABLE2

__all__ = [
    "Prior",
    "DEFAULT_LOG_SIGMA",
    "default_priors",
    "update_priors",
    "load_priors_json",
    "parse_prior_option",
    "X0_ANGLE_SD",
    "X0_RATE_SD",
    "SIGMA_PRIOR",
    "TAU_PRIOR",
]

DEFAULT_LOG_SIGMA = 2.0
X0_ANGLE_SD = 0.05  # rad
X0_RATE_SD = 0.2  # rad/s
SIGMA_PRIOR = (0.05, 1.5)  # (median [rad], sigma_log) of the per-output residual scale
TAU_PRIOR = (0.5, 1.0)  # (median [s], sigma_log) of the AR(1) correlation time per output
_KINDS = ("lognormal", "normal", "fixed")


@dataclasses.dataclass(frozen=True)
class Prior:
    """A one-dimensional prior.

    ``lognormal``: ``a`` = median (> 0), ``b`` = sigma of log; ``normal``: ``a`` = mean,
    ``b`` = standard deviation; ``fixed``: ``a`` = value (not sampled).
    """

    kind: str
    a: float
    b: float = 0.0

    def __post_init__(self):
        if self.kind not in _KINDS:
            raise ParameterError(f"prior kind must be one of {_KINDS}, found {self.kind!r}")
        if not (math.isfinite(self.a) and math.isfinite(self.b)):
            raise ParameterError(f"{self.kind} prior needs finite numbers, found {self.a}, {self.b}")
        if self.kind == "lognormal" and (self.a <= 0 or self.b <= 0):
            raise ParameterError(
                f"lognormal prior needs median > 0 and sigma > 0, found {self.a}, {self.b}"
            )
        if self.kind == "normal" and self.b <= 0:
            raise ParameterError(f"normal prior needs sd > 0, found {self.b}")

    @property
    def free(self) -> bool:
        return self.kind != "fixed"

    def to_coordinate(self, value):
        """The coordinate the prior is Gaussian in: log for log-normal, identity otherwise."""
        return jnp.log(value) if self.kind == "lognormal" else value

    @property
    def coordinate_mean(self) -> float:
        """Mean of the prior in its Gaussian coordinate (log median for log-normal)."""
        return math.log(self.a) if self.kind == "lognormal" else self.a

    def log_density_coordinate(self, w):
        """Log density of the Gaussian in :meth:`to_coordinate` coordinates."""
        mu = self.coordinate_mean
        return -0.5 * ((w - mu) / self.b) ** 2 - math.log(self.b) - 0.5 * math.log(2 * math.pi)

    def sample(self, rng: np.random.Generator, size=None):
        """Draws in physical units (numpy)."""
        if self.kind == "fixed":
            return np.full(size, self.a) if size is not None else self.a
        if self.kind == "lognormal":
            return np.exp(rng.normal(math.log(self.a), self.b, size))
        return rng.normal(self.a, self.b, size)

    def variance(self) -> float:
        """Variance in physical units (for prior-to-posterior contraction)."""
        if self.kind == "fixed":
            return 0.0
        if self.kind == "normal":
            return self.b**2
        s2 = self.b**2
        return (math.exp(s2) - 1.0) * math.exp(2 * math.log(self.a) + s2)

    def describe(self) -> str:
        if self.kind == "fixed":
            return f"fixed {self.a:g}"
        if self.kind == "lognormal":
            return f"lognormal(median {self.a:g}, sigma_log {self.b:g})"
        return f"normal({self.a:g}, {self.b:g})"


def default_priors() -> dict[str, Prior]:
    """The default prior of every Table 2 parameter (see the module table)."""
    out = {}
    for name in PARAM_NAMES:
        if name == "g":
            out[name] = Prior("fixed", TABLE2["g"])
        elif name == "h":
            out[name] = Prior("normal", 0.0, 0.01)
        else:
            out[name] = Prior("lognormal", TABLE2[name], DEFAULT_LOG_SIGMA)
    return out


def _prior_from_json(name: str, spec, where: str) -> Prior:
    if isinstance(spec, (int, float)) and not isinstance(spec, bool):
        return Prior("fixed", float(spec))
    if not isinstance(spec, Mapping) or len(spec) != 1:
        raise ParameterError(
            f"{where}: prior of {name!r} must be a number (fixed) or one of "
            f'{{"lognormal": [median, sigma_log]}}, {{"normal": [mean, sd]}}, '
            f'{{"fixed": value}}; found {spec!r}'
        )
    (kind, args), = spec.items()
    args = args if isinstance(args, list) else [args]
    try:
        return Prior(kind, *[float(a) for a in args])
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"{where}: prior of {name!r}: {exc}") from None


def update_priors(priors: Mapping[str, Prior], changes: Mapping, *, where="priors") -> dict:
    """A copy of ``priors`` with entries replaced; ``changes`` maps names to Prior or JSON specs."""
    out = dict(priors)
    for name, spec in changes.items():
        if name not in PARAM_NAMES:
            raise ParameterError(
                f"{where}: unknown parameter {name!r}; expected one of {', '.join(PARAM_NAMES)}"
            )
        out[name] = spec if isinstance(spec, Prior) else _prior_from_json(name, spec, where)
    return out


def load_priors_json(path: str | os.PathLike, priors: Mapping[str, Prior] | None = None):
    """Read ``{"name": spec, ...}`` from a JSON file and apply it to ``priors``."""
    from heli_uq.io import read_json_object

    path = os.fspath(path)
    raw = read_json_object(path, "prior")
    return update_priors(priors or default_priors(), raw, where=path)


def parse_prior_option(text: str) -> tuple[str, Prior]:
    """``"m=lognormal:0.5:1.0"``, ``"h=normal:0:0.01"`` or ``"h=0"`` (fixed) -> (name, Prior)."""
    name, sep, rest = text.partition("=")
    if not sep:
        raise ParameterError(f"expected NAME=KIND:A:B or NAME=VALUE, found {text!r}")
    parts = rest.split(":")
    try:
        if len(parts) == 1:
            return name.strip(), Prior("fixed", float(parts[0]))
        return name.strip(), Prior(parts[0].strip(), *[float(p) for p in parts[1:]])
    except (TypeError, ValueError):
        raise ParameterError(f"expected NAME=KIND:A:B or NAME=VALUE, found {text!r}") from None
