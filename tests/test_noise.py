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
