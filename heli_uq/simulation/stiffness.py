"""How stiff a model is over a set of parameter draws, and the substeps that cover them.

The fixed-step RK4 solver (:mod:`heli_uq.simulation.solver`) is stable on a decaying mode of
rate ``r`` [1/s] while ``r h < RK4_STABILITY`` (``h`` the step), and accurate while ``r h``
stays below :data:`STABLE_STEP` (on the rig record, yaw friction
at ``r h`` = 1.05: 2.5e-5 rad from the adaptive reference; pitch friction at 1.19: 1.3e-7).
A friction term's rate at rest (``F_c / (omega_s M)``) varies over a posterior, so the
substeps must cover the draws, not only the MAP: a draw beyond the limit is simulated
wrongly (on the rig record, pitch friction at ``r h`` = 4.2 is 13 mrad from the adaptive
reference, four times the pitch noise) and nothing in the solve fails.  A viscous damping's
linear mode blows up past the limit, so such a draw is rejected, and inside it errs far
less (yaw damping at ``r h`` = 2.7: 1.3e-4 rad, a sixtieth of the yaw noise; 2e-5 at 1.4).
:func:`default_substeps` chooses one point's substeps (its damping included), capped at
:data:`MAX_SUBSTEPS` by :func:`capped_substeps`; :func:`substeps_covering` chooses them for
a set of draws (a Laplace approximation's, before sampling); :func:`stiffness_check` counts
the draws of a finished run beyond the limit.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping

import numpy as np

from heli_uq.model.heli_model import HeliModel

__all__ = ["RK4_STABILITY", "STABLE_STEP", "MAX_SUBSTEPS", "EDGE_FRACTION", "default_substeps",
           "capped_substeps", "count_text", "damping_edge", "edge_text", "stiffness_rates",
           "substeps_covering", "stiffness_check"]  # fmt: skip

#: RK4's stability limit on a decaying real mode: ``|r h|`` below 2.785.
RK4_STABILITY = 2.785

#: Most substeps a solve is given (:func:`heli_uq.inference.prepare_start`, ``simulate``,
#: synthetic records).  A model that needs more (friction far sharper than the rig's, or
#: absurd inertias) is left at this number, with a warning or a failed solve: such a stiff
#: mode is better smoothed (a larger ``omega_s``) than resolved.
MAX_SUBSTEPS = 16
#: ``rate * h`` at which :func:`default_substeps` places an RK4 step: half the stability
#: limit 2.785 of RK4 on a decaying mode, which keeps its settling error small.
STABLE_STEP = 1.4


#: A viscous decay this close to RK4's stability limit (``r h`` over this fraction of
#: :data:`RK4_STABILITY`) at a fit's substeps is pinned by the solver (:func:`damping_edge`).
EDGE_FRACTION = 0.9
#: What :func:`capped_substeps` suggests by default.
SMOOTHER_FRICTION = "for a sharp friction consider a smoother one (a larger omega_s)"


def count_text(need: int) -> str:
    """A substep count as a person reads it: exact up to a million, else ``2.9e+300``
    (the count of an absurd parameter value has hundreds of digits)."""
    return str(need) if need <= 1_000_000 else f"{float(need):.1e}"


def capped_substeps(need: int, what: str, hint: str = SMOOTHER_FRICTION, cap: int = MAX_SUBSTEPS) -> int:
    """``min(need, cap)``, with a warning naming ``what`` (e.g. ``"the MAP"``) and ending
    with ``hint`` when the cap (default :data:`MAX_SUBSTEPS`) is reached."""
    if need > cap:
        logging.getLogger(__name__).warning(
            f"{what} needs {count_text(need)} solver substeps per sample for its stiffest mode; using "
            f"{cap}{' (MAX_SUBSTEPS)' if cap == MAX_SUBSTEPS else ''}: the simulation may be "
            f"inaccurate or diverge; {hint}")  # fmt: skip
    return min(need, cap)


def damping_edge(model: HeliModel, params: Mapping, dt: float, substeps: int, *,
                 thetas=None) -> dict | None:  # fmt: skip
    """The viscous decay of a fit pinned at RK4's stability limit, or None.

    A model that lacks a torque the data hold (a pitch friction) can imitate it by
    damping: on a stiff record the likelihood then grows toward the overdamped limit
    (``D / M`` without bound, a first-order axis), and what stops the fit is the solver,
    whose linear mode blows up past ``r h = 2.785``.  Every raise of the substeps moves such
    a MAP to the new limit (measured on a 131 s record with a hidden pitch friction: the
    MAP needed 2, 4, 8, 16 and 32 substeps at 1, 2, 4, 8 and 16, its ``D_theta / M11``
    4455 /s, ``r h`` = 2.78 at 16).  Its values are then set by the solver, not the data.

    ``params``: the fit's values by name; ``dt`` [s]: the sample interval; ``substeps``:
    the solver's substeps per sample; ``thetas``: as for :func:`stiffness_rates`.

    Returns
    -------
    dict or None
        ``{"axis", "rate" [1/s], "rh", "substeps"}`` of the most damped axis when its
        ``rate * dt / substeps`` exceeds ``EDGE_FRACTION * RK4_STABILITY``; else None.
    """
    p = model.complete(params)
    rates: dict = {}
    with np.errstate(all="ignore"):  # an extreme value's x/0 gives a rate that is not an edge
        inertia = model.mechanics.inertia_bounds(p, thetas)
        for term in model.terms:  # decays on one axis add
            for axis, r in term.decay_rates(p, inertia).items():
                rates[axis] = rates.get(axis, 0.0) + float(r)
    if not rates:
        return None
    axis = max(rates, key=rates.get)
    rh = rates[axis] * float(dt) / substeps
    if not rh > EDGE_FRACTION * RK4_STABILITY:
        return None
    return {"axis": axis, "rate": rates[axis], "rh": rh, "substeps": int(substeps)}


def edge_text(edge: dict) -> str:
    """What :func:`damping_edge` found, as a sentence's clause a person reads."""
    return (f"the fit damps {edge['axis']} as hard as the solver allows (its viscous decay D/M = "
            f"{edge['rate']:.0f} /s, r h = {edge['rh']:.2f} at {edge['substeps']} substeps, RK4's limit "
            f"{RK4_STABILITY}): the data want an overdamped {edge['axis']}, a sign of a torque the "
            f"model lacks there (e.g. friction), and the fit's values are set by the solver, not the data")


