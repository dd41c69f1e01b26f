"""One-dimensional priors of model parameters, and the coordinate each is sampled in.

A :class:`Prior` is a distribution in physical units (SI).  Samplers move in an
unconstrained *coordinate* ``w`` that depends on the prior's support, as numpyro does:

=============  ======================================  ==========  =====================
kind           arguments ``a``, ``b``                   support     coordinate ``w``
=============  ======================================  ==========  =====================
``lognormal``  median > 0, sigma of the log > 0         (0, inf)    ``log x``
``halfnormal`` scale > 0 (``b`` unused)                 [0, inf)    ``log x``
``normal``     mean, standard deviation > 0             R           ``x``
``uniform``    low < high                               [a, b]      ``logit((x-a)/(b-a))``
``fixed``      the value (not sampled)                  {a}         none
=============  ======================================  ==========  =====================

A half-normal prior puts its mode at 0, so it suits a dead-band width or a friction
level that may be exactly 0 ("no effect"): in its log coordinate the density falls off
like ``e^w`` towards ``w -> -inf``, a light tail that MCMC explores without trouble.

:meth:`Prior.log_density_coordinate` is the density of ``w`` (the Jacobian included);
:meth:`Prior.coordinate_moments` gives its exact mean and standard deviation.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from heli_uq.errors import ParameterError

__all__ = ["Prior", "PRIOR_KINDS", "parse_prior_text", "prior_from_json"]

PRIOR_KINDS = ("lognormal", "halfnormal", "normal", "uniform", "fixed")
_FORMS = ("lognormal:MEDIAN:SIGMA_LOG, halfnormal:SCALE, normal:MEAN:SD, uniform:LOW:HIGH "
          "or a number (fixed)")  # fmt: skip
_EULER_GAMMA = 0.5772156649015329


@dataclasses.dataclass(frozen=True)
class Prior:
    """A one-dimensional prior in physical units (see the module table).

    Raises
    ------
    ParameterError
        Unknown kind, or arguments outside their ranges (the message says which).
    """

    kind: str
    a: float
    b: float = 0.0

    def __post_init__(self):
        if self.kind not in PRIOR_KINDS:
            raise ParameterError(f"prior kind must be one of {', '.join(PRIOR_KINDS)}, "
                                 f"found {self.kind!r}")  # fmt: skip
        object.__setattr__(self, "a", float(self.a))
        object.__setattr__(self, "b", float(self.b))
        if not (math.isfinite(self.a) and math.isfinite(self.b)):
            raise ParameterError(f"{self.kind} prior needs finite numbers, found {self.a}, {self.b}")
        if self.kind == "lognormal" and (self.a <= 0 or self.b <= 0):
            raise ParameterError(f"lognormal prior needs median > 0 and sigma_log > 0, found "
                                 f"{self.a:g}, {self.b:g}")  # fmt: skip
        if self.kind == "halfnormal" and self.a <= 0:
            raise ParameterError(f"halfnormal prior needs scale > 0, found {self.a:g}")
        if self.kind == "normal" and self.b <= 0:
            raise ParameterError(f"normal prior needs sd > 0, found {self.b:g}")
        if self.kind == "uniform" and not self.a < self.b:
            raise ParameterError(f"uniform prior needs low < high, found {self.a:g}, {self.b:g}")

    # ------------------------------------------------------------------ facts
    @property
    def free(self) -> bool:
        """False for a fixed (not sampled) parameter."""
        return self.kind != "fixed"

    @property
    def support(self) -> tuple[float, float]:
        """Closed hull ``(low, high)`` of the support in physical units."""
        return {
            "lognormal": (0.0, math.inf), "halfnormal": (0.0, math.inf),
            "normal": (-math.inf, math.inf), "uniform": (self.a, self.b),
            "fixed": (self.a, self.a),
        }[self.kind]  # fmt: skip

    @property
    def transform(self) -> str | None:
        """``"log"``, ``"identity"``, ``"logit"`` or ``None`` (fixed)."""
        return {"lognormal": "log", "halfnormal": "log", "normal": "identity",
                "uniform": "logit", "fixed": None}[self.kind]  # fmt: skip

    # ------------------------------------------------------------ coordinate
    def to_coordinate(self, x):
        """Unconstrained coordinate ``w`` of a physical value ``x`` (jax or numpy)."""
        if self.transform == "log":
            return jnp.log(x)
        if self.transform == "logit":
            f = (x - self.a) / (self.b - self.a)
            return jnp.log(f) - jnp.log1p(-f)
        return x

    def from_coordinate(self, w):
        """Physical value of a coordinate ``w``."""
        if self.transform == "log":
            return jnp.exp(w)
        if self.transform == "logit":
            return self.a + (self.b - self.a) * jax.nn.sigmoid(w)
        return w

    def log_density_coordinate(self, w):
        """Log density of the coordinate ``w`` (the prior of ``x`` times ``|dx/dw|``)."""
        if self.kind == "lognormal":
            return _normal_logpdf(w, math.log(self.a), self.b)
        if self.kind == "halfnormal":
            x = jnp.exp(w)
            return math.log(2.0) + _normal_logpdf(x, 0.0, self.a) + w
        if self.kind == "normal":
            return _normal_logpdf(w, self.a, self.b)
        if self.kind == "uniform":
            return -jax.nn.softplus(-w) - jax.nn.softplus(w)
        raise ParameterError("a fixed prior has no density")

    def coordinate_moments(self) -> tuple[float, float]:
        """Exact ``(mean, sd)`` of the prior in its coordinate ``w``."""
        if self.kind == "lognormal":
            return math.log(self.a), self.b
        if self.kind == "halfnormal":  # w = log|z| + log s with z ~ N(0, 1)
            return math.log(self.a) - 0.5 * (_EULER_GAMMA + math.log(2.0)), math.pi / math.sqrt(8.0)
        if self.kind == "normal":
            return self.a, self.b
        if self.kind == "uniform":  # standard logistic
            return 0.0, math.pi / math.sqrt(3.0)
        return self.a, 0.0

    def coordinate_mode(self) -> float:
        """Mode of the density of ``w`` (a start point that is always inside the support)."""
        if self.kind == "lognormal":
            return math.log(self.a)
        if self.kind == "halfnormal":  # maximise -x^2/(2 s^2) + log x: x = s
            return math.log(self.a)
        if self.kind == "normal":
            return self.a
        return 0.0 if self.kind == "uniform" else self.a

    def typical_value(self) -> float:
        """A physical value inside the open support (the coordinate's mode)."""
        return float(self.from_coordinate(self.coordinate_mode())) if self.free else self.a

    # ------------------------------------------------------------- physical
    def sample(self, rng: np.random.Generator, size=None):
        """Draws in physical units (numpy)."""
        if self.kind == "fixed":
            return np.full(size, self.a) if size is not None else self.a
        if self.kind == "lognormal":
            return np.exp(rng.normal(math.log(self.a), self.b, size))
        if self.kind == "halfnormal":
            return np.abs(rng.normal(0.0, self.a, size))
        if self.kind == "uniform":
            return rng.uniform(self.a, self.b, size)
        return rng.normal(self.a, self.b, size)

    def variance(self) -> float:
        """Variance in physical units (for prior-to-posterior contraction)."""
        if self.kind == "fixed":
            return 0.0
        if self.kind == "normal":
            return self.b**2
        if self.kind == "halfnormal":
            return self.a**2 * (1.0 - 2.0 / math.pi)
        if self.kind == "uniform":
            return (self.b - self.a) ** 2 / 12.0
        s2 = self.b**2
        return (math.exp(s2) - 1.0) * math.exp(2 * math.log(self.a) + s2)

    def describe(self) -> str:
        """Short text, e.g. ``lognormal(median 0.5, sigma_log 2)``."""
        return {
            "fixed": f"fixed {self.a:g}",
            "lognormal": f"lognormal(median {self.a:g}, sigma_log {self.b:g})",
            "halfnormal": f"halfnormal(scale {self.a:g})",
            "normal": f"normal({self.a:g}, {self.b:g})",
            "uniform": f"uniform({self.a:g}, {self.b:g})",
        }[self.kind]

    def to_json(self):
        """JSON form read back by :func:`prior_from_json`: ``{"kind": [a, b]}`` or a number."""
        if self.kind == "fixed":
            return self.a
        if self.kind == "halfnormal":
            return {"halfnormal": [self.a]}
        return {self.kind: [self.a, self.b]}


def _normal_logpdf(x, mu, sd):
    return -0.5 * ((x - mu) / sd) ** 2 - math.log(sd) - 0.5 * math.log(2 * math.pi)


def _build(kind: str, args: list, where: str) -> Prior:
    """A Prior from a kind and its numeric arguments; errors say what the form is."""
    need = {"lognormal": 2, "halfnormal": 1, "normal": 2, "uniform": 2, "fixed": 1}
    if kind not in need:
        raise ParameterError(f"{where}: unknown prior kind {kind!r}; expected one of {_FORMS}")
    if len(args) != need[kind]:
        raise ParameterError(f"{where}: a {kind} prior takes {need[kind]} number(s), "
                             f"found {len(args)}; expected one of {_FORMS}")  # fmt: skip
    try:
        values = [float(a) for a in args]
    except (TypeError, ValueError):
        raise ParameterError(f"{where}: expected numbers, found {args!r}") from None
    try:
        return Prior(kind, *values)
    except ParameterError as exc:  # a valid form with an invalid value: say why
        raise ParameterError(f"{where}: {exc}") from None


def parse_prior_text(text: str, where: str) -> Prior:
    """``"lognormal:0.5:1"``, ``"halfnormal:0.01"``, ``"normal:0:0.01"``,
    ``"uniform:0:1"`` or ``"0.5"`` (fixed)."""
    parts = [p.strip() for p in str(text).split(":")]
    if len(parts) == 1:
        return _build("fixed", parts, where)
    return _build(parts[0].lower(), parts[1:], where)


def prior_from_json(spec, where: str) -> Prior:
    """A number (fixed), or ``{"kind": [a, b]}`` / ``{"kind": a}``."""
    if isinstance(spec, (int, float)) and not isinstance(spec, bool):
        return _build("fixed", [spec], where)
    if not isinstance(spec, dict) or len(spec) != 1:
        raise ParameterError(f"{where}: expected a number (fixed) or one of "
                             f'{{"lognormal": [median, sigma_log]}}, {{"halfnormal": [scale]}}, '
                             f'{{"normal": [mean, sd]}}, {{"uniform": [low, high]}}; '
                             f"found {spec!r}")  # fmt: skip
    ((kind, args),) = spec.items()
    return _build(str(kind), args if isinstance(args, list) else [args], where)
