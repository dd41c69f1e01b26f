"""Out-of-sample predictive scores by blocks, their comparison, and the gap metrics.

**Score.**  The log predictive density of the held-out angles under a model's posterior
(predictive draws ``s = 1..S`` of the simulated angles with iid Gaussian errors of scale
``sigma_s``), pointwise and summed over *blocks*:

    ``lpd_t = log (1/S) sum_s prod_j N(y_tj | sim_stj, sigma_sj)``,   ``score_b = sum_{t in b} lpd_t``.

Blocks are the input segments of the held-out window (runs of constant voltages, at
least :data:`MIN_BLOCK_S` long): residuals of a free-running simulation are correlated
over seconds, so single samples are not independent evidence, segments nearly are.  A
window with fewer than :data:`MIN_BLOCKS` segments is cut into :data:`MIN_BLOCKS` equal
blocks instead (a standard error needs several).

**Comparison.**  Between a candidate and the base on the same blocks, ``d_b = score_b -
base_b``; the difference is ``sum d_b`` with standard error ``sqrt(B) sd(d_b)`` (as for
the elpd differences of ``arviz.compare``, with blocks in place of points).

**CRPS** (:func:`block_crps`).  The continuous ranked
probability score of the predictive draws with errors, ``E|X - y| - E|X - X'| / 2`` per
sample and angle [rad] (the fair ensemble estimator, ``scoringrules.crps_ensemble``), summed
per block over both angles; lower is better.  Both are proper scores; they differ in the
tails.  The log density charges a miss by its square in units of the band, the CRPS by
its size in radians, so a model whose mean is much closer but whose band is too narrow
for its remaining misses loses on the log density and wins on the CRPS.  On the rig
record (fitted on 0-91 s, scored on 91-131 s), yaw friction + offset scores -21761 +-
13997 nats against the base, and beats it by 0.25 rad of CRPS per sample (2.8 SE).
Both are reported; one decides (:class:`Criterion`, ``discover(score=...)``): the log
density by default (:data:`LOG_DENSITY`), whose margin is :data:`MARGIN_PER_SAMPLE`
nats per held-out sample, or the CRPS (:data:`CRPS`), whose margin is
:data:`MARGIN_CRPS_FRACTION` of the current model's held-out CRPS (a fraction, because
the CRPS is in radians and scales with the noise).  Both margins are calibrated on null
records (``studies/discovery_confusion.py``).

**Gap metrics** of a predictive ensemble on a window: RMSE of the mean simulation per
angle [rad], the paper's loss ``V`` of the mean simulation [rad^2] and the coverage of the
central 90 % predictive band.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scoringrules
from scipy.special import logsumexp

from heli_uq.output import predictive_metrics

__all__ = ["input_blocks", "block_scores", "block_crps", "compare", "passes", "gap_metrics", "gap_text",
           "gain_text", "Criterion", "LOG_DENSITY", "CRPS", "CRITERIA", "MIN_BLOCK_S", "MIN_BLOCKS",
           "GAP_KEYS", "MARGIN_SE", "MARGIN_PER_SAMPLE", "MARGIN_CRPS_FRACTION"]  # fmt: skip

#: Shortest block [s]: shorter input segments are merged into the one before.
MIN_BLOCK_S = 2.0
#: Fewest blocks of a held-out window.
MIN_BLOCKS = 4
#: A model beats another if its score difference exceeds this many standard errors ...
MARGIN_SE = 2.0
#: ... and this many nats per held-out sample, calibrated on the confusion study's records
#: (``studies/discovery_confusion.py``): on 37 records without a hidden effect the best
#: candidate scored at most 0.0051 nats per held-out sample; the weakest hidden effect that
#: the base model could not absorb scored 0.0155 (a pitch quadratic thrust, 3.2 SE, which
#: the earlier margin of 0.02 called ``none``).  The margin is near their geometric mean
#: (the CRPS margin's rule).
MARGIN_PER_SAMPLE = 0.009
#: The CRPS's margin: a model beats another if its held-out CRPS is lower by this fraction
#: of the other's (and by 2 SE).  On eight null records the largest gain of any candidate
#: was 0.36 %; the smallest of four hidden effects 0.95 %; the margin is near their
#: geometric mean (``studies/notes/discovery.md#a-crps-margin-from-null-records``).
MARGIN_CRPS_FRACTION = 0.006
#: Keys of a gap-metrics record (``discovery.json``).
GAP_KEYS = ("rmse_theta", "rmse_psi", "V", "coverage90_theta", "coverage90_psi")


def input_blocks(u: np.ndarray, dt: float, *, min_block_s: float = MIN_BLOCK_S,
                 min_blocks: int = 1) -> list[tuple[int, int]]:  # fmt: skip
    """``(start, stop)`` sample ranges of the input segments of ``u`` (N, 2) [V], runs of
    constant voltages, each at least ``min_block_s`` long (shorter runs join the previous
    block; a short first run joins the next).  Fewer than ``min_blocks`` segments: that
    many equal blocks instead."""
    u = np.asarray(u)
    edges = [0] + [i for i in range(1, len(u)) if np.any(u[i] != u[i - 1])] + [len(u)]
    min_n = max(1, int(round(min_block_s / dt)))
    blocks = []
    for a, b in zip(edges[:-1], edges[1:]):
        if blocks and (b - a < min_n or blocks[-1][1] - blocks[-1][0] < min_n):
            blocks[-1] = (blocks[-1][0], b)
        else:
            blocks.append((a, b))
    if len(blocks) > 1 and blocks[-1][1] - blocks[-1][0] < min_n:
        last = blocks.pop()
        blocks[-1] = (blocks[-1][0], last[1])
    if len(blocks) < min_blocks:
        edges = np.linspace(0, len(u), min_blocks + 1).round().astype(int)
        blocks = [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])]
    return blocks


def block_scores(y_sim: np.ndarray, sigma: np.ndarray, y_obs: np.ndarray, blocks) -> np.ndarray:
    """Log predictive density summed per block (module docstring), shape (B,) [nats].

    Parameters
    ----------
    y_sim : array, shape (S, N, 2)
        Simulated angles [rad] of S draws (NaN where a draw's solve failed).
    sigma : array, shape (S, 2)
        Each draw's error scale [rad] of (theta, psi).
    y_obs : array, shape (N, 2)
    blocks : list of (start, stop)
    """
    y_sim = np.asarray(y_sim, dtype=float)
    sigma = np.asarray(sigma, dtype=float)[:, None, :]
    z = (np.asarray(y_obs, dtype=float)[None] - y_sim) / sigma
    ll = (-0.5 * z**2 - np.log(sigma) - 0.5 * np.log(2 * np.pi)).sum(axis=2)  # (S, N)
    ll = np.where(np.isfinite(ll), ll, -np.inf)
    lpd = logsumexp(ll, axis=0) - np.log(ll.shape[0])
    return np.asarray([lpd[a:b].sum() for a, b in blocks])


def block_crps(y_pred: np.ndarray, y_obs: np.ndarray, blocks) -> np.ndarray:
    """CRPS summed per block over its samples and both angles (module docstring), shape
    (B,) [rad]; lower is better.

    Parameters
    ----------
    y_pred : array, shape (S, N, 2)
        Predictive draws of the measured angles [rad] (simulations with errors).  Draws
        whose solve failed anywhere in the window (NaN) are left out; with fewer than two
        left, every block is NaN (not scored).
    y_obs : array, shape (N, 2)
    blocks : list of (start, stop)
    """
    y_pred = np.asarray(y_pred, dtype=float)
    ok = np.all(np.isfinite(y_pred), axis=(1, 2))
    if ok.sum() < 2:
        return np.full(len(blocks), np.nan)
    # the probability-weighted-moment form equals the fair estimator (Zamo & Naveau 2018) in
    # O(S log S) per sample; the pairwise "fair" form held S x S differences (1.3 GB, 3.4 s
    # for 100 draws of 4000 samples, against 19 MB and 0.05 s)
    crps = scoringrules.crps_ensemble(np.asarray(y_obs, dtype=float), y_pred[ok], m_axis=0,
                                      estimator="pwm")  # (N, 2)  # fmt: skip
    return np.asarray([crps[a:b].sum() for a, b in blocks])


def compare(scores: np.ndarray, base: np.ndarray) -> tuple[float, float]:
    """``(sum d_b, sqrt(B) sd(d_b))`` of ``d = scores - base`` (module docstring) [nats]."""
    d = np.asarray(scores, dtype=float) - np.asarray(base, dtype=float)
    if not np.all(np.isfinite(d)):
        return -np.inf, np.inf
    se = float(np.sqrt(d.size) * np.std(d, ddof=1)) if d.size > 1 else float("inf")
    return float(d.sum()), se


def passes(scores, base, n_scored: int, *, margin: float | None = None) -> bool:
    """Whether block ``scores`` beat ``base`` over ``n_scored`` held-out samples (higher
    is better).

    The difference must exceed ``margin`` (default :data:`MARGIN_PER_SAMPLE` nats per
    sample), and be significant: more than :data:`MARGIN_SE` standard errors, *or* no
    block favouring the other model by more than its share of the margin (``B >=
    MIN_BLOCKS`` blocks).  The second form matters when a model's error grows over the
    window (a drifting simulation): the block differences then grow from about 0 right
    after the fitting window to large values at its end, and their spread inflates the
    standard error although every block tells the same story.
    """
    margin = MARGIN_PER_SAMPLE * n_scored if margin is None else margin
    diff, se = compare(scores, base)
    d = np.asarray(scores, dtype=float) - np.asarray(base, dtype=float)
    tolerance = margin / max(d.size, 1)  # per block, of mean length
    consistent = d.size >= MIN_BLOCKS and bool(np.all(d > -tolerance))
    significant = diff > MARGIN_SE * se or consistent
    return bool(np.isfinite(diff) and diff > margin and significant)


@dataclasses.dataclass(frozen=True)
class Criterion:
    """The held-out score that decides between models, and its calibrated margin.

    Attributes
    ----------
    name : str
        ``"log"`` or ``"crps"`` (``heli-uq discover --score``).
    key : str
        The result's per-block values (``block_scores`` [nats] or ``block_crps`` [rad]).
    sign : float
        +1 if higher is better, -1 if lower is.
    unit : str
    rank_key : str
        The field of a :func:`~heli_uq.discovery.decide.rank` row it orders by
        (``score`` [nats] or ``crps_gain`` [rad]).
    margin_per_sample : float, optional
        The margin per held-out sample [:attr:`unit`] ...
    margin_fraction : float, optional
        ... or as a fraction of the reference's summed block values (one of the two).
    """

    name: str
    key: str
    sign: float
    unit: str
    rank_key: str
    margin_per_sample: float | None = None
    margin_fraction: float | None = None

    def values(self, result: dict) -> np.ndarray:
        """The result's per-block values, higher better, shape (B,); ``[nan]`` if not
        stored (a fit made before the CRPS was kept: it never passes)."""
        return self.sign * np.asarray(result.get(self.key, [np.nan]), dtype=float)

    def margin(self, reference: dict, n_scored: int) -> float:
        """The margin a model must beat ``reference`` by, over the held-out window."""
        if self.margin_fraction is None:
            return self.margin_per_sample * n_scored
        return self.margin_fraction * float(np.sum(reference.get(self.key, np.nan)))

    def gain(self, result: dict, reference: dict) -> tuple[float, float]:
        """``(difference, SE)`` of ``result`` over ``reference`` (:func:`compare`, positive
        is better) in :attr:`unit`."""
        return compare(self.values(result), self.values(reference))

    def passes(self, result: dict, reference: dict, n_scored: int) -> bool:
        """Whether ``result`` beats ``reference`` by the margin (:func:`passes`)."""
        return passes(self.values(result), self.values(reference), n_scored,
                      margin=self.margin(reference, n_scored))  # fmt: skip


#: The held-out log predictive density decides (the default).
LOG_DENSITY = Criterion("log", "block_scores", 1.0, "nats", "score", margin_per_sample=MARGIN_PER_SAMPLE)
#: The held-out CRPS decides: robust to a band too narrow for a few misses (module docstring).
CRPS = Criterion("crps", "block_crps", -1.0, "rad", "crps_gain", margin_fraction=MARGIN_CRPS_FRACTION)
#: The criteria by name.
CRITERIA = {c.name: c for c in (LOG_DENSITY, CRPS)}


def gap_metrics(y_sim: np.ndarray, y_pred: np.ndarray, y_obs: np.ndarray) -> dict:
    """``{rmse_theta, rmse_psi, V, coverage90_theta, coverage90_psi}`` of predictive draws
    ``y_sim`` (S, N, 2) (simulations) and ``y_pred`` (S, N, 2) (with errors) on ``y_obs``
    (:func:`heli_uq.output.predictive_metrics`, flattened)."""
    m = predictive_metrics(y_sim, y_pred, y_obs)
    return {"rmse_theta": m["rmse"]["theta"], "rmse_psi": m["rmse"]["psi"], "V": m["loss_v"],
            "coverage90_theta": m["coverage90"]["theta"], "coverage90_psi": m["coverage90"]["psi"]}


def gap_text(gap: dict, after: dict | None = None, *, coverage: bool = True) -> str:
    """Both axes' RMSE (and 90 % coverage) of a gap record (:func:`gap_metrics`), or
    ``gap -> after`` for two, e.g. ``"RMSE pitch 0.008 -> 0.003, yaw 0.008 -> 0.008 rad,
    90 % coverage pitch 96% -> 89%, yaw 87% -> 89%"``.  Both axes always: an effect named
    for one axis can act on the other (a pitch dead band shifts yaw's torque)."""
    def pair(key, fmt):
        return f"{gap[key]:{fmt}}" + ("" if after is None else f" -> {after[key]:{fmt}}")

    text = f"RMSE pitch {pair('rmse_theta', '.3f')}, yaw {pair('rmse_psi', '.3f')} rad"
    if coverage:
        text += (f", 90 % coverage pitch {pair('coverage90_theta', '.0%')}, "
                 f"yaw {pair('coverage90_psi', '.0%')}")
    return text


def gain_text(row: dict, criterion: str, n_scored: int) -> str:
    """A candidate's held-out gain over the current model in words, the deciding score
    first: ``"+120 ± 30 nats"`` (``"log"``), or ``"a CRPS lower by 0.0123 ± 0.004 rad per
    sample (log density -50 ± 20 nats)"`` (``"crps"``); ``row`` as
    :func:`~heli_uq.discovery.decide.rank` makes it."""
    log = f"{row['score']:+.0f} ± {row['score_se']:.0f} nats"
    if criterion == "log" or row.get("crps_gain") is None:
        return log
    return (f"a CRPS lower by {row['crps_gain'] / n_scored:.3g} ± {row['crps_gain_se'] / n_scored:.2g} "
            f"rad per sample (log density {log})")
