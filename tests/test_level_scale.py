"""The NUTS metric's rescaling of the Laplace covariance to the posterior's level width."""

import numpy as np
import pytest

from heli_uq.inference import level_scale
from heli_uq.inference.level_scale import R_LIMITS, level_distance, level_scaled_covariance

#: Relative precision of a level distance: the bisection brackets r within 2^(1/64).
LEVEL_RTOL = 0.02


def _gaussian(cov):
    prec = np.linalg.inv(cov)
    return lambda x: 0.5 * float(x @ prec @ x)


def _rotated(sds, seed=0):
    q, _ = np.linalg.qr(np.random.default_rng(seed).normal(size=(len(sds), len(sds))))
    return (q * np.asarray(sds) ** 2) @ q.T, q


def test_exact_laplace_covariance_is_kept():
    cov, _ = _rotated([0.1, 1.0, 3.0])
    out, factors = level_scaled_covariance(_gaussian(cov), np.zeros(3), 0.0, cov)
    np.testing.assert_array_equal(factors, 1.0)
    np.testing.assert_array_equal(out, cov)


def test_wrong_scales_are_corrected_along_the_eigen_axes():
    """Laplace sds off by 4x (too wide) and 1/3 (too narrow) on two axes of a Gaussian: the
    rescaled covariance is the true one; the axis within KEEP_RANGE is untouched."""
    true_sds = np.array([0.2, 1.0, 5.0])
    cov_true, q = _rotated(true_sds, seed=1)
    given = (q * (true_sds * np.array([4.0, 1.1, 1.0 / 3.0])) ** 2) @ q.T
    out, factors = level_scaled_covariance(_gaussian(cov_true), np.zeros(3), 0.0, given)
    np.testing.assert_allclose(np.sqrt(np.diag(q.T @ out @ q)), true_sds * np.array([1.0, 1.1, 1.0]),
                               rtol=LEVEL_RTOL)  # fmt: skip
    assert factors[1] == 1.0


def test_level_of_a_quartic_and_of_a_wall():
    """``x^4 / 4``: the LEVEL_NATS level is at (4 LEVEL_NATS)^(1/4); a potential that is infinite beyond 0.3
    (a solver failure) puts the level at the wall; a flat one stops at the limit."""

    def quartic(x):
        return 0.25 * float(x[0]) ** 4

    expected = (4 * level_scale.LEVEL_NATS) ** 0.25
    assert level_distance(quartic, np.zeros(1), np.ones(1), 0.0) == pytest.approx(expected, rel=LEVEL_RTOL)

    def wall(x):
        return np.inf if abs(float(x[0])) > 0.3 else 0.0

    assert level_distance(wall, np.zeros(1), np.ones(1), 0.0) == pytest.approx(0.3, rel=LEVEL_RTOL)
    assert level_distance(lambda x: 0.0, np.zeros(1), np.ones(1), 0.0) == R_LIMITS[1]


def test_another_level_is_measured_in_sd(monkeypatch):
    """With LEVEL_NATS = 0.5 a Gaussian's level is at 1 sd, so an exact covariance still
    keeps its factors at 1."""
    monkeypatch.setattr(level_scale, "LEVEL_NATS", 0.5)
    cov, _ = _rotated([0.5, 2.0], seed=2)
    _, factors = level_scaled_covariance(_gaussian(cov), np.zeros(2), 0.0, cov)
    np.testing.assert_array_equal(factors, 1.0)
