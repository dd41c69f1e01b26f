"""The effort of a discovery run: :class:`Budget` and the two presets, ``quick`` and ``full``."""

from __future__ import annotations

import dataclasses

__all__ = ["Budget", "BUDGETS", "label"]


@dataclasses.dataclass(frozen=True)
class Budget:
    """Effort of a discovery run.

    ``n_starts``: MAP starts of the base model after the one from the shipped rig fit;
    ``cold_starts``: starts of a candidate beyond its warm ones
    (:func:`~heli_uq.discovery.candidates.warm_starts`); ``draws``: Laplace draws per
    candidate; ``pair_top``: how many of the best singles are paired with each other;
    ``pair_anchors``: how many of the best are paired with every other supported single
    (:func:`~heli_uq.discovery.decide.pairs_to_fit`); ``chains, warmup,
    samples``: the NUTS refit; ``nuts_before``: the base model gets a NUTS posterior too
    (else its Laplace approximation is *before*); ``newton_steps``: of each MAP polish;
    ``max_tree_depth``: of the NUTS refit (a stiff friction model can otherwise spend 2^8
    leapfrog steps per draw); ``adapt_mass_matrix``: the refit adapts a dense mass matrix in
    whitened coordinates (``False``, quick: the level-scaled Laplace covariance stays the metric);
    ``minutes``: the whole run's time target: a NUTS posterior still sampling when it would
    be exceeded stops with the draws made (at least
    :data:`~heli_uq.inference.nuts.MIN_DRAWS_AT_LIMIT` per chain), and one whose warm-up
    would leave no time for those is cut (:mod:`heli_uq.inference.warmup_limit`); the
    summary's health notes say so; ``None``: every draw is made.  Quick: 10 min, which
    only a stiff friction refit reaches (2026-11-28, pitch friction F_c = 0.005 N m on the
    published profile, alone on the 2 cores: the candidates took 5.5 min, the refit stopped
    at 102 of 350 draws per chain, 9.8 min in all; F_c's 95 % interval [0.0031, 0.0432]
    against [0.0032, 0.0431] with every draw made in 14.1 min).
    ``max_samples``: the NUTS runs go on past ``samples`` draws per chain, a chunk at a
    time, while R-hat or ESS fail their checks, up to this many (and the time target);
    ``None``: exactly ``samples``.  Quick: 2000, since most refits end far inside the
    target and 2 x 350 draws of a model with an initial rate on a ridge failed the ESS
    check on every record (bulk ESS 15-399, 2026-11-28).
    ``screen``: candidates that act only on axes where the base model's residuals are
    white are not fitted (:mod:`heli_uq.discovery.screen`); ``False`` fits every one.
    """

    n_starts: int
    cold_starts: int
    draws: int
    pair_top: int
    chains: int
    warmup: int
    samples: int
    nuts_before: bool = False
    newton_steps: int = 4
    max_tree_depth: int = 8
    adapt_mass_matrix: bool = True
    minutes: float | None = None
    max_samples: int | None = None
    pair_anchors: int = 0
    screen: bool = True


BUDGETS = {"quick": Budget(n_starts=2, cold_starts=0, draws=64, pair_top=3, chains=2, warmup=150,
                           samples=350, max_tree_depth=6, adapt_mass_matrix=False, minutes=10.0,
                           max_samples=2000, pair_anchors=2),
           "full": Budget(n_starts=4, cold_starts=1, draws=200, pair_top=4, chains=4, warmup=1000,
                          samples=1000, nuts_before=True, newton_steps=10, minutes=60.0,
                          pair_anchors=2)}


def label(budget: Budget | str) -> str:
    """A budget as a person reads it: a preset's name, or the nearest preset's name and the
    settings that differ from it (``"quick, cold_starts=1"``)."""
    if isinstance(budget, str):
        return budget

    def differ(preset: Budget) -> list[str]:
        names = [f.name for f in dataclasses.fields(budget)]
        return [n for n in names if getattr(budget, n) != getattr(preset, n)]

    name, preset = min(BUDGETS.items(), key=lambda item: len(differ(item[1])))
    return ", ".join([name] + [f"{f}={getattr(budget, f)}" for f in differ(preset)])
