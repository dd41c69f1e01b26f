"""How much memory the kept draws of a sampler need, checked before it starts."""

from __future__ import annotations

from heli_uq.io import require_memory
from heli_uq.probability.problem import Problem

__all__ = ["check_draws_memory", "DRAW_COPIES", "DRAW_EXTRA_VALUES"]

#: Copies of every kept draw held at once (sampler coordinates, whitened ones, constrained
#: sites, the InferenceData), each of ``dim + DRAW_EXTRA_VALUES`` float64 values.
DRAW_COPIES = 4
DRAW_EXTRA_VALUES = 16


def check_draws_memory(problem: Problem, n_draws: int, what: str) -> None:
    """Refuse up front ``n_draws`` kept draws (all chains) that would not fit in memory.

    ``what`` names the request, starting with the argument (``"draws: 4 chains x 1e9"``).

    Raises
    ------
    ParameterError
        With the memory the draws would need.
    """
    per_draw = DRAW_COPIES * 8 * (problem.coords.dim + DRAW_EXTRA_VALUES)
    require_memory(float(n_draws) * per_draw, what, "ask for fewer draws or chains")
