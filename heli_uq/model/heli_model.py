"""The helicopter model: mechanics + input maps + torque terms, and its parameter set.

:class:`HeliModel` is an equinox module whose configuration is static (which terms, on
which axes); parameter *values* are a dict ``{name: value}`` passed alongside, so one
compiled simulator serves every parameter value a sampler proposes.  The model gathers
the parameter declarations of its terms (:meth:`HeliModel.parameters`); every later
stage iterates over them.

The vector field is the pure function ``model(t, y, args)`` with
``y = (theta, psi, omega_theta, omega_psi)`` [rad, rad, rad/s, rad/s] and
``args = (p, u)``: parameter values and the held voltages (2,) [V].
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from heli_uq.errors import ParameterError
from heli_uq.model.parameter import AXES, Parameter, check_value
from heli_uq.model.terms.base import AbstractInputMap, AbstractTorque
from heli_uq.model.terms.linear_torque import LinearTorque
from heli_uq.model.terms.rigid_body import (
    AbstractMechanics,
    ClosedFormMechanics,
    dl_dx,
    mass_matrix,
)

__all__ = ["HeliModel", "momentum_vector_field"]


class HeliModel(eqx.Module):
    """Mechanics, input maps (applied to the voltages in order) and summed torque terms.

    Parameters
    ----------
    mechanics : AbstractMechanics
        Default :class:`~heli_uq.model.terms.ClosedFormMechanics`.
    inputs : tuple of AbstractInputMap
        E.g. ``(DeadBand("yaw"),)``.
    torques : tuple of AbstractTorque
        Default ``(LinearTorque(),)``, the paper's ``F = K u - D v``.

    Raises
    ------
    ParameterError
        If two terms declare the same parameter name (e.g. one effect twice on one axis).
    """

    mechanics: AbstractMechanics = ClosedFormMechanics()
    inputs: tuple[AbstractInputMap, ...] = ()
    torques: tuple[AbstractTorque, ...] = (LinearTorque(),)

    def __check_init__(self):
        seen = {}
        for term in self.terms:
            for par in term.parameters():
                if par.name in seen:
                    raise ParameterError(f"model: {term.label} and {seen[par.name]} both declare "
                                     f"parameter {par.name!r}; use each effect once per axis")
                seen[par.name] = term.label
        adapted = [t.label for t in self.terms if t.record_keys]
        if self.filters_voltages and adapted:
            raise ParameterError(f"model: {', '.join(adapted)} is set up on the recorded voltages, "
                                 "which a motor lag or dead time changes; use one or the other")  # fmt: skip
        for term in self.terms:
            missing = [name for name in term.reads() if name not in seen]
            if missing:
                raise ParameterError(f"model: {term.label} reads {', '.join(missing)}, which no term "
                                     "of the model declares (is the linear torque left out?)")

    # ----------------------------------------------------------- parameters
    @property
    def terms(self) -> tuple:
        """All terms, in order: mechanics, input maps, torques."""
        return (self.mechanics, *self.inputs, *self.torques)

    def parameters(self) -> tuple[Parameter, ...]:
        """Declarations of every parameter, gathered from the terms."""
        return tuple(par for term in self.terms for par in term.parameters())

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(par.name for par in self.parameters())

    def parameter(self, name: str) -> Parameter:
        """The declaration of ``name``.

        Raises
        ------
        ParameterError
            Unknown name (the message lists the model's names).
        """
        for par in self.parameters():
            if par.name == name:
                return par
        raise ParameterError(f"unknown parameter {name!r}; this model has {', '.join(self.names)}")

    def defaults(self) -> dict[str, float]:
        """``{name: default value}`` (Table 2 for the mechanics; "no effect" for effects)."""
        return {par.name: float(par.default) for par in self.parameters()}

    def start_values(self) -> dict[str, float]:
        """``{name: first guess of a fit}`` (Table 1 for the mechanics and gains)."""
        return {par.name: par.start_value() for par in self.parameters()}

    @property
    def joint_names(self) -> tuple[str, ...]:
        """Parameters under a term's joint prior (:meth:`AbstractTerm.joint_names`)."""
        return tuple(n for term in self.terms for n in term.joint_names())

    def joint_log_prior(self, p):
        """Sum of the terms' joint log priors at parameters ``p`` (0 without any)."""
        return sum((term.joint_log_prior(p) for term in self.terms if term.joint_names()), 0.0)

    def draw_joint(self, values: dict, rng) -> dict:
        """``values`` (draws of one shape) with the :attr:`joint_names` redrawn from the
        terms' joint priors."""
        out = dict(values)
        for term in self.terms:
            out.update(term.draw_joint(out, rng))
        return out

    def complete(self, values: Mapping | None = None, *, where: str = "parameters") -> dict:
        """All parameters as a dict: ``values`` where given, defaults elsewhere.

        Values may be jax tracers (no checks then); concrete numbers are checked against
        each parameter's support.

        Raises
        ------
        ParameterError
            Unknown names, non-numbers or values outside a support.
        """
        values = dict(values or {})
        unknown = sorted(set(values) - set(self.names))
        if unknown:
            raise ParameterError(f"{where}: unknown parameter name(s) "
                                 f"{', '.join(map(repr, unknown))}; this model has "
                                 f"{', '.join(self.names)}")  # fmt: skip
        out = {}
        for par in self.parameters():
            if par.name not in values:
                out[par.name] = jnp.asarray(par.default, dtype=jnp.float64)
                continue
            v = values[par.name]
            if not isinstance(v, jax.core.Tracer) and np.ndim(v) == 0:
                check_value(par, v, where)  # concrete scalars only; batches are not checked
            out[par.name] = jnp.asarray(v, dtype=jnp.float64)
        return out

    @property
    def scale_names(self) -> tuple[str, ...]:
        """Parameters flagged ``scales_with_inertia``: they span the common-scale direction."""
        return tuple(par.name for par in self.parameters() if par.scales_with_inertia)

    def on_the_scale_of(self, values: Mapping, fixed: Mapping) -> dict:
        """``values`` moved along the common-scale direction to meet ``fixed``, then ``fixed``.

        Multiplying every inertia-scaled parameter (:attr:`scale_names`) by one factor
        leaves the angles unchanged, so a guess whose scale differs from a fixed scaled
        parameter (a start at Table 1 with ``m`` fixed at a fit's value) is moved by the
        factor ``fixed[n] / values[n]`` (the geometric mean over the fixed scaled
        parameters, where both are positive) before the fixed values are written in.  A
        fixed value written into an unscaled guess would change the dynamics instead (the
        gravity torque ``m g r_c`` against Table 1's gains turns the pitch over).

        Parameters
        ----------
        values, fixed : mapping of str to float
            Physical values [SI]; ``fixed`` wins where both name a parameter.

        Returns
        -------
        dict
            ``{name: value}`` with the names of ``values`` and ``fixed``.
        """
        scaled = set(self.scale_names)
        logs = [math.log(float(fixed[n]) / float(values[n])) for n in fixed
                if n in scaled and n in values and float(values[n]) > 0 and float(fixed[n]) > 0]  # fmt: skip
        c = math.exp(sum(logs) / len(logs)) if logs else 1.0
        moved = {n: (float(v) * c if n in scaled else v) for n, v in values.items()}
        return {**moved, **fixed}

    # ------------------------------------------------------------- dynamics
    def prepare(self, p):
        """Parameter-only work, once per solve: ``(mechanics coefficients, p)``, with ``p``
        extended by the terms' derived values (:meth:`AbstractTerm.derived`)."""
        extra = {}
        for term in self.inputs + self.torques:
            extra.update(term.derived(p))
        return self.mechanics.prepare(p), ({**p, **extra} if extra else p)

    def adapted(self, u, y, dt, span_u=None) -> HeliModel:
        """This model with every term set up for a training window (``u`` (N, 2) [V],
        ``y`` (N, 2) [rad], ``dt`` [s]; e.g. a neural term's input scaling) and the
        voltages ``span_u`` (M, 2) [V] of the whole span it will simulate (training and
        test window; default ``u``)."""
        return HeliModel(self.mechanics, tuple(t.adapt_to(u, y, dt, span_u) for t in self.inputs),
                         tuple(t.adapt_to(u, y, dt, span_u) for t in self.torques))

    def start_grid(self, u) -> dict:
        """Every term's :meth:`~heli_uq.model.terms.base.AbstractTerm.start_grid` for
        voltages ``u`` (N, 2) [V]: ``{parameter name: values}``."""
        out = {}
        for term in self.terms:
            out.update(term.start_grid(u))
        return out

    def input_voltages(self, p, u):
        """The voltages after every input map, a pair ``(u_theta, u_psi)`` [V]."""
        u = (u[0], u[1])
        for term in self.inputs:
            u = term(p, u)
        return u

    @property
    def filters_voltages(self) -> bool:
        """True if an input map acts on the voltage sequence (a motor's lag or dead time)."""
        return any(t.filters_sequence for t in self.inputs)

    def filtered_voltages(self, p, u, h):
        """The voltages ``u`` (N, 2) [V], held on solver steps of ``h`` [s], after every
        sequence map (:meth:`~heli_uq.model.terms.base.AbstractInputMap.filter_sequence`),
        in order; ``u`` itself without one."""
        for term in self.inputs:
            if term.filters_sequence:
                u = term.filter_sequence(p, u, h)
        return u

    @property
    def holds_torque(self) -> bool:
        """True if some torque depends on the voltages only (``input_only``): the simulator
        then evaluates those once per sample (:meth:`held_torque`), not at every stage."""
        return any(t.input_only for t in self.torques)

    @property
    def held_still(self) -> tuple[bool, bool]:
        """Per axis (pitch, yaw), whether a friction term (:attr:`AbstractTorque.holds_still`)
        can hold it at rest."""
        axes = {t.axis for t in self.torques if t.holds_still}
        return tuple(axis in axes for axis in AXES)

    def held_torque(self, p, u):
        """Sum of the ``input_only`` torques at voltages ``u`` (2,) [V] before the input
        maps, shape (2,) [N m]; ``p`` with the derived values (:meth:`prepare`)."""
        terms = tuple(t for t in self.torques if t.input_only)
        return _stacked(_sum_forces(terms, p, (0.0, 0.0), (0.0, 0.0), self.input_voltages(p, u)))

    def force(self, p, x, v, u, held=None):
        """Generalized force ``(T_theta, T_psi)`` [N m] of all torque terms at mapped ``u``,
        a pair of scalars (literal ``0.0`` components of a term are skipped).

        ``held`` (2,) [N m]: the ``input_only`` torques already summed at these voltages
        (:meth:`held_torque`); those terms are then not evaluated again.
        """
        if held is None:
            return _sum_forces(self.torques, p, x, v, u)
        total = _sum_forces(tuple(t for t in self.torques if not t.input_only), p, x, v, u)
        return (total[0] + held[0], total[1] + held[1])

    def force_vector(self, p, x, v, u):
        """:meth:`force` as an array of shape (2,) [N m]."""
        return _stacked(self.force(p, x, v, u))

    def acceleration(self, prepared, x, v, u, sc=None, held=None):
        """Generalized accelerations (2,) [rad/s^2]; ``u`` (2,) [V] before the input maps.

        ``sc = (sin theta, cos theta)`` may be passed by a caller that already has them;
        ``held``: the ``input_only`` torques at ``u`` (:meth:`held_torque`), likewise.
        """
        coeffs, p = prepared
        force = self.force(p, x, v, self.input_voltages(p, u), held)
        return self.mechanics.acceleration(coeffs, x, v, force, sc)

    def __call__(self, t, y, args):
        """Vector field ``dy/dt`` (4,) for ``args = (p, u)``."""
        p, u = args
        a = self.acceleration(self.prepare(p), y[:2], y[2:], u)
        return jnp.concatenate([y[2:], a])

    def stiffness(self, p, thetas=None, *, decay: bool = False):
        """Largest rate [1/s] the terms add near rest, on either axis (0 for the linear model).

        The rates of the terms on one axis add (Coulomb friction and stiction on yaw both
        steepen the yaw friction law at rest); the larger axis sum is returned.  A term's
        rate that is not finite is left out.  ``p``: values by name, scalars (a float is
        returned) or arrays of one shape, e.g. ``(n,)`` posterior draws (an array of that
        shape is returned).  ``thetas``: the pitch angles [rad] the yaw inertia is taken
        over (default all).  ``decay``: the terms' linear decay rates
        (:meth:`~heli_uq.model.terms.base.AbstractTerm.decay_rate`, the viscous damping's)
        add to every axis, for one point's solve.
        """
        p = {k: np.asarray(v, dtype=float) for k, v in p.items()}
        per_axis: dict = {}
        # an extreme value (an inertia of 1e-300, a mass of 1e200) makes a rate 0/0 or x/0:
        # that rate is left out, and numpy's warnings say nothing more
        with np.errstate(all="ignore"):
            inertia = self.mechanics.inertia_bounds(p, thetas)
            for term in self.terms:
                rate = np.asarray(term.stiffness(p, inertia), dtype=float)
                axis = getattr(term, "axis", None)
                per_axis[axis] = per_axis.get(axis, 0.0) + np.where(np.isfinite(rate), rate, 0.0)
            shared = (sum(np.asarray(t.decay_rate(p, inertia), dtype=float) for t in self.terms)
                      if decay else 0.0)  # fmt: skip
        shared = np.where(np.isfinite(shared), shared, 0.0)
        shape = np.broadcast_shapes(*(np.shape(v) for v in p.values()))
        sums = (np.broadcast_to(r + shared, shape) for r in per_axis.values())
        rate = np.maximum.reduce([np.zeros(shape), *sums])
        return float(rate) if rate.ndim == 0 else rate

    # ---------------------------------------------------------- description
    @property
    def effects(self) -> tuple:
        """The named effects of the model (input maps and torques beyond the linear one)."""
        from heli_uq.model.terms.base import AbstractEffect

        return tuple(t for t in self.terms if isinstance(t, AbstractEffect))

    def describe(self) -> dict:
        """JSON description: ``{"mechanics": ..., "effects": [{"effect", "axis", ...}]}``.

        Read back by :func:`heli_uq.model.model_from_description`.
        """
        return {"mechanics": self.mechanics.kind,
                "linear_torque": any(isinstance(t, LinearTorque) for t in self.torques),
                "effects": [t.describe() for t in self.effects]}  # fmt: skip

    def specification(self) -> dict:
        """:meth:`describe` without what the terms took from a record (:meth:`adapted`: a
        GP's voltage pairs, a network's input scaling): the model as a user specifies it,
        equal for the same model adapted to different records."""
        desc = self.describe()
        desc["effects"] = [{k: v for k, v in d.items() if k not in t.record_keys}
                           for t, d in zip(self.effects, desc["effects"])]  # fmt: skip
        return desc

    @property
    def label(self) -> str:
        """Short text, e.g. ``"mechanistic + coulomb_friction(yaw)"``."""
        return " + ".join(["mechanistic"] + [t.label for t in self.effects])


def _stacked(pair):
    """A force pair of scalars (some maybe literal ``0.0``) as an array (2,) [N m]."""
    return jnp.stack([jnp.asarray(f, dtype=jnp.float64) for f in pair])


def _sum_forces(terms, p, x, v, u):
    """``(T_theta, T_psi)`` summed over ``terms`` (literal ``0.0`` parts are skipped, so
    no operation is traced for them)."""
    total = [0.0, 0.0]
    for term in terms:
        for i, part in enumerate(term(p, x, v, u)):
            if not (isinstance(part, float) and part == 0.0):
                total[i] = part if isinstance(total[i], float) else total[i] + part
    return tuple(total)


def momentum_vector_field(t, z, args):
    """Momentum (DAE) form, Sec. 2.6: ``dx/dt = v``, ``dp/dt = dL/dx + F``, ``p = M(x) v``.

    The algebraic equation ``p = M(x) v`` is solved for ``v`` at every evaluation, so
    the state is ``z = (theta, psi, p_theta, p_psi)`` [rad, rad, kg m^2/s, kg m^2/s].

    Parameters
    ----------
    t : float
        Time [s] (unused: the system is autonomous for held inputs).
    z : array, shape (4,)
    args : tuple
        ``(model, p, u)``: a :class:`HeliModel`, parameter values and voltages (2,) [V].
    """
    model, p, u = args
    x, mom = z[:2], z[2:]
    v = jnp.linalg.solve(mass_matrix(p, x[0]), mom)
    dp = dl_dx(p, x, v) + model.force_vector(p, x, v, model.input_voltages(p, u))
    return jnp.concatenate([v, dp])
