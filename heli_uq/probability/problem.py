"""A posterior problem: the record's windows, the model, the priors, the coordinates and the
error model, in one frozen object that every inference stage takes.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json

import jax.numpy as jnp
import numpy as np

from heli_uq.data.record import Experiment
from heli_uq.errors import ParameterError
from heli_uq.model.heli_model import HeliModel
from heli_uq.model.tables import X0_NAMES
from heli_uq.probability.coordinates import Coordinates
from heli_uq.probability.noise import ERROR_MODELS, error_parts
from heli_uq.probability.priors import PriorSet, RecordStart
from heli_uq.simulation.solver import solve
from heli_uq.simulation.stiffness import default_substeps

__all__ = ["Problem", "check_split", "make_problem", "fingerprint", "data_sha256", "training_data"]


@dataclasses.dataclass(frozen=True, eq=False)
class Problem:
    """Everything the probabilistic model needs.

    Attributes
    ----------
    model : HeliModel
    u : ndarray, shape (N, 2)
        Voltages [V] over the whole simulated span (training window, then up to the end
        of the test window).
    y : ndarray, shape (N, 2)
        Measured angles [rad] over the same span.
    t : ndarray, shape (N,)
        Sample times [s] (absolute, as in the record).
    dt : float
        Sample time [s].
    n_train : int
        The likelihood uses samples ``[0, n_train)`` (and simulates only those).
    test : tuple of int or None
        ``(start, stop)`` sample indices of the held-out test window, if any.
    priors : PriorSet
    coords : Coordinates
    error : {"iid", "ar1", "iid+timing", "ar1+timing"}
        The error model (:mod:`heli_uq.probability.noise`).
    substeps : int
        RK4 substeps per sample of every simulation.
    source : str
    """

    model: HeliModel
    u: np.ndarray
    y: np.ndarray
    t: np.ndarray
    dt: float
    n_train: int
    test: tuple[int, int] | None
    priors: PriorSet
    coords: Coordinates
    error: str = "ar1"
    substeps: int = 1
    source: str = ""

    @property
    def ar1(self) -> bool:
        """Whether the residuals are AR(1) (else independent)."""
        return error_parts(self.error)[0]

    @property
    def timing(self) -> bool:
        """Whether the error model has a timing error (:mod:`heli_uq.probability.noise`)."""
        return error_parts(self.error)[1]

    @property
    def record_start(self) -> RecordStart:
        """What the record says about the initial state (the initial-state priors' default)."""
        return RecordStart.of(self.y, self.dt, self.u)

    def x0_priors(self) -> tuple:
        """The priors of ``theta0, psi0, omega_theta0, omega_psi0`` (in that order): each
        one set by name, else the default from :attr:`record_start` and the model's
        friction terms (:meth:`PriorSet.x0_prior`)."""
        start, held = self.record_start, self.model.held_still
        return tuple(self.priors.x0_prior(name, start, held) for name in X0_NAMES)

    def draw_parameters(self, rng, shape=()) -> dict:
        """Draws ``{name: array shape}`` of every free model parameter from the prior the
        samplers use: the product of the priors (:meth:`PriorSet.draw`) with the common
        scale's prior of the coordinates (:meth:`Coordinates.joint_draws`)."""
        draws = self.priors.draw(self.model, rng, shape)
        return self.coords.joint_draws(draws, rng.standard_normal(shape))

    def windows(self) -> dict[str, tuple[int, int]]:
        """``{"train": (0, n_train), "test": (start, stop)}`` sample-index ranges."""
        out = {"train": (0, self.n_train)}
        if self.test is not None:
            out["test"] = self.test
        return out

    def masks(self) -> dict[str, np.ndarray]:
        """``{"train": (N,) bool, "test": (N,) bool}`` over the simulated span (the test
        mask all False without a test window)."""
        out = {}
        for w in ("train", "test"):
            out[w] = np.zeros(len(self.t), bool)
            a, b = self.windows().get(w, (0, 0))
            out[w][a:b] = True
        return out

    def solve(self, params, x0, n: int | None = None, *, gradients: str = "adjoint"):
        """Simulate the first ``n`` samples of the span (default all) with the problem's
        model and substeps; a :class:`~heli_uq.simulation.Solution`."""
        u = jnp.asarray(self.u if n is None else self.u[:n])
        return solve(params, x0, u, self.dt, model=self.model, substeps=self.substeps,
                     gradients=gradients)  # fmt: skip

    def with_substeps(self, substeps: int) -> Problem:
        """A copy simulating with ``substeps`` RK4 steps per sample."""
        return dataclasses.replace(self, substeps=int(substeps))


def check_split(train, test, dt: float) -> None:
    """Raise :class:`ParameterError` if the test window ``(c, d)`` [s] starts before the
    training window ``(a, b)`` ends (by more than half a sample ``dt``)."""
    (a, b), (c, d) = train, test
    if c < b - 0.5 * dt:
        raise ParameterError(f"test: window {c:g}:{d:g} s overlaps the training window {a:g}:{b:g} s")


def _window(record: Experiment, name: str, a: float, b: float) -> Experiment:
    """``record.window(a, b)``, its error naming the window (``train``, ``test``)."""
    try:
        return record.window(a, b)
    except ParameterError as exc:
        raise ParameterError(f"{name}: {exc}") from None


def make_problem(record: Experiment, train=None, test=None, *, model: HeliModel | None = None,
                 priors: PriorSet | None = None, error: str = "ar1", strategy: str = "auto",
                 substeps: int | None = None) -> Problem:  # fmt: skip
    """Build a :class:`Problem` from a record and optional train/test windows [s].

    Parameters
    ----------
    record : Experiment
    train, test : (float, float), optional
        ``(start, stop)`` in seconds; ``train`` defaults to the whole record.  The test
        window must start at or after the end of the training window.  The likelihood
        simulates the training window only; predictions run to the end of ``test``.
    model : HeliModel, optional
        Default: the paper's model.
    priors : PriorSet, optional
        Default: :meth:`PriorSet.default` of the model.
    error : {"iid", "ar1", "iid+timing", "ar1+timing"}
        The error model (:mod:`heli_uq.probability.noise`).
    strategy : {"auto", "identifiable", "log"}
        Sampling coordinates (:class:`~heli_uq.probability.Coordinates`).
    substeps : int, optional
        RK4 substeps per sample; default :func:`~heli_uq.simulation.default_substeps` at the
        model's start values over the training window's pitch angles (1 for the paper's
        model).  The MAP stage raises it if the fitted parameters need more.

    Raises
    ------
    ParameterError
        Unknown error model, overlapping windows, or priors of another model.
    """
    if error not in ERROR_MODELS:
        raise ParameterError(f"error: expected one of {ERROR_MODELS}, found {error!r}")
    model = HeliModel() if model is None else model
    priors = PriorSet.default(model) if priors is None else priors
    if set(priors.params) != set(model.names):
        raise ParameterError(f"priors: they are for the parameters {', '.join(priors.params)}, "
                             f"the model has {', '.join(model.names)}")  # fmt: skip
    t0 = float(record.t[0])
    a, b = train if train is not None else (t0, t0 + record.duration)
    tr = _window(record, "train" if train is not None else "window", a, b)
    if test is None:
        span, test_idx = tr, None
    else:
        c, d = test
        check_split((a, b), test, record.dt)
        te = _window(record, "test", c, d)
        span = record.window(a, float(te.t[-1]) + 0.5 * record.dt)
        start = int(round((te.t[0] - span.t[0]) / record.dt))
        test_idx = (start, start + te.n)
    # e.g. a neural term's input scaling, a GP term's voltage pairs (of the whole span)
    model = model.adapted(tr.u, tr.y, record.dt, span_u=span.u)
    priors = priors.completed(model)
    coords = Coordinates(model, priors.params, strategy, yaw_theta_ref=float(np.median(tr.y[:, 0])),
                         u_ref=tuple(float(m) for m in np.mean(tr.u, axis=0)))  # fmt: skip
    if substeps is None:
        substeps = default_substeps(model, model.start_values(), record.dt, thetas=tr.y[:, 0])
    return Problem(model=model, u=np.asarray(span.u), y=np.asarray(span.y), t=np.asarray(span.t),
                   dt=float(record.dt), n_train=int(tr.n), test=test_idx, priors=priors,
                   coords=coords, error=error, substeps=int(substeps),
                   source=str(record.source))  # fmt: skip


def data_sha256(u, y, t) -> str:
    """sha256 of a record's voltages ``u`` (N, 2), angles ``y`` (N, 2) and times ``t``
    (N,), as float64: the identity of the data a posterior was computed from."""
    digest = hashlib.sha256()
    for arr in (u, y, t):
        digest.update(np.ascontiguousarray(arr, dtype=np.float64).tobytes())
    return digest.hexdigest()


def training_data(problem: Problem) -> dict:
    """``{"train_s": "[a, b]", "train_sha256": ...}``: the window the likelihood scores [s]
    (JSON) and :func:`data_sha256` of its samples, the attributes by which ``posterior.nc``
    names its data (:func:`heli_uq.identifiability.report.check_posterior_data`)."""
    n = problem.n_train
    return {"train_s": json.dumps(fingerprint(problem)["train_s"]),
            "train_sha256": data_sha256(*(np.asarray(a)[:n] for a in (problem.u, problem.y, problem.t)))}


def fingerprint(problem: Problem) -> dict:
    """What determines a problem's posterior, as JSON-able values: a sha256 of the record's
    arrays, the windows (sample indices and seconds, ``[start, stop)``), the model
    description, the priors, the error model, the coordinates and the substeps.  Samplers
    store it to refuse resuming another problem."""
    t0, dt = float(problem.t[0]), float(problem.dt)
    train = [t0, t0 + problem.n_train * dt]
    test = None if problem.test is None else [t0 + problem.test[0] * dt, t0 + problem.test[1] * dt]
    return {"data_sha256": data_sha256(problem.u, problem.y, problem.t), "dt": dt, "n_train": problem.n_train,
            "train_s": [round(v, 9) for v in train],
            "test_s": None if test is None else [round(v, 9) for v in test],
            "test": None if problem.test is None else list(problem.test),
            "model": json.dumps(problem.model.describe(), sort_keys=True),
            "priors": json.dumps(problem.priors.to_json(), sort_keys=True),
            "error": problem.error, "coordinates": problem.coords.resolved,
            "substeps": problem.substeps}  # fmt: skip
