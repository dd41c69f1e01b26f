"""Settling a MAP held at the solver's limit: refits from its own MAP.

A fit whose viscous decay sits at RK4's stability limit is held at a fixed substep count
(:func:`heli_uq.inference.substeps.map_need`), and its MAP is then a boundary point: Newton's
steps past the limit are rejected, so it stops short with a large decrement.  Fitting it
again from its own MAP (least squares, then Newton, ``prepare_start(..., from_fit=True)``)
moves it along the limit to a better point, as often as that helps.

Layer 5 (imports :mod:`heli_uq.inference.start`).
"""

from __future__ import annotations

from heli_uq.inference.start import Start, prepare_start

__all__ = ["EDGE_DECREMENT", "EDGE_PASSES", "settle_edge"]

#: A fit held at the solver's limit (``Start.solver_edge``) is refitted from its own MAP
#: while its Newton decrement exceeds this [nats], at most :data:`EDGE_PASSES` times.  On a
#: 131 s record hiding a pitch friction the base model held at 2 substeps ended at
#: ``-log p`` = -63583 with a decrement of 355 nats; passes gave -64014 (66), -64106 (2.0),
#: -64111 (0.02), 17-19 s each.  Left at -63583, every wrong discovery candidate nesting it
#: (fitted from it by least squares) beat it by 200-480 nats on the fitting window and
#: 1400-2200 held out, all above the margin.
EDGE_DECREMENT = 10.0
EDGE_PASSES = 3


def settle_edge(start: Start, *, seed: int = 0, newton_steps: int | None = None, log=None) -> Start:
    """``start``, or, if it is held at the solver's limit short of convergence
    (:data:`EDGE_DECREMENT`), its refit from its own MAP on its own problem (same substeps),
    repeated while that improves ``-log p``, at most :data:`EDGE_PASSES` times.

    Parameters
    ----------
    start : Start
        A finished MAP (:func:`~heli_uq.inference.start.prepare_start`).
    seed, newton_steps
        Passed to :func:`~heli_uq.inference.start.prepare_start`.
    log : callable, optional
        Called with one line per refit.

    Returns
    -------
    Start
        The best of ``start`` and its refits.
    """
    for _ in range(EDGE_PASSES):
        if start.solver_edge is None or not start.map_decrement > EDGE_DECREMENT:
            break
        again = prepare_start(start.problem, n_starts=1, seed=seed, guesses=(start.map_guess(),), grid=False,
                              newton_steps=newton_steps, polish_best=1, from_fit=True)  # fmt: skip
        if log is not None:
            log(f"MAP held at the solver's limit (Newton decrement {start.map_decrement:.3g}): refitted "
                f"from itself, -log p {start.map_value:.6g} -> {again.map_value:.6g}")  # fmt: skip
        if not again.map_value < start.map_value:
            break
        start = again
    return start
