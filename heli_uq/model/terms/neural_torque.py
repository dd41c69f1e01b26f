"""``neural_torque``: a small neural network torque on one axis (the hybrid model, Sec. 4).

A one-hidden-layer tanh network of named inputs ``q`` (``"u"``: the two voltages after
any dead band; ``"u,x,v"``: also the angles and the rates),

    s_i = (q_i - c_i) / a_i,                       (input scaling fixed from the record)
    n(q) = sum_j w_j tanh(sum_i W_ji s_i + b_j)     [N m]
    T(q) = n(q) - beta . b(q)                               (the projection, below)

acts on ``axis``.  The output weights ``w_j`` [N m] are torque-type parameters
(``scales_with_inertia``: they keep the common-scale null direction exact); ``W_ji``
and ``b_j`` are dimensionless.  Default priors: ``W, b ~ N(0, 1)`` on the scaled inputs,
``w ~ N(0, 0.05 N m)``, so the network's torque is O(0.01-0.1 N m).

**Keeping the network from absorbing the physics.**  A network of the voltages can
reproduce the linear gains ``K u`` (and a torque offset) exactly, so ``K`` and the
network would trade off along flat directions.  For ``inputs="u"`` the network's output
is made orthogonal to what the physics owns over the record's inputs: ``{u_theta,
u_psi}`` (option ``project="u"``, the default: the gains of the axis) or ``{1, u_theta,
u_psi}`` (``project="1,u"``, for a model with a ``torque_offset`` on that axis, which
then owns the constant; ``beta_0`` is 0 otherwise).  ``beta`` is the weighted
least-squares fit of ``n`` at the record's distinct voltage pairs (weights: the samples
held at each pair), subtracted everywhere.  ``K`` then owns the linear part; the
network can only add curvature, which needs more distinct voltage pairs than basis
functions (otherwise every function of ``u`` is linear over the pairs and the network's
torque is zero on the record).  ``project="none"`` switches the projection off.

A network of the states (``inputs="u,x,v"``) can also reproduce the axis's viscous
damping ``-D omega`` and, on pitch, the gravity torque ``-m g (r_c cos theta - h sin
theta)``.  Its basis ``b(q)`` is therefore ``(1,) u_theta, u_psi, omega_<axis>`` (and
``cos theta, sin theta`` on pitch), and ``beta`` is the least-squares fit of ``n`` over
up to :data:`MAX_REFERENCE_POINTS` evenly spaced samples of the training window (the
measured angles, their smoothed rates :func:`heli_uq.data.rates.measured_rates`, the
voltages; equal weights).  The network keeps what no linear physics term can hold (a
friction law, a restoring torque, an input nonlinearity), and the gains, damping and
gravity parameters stay identified.  Measured on a synthetic record with a hidden yaw
drag (``studies/hybrid_state_network.py``): without the projection the yaw gains and
damping correlate -0.76 to -0.89 with the network's linear part over the posterior, and
their sds are 1.5-2.2x what the data fix; with it the network has no linear part and the
sds equal what the data fix.

The input scaling ``(c, a)`` and the reference points come from the training window
(:meth:`NeuralTorque.adapt_to`, called by :func:`heli_uq.probability.make_problem`) and
are stored in the model's description, so a reloaded posterior uses the same network.

Parameters are named ``nn_<axis>_W_<j>_<input>``, ``nn_<axis>_b_<j>`` and
``nn_<axis>_w_<j>``.  The network's sign and permutation symmetries make its weights
non-identifiable one by one; judge a posterior by its output torque, not by R-hat on
weights.
"""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from heli_uq.data.rates import evenly_spaced, measured_rates
from heli_uq.errors import ParameterError
from heli_uq.model.parameter import Parameter
from heli_uq.model.prior import Prior
from heli_uq.model.terms.base import AbstractEffect, AbstractTorque, float_tuple, on_axis, weighted_projection

__all__ = ["NeuralTorque", "NN_INPUTS", "WEIGHT_PRIOR_SD", "OUTPUT_PRIOR_SD", "DEFAULT_HIDDEN",
           "MAX_REFERENCE_POINTS"]

