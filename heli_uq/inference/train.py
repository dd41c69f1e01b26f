"""Point training of a hybrid model as in the paper (Sec. 4): Adam, then L-BFGS, on V.

The paper trained its networks with the physics frozen at fitted values: 100 Adam steps,
then 100 BFGS steps, on the loss ``V`` (Eq. 1, [rad^2]) of the training window.
:func:`train` does that with optax (Adam, then optax's L-BFGS with a zoom line search)
over any subset of the model's parameters: by default the neural terms' weights, the
physics held at the given values; with ``trainable="all"`` every free parameter jointly.
Positive parameters are trained as logs, real ones as they are; the initial state is
held.  The solver takes at least the substeps its start needs
(:func:`~heli_uq.simulation.default_substeps`: a fit with a heavy damping or sharp friction
is stiff), so a start that a one-step solve would blow up is trained, not refused.  This is
the fast, non-Bayesian route; the posterior over the same parameters is the NUTS / Laplace
workflow of :mod:`heli_uq.inference`.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Mapping, Sequence

import jax
import jax.numpy as jnp
import numpy as np
import optax

from heli_uq.errors import ParameterError
from heli_uq.inference.map import _lbfgs
from heli_uq.model.terms.neural_torque import NeuralTorque
from heli_uq.probability.likelihood import loss_v
from heli_uq.probability.problem import Problem
from heli_uq.simulation.stiffness import capped_substeps, default_substeps

__all__ = ["train", "Training", "ADAM_STEPS", "LBFGS_STEPS", "LEARNING_RATE"]

#: The paper's schedule: Adam steps, then (L-)BFGS steps.
ADAM_STEPS = 100
LBFGS_STEPS = 100
#: Adam's learning rate (in the trained coordinates: raw weights, log positive parameters).
LEARNING_RATE = 1e-2


@dataclasses.dataclass(frozen=True)
class Training:
    """Result of :func:`train`.

    Attributes
    ----------
    params : dict
        Every model parameter [SI] after training (the held ones unchanged).
    trained : tuple of str
        The names that were trained.
    v_start, v : float
        ``V`` [rad^2] of the training window before and after.
    v_adam : ndarray, shape (adam_steps,)
        ``V`` before each Adam step.
    lbfgs_steps : int
        L-BFGS iterations taken.
    seconds : float
    substeps : int
        RK4 substeps per sample of the solves: the problem's, or more if the start needed
        them.
    """

    params: dict
    trained: tuple
    v_start: float
    v: float
    v_adam: np.ndarray
    lbfgs_steps: int
    seconds: float
    substeps: int


def _trainable_names(problem: Problem, trainable) -> tuple[str, ...]:
    model = problem.model
    if trainable is None:
        names = tuple(p.name for t in model.torques if isinstance(t, NeuralTorque)
                      for p in t.parameters())  # fmt: skip
        if not names:
            raise ParameterError("trainable: the model has no neural term; name the parameters "
                                 "to train or pass 'all'")  # fmt: skip
        return names
    if trainable == "all":
        return tuple(problem.coords.free)
    unknown = sorted(set(trainable) - set(model.names))
    if unknown:
        raise ParameterError(f"trainable: unknown parameter(s) {', '.join(unknown)}; this model "
                             f"has {', '.join(model.names)}")  # fmt: skip
    return tuple(trainable)


def _transforms(problem: Problem, names):
    """Per name: True to train its log (positive supports), False for the raw value."""
    logs = []
    for n in names:
        support = problem.model.parameter(n).support
        if support in ("positive", "nonnegative"):
            logs.append(True)
        elif support == "real":
            logs.append(False)
        else:
            raise ParameterError(f"trainable: {n} has a bounded support {support}; train it "
                                 "through the posterior workflow instead")  # fmt: skip
    return np.asarray(logs)


def train(problem: Problem, params: Mapping, x0, *, trainable: Sequence[str] | str | None = None,
          adam_steps: int = ADAM_STEPS, lbfgs_steps: int = LBFGS_STEPS,
          learning_rate: float = LEARNING_RATE) -> Training:  # fmt: skip
    """Minimise ``V`` of ``problem``'s training window: Adam, then L-BFGS.

    Parameters
    ----------
    problem : Problem
        Record, windows and model (:func:`heli_uq.probability.make_problem`).
    params : mapping
        Starting values [SI]; missing names take the model's start values (a neural
        term's spread first guess of its hidden layer), except the networks' output
        weights, which start at 0: the hybrid starts at the physics' own ``V``.
    x0 : array, shape (4,)
        Initial state [rad, rad, rad/s, rad/s], held.
    trainable : None, "all" or sequence of str
        None (default): the neural terms' weights, physics held.  ``"all"``: every free
        parameter jointly.  Or the names to train.
    adam_steps, lbfgs_steps : int
    learning_rate : float

    Raises
    ------
    ParameterError
        Unknown names, a bounded parameter, bad step counts, or a non-finite ``V`` at the
        start.  A step whose simulation blows up (non-finite ``V`` or gradient) is
        rejected: Adam stops at its best finite iterate, and an L-BFGS result that is not
        finite or not better is discarded, so training never returns worse than its start.
    """
    for name, value in (("adam_steps", adam_steps), ("lbfgs_steps", lbfgs_steps)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 0:
            raise ParameterError(f"{name}: expected an integer >= 0, found {value!r}")
    if not learning_rate > 0:
        raise ParameterError(f"learning_rate: expected > 0, found {learning_rate!r}")
    t0 = time.perf_counter()
    model = problem.model
    # a network's output weights start at 0 (unless given): training starts from the
    # physics' own V and can only improve on it (the hidden layer's spread first guess
    # keeps every gradient alive)
    silent = {p.name: 0.0 for t in model.torques if isinstance(t, NeuralTorque)
              for p in t.parameters() if p.bare.startswith("nn_w_")}  # fmt: skip
    full = {**model.start_values(), **silent, **dict(params)}
    need = capped_substeps(default_substeps(model, {k: v for k, v in full.items() if k in model.names},
                                            problem.dt), "train's start")  # fmt: skip
    if need > problem.substeps:  # a stiff start (a heavy damping) would blow up a coarser solve
        problem = problem.with_substeps(need)
    names = _trainable_names(problem, trainable)
    logs = _transforms(problem, names)
    held = {k: jnp.asarray(v, dtype=jnp.float64) for k, v in full.items() if k not in names}
    x0 = jnp.asarray(x0, dtype=jnp.float64)
    y = jnp.asarray(problem.y[: problem.n_train])

    def unpack(w):
        values = jnp.where(logs, jnp.exp(w), w)
        return {**held, **dict(zip(names, values))}

    def loss(w):
        return loss_v(problem.solve(unpack(w), x0, problem.n_train).ys, y)

    w0 = np.array([full[n] for n in names], dtype=float)
    w0 = jnp.asarray(np.where(logs, np.log(np.maximum(w0, 1e-300)), w0))
    opt = optax.adam(learning_rate)
    grad = jax.value_and_grad(loss)

    loss_at = jax.jit(loss)  # traced, so non-finite parameters give NaN instead of raising

    @jax.jit
    def adam(w):
        # A step whose loss or gradient is not finite (a simulation that blew up) ends the
        # Adam phase at the best finite iterate seen: the failed solve is a rejected step.
        def step(carry, _):
            w, state, best_w, best_v, stopped = carry
            value, g = grad(w)
            ok = jnp.isfinite(value) & jnp.all(jnp.isfinite(g)) & ~stopped
            better = ok & (value < best_v)
            best_w = jnp.where(better, w, best_w)
            best_v = jnp.where(better, value, best_v)
            updates, new_state = opt.update(g, state, w)
            stopped = ~ok
            w_next = jnp.where(stopped, best_w, optax.apply_updates(w, updates))
            state = jax.tree.map(lambda old, new: jnp.where(stopped, old, new), state, new_state)
            return (w_next, state, best_w, best_v, stopped), value

        carry = (w, opt.init(w), w, jnp.asarray(jnp.inf), jnp.asarray(False))
        (w, _, best_w, best_v, _), values = jax.lax.scan(step, carry, None, length=adam_steps)
        return w, values, best_w

    v_start = float(loss_at(w0))
    if not np.isfinite(v_start):
        raise ParameterError(f"train: V is {v_start} at the start (the model blows up there); start "
                             "closer to a fit")  # fmt: skip
    w, v_adam, best_w = adam(w0)
    if not float(loss_at(w)) <= float(loss_at(best_w)):  # also when loss_at(w) is NaN
        w = best_w
    k = 0
    if lbfgs_steps:
        w_l, _, k = jax.jit(lambda w: _lbfgs(loss, w, lbfgs_steps, 0.0))(w)
        if np.isfinite(v_l := float(loss_at(w_l))) and v_l <= float(loss_at(w)):
            w = w_l
    v = float(loss_at(w))
    if not np.isfinite(v):
        raise ParameterError(f"train: V is {v} after training (the model blew up); lower "
                             "learning_rate or start closer")  # fmt: skip
    out = {k_: float(v_) for k_, v_ in unpack(w).items()}
    return Training(params=out, trained=names, v_start=v_start, v=v,
                    v_adam=np.asarray(v_adam), lbfgs_steps=int(k),
                    seconds=time.perf_counter() - t0, substeps=problem.substeps)  # fmt: skip
