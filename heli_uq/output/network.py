"""The neural terms' output torque on a named grid: what a hybrid posterior is judged by.

A network's weights are not identifiable one by one (a hidden unit's sign and the order
of the units can be swapped without changing the function), so R-hat and ESS of raw
weights say nothing about convergence.  The quantity that matters is the torque the
network adds.  :func:`network_points` fixes where it is reported:

* ``inputs="u"``: at the training window's distinct voltage pairs (the only inputs the
  record constrains; at most :data:`MAX_POINTS`, the most-held first); and, as a second
  grid ``<axis>_unseen``, at the span's pairs the training window never holds (a test
  window's new pairs: where the band must widen, :func:`band_widths`);
* ``inputs="u,x,v"``: at evenly spaced samples of the training window (measured angles,
  their smoothed rates, voltages): the term's projection points if it has them (the
  torque is then exactly orthogonal to the linear physics on the grid), else
  :data:`MAX_POINTS`.

:func:`network_torques` evaluates every posterior draw there, with the orthogonal
projection applied (the torque the term adds to the equations of motion, [N m]).
:mod:`heli_uq.output.inference_data` stores it in the posterior as
``nn_torque_<axis>`` with dims ``(chain, draw, nn_point_<axis>)`` and the inputs as
coordinates of that dim (the unseen pairs as ``nn_torque_<axis>_unseen`` on
``nn_point_<axis>_unseen``); :mod:`heli_uq.output.diagnostics` judges convergence on it and
on the physical parameters, and reports the weights' R-hat separately.

Layer 7, with the rest of :mod:`heli_uq.output` (reads the model and the problem).
"""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import numpy as np

from heli_uq.data import unseen_inputs
from heli_uq.data.rates import evenly_spaced, measured_rates
from heli_uq.model.terms.base import axis_index
from heli_uq.model.terms.linear_torque import LINEAR_TORQUE_PARAMETERS
from heli_uq.model.terms.neural_torque import NeuralTorque
from heli_uq.model.terms.rigid_body import MECHANICS_PARAMETERS, pitch_inertia, yaw_inertia
from heli_uq.probability.priors import fixed_values

__all__ = ["network_points", "network_torques", "network_terms", "is_network_weight", "draw_torques",
           "gain_trade_off", "network_pairs", "band_widths", "axis_inertia", "reference_pitch", "MAX_POINTS",
           "WEIGHT_PREFIXES", "UNSEEN"]  # fmt: skip

#: Most grid points per network.
MAX_POINTS = 64
#: A network's linear part below this fraction of the gain's sd counts as constant
#: (rounding of a projected network), its correlation as undefined.
FLAT = 1e-9
#: Name prefixes of network weights (see :mod:`heli_uq.model.terms.neural_torque`).
WEIGHT_PREFIXES = ("nn_W_", "nn_b_", "nn_w_")
#: Suffix of the grid of voltage pairs the training window never holds.
UNSEEN = "_unseen"


def is_network_weight(name: str) -> bool:
    """Whether a posterior variable is a raw network weight (not a physical quantity)."""
    return name.startswith(WEIGHT_PREFIXES)


def network_terms(model) -> list[NeuralTorque]:
    """The model's neural terms, in order."""
    return [t for t in model.torques if isinstance(t, NeuralTorque)]


def _most_held(u: np.ndarray, max_points: int, exclude: np.ndarray | None = None) -> np.ndarray:
    """The distinct rows of ``u`` (N, 2) not among the rows of ``exclude``, at most
    ``max_points`` of the most held, sorted."""
    if len(u) == 0:
        return np.zeros((0, 2))
    pairs, counts = np.unique(u, axis=0, return_counts=True)
    if exclude is not None:
        new = unseen_inputs(exclude, pairs)
        pairs, counts = pairs[new], counts[new]
    return pairs[np.sort(np.argsort(-counts, kind="stable")[:max_points])]


def network_points(problem, term: NeuralTorque, max_points: int = MAX_POINTS, *,
                   unseen: bool = False) -> dict[str, np.ndarray]:  # fmt: skip
    """Grid of ``term``'s inputs (module docstring): ``{input name: values (k,)}``, the
    voltages [V], angles [rad] and rates [rad/s] named as in ``term.input_names``.

    ``unseen=True`` (a network of ``u`` only): the voltage pairs of the problem's span that
    the training window never holds (k may be 0)."""
    n = problem.n_train
    u = np.asarray(problem.u[:n], dtype=float)
    if term.inputs == "u":
        rest = np.asarray(problem.u[n:], dtype=float)
        pairs = _most_held(rest, max_points, exclude=u) if unseen else _most_held(u, max_points)
        return {"u_theta": pairs[:, 0], "u_psi": pairs[:, 1]}
    if unseen:
        raise ValueError(f"unseen grid: defined for a network of u only, not of {term.inputs}")
    y = np.asarray(problem.y[:n], dtype=float)
    rates = measured_rates(y, problem.dt)
    idx = evenly_spaced(n, len(term.reference) or max_points)  # a projected network: its own points
    columns = {"u_theta": u[:, 0], "u_psi": u[:, 1], "theta": y[:, 0], "psi": y[:, 1],
               "omega_theta": rates[:, 0], "omega_psi": rates[:, 1]}  # fmt: skip
    return {"time": np.asarray(problem.t)[idx], **{k: v[idx] for k, v in columns.items()}}


