"""An experiment that tells two rival models apart (T-optimality with the fits held fixed).

For two fitted models ``a`` and ``b`` and iid Gaussian errors of sd ``sigma`` per angle, the
expected log Bayes factor in favour of ``a`` when ``a`` is true (the Kullback-Leibler
divergence of the predictive distributions) is

    D(u) = 1/2 sum_k sum_j ((y_a,j(t_k; u) - y_b,j(t_k; u)) / sigma_j)^2   [nats].

:meth:`Rivals.from_discovery` takes the two best-scored candidate models of a
``heli-uq discover`` run with their MAP parameters.
"""

from __future__ import annotations

import dataclasses
import json
import pathlib

import jax.numpy as jnp
import numpy as np

from heli_uq.errors import DataFormatError
from heli_uq.model.heli_model import HeliModel
from heli_uq.model.spec import build_model
from heli_uq.model.tables import X0_NAMES
from heli_uq.simulation.physical import PITCH_LIMIT
from heli_uq.simulation.solver import solve
from heli_uq.simulation.stiffness import default_substeps

__all__ = ["Rival", "Rivals"]


@dataclasses.dataclass(frozen=True, eq=False)
class Rival:
    """One fitted model: ``name`` (e.g. ``yaw:torque_offset``), model, parameters, substeps."""

    name: str
    model: HeliModel
    params: dict
    substeps: int

    def angles(self, u, dt, x0, pitch=(-PITCH_LIMIT, PITCH_LIMIT)):
        """Simulated (theta, psi) (N, 2) [rad], and whether pitch stays in ``pitch`` [rad]."""
        sol = solve(self.params, x0, u, dt, model=self.model, substeps=self.substeps)
        ys = np.asarray(sol.ys[:, :2])
        ok = bool(sol.ok) and bool(np.all((ys[:, 0] >= pitch[0]) & (ys[:, 0] <= pitch[1])))
        return ys, ok


@dataclasses.dataclass(frozen=True, eq=False)
class Rivals:
    """Two rival fitted models, the noise sd (2,) [rad], the experiment's initial state (4,)
    and the envelope ``pitch`` [rad] both predictions must keep."""

    a: Rival
    b: Rival
    sigma: np.ndarray
    x0: np.ndarray
    dt: float = 0.01
    source: str = ""
    pitch: tuple = (-PITCH_LIMIT, PITCH_LIMIT)

    def value(self, u) -> float:
        """``D(u)`` [nats]; ``-inf`` when either simulation fails or leaves the envelope."""
        ya, ok_a = self.a.angles(jnp.asarray(u), self.dt, self.x0, self.pitch)
        yb, ok_b = self.b.angles(jnp.asarray(u), self.dt, self.x0, self.pitch)
        if not (ok_a and ok_b):
            return -np.inf
        return float(0.5 * np.sum(((ya - yb) / self.sigma) ** 2))

    @classmethod
    def from_discovery(cls, directory, *, sigma, x0, dt: float = 0.01) -> Rivals:
        """The two best-scored candidates of the first step of the discovery run in ``directory``
        (``discovery.json`` and ``candidates/*.json``).

        Raises
        ------
        DataFormatError
            A missing or unreadable file, or fewer than two fitted candidates.
        """
        directory = pathlib.Path(directory)
        path = directory / "discovery.json"
        try:
            ranked = json.loads(path.read_text(encoding="utf-8"))["candidates"]
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise DataFormatError(f"{path}: not a discovery result ({type(exc).__name__}: {exc})") from None
        try:  # failed or screened-out rows have no score
            names = [str(c["model"]) for c in ranked if c.get("step", 1) == 1 and c.get("score") is not None
                     and np.isfinite(float(c["score"]))]  # fmt: skip
        except (AttributeError, KeyError, TypeError, ValueError) as exc:
            raise DataFormatError(f"{path}: 'candidates' must be a list of objects with 'model' and a "
                                  f"numeric 'score' ({type(exc).__name__}: {exc})") from None
        if len(names) < 2:
            raise DataFormatError(f"{path}: expected at least two fitted candidates, found {len(names)}")
        rivals = [_rival(directory, name, dt) for name in names[:2]]
        return cls(rivals[0], rivals[1], np.asarray(sigma, float), np.asarray(x0, float), dt,
                   f"the two best candidates of {path}: {names[0]} and {names[1]}")


def _rival(directory: pathlib.Path, name: str, dt: float) -> Rival:
    path = directory / "candidates" / (name.replace(":", "-") + ".json")
    try:
        fitted = json.loads(path.read_text(encoding="utf-8"))["result"]["map"]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise DataFormatError(f"{path}: no fitted candidate {name!r} ({type(exc).__name__})") from None
    model = build_model([] if name == "base" else name.split("+"), where=str(path))
    params = {k: float(v) for k, v in fitted.items() if k not in X0_NAMES}
    params = {k: float(v) for k, v in model.complete(params, where=str(path)).items()}
    return Rival(name, model, params, default_substeps(model, params, dt, margin=2.0))
