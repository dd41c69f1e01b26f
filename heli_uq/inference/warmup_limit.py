"""A NUTS warm-up sized to a time limit (:func:`heli_uq.inference.nuts.run_nuts`).

A run with a ``time_limit`` stops *sampling* when the limit passes, but a warm-up cannot
be stopped part way: numpyro fixes its adaptation windows from its length.  On a stiff
model a 1000-iteration warm-up with dense mass-matrix adaptation alone can take longer
than the whole limit (43 min of a 60 min discovery budget on a yaw friction record).  So
the run times its first warm-up iterations, and when the requested warm-up and the fewest
draws it keeps would not fit in the time left, it starts the warm-up again from the
chains' current positions with fewer iterations that do, adapting the step size only:
the metric stays the level-scaled Laplace covariance (a dense estimate from a few dozen
draws is worse than that metric; the quick discovery refit samples stiff friction
models with it after 150 iterations).  The iterations that fit are shared between warm-up
and draws in the requested proportion.
"""

from __future__ import annotations

import math

__all__ = ["PACE_ITERATIONS", "MIN_WARMUP_AT_LIMIT", "sized_warmup"]

#: Warm-up iterations, after the first block (which compiles), timed to measure the pace.
PACE_ITERATIONS = 10
#: Shortest warm-up a time limit cuts to (and a requested warm-up this short is never
#: cut): the quick discovery budget's, with which its refits of stiff friction models
#: adapt their step size.
MIN_WARMUP_AT_LIMIT = 150


def sized_warmup(warmup: int, draws: int, done: int, pace: float, seconds_left: float,
                 restart_seconds: float, min_draws: int) -> int | None:  # fmt: skip
    """The warm-up length to start again with, or None to keep the requested one.

    The iterations that fit in the time left after the restart are shared between the
    warm-up and the draws in the requested proportion (a shorter run of the same shape):
    a warm-up that adapts the step size alone needs no more, and every iteration it does
    not take is a draw.  The warm-up keeps at least :data:`MIN_WARMUP_AT_LIMIT` and leaves
    at least ``min_draws`` when both fit.

    Parameters
    ----------
    warmup, draws : int
        Requested warm-up iterations and draws per chain.
    done : int
        Warm-up iterations already made (lost if the warm-up starts again).
    pace : float
        Measured wall seconds per iteration (all chains).
    seconds_left : float
        Wall seconds until the time limit.
    restart_seconds : float
        Cost of starting again [s] (compiling the new warm-up's step).
    min_draws : int
        Fewest draws per chain the run keeps at its limit.

    Returns
    -------
    int or None
        None when the rest of the requested warm-up and ``min_draws`` fit in
        ``seconds_left``, or the requested warm-up is no longer than
        :data:`MIN_WARMUP_AT_LIMIT`; else the warm-up after the restart, at least
        :data:`MIN_WARMUP_AT_LIMIT` (if even that and ``min_draws`` do not fit, the
        limit will be passed).
    """
    if warmup <= MIN_WARMUP_AT_LIMIT or pace * (warmup - done + min_draws) <= seconds_left:
        return None
    fits = math.floor((seconds_left - restart_seconds) / pace)
    share = min(math.floor(fits * warmup / (warmup + draws)), fits - min_draws)
    return int(min(max(share, MIN_WARMUP_AT_LIMIT), warmup - 1))
