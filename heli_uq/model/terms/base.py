"""Interfaces of model terms: parameter declarations, generalized forces and input maps.

A model (:class:`~heli_uq.model.HeliModel`) is mechanics plus two stages of terms:

1. **input maps** ``u -> u'`` act on the motor voltages before any gain (a dead band);
   they are applied in order;
2. **torques** ``F(x, v, u') -> (T_theta, T_psi)`` [N m] are summed into the generalized
   force of the Euler-Lagrange equations (the linear gains and damping, friction,
   springs, neural terms, ...).  A torque is returned as a pair of scalars
   ``(T_theta, T_psi)`` rather than a (2,) array: XLA then fuses every term into the
   mechanics' kernel, where stacking small arrays split each Runge-Kutta stage into
   several kernels (3-10x slower per step on the CPU).

Every term declares its parameters (:meth:`AbstractTerm.parameters`) and reads their
values by name from the dict ``p`` it is called with, so adding an effect is one new
file with one class and one line that registers it (:mod:`heli_uq.model.terms`; the
contract: :class:`AbstractEffect`).  All terms are equinox modules with static configuration, so a
model is a pytree that ``jax.jit`` treats as a constant.
"""

from __future__ import annotations

import abc
import dataclasses
from typing import ClassVar

import equinox as eqx
import numpy as np

from heli_uq.errors import ParameterError
from heli_uq.model.parameter import AXES, Parameter

__all__ = ["AbstractTerm", "AbstractTorque", "AbstractInputMap", "AbstractEffect", "on_axis",
           "axis_index", "float_tuple", "gain_projection", "weighted_projection"]  # fmt: skip


def axis_index(axis: str) -> int:
    """0 for ``"pitch"``, 1 for ``"yaw"``."""
    if axis not in AXES:
        raise ParameterError(f"axis must be one of {', '.join(AXES)}, found {axis!r}")
    return AXES.index(axis)


def float_tuple(value):
    """Nested tuples of floats (hashable static fields; JSON lists read back)."""
    if isinstance(value, (list, tuple, np.ndarray)):
        return tuple(float_tuple(v) for v in value)
    return float(value)


def weighted_projection(basis, weights) -> np.ndarray:
    """Rows ``P`` (m, k) with ``beta = P @ f`` the weighted least-squares fit of values ``f``
    (k,) on the columns of ``basis`` (k, m), with weights ``weights`` (k,).  A column of
    zeros gets a row of zeros.  Subtracting ``basis @ beta`` makes a data-driven torque
    orthogonal to the span the physics owns."""
    basis, weights = np.asarray(basis, dtype=float), np.asarray(weights, dtype=float)
    root_w = np.sqrt(weights / weights.sum())
    return np.linalg.pinv(root_w[:, None] * basis, rcond=1e-10) * root_w[None, :]


def residual_projector(basis, weights) -> np.ndarray:
    """``I - basis @ P`` (k, k) with ``P`` from :func:`weighted_projection`: applied to values
    (k,), what the weighted least-squares fit on ``basis`` (k, m) leaves (m = 0: identity)."""
    basis = np.asarray(basis, dtype=float)
    return np.eye(len(basis)) - basis @ weighted_projection(basis, weights)


def gain_projection(pairs, weights, intercept: bool) -> np.ndarray:
    """Rows ``P`` (3, k) of :func:`weighted_projection` for values at voltage pairs
    ``pairs`` (k, 2) [V] on ``(1,) u_theta, u_psi`` (weights: samples held at each pair;
    ``beta_0 = 0`` without ``intercept``): what the linear gains (and an offset) own."""
    pairs = np.asarray(pairs, dtype=float)
    return weighted_projection(np.column_stack([np.ones(len(pairs)) * intercept, pairs]), weights)


def on_axis(axis: str, torque):
    """The generalized force ``(T_theta, T_psi)`` [N m] of a scalar torque on one axis.

    The other component is the Python float ``0.0``, which :meth:`HeliModel.force` skips:
    no operation is traced for it.
    """
    return (torque, 0.0) if axis == "pitch" else (0.0, torque)


