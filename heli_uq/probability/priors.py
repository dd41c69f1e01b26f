"""The prior of a posterior study: the model's parameters, the initial state, the errors.

The default prior of each model parameter is declared by the term that owns it
(:class:`heli_uq.model.Parameter`); :class:`PriorSet` adds the initial state and the
error model.  Users change any entry by name (``--prior NAME=KIND:A:B``, ``--fix
NAME=VALUE`` or ``--priors FILE.json`` with ``{"m": {"lognormal": [0.5, 1.0]}, "h": 0}``).

==========================  ===========================  ===================================
quantity                    default prior                why
==========================  ===========================  ===================================
model parameters            declared by each term        e.g. Table 2 log-normals (sigma_log
                                                         2) for the mechanics and the gains,
                                                         half-normals for friction levels
theta0, psi0                normal(first sample, 0.05)   rad; measurement noise is a few mrad
omega_theta0, omega_psi0    normal(0, 0.2); where the    rad/s; the rig starts nearly at
                            record starts still, updated rest, and a still start says
                            with its measured rate       how nearly
                            (:class:`RecordStart`), or
                            fixed at 0 if a friction
                            term holds the axis
sigma_theta, sigma_psi      log-normal(0.05 rad, 1.5)    residual scale incl. model error
tau_theta, tau_psi (AR(1))  log-normal(0.5 s, 1.0)       correlation time of the residuals;
                                                         rho = exp(-dt / tau).  A prior on
                                                         tau (not a flat one on rho) keeps
                                                         the AR(1) from turning a misfit
                                                         into a random walk (rho -> 1)
timing_theta, timing_psi    log-normal(0.2 s, 1.5)       sd of the simulation's timing error
(with a timing error)                                    (:mod:`heli_uq.probability.noise`):
                                                         from 0.01 s (a model that keeps
                                                         time) to 4 s (one that does not)
==========================  ===========================  ===================================

The record fixes only ratios of the inertia-scaled parameters, so the samplers' prior
along their common scale is not the product of these: it is as wide as the tightest
single log-normal one among them, and the others are taken at its mean
(:mod:`heli_uq.probability.common_scale`).

The initial-state priors may be ``normal`` or ``fixed`` (an explicit normal replaces the
default centred on the record); the error-model priors ``lognormal`` or ``fixed``.

**Why the initial rates' default looks at the record.**  A model with a sticking term
(Coulomb friction, a network of the states) stops a small initial rate within a few
samples, after a displacement ``omega^2 / (2 a)`` that the initial angle can absorb: on
``normal(0, 0.2)`` alone the initial yaw rate and angle then share a curved ridge, the
coordinate NUTS mixed worst on the rig record and in half of ``discover``'s quick refits.
Where a record starts still, its first second measures the rate directly
(:func:`heli_uq.data.initial_rates`: to about 0.01 rad/s on the rig's yaw), so the default
is ``normal(0, X0_RATE_SD)`` updated with that measurement, whose sd is widened by
:data:`X0_RATE_FLOOR`.  Where it moves, a polynomial's slope is no trustworthy rate (a
start that accelerates bends it) and the default stays ``normal(0, X0_RATE_SD)``.  The same
samples also enter the likelihood; for a nuisance entry of the state that double use is
accepted, as for the initial angles' prior centred on the first sample.

**Where a friction term can hold a still axis, its initial rate is fixed at 0.**  The
measured prior narrows the ridge but does not remove it: a small rate against the applied
torque slides on for a while before the friction stops it, and on a synthetic record
started at rest with a hidden yaw friction (F_c = 0.012 N m) the refit's ``omega_psi0`` and
``psi0`` still shared a bent ridge (correlation -0.98, R-hat 1.26, bulk ESS 6 in 2 x 350
draws) that fixing the rate at 0 removes (R-hat 1.01, bulk ESS 700, the same F_c interval,
141-170 s against 284 s).  A still start is an axis at rest, and an axis held by friction
stays there, so the record says nothing about the rate beyond it being 0.  The fixed rate
is the default only: a prior set by name replaces it.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Mapping

import numpy as np

from heli_uq.data.rates import initial_rates
from heli_uq.errors import ParameterError
from heli_uq.model.heli_model import HeliModel
from heli_uq.model.parameter import check_prior
from heli_uq.model.prior import Prior, parse_prior_text, prior_from_json
from heli_uq.model.tables import X0_NAMES

__all__ = ["PriorSet", "RecordStart", "fixed_values", "X0_ANGLE_SD", "X0_RATE_SD", "X0_RATE_FLOOR",
           "SIGMA_PRIOR", "TAU_PRIOR", "TIMING_PRIOR", "NOISE_KINDS", "OUTPUTS",
           "parse_prior_option", "load_priors_json"]  # fmt: skip

X0_ANGLE_SD = 0.05  # rad
X0_RATE_SD = 0.2  # rad/s, the initial rates' prior before the record's first second
#: Added in quadrature to the standard error of a record's measured initial rate [rad/s]:
#: what the first second's quadratic cannot follow (module docstring).
X0_RATE_FLOOR = 0.01
SIGMA_PRIOR = Prior("lognormal", 0.05, 1.5)  # residual scale per output [rad]
TAU_PRIOR = Prior("lognormal", 0.5, 1.0)  # AR(1) correlation time per output [s]
TIMING_PRIOR = Prior("lognormal", 0.2, 1.5)  # timing error's sd per output [s]
OUTPUTS = ("theta", "psi")
#: The error model's parameters, each per output: residual scale, AR(1) correlation time,
#: timing error (:mod:`heli_uq.probability.noise`).
NOISE_KINDS = ("sigma", "tau", "timing")
_NOISE_NAMES = tuple(f"{k}_{o}" for k in NOISE_KINDS for o in OUTPUTS)


@dataclasses.dataclass(frozen=True)
class RecordStart:
    """What a record says about its initial state, for the initial state's default prior.

    Attributes
    ----------
    angles : tuple of float
        The first measured (theta, psi) [rad].
    still : tuple of bool
        Whether each angle starts still (:func:`heli_uq.data.initial_rates`).
    rates, rate_se : tuple of float
        The rates at the first sample and their standard errors [rad/s].
    """

    angles: tuple
    still: tuple = (False, False)
    rates: tuple = (0.0, 0.0)
    rate_se: tuple = (np.inf, np.inf)

    @classmethod
    def of(cls, y, dt: float, u=None) -> RecordStart:
        """The start of the record ``y`` (N, 2) [rad] with voltages ``u`` (N, 2) [V]."""
        still, rates, se = initial_rates(y, dt, u)
        return cls(tuple(float(a) for a in np.asarray(y)[0, :2]), tuple(bool(s) for s in still),
                   tuple(float(r) for r in rates), tuple(float(e) for e in se))  # fmt: skip

    def rate_prior(self, i: int, held: bool = False) -> Prior:
        """The default prior of initial rate ``i`` (0 pitch, 1 yaw): ``normal(0,
        X0_RATE_SD)``, updated, where the angle starts still, with its measured rate, whose
        sd is ``sqrt(se^2 + X0_RATE_FLOOR^2)`` (precisions add); fixed at 0 where the angle
        starts still and the model's friction can hold it there (``held``, module docstring)."""
        if not self.still[i]:
            return Prior("normal", 0.0, X0_RATE_SD)
        if held:
            return Prior("fixed", 0.0)
        measured = self.rate_se[i] ** 2 + X0_RATE_FLOOR**2
        precision = X0_RATE_SD**-2 + 1.0 / measured
        return Prior("normal", float(self.rates[i] / measured / precision), float(precision**-0.5))


