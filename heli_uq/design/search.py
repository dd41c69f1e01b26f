"""The search for the best staircase: random staircases, then a seeded hill climb from the best.

The random phase doubles as the baseline "random staircases of the same length"; the hill
climb proposes :func:`~heli_uq.design.staircase.mutate` neighbours and keeps any that
raises the criterion.  Infeasible inputs (a failed or unphysical simulation) score
``-inf`` and are never kept.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable

import numpy as np

from heli_uq.design.staircase import Staircase, StaircaseBounds, mutate, random_staircase
from heli_uq.errors import ParameterError
from heli_uq.log import progress_log

__all__ = ["SearchBudget", "SEARCH_BUDGETS", "SearchResult", "search_staircase"]


@dataclasses.dataclass(frozen=True)
class SearchBudget:
    """Effort of :func:`search_staircase`: random staircases, hill-climb proposals and the
    number of posterior draws the criterion averages over."""

    random: int
    climb: int
    draws: int


#: ``quick``: a minute or two for 60 s on this 2-core machine; ``full``: about ten times that.
SEARCH_BUDGETS = {"quick": SearchBudget(random=24, climb=60, draws=2),
                  "full": SearchBudget(random=100, climb=500, draws=8)}  # fmt: skip


@dataclasses.dataclass(frozen=True)
class SearchResult:
    """The best staircase and the search's record.

    ``random_values`` (R,) are the criterion of the random phase's staircases (the
    baseline), ``trace`` the best value after each evaluation, ``accepted`` the number of
    hill-climb moves kept, ``seconds`` the wall time.
    """

    best: Staircase
    value: float
    random_values: np.ndarray
    trace: np.ndarray
    accepted: int
    seconds: float


def search_staircase(criterion: Callable[[np.ndarray], float], bounds: StaircaseBounds, *,
                     budget: SearchBudget, seed: int = 0,
                     log: Callable[[str], None] | None = None) -> SearchResult:  # fmt: skip
    """Maximise ``criterion(u)`` (u of shape (N, 2) [V]) over staircases within ``bounds``.

    Raises
    ------
    ParameterError
        When every random staircase is infeasible (the criterion is ``-inf`` for all).
    """
    t0 = time.perf_counter()
    log = progress_log(log, __name__)
    rng = np.random.default_rng(seed)
    best, value, randoms, trace = None, -np.inf, [], []
    for i in range(budget.random):
        stairs = random_staircase(bounds, rng)
        v = criterion(stairs.inputs())
        randoms.append(v)
        if v > value:
            best, value = stairs, v
        trace.append(value)
        log(f"random staircase {i + 1}/{budget.random}: {v:.4g} (best {value:.4g})")
    if best is None:
        raise ParameterError(f"design: all {budget.random} random staircases are infeasible "
                             "(the simulation fails or pitch leaves its envelope); narrow the "
                             "voltage ranges or widen --pitch")  # fmt: skip
    accepted = 0
    for i in range(budget.climb):
        stairs = mutate(best, bounds, rng)
        v = criterion(stairs.inputs())
        if v > value:
            best, value, accepted = stairs, v, accepted + 1
        trace.append(value)
        if (i + 1) % 10 == 0 or i + 1 == budget.climb:
            log(f"hill climb {i + 1}/{budget.climb}: best {value:.4g} ({accepted} moves kept)")
    best.check(bounds)
    return SearchResult(best, float(value), np.asarray(randoms), np.asarray(trace), accepted,
                        time.perf_counter() - t0)  # fmt: skip