class AbstractTerm(eqx.Module):
    """A model component that declares parameters."""

    #: Name of the term kind, e.g. ``"coulomb_friction"`` (set by each final class).
    kind: eqx.AbstractClassVar[str]
    #: Keys of :meth:`describe` that :meth:`adapt_to` sets from a record (none by default).
    record_keys: ClassVar[tuple[str, ...]] = ()

    @abc.abstractmethod
    def parameters(self) -> tuple[Parameter, ...]:
        """The term's parameters, with names as they appear in results."""

    @property
    def label(self) -> str:
        """Human-readable name, e.g. ``"coulomb_friction(yaw)"``."""
        return self.kind

    def describe(self) -> dict:
        """JSON description, read back by :func:`heli_uq.model.model_from_description`."""
        return {"term": self.kind}

    def reads(self) -> tuple[str, ...]:
        """Names of other terms' parameters this term reads from ``p`` (none by default);
        :class:`~heli_uq.model.HeliModel` refuses a model where no term declares one."""
        return ()

    def derived(self, p) -> dict:
        """Values computed from the parameters once per solve, added to ``p`` under names
        of this term (none by default)."""
        return {}

    @property
    def awaits_record(self) -> bool:
        """True if this term takes values from a record (:attr:`record_keys`) and has not
        been set up from one yet (:meth:`adapt_to`); False by default."""
        return False

    def adapt_to(self, u, y, dt, span_u=None) -> AbstractTerm:
        """This term set up for a training window (``u`` (N, 2) [V], ``y`` (N, 2) [rad],
        ``dt`` [s]) and the voltages ``span_u`` (M, 2) [V] of the whole simulated span
        (default ``u``); most terms need nothing from the record and return themselves."""
        return self

    def start_grid(self, u) -> dict:
        """Values of this term's parameters that separate the basins of a fit to a record
        with voltages ``u`` (N, 2) [V]: ``{name: array of values}``, none by default.

        A term whose fit has a local optimum per interval of a parameter (a dead band's
        width between two voltage levels the record holds) declares one value in each, and
        the MAP search screens them (:func:`heli_uq.inference.multistart.map_starts`).
        """
        return {}

    def joint_names(self) -> tuple[str, ...]:
        """Parameters whose prior is this term's joint prior (:meth:`joint_log_prior`), not
        their declared one-dimensional prior (none by default).  Their declared prior is
        normal: it sets their sampling coordinate and a least-squares start's scale."""
        return ()

    def joint_log_prior(self, p):
        """Log density [in physical units] of the :meth:`joint_names` given the other
        parameters in ``p`` (0 by default)."""
        return 0.0

    def check_priors(self, priors) -> None:
        """Raise a :class:`~heli_uq.errors.ParameterError` if the priors ``{name: Prior}``
        of the adapted model leave this term without a proper density (nothing by default)."""

    def draw_joint(self, values: dict, rng) -> dict:
        """Draws of the :meth:`joint_names` from their joint prior given draws of the other
        parameters in ``values`` (arrays of one shape S): ``{name: array S}``."""
        return {}

    def stiffness(self, p, inertia) -> float:
        """Largest rate [1/s] this term adds to the linearised dynamics (0 if negligible).

        ``p``: parameter values; ``inertia``: ``(M11, M22_min)`` [kg m^2]; either may hold
        arrays of one shape (posterior draws), and the rate then has that shape (numpy
        operations, not ``math``).  Used to choose the number of solver substeps
        (:func:`heli_uq.simulation.default_substeps`) and to check a run's draws
        (:func:`heli_uq.simulation.stiffness_check`).
        """
        return 0.0

    def decay_rate(self, p, inertia) -> float:
        """Rate [1/s] of a linear decaying mode this term adds at rest, which one point's
        solve must resolve and a posterior's spread need not: the largest of
        :meth:`decay_rates` (0 without any).  Past RK4's limit a linear mode blows up, so a
        draw there fails visibly, where a friction draw (:meth:`stiffness`) would drift
        silently; inside it the posterior's solver check compares the most damped draw with
        the adaptive reference.  Arguments as for :meth:`stiffness`."""
        rates = [np.asarray(r, dtype=float) for r in self.decay_rates(p, inertia).values()]
        return np.maximum.reduce(rates) if rates else 0.0

    def decay_rates(self, p, inertia) -> dict:
        """``{axis: rate [1/s]}`` of the linear decaying modes this term adds at rest, per
        axis it damps (none by default).  Arguments as for :meth:`stiffness`."""
        return {}