@dataclasses.dataclass(frozen=True, eq=False)
class PriorSet:
    """Priors of everything a posterior study samples.

    Attributes
    ----------
    params : dict of str to Prior
        One per model parameter (``fixed`` ones are not sampled).
    x0 : dict of str to Prior or None
        ``theta0, psi0, omega_theta0, omega_psi0``; ``None`` is the default (angles:
        normal around the first measured sample, sd :data:`X0_ANGLE_SD`; rates:
        normal(0, :data:`X0_RATE_SD`), updated where the record starts still with its
        measured initial rate, :meth:`RecordStart.rate_prior`).
    noise : dict of str to Prior
        ``sigma_theta, sigma_psi, tau_theta, tau_psi, timing_theta, timing_psi``.
    """

    params: dict
    x0: dict
    noise: dict

    @classmethod
    def default(cls, model: HeliModel) -> PriorSet:
        """Every term's declared prior, the default initial-state and error priors."""
        return cls({p.name: p.prior for p in model.parameters()}, {n: None for n in X0_NAMES},
                   {**{f"sigma_{o}": SIGMA_PRIOR for o in OUTPUTS},
                    **{f"tau_{o}": TAU_PRIOR for o in OUTPUTS},
                    **{f"timing_{o}": TIMING_PRIOR for o in OUTPUTS}})  # fmt: skip

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self.params) + X0_NAMES + _NOISE_NAMES

    def completed(self, model: HeliModel) -> PriorSet:
        """These priors with the declared default of every parameter of ``model`` they lack,
        in the model's order: the parameters a term creates when it adapts to a record (a
        GP torque's value at each voltage pair, :meth:`HeliModel.adapted`)."""
        if set(self.params) == set(model.names):
            return self
        params = {p.name: self.params.get(p.name, p.prior) for p in model.parameters()}
        return PriorSet(params, self.x0, self.noise)

    def x0_prior(self, name: str, start: RecordStart, held: tuple = (False, False)) -> Prior:
        """The prior of an initial-state entry: the one set by name, else the default of
        ``start``, the record's start (angles: normal around the first sample, sd
        :data:`X0_ANGLE_SD`; rates: :meth:`RecordStart.rate_prior`, ``held`` per axis
        whether the model's friction can hold it still, :attr:`HeliModel.held_still`)."""
        prior = self.x0[name]
        if prior is not None:
            return prior
        i = X0_NAMES.index(name)
        if i < 2:
            return Prior("normal", start.angles[i], X0_ANGLE_SD)
        return start.rate_prior(i - 2, held[i - 2])

    def updated(self, model: HeliModel, changes: Mapping, *, where: str = "priors") -> PriorSet:
        """A copy with entries replaced; ``changes`` maps names to :class:`Prior` or JSON specs.

        Raises
        ------
        ParameterError
            Unknown name, a prior whose support leaves the parameter's support, or an
            initial-state / error prior of an unsupported kind.
        """
        params, x0, noise = dict(self.params), dict(self.x0), dict(self.noise)
        for name, spec in changes.items():
            prior = spec if isinstance(spec, Prior) else prior_from_json(spec, f"{where}: {name}")
            if name in params:
                if name in model.joint_names and prior.kind not in ("normal", "fixed"):
                    raise ParameterError(f"{where}: the prior of {name!r} is its term's joint prior "
                                         f"(a normal one sets only its sampling coordinate); fix it or "
                                         f"leave it, found {prior.describe()}")  # fmt: skip
                params[name] = check_prior(model.parameter(name), prior, where)
            elif name in x0:
                if prior.kind not in ("normal", "fixed"):
                    raise ParameterError(f"{where}: prior of {name!r} must be normal or fixed, found "
                                         f"{prior.describe()}")  # fmt: skip
                x0[name] = prior
            elif name in noise:
                if prior.kind not in ("lognormal", "fixed") or (prior.kind == "fixed" and prior.a <= 0):
                    raise ParameterError(f"{where}: prior of {name!r} must be lognormal or fixed > 0, "
                                         f"found {prior.describe()}")  # fmt: skip
                noise[name] = prior
            else:
                waiting = [t.label for t in model.effects if t.awaits_record]
                later = (f" ({', '.join(waiting)} gets more parameters from the record, which "
                         "take their declared priors)") if waiting else ""  # fmt: skip
                raise ParameterError(f"{where}: unknown name {name!r}; expected one of "
                                     f"{', '.join(self.names)}{later}")  # fmt: skip
        return PriorSet(params, x0, noise)

    def draw(self, model: HeliModel, rng, shape=()) -> dict:
        """Prior draws ``{name: array shape}`` of every free parameter of ``model``: each
        from its own prior, those under a term's joint prior (:attr:`HeliModel.joint_names`)
        from that prior given the others."""
        free = [n for n in model.names if self.params[n].free]
        draws = {n: self.params[n].sample(rng, shape) for n in free}
        fixed = {n: np.full(shape, self.params[n].a) for n in model.names if not self.params[n].free}
        joint = model.draw_joint({**fixed, **draws}, rng)
        return {n: joint[n] for n in free}

    def to_json(self) -> dict:
        """``{name: spec}`` of every entry (``null`` for the data-centred x0 default)."""
        out = {n: p.to_json() for n, p in self.params.items()}
        out.update({n: (None if p is None else p.to_json()) for n, p in self.x0.items()})
        out.update({n: p.to_json() for n, p in self.noise.items()})
        return out


