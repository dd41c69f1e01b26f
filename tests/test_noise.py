"""Error models: AR(1) likelihood vs a dense multivariate normal; noise statistics."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.stats import multivariate_normal

from heli_uq.probability.likelihood import pointwise_log_likelihood
from heli_uq.probability.noise import ar1_noise

LOGLIK_ATOL = 1e-9
#: Sample statistics of 200k AR(1) draws: sd and lag-1 correlation within these bounds.
SD_RTOL = 0.02
LAG1_ATOL = 0.01


@pytest.mark.parametrize("rho", [0.0, 0.5, 0.95])
def test_ar1_log_likelihood_matches_dense_mvn(rho):
    rng = np.random.default_rng(0)
    n = 40
    sigma = np.array([0.03, 0.2])
    sim = rng.normal(size=(n, 2))
    y = sim + rng.normal(scale=0.1, size=(n, 2))
    lags = np.abs(np.subtract.outer(np.arange(n), np.arange(n)))
    dense = sum(
        multivariate_normal(sim[:, j], sigma[j] ** 2 * rho**lags).logpdf(y[:, j]) for j in range(2)
    )
    ours = pointwise_log_likelihood(jnp.asarray(sim), jnp.asarray(y), jnp.asarray(sigma),
                                    jnp.full(2, rho))  # fmt: skip
    assert abs(float(ours.sum()) - dense) < LOGLIK_ATOL * max(1.0, abs(dense))


def test_iid_log_likelihood_is_normal():
    rng = np.random.default_rng(1)
    sim, y = rng.normal(size=(30, 2)), rng.normal(size=(30, 2))
    sigma = np.array([0.5, 2.0])
    ours = pointwise_log_likelihood(jnp.asarray(sim), jnp.asarray(y), jnp.asarray(sigma))
    ref = -0.5 * ((y - sim) / sigma) ** 2 - np.log(sigma) - 0.5 * np.log(2 * np.pi)
    np.testing.assert_allclose(ours, ref, atol=1e-12)


def test_ar1_noise_has_requested_sd_and_correlation():
    sigma, rho = jnp.array([0.01, 0.3]), jnp.array([0.9, 0.2])
    e = np.asarray(ar1_noise(jax.random.PRNGKey(0), 200_000, sigma, rho))
    np.testing.assert_allclose(e.std(axis=0), sigma, rtol=SD_RTOL)
    lag1 = [np.corrcoef(e[1:, j], e[:-1, j])[0, 1] for j in range(2)]
    np.testing.assert_allclose(lag1, rho, atol=LAG1_ATOL)


#: Rates [rad/s] and the timing error [s] of the timing tests: the sd of the residuals goes
#: from sigma alone (rate 0) to ~10 sigma.
RATES = (0.0, 0.4, 2.0)
TIMING = np.array([0.05, 0.3])


def _rates(n, rng):
    return rng.choice(RATES, size=(n, 2)) * rng.choice([-1.0, 1.0], size=(n, 2))


@pytest.mark.parametrize("rho", [None, 0.5, 0.95])
def test_timing_log_likelihood_matches_dense_mvn(rho):
    """Marginal sd ``s_k = sqrt(sigma^2 + (timing omega_k)^2)``, correlation ``rho^|i-j|``:
    the one-step conditionals sum to the dense normal's log density."""
    rng = np.random.default_rng(2)
    n = 40
    sigma = np.array([0.03, 0.2])
    sim = rng.normal(size=(n, 2))
    y = sim + rng.normal(scale=0.3, size=(n, 2))
    rate = _rates(n, rng)
    s = np.sqrt(sigma**2 + (TIMING * rate) ** 2)
    lags = np.abs(np.subtract.outer(np.arange(n), np.arange(n)))
    corr = np.eye(n) if rho is None else rho**lags
    dense = sum(multivariate_normal(sim[:, j], np.outer(s[:, j], s[:, j]) * corr).logpdf(y[:, j])
                for j in range(2))  # fmt: skip
    ours = pointwise_log_likelihood(jnp.asarray(sim), jnp.asarray(y), jnp.asarray(sigma),
                                    None if rho is None else jnp.full(2, rho),
                                    jnp.asarray(TIMING), jnp.asarray(rate))  # fmt: skip
    assert abs(float(ours.sum()) - dense) < LOGLIK_ATOL * max(1.0, abs(dense))


@pytest.mark.parametrize("rho", [None, 0.7])
def test_zero_timing_error_is_the_constant_scale(rho):
    rng = np.random.default_rng(3)
    sim, y, rate = rng.normal(size=(30, 2)), rng.normal(size=(30, 2)), _rates(30, rng)
    sigma = jnp.array([0.5, 2.0])
    rho = None if rho is None else jnp.full(2, rho)
    plain = pointwise_log_likelihood(jnp.asarray(sim), jnp.asarray(y), sigma, rho)
    timed = pointwise_log_likelihood(jnp.asarray(sim), jnp.asarray(y), sigma, rho, jnp.zeros(2),
                                     jnp.asarray(rate))  # fmt: skip
    np.testing.assert_array_equal(np.asarray(timed), np.asarray(plain))


@pytest.mark.parametrize("rho", [None, 0.9])
def test_timing_noise_sd_follows_the_rate(rho):
    """Draws of the error model: sd ``sqrt(sigma^2 + (timing omega)^2)`` at each rate, and
    the AR(1) correlation of the unit process between samples of equal rate."""
    sigma = jnp.array([0.01, 0.05])
    n = 300_000
    rate = np.repeat(np.array([[0.0, 0.0], [2.0, -2.0]]), n // 2, axis=0)
    e = np.asarray(ar1_noise(jax.random.PRNGKey(1), n, sigma, None if rho is None else jnp.full(2, rho),
                             jnp.asarray(TIMING), jnp.asarray(rate)))  # fmt: skip
    for half, r in ((slice(0, n // 2), 0.0), (slice(n // 2, n), 2.0)):
        want = np.sqrt(np.asarray(sigma) ** 2 + (TIMING * r) ** 2)
        np.testing.assert_allclose(e[half].std(axis=0), want, rtol=SD_RTOL)
        lag1 = [np.corrcoef(e[half][1:, j], e[half][:-1, j])[0, 1] for j in range(2)]
        np.testing.assert_allclose(lag1, 0.0 if rho is None else rho, atol=LAG1_ATOL)
