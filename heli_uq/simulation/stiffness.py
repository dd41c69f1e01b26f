"""How stiff a model is over a set of parameter draws, and the substeps that cover them.

The fixed-step RK4 solver (:mod:`heli_uq.simulation.solver`) is stable on a decaying mode of
rate ``r`` [1/s] while ``r h < RK4_STABILITY`` (``h`` the step), and accurate while ``r h``
stays below :data:`~heli_uq.simulation.solver.STABLE_STEP` (on the rig record, yaw friction
at ``r h`` = 1.05: 2.5e-5 rad from the adaptive reference; pitch friction at 1.19: 1.3e-7).
A friction term's rate at rest (``F_c / (omega_s M)``) varies over a posterior, so the
substeps must cover the draws, not only the MAP: a draw beyond the limit is simulated
wrongly (on the rig record, pitch friction at ``r h`` = 4.2 is 13 mrad from the adaptive
reference, four times the pitch noise) and nothing in the solve fails.
:func:`substeps_covering` chooses the substeps for a set of draws (a Laplace
approximation's, before sampling); :func:`stiffness_check` counts the draws of a finished
run beyond the limit.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from heli_uq.model.heli_model import HeliModel
from heli_uq.simulation.solver import STABLE_STEP

__all__ = ["RK4_STABILITY", "stiffness_rates", "substeps_covering", "stiffness_check"]

#: RK4's stability limit on a decaying real mode: ``|r h|`` below 2.785.
RK4_STABILITY = 2.785


def stiffness_rates(model: HeliModel, draws: Mapping, *, fixed: Mapping | None = None,
                    thetas=None) -> np.ndarray:  # fmt: skip
    """The model's stiffness rate (:meth:`HeliModel.stiffness`) [1/s] at each draw, shape (n,).

    ``draws``: ``{parameter name: array (n,)}``; names the model has and ``draws`` lacks
    take their value in ``fixed``, else the model's start value.  ``thetas``: pitch angles
    [rad] the yaw inertia is taken over.
    """
    base = {**model.start_values(), **{k: float(v) for k, v in (fixed or {}).items()}}
    columns = {k: np.ravel(np.asarray(draws[k], dtype=float)) for k in base if k in draws}
    return np.atleast_1d(model.stiffness({**base, **columns}, thetas))


def substeps_covering(rates, dt: float) -> int:
    """Fewest substeps per sample of ``dt`` [s] with ``max(rates) h <= STABLE_STEP``
    (1 for a model without stiff terms)."""
    rate = float(np.max(rates)) if np.size(rates) else 0.0
    return max(1, math.ceil(rate * float(dt) / STABLE_STEP))


def stiffness_check(model: HeliModel, draws: Mapping, substeps: int, dt: float, *,
                    fixed: Mapping | None = None, thetas=None) -> dict | None:  # fmt: skip
    """Stiffness of a run's draws against its solver: ``{rate_max [1/s], rate_limit [1/s]
    (RK4's stability limit at these substeps), beyond (draws past it), of (draws),
    stiffest (index of the stiffest draw)}``; None for a model without stiff terms.
    ``draws``, ``fixed``, ``thetas``: as for :func:`stiffness_rates`."""
    rates = stiffness_rates(model, draws, fixed=fixed, thetas=thetas)
    if not np.any(rates > 0.0):
        return None
    limit = RK4_STABILITY * substeps / float(dt)
    return {"rate_max": float(np.max(rates)), "rate_limit": float(limit),
            "beyond": int(np.sum(rates > limit)), "of": int(rates.size),
            "stiffest": int(np.argmax(rates))}  # fmt: skip
