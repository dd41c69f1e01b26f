"""The neural terms' output torque on a named grid: what a hybrid posterior is judged by.

A network's weights are not identifiable one by one (a hidden unit's sign and the order
of the units can be swapped without changing the function), so R-hat and ESS of raw
weights say nothing about convergence.  The quantity that matters is the torque the
network adds.  :func:`network_points` fixes where it is reported:

* ``inputs="u"``: at the training window's distinct voltage pairs (the only inputs the
  record constrains; at most :data:`MAX_POINTS`, the most-held first);
* ``inputs="u,x,v"``: at :data:`MAX_POINTS` evenly spaced samples of the training
  window (measured angles, rates by finite differences, voltages).

:func:`network_torques` evaluates every posterior draw there, with the orthogonal
projection applied (the torque the term adds to the equations of motion, [N m]).
:mod:`heli_uq.output.inference_data` stores it in the posterior as
``nn_torque_<axis>`` with dims ``(chain, draw, nn_point_<axis>)`` and the inputs as
coordinates of that dim; :mod:`heli_uq.output.diagnostics` judges convergence on it and
on the physical parameters, and reports the weights' R-hat separately.

Layer 7, with the rest of :mod:`heli_uq.output` (reads the model and the problem).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from heli_uq.model.terms.neural_torque import NeuralTorque

__all__ = ["network_points", "network_torques", "network_terms", "is_network_weight",
           "MAX_POINTS", "WEIGHT_PREFIXES"]  # fmt: skip

#: Most grid points per network.
MAX_POINTS = 64
#: Name prefixes of network weights (see :mod:`heli_uq.model.terms.neural_torque`).
WEIGHT_PREFIXES = ("nn_W_", "nn_b_", "nn_w_")


def is_network_weight(name: str) -> bool:
    """Whether a posterior variable is a raw network weight (not a physical quantity)."""
    return name.startswith(WEIGHT_PREFIXES)


def network_terms(model) -> list[NeuralTorque]:
    """The model's neural terms, in order."""
    return [t for t in model.torques if isinstance(t, NeuralTorque)]


def network_points(problem, term: NeuralTorque, max_points: int = MAX_POINTS) -> dict[str, np.ndarray]:
    """Grid of ``term``'s inputs (module docstring): ``{input name: values (k,)}``, the
    voltages [V], angles [rad] and rates [rad/s] named as in ``term.input_names``."""
    n = problem.n_train
    u = np.asarray(problem.u[:n], dtype=float)
    if term.inputs == "u":
        pairs, counts = np.unique(u, axis=0, return_counts=True)
        keep = np.sort(np.argsort(-counts, kind="stable")[:max_points])
        return {"u_theta": pairs[keep, 0], "u_psi": pairs[keep, 1]}
    y = np.asarray(problem.y[:n], dtype=float)
    rates = np.gradient(y, float(problem.dt), axis=0) if n > 1 else np.zeros_like(y)
    idx = np.unique(np.linspace(0, n - 1, min(n, max_points)).round().astype(int))
    columns = {"u_theta": u[:, 0], "u_psi": u[:, 1], "theta": y[:, 0], "psi": y[:, 1],
               "omega_theta": rates[:, 0], "omega_psi": rates[:, 1]}  # fmt: skip
    return {"time": np.asarray(problem.t)[idx], **{k: v[idx] for k, v in columns.items()}}


def _torque_at(term: NeuralTorque, params: dict, points: dict):
    """The term's torque [N m] at every grid point, shape (k,), for one parameter set."""
    k = len(points["u_theta"])
    zeros = jnp.zeros(k)

    def col(name):
        return jnp.asarray(points[name]) if name in points else zeros

    x = jnp.stack([col("theta"), col("psi")], axis=1)
    v = jnp.stack([col("omega_theta"), col("omega_psi")], axis=1)
    u = jnp.stack([col("u_theta"), col("u_psi")], axis=1)
    p = {**params, **term.derived(params)}
    return jax.vmap(lambda xi, vi, ui: term.torque(p, xi, vi, ui))(x, v, u)


def network_torques(problem, samples: dict, max_points: int = MAX_POINTS) -> dict:
    """Every draw's network torque on the grid of each neural term.

    Parameters
    ----------
    problem : Problem
    samples : dict
        Posterior draws by site name, shape (chain, draw) for scalars.

    Returns
    -------
    dict
        ``{axis: (torque (chain, draw, k) [N m], points)}`` per neural term, ``points``
        as :func:`network_points`; empty for a model without neural terms.
    """
    out = {}
    for term in network_terms(problem.model):
        points = network_points(problem, term, max_points)
        names = [p.name for p in term.parameters()]
        shape = None
        flat = {}
        for name in names:
            prior = problem.priors.params[name]
            if prior.free:
                value = np.asarray(samples[name], dtype=float)
                shape = value.shape
                flat[name] = value.reshape(-1)
        if shape is None:  # every weight fixed: one torque, repeated
            shape = np.asarray(samples["z"]).shape[:2]
        for name in names:
            if name not in flat:
                flat[name] = np.full(int(np.prod(shape)), problem.priors.params[name].a)
        batched = jax.jit(jax.vmap(lambda p, t=term, q=points: _torque_at(t, p, q)))
        torque = np.asarray(batched({k: jnp.asarray(v) for k, v in flat.items()}))
        out[term.axis] = (torque.reshape(shape + (torque.shape[-1],)), points)
    return out
