"""Voltage staircases within the rig's limits: the experiments :mod:`heli_uq.design` searches over.

A staircase holds one voltage pair per segment; segment lengths are whole samples.  Every
staircase made here satisfies its :class:`StaircaseBounds` exactly: levels inside the voltage
ranges, every segment (the last one too) between the shortest and the longest hold, lengths
summing to the duration.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from heli_uq.errors import ParameterError
from heli_uq.simulation.physical import PITCH_LIMIT
from heli_uq.simulation.synthetic import RIG_HOLD, RIG_RANGES

__all__ = ["StaircaseBounds", "Staircase", "random_staircase", "mutate", "PITCH_ENVELOPE"]

#: Default envelope of the predicted pitch [rad]: -60 to 0 deg, the arm below horizontal.  The
#: rig record stays within -39 to -4 deg, where the model was fitted; a design that drives the
#: arm over the top gains information from a motion the rig cannot make safely.
PITCH_ENVELOPE = (math.radians(-60.0), 0.0)
#: Most samples a designed experiment may have (10,000 s at the rig's 0.01 s, far above
#: the 60-131 s experiments designed here): each candidate's information simulates every
#: prior draw's sensitivities over all of them, and 1e9 samples asked for 15 GiB at once.
MAX_DESIGN_SAMPLES = 1_000_000


@dataclasses.dataclass(frozen=True)
class StaircaseBounds:
    """Limits of a designed input.

    Parameters
    ----------
    duration : float
        Length of the experiment [s].
    dt : float
        Sample time [s].
    ranges : ((float, float), (float, float))
        ``(low, high)`` voltages [V] of u_theta and u_psi (default: the rig record's).
    hold : (float, float)
        Shortest and longest segment [s] (default: the rig record's 3-14 s).
    pitch : (float, float)
        Envelope [rad] the predicted pitch must stay in (default :data:`PITCH_ENVELOPE`).

    Raises
    ------
    ParameterError
        A range that is empty or not finite, a hold that is not ``0 < min <= max``, or a
        duration that no sequence of segments within the hold can fill (the message
        names the shortest feasible duration).
    """

    duration: float
    dt: float = 0.01
    ranges: tuple = RIG_RANGES
    hold: tuple = RIG_HOLD
    pitch: tuple = None

    def __post_init__(self):
        if self.pitch is None:
            object.__setattr__(self, "pitch", PITCH_ENVELOPE)
        lo, hi = self.pitch
        if not (-PITCH_LIMIT <= lo < hi <= PITCH_LIMIT):
            raise ParameterError(f"pitch envelope: expected -90 <= LOW < HIGH <= 90 deg, found "
                                 f"{math.degrees(lo):g}:{math.degrees(hi):g} deg")  # fmt: skip
        for name, (lo, hi) in zip(("u_theta", "u_psi"), self.ranges):
            if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
                raise ParameterError(f"{name} range: expected finite LOW < HIGH [V], found {lo:g}:{hi:g}")
        lo, hi = self.hold
        if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo <= hi):
            raise ParameterError(f"segment lengths: expected 0 < MIN <= MAX [s], found {lo:g}:{hi:g}")
        if not (math.isfinite(self.dt) and self.dt > 0):
            raise ParameterError(f"dt: expected a number > 0 [s], found {self.dt!r}")
        if not (math.isfinite(self.duration) and self.duration > 0):
            raise ParameterError(f"duration: expected a number > 0 [s], found {self.duration!r}")
        if self.duration / self.dt > MAX_DESIGN_SAMPLES:
            raise ParameterError(f"duration: {self.duration:g} s at dt = {self.dt:g} s is "
                                 f"{self.duration / self.dt:.3g} samples, more than a design's "
                                 f"{MAX_DESIGN_SAMPLES:,}")  # fmt: skip
        if self.hold_samples[0] < 1:
            raise ParameterError(f"segment lengths: the shortest, {lo:g} s, is below one sample "
                                 f"(dt = {self.dt:g} s)")  # fmt: skip
        if not self.segment_counts:
            raise ParameterError(
                f"duration: {self.duration:g} s cannot be split into segments of {lo:g}-{hi:g} s "
                f"(the shortest experiment is one segment of {lo:g} s)"
            )

    @property
    def n(self) -> int:
        """Number of samples."""
        return round(self.duration / self.dt)

    @property
    def hold_samples(self) -> tuple[int, int]:
        """Shortest and longest segment in samples."""
        return math.ceil(self.hold[0] / self.dt - 1e-9), math.floor(self.hold[1] / self.dt + 1e-9)

    @property
    def segment_counts(self) -> range:
        """The feasible numbers of segments ``K`` (``K min_hold <= n <= K max_hold``)."""
        a, b = self.hold_samples
        return range(max(1, math.ceil(self.n / b)), self.n // a + 1)

    def to_json(self) -> dict:
        return {"duration_s": self.duration, "dt_s": self.dt,
                "u_theta_V": list(self.ranges[0]), "u_psi_V": list(self.ranges[1]),
                "segment_s": list(self.hold), "pitch_deg": [math.degrees(v) for v in self.pitch]}  # fmt: skip


@dataclasses.dataclass(frozen=True)
class Staircase:
    """Piecewise-constant voltages.

    Attributes
    ----------
    levels : ndarray, shape (K, 2)
        ``(u_theta, u_psi)`` of each segment [V].
    lengths : ndarray of int, shape (K,)
        Samples per segment.
    """

    levels: np.ndarray
    lengths: np.ndarray

    def inputs(self) -> np.ndarray:
        """Voltages on the sample grid, shape (sum(lengths), 2) [V]."""
        return np.repeat(np.asarray(self.levels, dtype=float), np.asarray(self.lengths), axis=0)

    def check(self, bounds: StaircaseBounds) -> None:
        """Raise :class:`ParameterError` unless the staircase keeps within ``bounds``."""
        a, b = bounds.hold_samples
        lengths = np.asarray(self.lengths)
        if lengths.sum() != bounds.n or lengths.min() < a or lengths.max() > b:
            raise ParameterError(f"staircase: segment lengths {lengths.tolist()} outside "
                                 f"{a}-{b} samples or not summing to {bounds.n}")  # fmt: skip
        low, high = np.array(bounds.ranges).T
        if np.any(self.levels < low) or np.any(self.levels > high):
            raise ParameterError("staircase: a level outside the voltage ranges")

    def segments(self, dt: float) -> list[dict]:
        """``[{start_s, length_s, u_theta, u_psi}]`` of each segment."""
        starts = np.concatenate([[0], np.cumsum(self.lengths)[:-1]])
        return [{"start_s": float(s * dt), "length_s": float(n * dt), "u_theta": float(v[0]),
                 "u_psi": float(v[1])} for s, n, v in zip(starts, self.lengths, self.levels)]  # fmt: skip


def _split(n: int, k: int, a: int, b: int, rng: np.random.Generator) -> np.ndarray:
    """``k`` integers in ``[a, b]`` summing to ``n`` (each drawn within what keeps the rest
    feasible; the order is shuffled)."""
    out, left = [], n
    for i in range(k - 1):
        rest = k - i - 1
        lo, hi = max(a, left - rest * b), min(b, left - rest * a)
        out.append(int(rng.integers(lo, hi + 1)))
        left -= out[-1]
    out.append(left)
    return rng.permutation(np.array(out, dtype=int))


def _levels(k: int, bounds: StaircaseBounds, rng: np.random.Generator) -> np.ndarray:
    low, high = np.array(bounds.ranges).T
    return rng.uniform(low, high, size=(k, 2))


def random_staircase(bounds: StaircaseBounds, rng: np.random.Generator) -> Staircase:
    """A staircase with a uniformly drawn feasible number of segments, lengths within the
    hold, levels uniform in the ranges."""
    counts = bounds.segment_counts
    k = int(rng.integers(counts.start, counts.stop))
    a, b = bounds.hold_samples
    return Staircase(_levels(k, bounds, rng), _split(bounds.n, k, a, b, rng))


def mutate(stairs: Staircase, bounds: StaircaseBounds, rng: np.random.Generator) -> Staircase:
    """A neighbour: one segment's level redrawn (half the time one voltage only), or a
    boundary between two segments moved (lengths stay within the hold)."""
    levels, lengths = np.array(stairs.levels, dtype=float), np.array(stairs.lengths)
    k = len(lengths)
    if k > 1 and rng.random() < 0.5:
        i = int(rng.integers(k - 1))
        a, b = bounds.hold_samples
        pair = lengths[i] + lengths[i + 1]
        lo, hi = max(a, pair - b), min(b, pair - a)
        lengths[i] = int(rng.integers(lo, hi + 1))
        lengths[i + 1] = pair - lengths[i]
    else:
        i = int(rng.integers(k))
        new = _levels(1, bounds, rng)[0]
        axes = [int(rng.integers(2))] if rng.random() < 0.5 else [0, 1]
        levels[i, axes] = new[axes]
    return Staircase(levels, lengths)
