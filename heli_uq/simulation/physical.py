"""The physical range of the rig: pitch stays within +-90 deg (the arm rests on its stops
before that), and every state stays finite.

A simulation that leaves this range (an unstable parameter set, a blow-up) is a valid
solve of the equations but not a motion the rig can make; the CLI and the figures report
it instead of drawing it as a result.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

__all__ = ["PITCH_LIMIT", "RangeReport", "physical_range", "unphysical_draws"]

#: Largest physical |pitch| [rad]: 90 deg.
PITCH_LIMIT = math.pi / 2


@dataclasses.dataclass(frozen=True)
class RangeReport:
    """Whether a trajectory stays in the physical range, and how far it leaves it.

    ``max_abs_pitch_deg`` is over the finite samples; ``first_exit`` is the index of the
    first sample out of range (None if there is none)."""

    ok: bool
    max_abs_pitch_deg: float
    nonfinite: bool
    first_exit: int | None

    def describe(self, ts=None) -> str:
        """``"UNPHYSICAL: pitch reaches 35000 deg (beyond +-90 deg) from t = 12.3 s"``, or ``""``."""
        if self.ok:
            return ""
        where = "" if self.first_exit is None or ts is None else f" from t = {float(ts[self.first_exit]):g} s"
        what = (f"the simulation blows up (non-finite states){where}" if self.nonfinite else
                f"pitch reaches {self.max_abs_pitch_deg:.4g} deg (beyond +-90 deg){where}")  # fmt: skip
        return "UNPHYSICAL: " + what


def physical_range(ys) -> RangeReport:
    """Check a trajectory ``ys`` (N, >= 1) whose first column is pitch [rad]."""
    ys = np.asarray(ys, dtype=float)
    finite = np.all(np.isfinite(ys), axis=1)
    pitch = np.abs(ys[:, 0])
    bad = ~finite | ~(pitch <= PITCH_LIMIT)
    max_pitch = float(np.degrees(pitch[finite].max())) if finite.any() else float("nan")
    first = int(np.argmax(bad)) if bad.any() else None
    return RangeReport(ok=not bad.any(), max_abs_pitch_deg=max_pitch, nonfinite=not finite.all(),
                       first_exit=first)  # fmt: skip


def unphysical_draws(y_sim) -> np.ndarray:
    """Per draw of ``y_sim`` (S, N, >= 1; pitch first), whether it leaves the physical range
    (non-finite anywhere, or |pitch| > :data:`PITCH_LIMIT`)."""
    y = np.asarray(y_sim, dtype=float)
    return ~np.all(np.isfinite(y), axis=(1, 2)) | ~np.all(np.abs(y[..., 0]) <= PITCH_LIMIT, axis=1)
