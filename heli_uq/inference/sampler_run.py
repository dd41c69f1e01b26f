"""The raw result every sampler returns (NUTS, emcee, Laplace draws), before it becomes
InferenceData (:func:`heli_uq.output.to_inference_data`)."""

from __future__ import annotations

import dataclasses

from heli_uq.probability.problem import Problem

__all__ = ["SamplerRun"]


@dataclasses.dataclass
class SamplerRun:
    """Raw result of a sampler.

    ``samples``: dict of constrained draws (chain, draw, ...) by site name (physical
    parameters, initial state, error model, coordinates ``z``); ``stats``: dict of per-draw
    statistics (chain, draw); ``info``: sampler facts (wall time, MAP value, step size...);
    ``problem``: the problem sampled (with the substeps the MAP chose).
    """

    samples: dict
    stats: dict
    info: dict
    problem: Problem
