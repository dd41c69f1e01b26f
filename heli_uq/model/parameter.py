"""The declaration of one model parameter, owned by the model term that uses it.

Every term of a :class:`~heli_uq.model.HeliModel` declares its parameters with
:class:`Parameter`; the model gathers them and every later stage (priors, sampling
coordinates, fits, samplers, results, identifiability) iterates over that set.
"""

from __future__ import annotations

import dataclasses
import math

from heli_uq.errors import ParameterError
from heli_uq.model.prior import Prior

__all__ = ["Parameter", "SUPPORTS", "AXES", "check_value", "check_prior"]

#: Supports of a parameter: ``positive`` (0, inf), ``nonnegative`` [0, inf) (0 means "no
#: effect"), ``real``; or ``("bounded", low, high)``.
SUPPORTS = ("positive", "nonnegative", "real")
#: The two generalized coordinates a torque can act on.
AXES = ("pitch", "yaw")


@dataclasses.dataclass(frozen=True)
class Parameter:
    """A parameter: name, unit, default, default prior, support and scaling.

    Attributes
    ----------
    name : str
        Name in the model and in results, e.g. ``"m"`` or ``"F_c_yaw"``.
    unit : str
        SI unit, e.g. ``"N m"``.
    default : float
        Value when none is given (for an effect: the value that switches it off).
    prior : Prior
        Default prior.
    support : str or tuple
        One of :data:`SUPPORTS` or ``("bounded", low, high)``.
    scales_with_inertia : bool
        True for masses, inertias and torque-type parameters: multiplying every such
        parameter by one factor leaves the angles unchanged (the common-scale null
        direction of the equations of motion), so the model derives that direction from
        these flags.
    axis : str or None
        ``"pitch"`` or ``"yaw"``: the equation a torque-type parameter acts on (its
        sampling coordinate is a ratio to that axis' inertia); None otherwise.
    description : str
    start : float or None
        First guess of a fit; ``None`` means ``default`` if it lies inside the support,
        else the prior's typical value.
    bare : str
        The name without the axis suffix (``"F_c"``), as in the effects table.
    input : tuple or None
        ``(index, sign)`` for a motor gain: the parameter multiplies voltage ``u[index]``
        with ``sign`` (+1 or -1) in the torque of its ``axis``; None otherwise.
    constant_torque : bool
        True for a constant torque on ``axis`` (a torque offset): with the gains of that
        axis it is sampled as the net constant torque at the record's mean voltages (see
        :class:`heli_uq.probability.coordinates.Coordinates`).
    """

    name: str
    unit: str
    default: float
    prior: Prior
    support: str | tuple = "real"
    scales_with_inertia: bool = False
    axis: str | None = None
    description: str = ""
    start: float | None = None
    bare: str = ""
    input: tuple | None = None
    constant_torque: bool = False

    def __post_init__(self):
        if not self.bare:
            object.__setattr__(self, "bare", self.name)
        if isinstance(self.support, tuple):
            kind, *bounds = self.support
            if kind != "bounded" or len(bounds) != 2 or not bounds[0] < bounds[1]:
                raise ParameterError(f"{self.name}: support must be one of {SUPPORTS} or "
                                     f"('bounded', low, high), found {self.support!r}")  # fmt: skip
        elif self.support not in SUPPORTS:
            raise ParameterError(f"{self.name}: support must be one of {SUPPORTS}, found {self.support!r}")
        if self.axis not in (None,) + AXES:
            raise ParameterError(f"{self.name}: axis must be one of {AXES} or None, found {self.axis!r}")
        check_value(self, self.default, "default")
        check_prior(self, self.prior, "default prior")

    @property
    def interval(self) -> tuple[float, float]:
        """Closed hull of the support."""
        if isinstance(self.support, tuple):
            return float(self.support[1]), float(self.support[2])
        return {"positive": (0.0, math.inf), "nonnegative": (0.0, math.inf),
                "real": (-math.inf, math.inf)}[self.support]  # fmt: skip

    def inside(self, value: float) -> bool:
        """``value`` lies strictly inside the support, where a fit can start (on a bound of a
        nonnegative or bounded parameter its sampling coordinate is infinite)."""
        lo, hi = self.interval
        return lo < value < hi

    def describe_support(self) -> str:
        if isinstance(self.support, tuple):
            unit = "" if self.unit == "1" else f" {self.unit}"
            return f"in [{self.support[1]:g}, {self.support[2]:g}]{unit}"
        return {"positive": "> 0", "nonnegative": ">= 0", "real": "any real number"}[self.support]

    def start_value(self) -> float:
        """The first guess of a fit, strictly inside the support of the default prior."""
        if self.start is not None:
            return float(self.start)
        lo, hi = self.prior.support
        if self.prior.free and lo < self.default < hi:
            return float(self.default)
        return self.prior.typical_value()


def check_value(param: Parameter, value, where: str) -> float:
    """``float(value)`` if it is a finite number in the parameter's support.

    Raises
    ------
    ParameterError
        Naming ``where``, the parameter, its support and the value found.
    """
    if isinstance(value, bool) or not isinstance(value, (int, float)) and not hasattr(value, "__float__"):
        raise ParameterError(f"{where}: parameter {param.name!r} must be a number, found {value!r}")
    x = float(value)
    if not math.isfinite(x):
        raise ParameterError(f"{where}: parameter {param.name!r} must be finite, found {value!r}")
    lo, hi = param.interval
    open_low = param.support == "positive"
    if x < lo or x > hi or (open_low and x <= lo):
        unit = "" if param.unit == "1" else f" ({param.unit})"
        raise ParameterError(f"{where}: parameter {param.name!r}{unit} must be "
                             f"{param.describe_support()}, found {value!r}")  # fmt: skip
    return x


def check_prior(param: Parameter, prior: Prior, where: str) -> Prior:
    """``prior`` if its support lies inside the parameter's support.

    A prior on a parameter that may not be negative (a friction level, a dead band)
    must not put mass below 0: a normal prior there is refused, a half-normal accepted.

    Raises
    ------
    ParameterError
        Naming ``where``, the parameter, its support and the prior.
    """
    if prior.kind == "fixed":
        check_value(param, prior.a, where)
        return prior
    lo, hi = prior.support
    plo, phi = param.interval
    if lo < plo or hi > phi:
        raise ParameterError(f"{where}: prior {prior.describe()} of {param.name!r} puts mass "
                             f"outside its support ({param.describe_support()}); choose e.g. "
                             f"{_suggest(param)}")  # fmt: skip
    return prior


def _suggest(param: Parameter) -> str:
    if param.support in ("positive", "nonnegative"):
        return "halfnormal:SCALE or lognormal:MEDIAN:SIGMA_LOG"
    if isinstance(param.support, tuple):
        return f"uniform:{param.support[1]:g}:{param.support[2]:g}"
    return "normal:MEAN:SD"