def parse_prior_option(text: str, *, option: str = "prior") -> tuple[str, Prior]:
    """``"m=lognormal:0.5:1.0"``, ``"F_c_yaw=halfnormal:0.01"`` or ``"h=0"`` -> (name, Prior)."""
    name, sep, rest = str(text).partition("=")
    if not sep or not name.strip():
        raise ParameterError(f"{option} {text!r}: expected NAME=KIND:A:B or NAME=VALUE")
    return name.strip(), parse_prior_text(rest, f"{option} {name.strip()}")


def fixed_values(specs: Mapping) -> dict[str, float]:
    """``{name: value}`` of the fixed entries of :meth:`PriorSet.to_json` output (e.g. the
    ``priors`` attribute of a saved posterior); sampled and ``null`` entries are left out."""
    return {name: prior.a for name, spec in specs.items() if spec is not None
            for prior in (prior_from_json(spec, f"priors: {name}"),) if prior.kind == "fixed"}  # fmt: skip


def load_priors_json(path: str | os.PathLike) -> dict:
    """``{name: spec}`` from a JSON file (applied with :meth:`PriorSet.updated`)."""
    from heli_uq.io import read_json_object

    path = os.fspath(path)
    raw = read_json_object(path, "prior")
    return {name: prior_from_json(spec, f"{path}: {name}") for name, spec in raw.items()}