def default_substeps(model: HeliModel, params: Mapping, dt: float, *, margin: float = 1.0,
                     thetas=None, decay: bool = True) -> int:  # fmt: skip
    """RK4 substeps per sample for ``model`` at ``params``: ``ceil(margin rate dt / 1.4)``.

    ``rate`` is the model's largest stiffness rate near rest (:meth:`HeliModel.stiffness`,
    e.g. ``F_c / (omega_s M22)`` for smoothed friction, with ``M22`` the smallest yaw
    inertia over the pitch angles ``thetas`` [rad], default all), the viscous damping's
    ``D / M`` included (one point), and 1.4 (:data:`STABLE_STEP`) is half RK4's stability
    limit on a decaying mode.  1 at the rig's parameters without stiff terms.  ``decay``
    False leaves the viscous damping out (the need of the other stiff terms).
    """
    rate = model.stiffness(model.complete(params), thetas, decay=decay)
    return max(1, math.ceil(margin * rate * float(dt) / STABLE_STEP))


def stiffness_rates(model: HeliModel, draws: Mapping, *, fixed: Mapping | None = None,
                    thetas=None, decay: bool = False) -> np.ndarray:  # fmt: skip
    """The model's stiffness rate (:meth:`HeliModel.stiffness`) [1/s] at each draw, shape (n,).

    ``draws``: ``{parameter name: array (n,)}``; names the model has and ``draws`` lacks
    take their value in ``fixed``, else the model's start value.  ``thetas``: pitch angles
    [rad] the yaw inertia is taken over.  ``decay``: the viscous damping's rate included.
    """
    base = {**model.start_values(), **{k: float(v) for k, v in (fixed or {}).items()}}
    columns = {k: np.ravel(np.asarray(draws[k], dtype=float)) for k in base if k in draws}
    return np.atleast_1d(model.stiffness({**base, **columns}, thetas, decay=decay))


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
