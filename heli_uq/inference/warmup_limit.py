"""A NUTS warm-up sized to a time limit (:func:`heli_uq.inference.nuts.run_nuts`).

A run with a ``time_limit`` stops *sampling* when the limit passes, but a warm-up cannot
be stopped part way: numpyro fixes its adaptation windows from its length.  On a stiff
model a 1000-iteration warm-up with dense mass-matrix adaptation alone can take longer
than the whole limit (43 min of a 60 min discovery budget on a yaw friction record).  So
the run times its warm-up iterations (:class:`PaceMeter`), and when the requested run
would not fit in the time left, it starts the warm-up again from the chains' current
positions with fewer iterations, adapting the step size only (decided when the pace is
first measured, and again whenever a kept warm-up, at its latest pace, would no longer
leave time for the fewest draws: dense mass-matrix adaptation can slow the later
warm-up):
the metric stays the level-scaled Laplace covariance (a dense estimate from a few dozen
draws is worse than that metric; the quick discovery refit samples stiff friction
models with it after 150 iterations).  The iterations that fit are shared between warm-up
and draws in the requested proportion, when that gives the draws enough more
(:func:`sized_warmup`).
"""

from __future__ import annotations

import math

__all__ = ["PACE_SKIP", "PACE_ITERATIONS", "MIN_WARMUP_AT_LIMIT", "DRAW_GAIN", "PaceMeter", "sized_warmup"]

#: Warm-up iterations after the first block (which compiles) that are not timed: while
#: the step size settles the trees are longer.  Timed from the first block on, a yaw
#: friction run on the rig record measured 0.76 s per iteration where its warm-up then
#: averaged 0.35 s and its draws 0.31 s (2026-11-28), and cut the warm-up to the floor.
PACE_SKIP = 10
#: Warm-up iterations timed after those to measure the pace.
PACE_ITERATIONS = 20
#: Shortest warm-up a time limit cuts to (and a requested warm-up this short is never
#: cut): the quick discovery budget's, with which its refits of stiff friction models
#: adapt their step size.
MIN_WARMUP_AT_LIMIT = 150


class PaceMeter:
    """Wall seconds per warm-up iteration over the latest :data:`PACE_ITERATIONS` or more
    iterations, from iteration ``first + PACE_SKIP`` on (``first``: the iterations of the
    compiling block)."""

    def __init__(self, first: int):
        self.first = first
        self.marks: list[tuple[int, float]] = []

    def update(self, iterations: int, seconds: float) -> float | None:
        """Record the warm-up's progress after a block (``iterations`` made, ``seconds`` of
        wall time so far); returns the pace over the shortest span of at least
        :data:`PACE_ITERATIONS` that ends here, or None while fewer are timed."""
        if iterations < self.first + PACE_SKIP:
            return None
        self.marks.append((iterations, seconds))
        start = [m for m in self.marks if iterations - m[0] >= PACE_ITERATIONS]
        if not start:
            return None
        it0, s0 = start[-1]
        self.marks = self.marks[self.marks.index(start[-1]):]
        return (seconds - s0) / (iterations - it0)


#: A cut must give at least this many times the draws the uncut run would make in the
#: time left (when that run makes its fewest draws at all): the requested warm-up adapts a
#: dense mass matrix, which a few more draws do not outweigh.
DRAW_GAIN = 1.5


def sized_warmup(warmup: int, draws: int, done: int, pace: float, seconds_left: float,
                 restart_seconds: float, min_draws: int) -> int | None:  # fmt: skip
    """The warm-up length to start again with, or None to keep the requested one.

    When the requested run does not fit, the iterations that fit in the time left after the
    restart are shared between the warm-up and the draws in the requested proportion (a
    shorter run of the same shape): a warm-up that adapts the step size alone needs no
    more, and every iteration it does not take is a draw.  The warm-up keeps at least
    :data:`MIN_WARMUP_AT_LIMIT` and leaves at least ``min_draws`` when both fit.  The
    requested warm-up is kept if the uncut run still makes ``min_draws`` and the cut would
    not give :data:`DRAW_GAIN` times its draws, or if the cut warm-up is no shorter than
    the rest of the requested one.  (Until 2026-11-28 it was kept whenever
    the uncut run made ``min_draws``: on the rig record a 5 min run then spent 1000
    warm-up iterations and kept 108 draws per chain, bulk ESS 141.)

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
        None when the rest of the requested run fits in ``seconds_left``, the requested
        warm-up is no longer than :data:`MIN_WARMUP_AT_LIMIT`, or the cut does not pay
        (above); else the warm-up after the restart, at least :data:`MIN_WARMUP_AT_LIMIT`
        (if even that and ``min_draws`` do not fit, the limit will be passed).
    """
    uncut = math.floor(seconds_left / pace) - (warmup - done)  # draws the uncut run makes
    if warmup <= MIN_WARMUP_AT_LIMIT or uncut >= draws:
        return None
    fits = math.floor((seconds_left - restart_seconds) / pace)
    share = min(math.floor(fits * warmup / (warmup + draws)), fits - min_draws)
    cut = int(min(max(share, MIN_WARMUP_AT_LIMIT), warmup - 1))
    if uncut >= min_draws and fits - cut < DRAW_GAIN * uncut:
        return None
    return cut if cut < warmup - done else None  # else finishing costs less than starting again