class AbstractTorque(AbstractTerm):
    """A generalized-force term ``(p, x, v, u) -> (T_theta, T_psi)`` [N m], a pair of scalars
    (use :func:`on_axis` for a torque on one axis).

    ``p``: dict of parameter values by name; ``x = (theta, psi)`` [rad];
    ``v = (omega_theta, omega_psi)`` [rad/s]; ``u = (u_theta, u_psi)`` [V] after the
    input maps.  Must be differentiable in ``p``, ``x``, ``v`` and jit-able.

    A torque that reads neither ``x`` nor ``v`` sets :attr:`input_only`: the voltages
    are held on each sample interval, so the simulator evaluates it once per sample
    instead of at every Runge-Kutta stage (:meth:`HeliModel.held_torque`).
    """

    @property
    def input_only(self) -> bool:
        """True if the torque depends on the parameters and the voltages only (default
        False; a term overrides it with a class variable, or a property when it depends
        on the term's configuration)."""
        return False

    #: True for a friction law that holds its axis (:attr:`axis`) still against a torque
    #: below its level: on a record that starts still such an axis starts at rest, and its
    #: initial rate is fixed at 0 (:meth:`heli_uq.probability.RecordStart.rate_prior`).
    holds_still: ClassVar[bool] = False

    @abc.abstractmethod
    def __call__(self, p, x, v, u):
        raise NotImplementedError


class AbstractInputMap(AbstractTerm):
    """A map of the voltages ``(p, u) -> u'`` [V] applied before every torque term; ``u``
    and ``u'`` are pairs ``(u_theta, u_psi)`` of scalars.

    A map with memory (a motor's lag) sets :attr:`filters_sequence` and acts on the whole
    held-voltage sequence in :meth:`filter_sequence`, before the solve and before every
    map of single samples (its ``__call__`` is then the identity).
    """

    #: True for a map that acts on the voltage sequence (:meth:`filter_sequence`).
    filters_sequence: ClassVar[bool] = False

    def filter_sequence(self, p, u, h):
        """The voltages ``u`` (N, 2) [V] held on solver steps of ``h`` [s], mapped as a
        sequence (N, 2) [V]; the identity unless :attr:`filters_sequence`."""
        return u

    @abc.abstractmethod
    def __call__(self, p, u):
        raise NotImplementedError


class AbstractEffect(AbstractTerm):
    """A named physical effect from the effects vocabulary, acting on one axis.

    The parameters are named ``<bare>_<axis>`` (e.g. ``F_c_yaw``).  Subclasses define
    :attr:`kind`, :meth:`_declare` (parameters with bare names) and the physics.

    The contract of a new effect (README, "Adding a term"; ``tests/test_terms_contract.py``
    checks it for every registered term):

    - every field has a default, so ``cls()`` builds it (the CLI lists each term's
      parameters from ``cls()``; a model file gives only the options it changes);
    - the first declared parameter is the effect's magnitude, and its default is "no
      effect" (the torque is 0, the voltage map the identity): discovery's network
      naming differentiates the torque by it, and ``simulate`` leaves a term it is not
      given values for switched off;
    - an effect of the vocabulary (``EFFECTS``) builds on both axes, since discovery
      tries every candidate on each;
    - :attr:`summary` is its line in ``heli-uq --help``'s effects list (the parameters
      with their units are added to it).
    """

    axis: eqx.AbstractVar[str]
    #: One line for the CLI's list of terms: the equation and what the term stands for.
    summary: ClassVar[str] = ""

    def __check_init__(self):
        axis_index(self.axis)

    @abc.abstractmethod
    def _declare(self) -> tuple[Parameter, ...]:
        """Parameters with bare names (``F_c``); :meth:`parameters` adds the axis."""

    def parameters(self) -> tuple[Parameter, ...]:
        return tuple(dataclasses.replace(
            par, name=f"{par.name}_{self.axis}", axis=self.axis if par.scales_with_inertia else None,
            description=f"{par.description} ({self.axis})", bare=par.name,
        ) for par in self._declare())  # fmt: skip

    def name(self, bare: str) -> str:
        """The full name of one of this effect's parameters."""
        return f"{bare}_{self.axis}"

    def acts_on(self) -> tuple[str, ...]:
        """The axes whose generalized force this effect changes directly: its own axis for a
        torque on one axis; both for a map of a motor's voltage, since a motor drives both
        axes through the gains ``K`` (a term whose torque has both components overrides
        this).  Discovery fits no candidate whose axes the base model already fits to white
        noise (:mod:`heli_uq.discovery.screen`)."""
        return AXES if isinstance(self, AbstractInputMap) else (self.axis,)

    @property
    def label(self) -> str:
        return f"{self.kind}({self.axis})"

    def describe(self) -> dict:
        return {"effect": self.kind, "axis": self.axis}