def _torque_at(term, params: dict, points: dict):
    """The torque [N m] of ``term`` (an effect on one axis) at every grid point, shape
    (k,), for one parameter set; angles, rates or voltages missing from ``points`` are 0."""
    k = len(points["u_theta"])
    zeros = jnp.zeros(k)

    def col(name):
        return jnp.asarray(points[name]) if name in points else zeros

    x = jnp.stack([col("theta"), col("psi")], axis=1)
    v = jnp.stack([col("omega_theta"), col("omega_psi")], axis=1)
    u = jnp.stack([col("u_theta"), col("u_psi")], axis=1)
    p = {**params, **term.derived(params)}
    i = axis_index(term.axis)
    return jax.vmap(lambda xi, vi, ui: term(p, xi, vi, ui)[i])(x, v, u)


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
        as :func:`network_points`; for a network of ``u`` whose span holds voltage pairs
        the training window does not, also ``{axis + UNSEEN: ...}`` at those pairs;
        empty for a model without neural terms.
    """
    out = {}
    for term in network_terms(problem.model):
        grids = {term.axis: network_points(problem, term, max_points)}
        if term.inputs == "u":
            grids[term.axis + UNSEEN] = network_points(problem, term, max_points, unseen=True)
        out.update({key: (draw_torques(problem, term, samples, points), points)
                    for key, points in grids.items() if len(points["u_theta"])})  # fmt: skip
    return out


def draw_torques(problem, term, samples: dict, points: dict) -> np.ndarray:
    """Every draw's torque of ``term`` (an effect on one axis whose parameters are its own)
    at ``points`` (``{input name: (k,)}``), shape (chain, draw, k) [N m]."""
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
    return torque.reshape(shape + (torque.shape[-1],))


def network_pairs(idata, axis: str) -> tuple[np.ndarray, np.ndarray]:
    """The voltage pairs [V] of a stored network-of-``u`` torque, shape (k, 2), and the
    samples the training window holds at each, shape (k,) (the projection's weights)."""
    post, cd = idata.posterior, idata.constant_data
    pairs = np.stack([np.asarray(post[f"nn_point_{axis}_{q}"]) for q in ("u_theta", "u_psi")], axis=1)
    held = np.asarray(cd["u"])[np.asarray(cd["train_mask"], dtype=bool)]
    return pairs, np.array([np.all(held == pair, axis=1).sum() for pair in pairs], dtype=float)


def _draws_of(post, fixed: dict, n: int):
    """``var -> (n,)``: a sampled parameter's draws, or a fixed one's value repeated."""

    def flat(var):
        if var in post:
            return np.asarray(post[var], dtype=float).reshape(-1)
        return np.full(n, fixed[var])

    return flat


def reference_pitch(idata) -> float:
    """The training window's median measured pitch [rad]: where ``M22`` is taken."""
    cd = idata.constant_data
    return float(np.median(np.asarray(cd["y_obs"])[np.asarray(cd["train_mask"], dtype=bool), 0]))


def axis_inertia(idata, axis: str) -> np.ndarray:
    """The inertia of ``axis`` per posterior draw, shape (S,) [kg m^2]: ``M11``, or ``M22``
    at the training window's median pitch.

    The angles fix torques only relative to it (every torque and inertia can be scaled by
    one factor; the yaw torques and ``M22`` nearly so by ``J_s`` alone, measured: with ``m``
    fixed, a 40 s record left ``M22`` uncertain by 15 %), so a torque divided by it, an
    angular acceleration [rad/s^2], is what a posterior identifies."""
    post = idata.posterior
    fixed = fixed_values(json.loads(post.attrs.get("priors", "{}")))
    flat = _draws_of(post, fixed, post.sizes["chain"] * post.sizes["draw"])
    body = {par.name: flat(par.name) for par in MECHANICS_PARAMETERS if par.name in post or par.name in fixed}
    return np.asarray(pitch_inertia(body) if axis == "pitch" else yaw_inertia(body, reference_pitch(idata)))


def band_widths(idata, axis: str = "yaw", level: float = 0.9) -> dict:
    """Width of the central ``level`` band of the network's angular acceleration (its
    torque over the axis inertia of each draw, :func:`axis_inertia`) at the training
    window's voltage pairs and at the pairs it never holds (``nn_torque_<axis>_unseen``).

    A posterior that knows what it does not know widens where the data say nothing: a
    ``ratio`` (median unseen width over median seen width) near 1 means the band at a new
    voltage pair is as narrow as at a pair the record held for seconds.

    Returns
    -------
    dict
        ``{"seen": {"n", "median", "max"}, "unseen": {...}, "ratio"}`` with widths
        [rad/s^2]; empty without a stored network of ``u`` on ``axis``, ``unseen`` and
        ``ratio`` absent when every pair of the span is in the training window.
    """
    post = idata.posterior
    dim = f"nn_point_{axis}"
    if f"{dim}_u_psi" not in post.coords or f"{dim}_time" in post.coords:  # no network of u only
        return {}
    inertia = axis_inertia(idata, axis)[:, None]
    out = {}
    for key, suffix in (("seen", ""), ("unseen", UNSEEN)):
        var = f"nn_torque_{axis}{suffix}"
        if var not in post:
            continue
        accel = np.asarray(post[var]).reshape(-1, post[var].shape[-1]) / inertia
        lo, hi = np.quantile(accel, [(1 - level) / 2, (1 + level) / 2], axis=0)
        width = hi - lo
        out[key] = {"n": int(accel.shape[1]), "median": float(np.median(width)), "max": float(np.max(width))}
    if "seen" in out and "unseen" in out and out["seen"]["median"] > 0:
        out["ratio"] = out["unseen"]["median"] / out["seen"]["median"]
    return out


def gain_trade_off(idata, axis: str = "yaw") -> dict:
    """How the linear physics of ``axis`` and the linear part of its network trade off.

    Per draw, ``b`` is the least-squares fit of the stored network torque
    ``nn_torque_<axis>`` over its grid on the columns the physics owns: ``u_theta, u_psi``
    (the gains) for a network of ``u``, weighted by the samples the training window holds
    at each voltage pair; and also the axis's rate ``omega_<axis>`` (the damping) for a
    network of the states, over its grid of training samples, unweighted.  These are the
    spans of the term's projection, so a projected network gives ``b`` near 0.  The axis's
    torque is ``sum_j s_j P_j c_j + T_nn`` (``P_j`` the gain or damping of column ``c_j``,
    ``s_j`` its sign), so ``s_j P_j`` and ``b_j`` trade off one for one when the network can
    reproduce ``c_j``.  Both are divided by the draw's inertia ``M`` of the axis (``M11``;
    ``M22`` at the training window's median pitch): the common inertia scale, which the
    angles never see, would otherwise correlate every torque with every other.

    Parameters
    ----------
    idata : arviz.InferenceData
        A hybrid posterior with ``nn_torque_<axis>`` on its grid and ``constant_data``
        ``u``, ``train_mask``.

    Returns
    -------
    dict
        ``{column: {"gain", "corr", "sd_gain", "sd_linear", "sd_total"}}`` for the columns
        ``u_theta``, ``u_psi`` (and ``omega_<axis>``): the physical parameter's name, the
        correlation over draws of ``s P / M`` with ``b / M`` (NaN when either is
        constant), and the sds of ``s P / M``, ``b / M`` and their sum (what the data
        determine) [1/(V s^2), or 1/s for the damping]; empty without such a network.
    """
    name = f"nn_torque_{axis}"
    post = idata.posterior
    if name not in post or f"nn_point_{axis}_u_psi" not in post.coords or "u" not in idata.constant_data:
        return {}
    columns = ["u_theta", "u_psi"]
    physics = {par.input[0]: (par.name, par.input[1]) for par in LINEAR_TORQUE_PARAMETERS
               if par.axis == axis and par.input is not None}  # fmt: skip
    if f"nn_point_{axis}_time" in post.coords:  # a network of the states: the damping too
        columns.append("omega_theta" if axis == "pitch" else "omega_psi")
        damping = next(p.name for p in LINEAR_TORQUE_PARAMETERS if p.axis == axis and p.input is None)
        physics[2] = (damping, -1.0)
        basis = np.stack([np.asarray(post[f"nn_point_{axis}_{q}"]) for q in columns], axis=1)
        counts = np.ones(len(basis))
    else:
        basis, counts = network_pairs(idata, axis)
    root_w = np.sqrt(counts / counts.sum())
    torque = np.asarray(post[name]).reshape(-1, len(basis))
    b = np.linalg.lstsq(root_w[:, None] * basis, (root_w * torque).T, rcond=None)[0].T  # (S, columns)
    fixed = fixed_values(json.loads(post.attrs.get("priors", "{}")))
    flat = _draws_of(post, fixed, len(torque))
    inertia = axis_inertia(idata, axis)
    out = {}
    for j, (par, sign) in sorted(physics.items()):
        if not (par in post or par in fixed):
            continue
        gain, linear = sign * flat(par) / inertia, b[:, j] / inertia
        varies = gain.std() > 0 and linear.std() > FLAT * gain.std()
        corr = float(np.corrcoef(gain, linear)[0, 1]) if varies else float("nan")
        out[columns[j]] = {"gain": par, "corr": corr, "sd_gain": float(gain.std()),
                           "sd_linear": float(linear.std()),
                           "sd_total": float((gain + linear).std())}  # fmt: skip
    return out