#: The span projected out of a network of the voltages (module docstring).
PROJECTIONS = ("u", "1,u", "none")
#: Named input sets: the quantities each feeds to the network, in order.
NN_INPUTS = {"u": ("u_theta", "u_psi"),
             "u,x,v": ("u_theta", "u_psi", "theta", "psi", "omega_theta", "omega_psi")}
#: Prior sd of the hidden-layer weights and biases (scaled inputs, dimensionless).
WEIGHT_PRIOR_SD = 1.0
#: Prior sd of the output weights [N m].
OUTPUT_PRIOR_SD = 0.05
#: First guess of the output weights [N m], alternating in sign: all-zero weights are a
#: stationary point (every gradient of the hidden layer vanishes with the output weights).
START_OUTPUT = 0.005
#: Largest number of reference points of the orthogonal projection: voltage pairs (the
#: most held) for a network of ``u``, evenly spaced training samples for one of states.
MAX_REFERENCE_POINTS = 200


def _start_weights(hidden: int, n_in: int) -> np.ndarray:
    """Fixed, seed-free first guess of ``W`` (hidden, n_in): spread directions of unit size,
    so no two hidden units start alike (at ``W = 0`` every gradient of ``W`` vanishes)."""
    angles = np.pi * (np.arange(hidden) + 0.5) / hidden
    w = np.zeros((hidden, n_in))
    w[:, 0] = np.cos(angles)
    w[:, 1 % n_in] += np.sin(angles)
    return w


#: Hidden units unless a model says otherwise.  On the rig's 0-91 s, NUTS over every weight
#: of a 2-unit FNN(u) mixes (R-hat 1.00, 33 leapfrog steps per draw, 10 min for 4 chains)
#: and a 4-unit one does not (R-hat 1.07 after 58 min, 242 steps per draw, 90 % of draws at
#: the tree depth); the 2-unit posterior also predicts the test window better (README).
DEFAULT_HIDDEN = 2
#: Most hidden units a network may have: each is ~4-8 parameters of a posterior over a
#: record of ~13,000 samples; 2000 units took 24 s to set up a simulation, 100,000 hung.
MAX_HIDDEN = 1024


class NeuralTorque(AbstractEffect, AbstractTorque):
    """Neural torque ``T(q)`` on ``axis`` (module docstring).

    Parameters
    ----------
    axis : {"pitch", "yaw"}
    inputs : {"u", "u,x,v"}
    hidden : int
        Hidden units (default :data:`DEFAULT_HIDDEN`; the paper used 16).
    project : {"u", "1,u", "none"}
        What the output is made orthogonal to (module docstring): the linear physics of
        the axis (gains; with states also damping and, on pitch, gravity), with a
        constant (``"1,u"``), or nothing.
    center, scale : tuple of float
        Input scaling ``s = (q - center) / scale``, one value per input; empty until
        :meth:`adapt_to` sets them from a record.
    projection : tuple of tuple of float
        Rows ``P`` (m, k) of the orthogonal projection, ``beta = P @ n(reference)``, with
        ``m`` the size of the basis (3 for a network of ``u``); empty for none.
    reference : tuple of tuple of float
        The reference points (k, n_in), in the order of :attr:`input_names`: the record's
        distinct voltage pairs [V] for a network of ``u``; samples of the training window
        (voltages, angles [rad], rates [rad/s]) for one of states.
    """

    kind: ClassVar[str] = "neural_torque"
    summary: ClassVar[str] = (
        "hybrid model: a tanh network torque of the voltages (weights nn_W_*, nn_b_*, nn_w_*); "
        "options inputs (u | u,x,v) and hidden in a model file")
    record_keys: ClassVar[tuple[str, ...]] = ("center", "scale", "projection", "reference")
    axis: str = eqx.field(static=True, default="yaw")
    inputs: str = eqx.field(static=True, default="u")
    hidden: int = eqx.field(static=True, default=DEFAULT_HIDDEN)
    project: str = eqx.field(static=True, default="u")
    center: tuple = eqx.field(static=True, default=(), converter=float_tuple)
    scale: tuple = eqx.field(static=True, default=(), converter=float_tuple)
    projection: tuple = eqx.field(static=True, default=(), converter=float_tuple)
    reference: tuple = eqx.field(static=True, default=(), converter=float_tuple)

    def __check_init__(self):
        if self.inputs not in NN_INPUTS:
            raise ParameterError(f"neural_torque: inputs must be one of {', '.join(NN_INPUTS)}, "
                                 f"found {self.inputs!r}")  # fmt: skip
        if self.project not in PROJECTIONS:
            raise ParameterError(f"neural_torque: project must be one of {', '.join(PROJECTIONS)}, "
                                 f"found {self.project!r}")  # fmt: skip
        hidden = self.hidden
        if isinstance(hidden, bool) or not isinstance(hidden, int) or not 1 <= hidden <= MAX_HIDDEN:
            raise ParameterError(f"neural_torque: hidden must be an integer in 1..{MAX_HIDDEN}, "
                                 f"found {self.hidden!r}")  # fmt: skip
        n = len(NN_INPUTS[self.inputs])
        for name in ("center", "scale"):
            value = getattr(self, name)
            if value and len(value) != n:
                raise ParameterError(f"neural_torque: {name} needs {n} values (one per input "
                                     f"{', '.join(NN_INPUTS[self.inputs])}), found {len(value)}")
        if self.scale and min(self.scale) <= 0:
            raise ParameterError(f"neural_torque: scale must be positive, found {self.scale}")

    @property
    def awaits_record(self) -> bool:
        return not self.center  # adapt_to sets the input scaling

    @property
    def input_names(self) -> tuple[str, ...]:
        return NN_INPUTS[self.inputs]

    @property
    def input_only(self) -> bool:
        """A network of the voltages alone is evaluated once per sample (not per stage)."""
        return self.inputs == "u"

    # ------------------------------------------------------------ parameters
    def _declare(self):
        pars = []
        w_start = _start_weights(self.hidden, len(self.input_names))
        for j in range(self.hidden):
            for i, q in enumerate(self.input_names):
                start = float(w_start[j, i])
                pars.append(Parameter(f"nn_W_{j}_{q}", "1", 0.0,
                                      Prior("normal", 0.0, WEIGHT_PRIOR_SD), "real", False, None,
                                      f"network weight, unit {j}, input {q}", start))  # fmt: skip
            b_start = float(np.linspace(-1.0, 1.0, self.hidden)[j]) if self.hidden > 1 else 0.0
            pars.append(Parameter(f"nn_b_{j}", "1", 0.0, Prior("normal", 0.0, WEIGHT_PRIOR_SD),
                                  "real", False, None, f"network bias, unit {j}", b_start))
            pars.append(Parameter(f"nn_w_{j}", "N m", 0.0, Prior("normal", 0.0, OUTPUT_PRIOR_SD),
                                  "real", True, None, f"network output weight, unit {j}",
                                  START_OUTPUT * (-1) ** j))
        return tuple(pars)

    # ------------------------------------------------------------ the record
    def adapt_to(self, u, y, dt, span_u=None) -> NeuralTorque:
        """This term with the input scaling and reference points of a training window.

        ``u`` (N, 2) [V] and ``y`` (N, 2) [rad] are the window's voltages and angles, ``dt``
        its sample time [s].  A term that already has them (e.g. reloaded with a
        posterior) is returned unchanged.
        """
        if self.center:
            return self
        u, y = np.asarray(u, dtype=float), np.asarray(y, dtype=float)
        rates = measured_rates(y, dt)
        columns = {"u_theta": u[:, 0], "u_psi": u[:, 1], "theta": y[:, 0], "psi": y[:, 1],
                   "omega_theta": rates[:, 0], "omega_psi": rates[:, 1]}  # fmt: skip
        q = np.stack([columns[n] for n in self.input_names], axis=1)
        center = q.mean(axis=0)
        scale = q.std(axis=0)
        scale = np.where(scale > 1e-9, scale, 1.0)
        if self.project == "none":
            return NeuralTorque(self.axis, self.inputs, self.hidden, self.project, center, scale)
        if self.inputs == "u":
            points, weights = np.unique(u, axis=0, return_counts=True)
            if len(points) > MAX_REFERENCE_POINTS:  # keep the most-held pairs
                keep = np.argsort(-weights)[:MAX_REFERENCE_POINTS]
                points, weights = points[keep], weights[keep]
        else:
            keep = evenly_spaced(len(q), MAX_REFERENCE_POINTS)
            points, weights = q[keep], np.ones(len(keep))
        basis = self.basis(dict(zip(self.input_names, points.T)), np)
        return NeuralTorque(self.axis, self.inputs, self.hidden, self.project, center, scale,
                            weighted_projection(basis, weights), points)  # fmt: skip

    def basis(self, values: dict, xp=jnp):
        """The span the physics owns, ``b(q)`` (module docstring), shape (..., m).

        ``values`` maps input names to arrays of one shape; ``xp`` is ``numpy`` or
        ``jax.numpy``.  The first column is the constant (zeros unless ``project="1,u"``).
        """
        u_theta = values["u_theta"]
        cols = [xp.ones_like(u_theta) * (self.project == "1,u"), u_theta, values["u_psi"]]
        if self.inputs != "u":
            cols.append(values["omega_theta" if self.axis == "pitch" else "omega_psi"])
            if self.axis == "pitch":
                cols += [xp.cos(values["theta"]), xp.sin(values["theta"])]
        return xp.stack(cols, axis=-1)

    # ---------------------------------------------------------------- physics
    def _network(self, p, q):
        """``n(q)`` [N m] for inputs ``q`` (n_in,) or (k, n_in)."""
        q = jnp.asarray(q)
        center = jnp.asarray(self.center) if self.center else 0.0
        scale = jnp.asarray(self.scale) if self.scale else 1.0
        s = (q - center) / scale
        out = 0.0
        for j in range(self.hidden):
            pre = p[self.name(f"nn_b_{j}")]
            for i, name in enumerate(self.input_names):
                pre = pre + p[self.name(f"nn_W_{j}_{name}")] * s[..., i]
            out = out + p[self.name(f"nn_w_{j}")] * jnp.tanh(pre)
        return out

    def linear_part(self, p):
        """``beta`` (m,): the least-squares fit of the raw network on the basis ``b`` over
        the reference points (module docstring; zeros (3,) without a projection)."""
        if not self.projection:
            return jnp.zeros(3)
        return jnp.asarray(self.projection) @ self._network(p, jnp.asarray(self.reference))

    def torque(self, p, x, v, u):
        """``T(q)`` [N m], a scalar (module docstring)."""
        values = {"u_theta": u[0], "u_psi": u[1], "theta": x[0], "psi": x[1],
                  "omega_theta": v[0], "omega_psi": v[1]}  # fmt: skip
        q = jnp.stack([values[n] for n in self.input_names])
        out = self._network(p, q)
        if self.projection:
            beta = p[self.name("nn_beta")] if self.name("nn_beta") in p else self.linear_part(p)
            out = out - self.basis(values) @ beta
        return out

    def derived(self, p) -> dict:
        """Parameter-only work once per solve: the projection coefficients ``beta``."""
        return {self.name("nn_beta"): self.linear_part(p)} if self.projection else {}

    def __call__(self, p, x, v, u):
        return on_axis(self.axis, self.torque(p, x, v, u))

    def describe(self) -> dict:
        return {"effect": self.kind, "axis": self.axis, "inputs": self.inputs,
                "hidden": self.hidden, "project": self.project, "center": list(self.center),
                "scale": list(self.scale),
                "projection": [list(r) for r in self.projection],
                "reference": [list(r) for r in self.reference]}  # fmt: skip
