"""The NUTS coordinate map: its Jacobian, the wall test, and an unchanged target."""

import arviz as az
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from numpyro.infer import MCMC, NUTS
from scipy import integrate, optimize

from heli_uq.inference.whiten import WALL_KINDS, SamplerMap, Wall, choose_walls, find_walls

JACOBIAN_ATOL = 1e-10  # log-determinant of the map vs autodiff
#: Monte Carlo tolerance of the sampled mean and sd, in units of their standard errors.
MC_SE = 4.0
#: A weakly identified positive parameter ``r = exp(x)``: log-normal prior (sd 2 in x),
#: likelihood Gaussian in ``r`` around 0 with sd ``R_SD`` (identified from above only),
#: next to an ordinary Gaussian coordinate.
PRIOR_MEAN, PRIOR_SD, R_SD = -1.0, 2.0, 0.02
#: A ridge straight in ``1 / r`` (the record sees ``1 / J_s`` when ``J_s`` dominates the
#: yaw inertia, and the initial yaw rate compensates it): ``x_1 = 1 / r`` to within
#: ``RIDGE_SD``, ``1 / r`` measured as ``1 +- INVERSE_SD``; ``x_0 = log r``.
RIDGE_SD, INVERSE_SD = 1e-2, 0.3
#: NUTS through the ridge's wall takes at least this many times fewer leapfrog steps
#: (measured: 12.6 -> 5.1 per draw).
RIDGE_STEP_GAIN = 1.5


def wall_potential(x):
    return (0.5 * ((x[0] - PRIOR_MEAN) / PRIOR_SD) ** 2 + 0.5 * (jnp.exp(x[0]) / R_SD) ** 2
            + 0.5 * (x[1] - 0.3) ** 2 / 0.1**2)  # fmt: skip


def ridge_potential(x):
    inverse = jnp.exp(-x[0])
    return (0.5 * (x[0] / PRIOR_SD) ** 2 + 0.5 * ((inverse - 1.0) / INVERSE_SD) ** 2
            + 0.5 * ((x[1] - inverse) / RIDGE_SD) ** 2)  # fmt: skip


def _map_and_covariance(potential, start=(0.0, 0.0)):
    f = jax.jit(potential)
    res = optimize.minimize(lambda x: float(f(jnp.asarray(x))), np.asarray(start), method="Nelder-Mead",
                            options={"xatol": 1e-12, "fatol": 1e-14, "maxiter": 20000})  # fmt: skip
    hess = np.asarray(jax.hessian(potential)(jnp.asarray(res.x)))
    return res.x, np.linalg.inv(hess)


def test_the_wall_coordinate_is_found_and_the_gaussian_one_is_not():
    x_map, cov = _map_and_covariance(wall_potential)
    assert find_walls(jax.jit(wall_potential), x_map, cov) == (0,)
    gaussian = lambda x: 0.5 * jnp.sum((x / jnp.array([1.0, 0.1])) ** 2)  # noqa: E731
    assert find_walls(jax.jit(gaussian), np.zeros(2), np.diag([1.0, 0.01])) == ()
    # the marginal probes add nothing where the posterior is Gaussian or already mapped
    assert choose_walls(jax.jit(gaussian), np.zeros(2), np.diag([1.0, 0.01])) == ()
    assert choose_walls(jax.jit(wall_potential), x_map, cov) == (Wall(0),)
    # The same wall below the MAP is left alone (a log coordinate does not steepen there).
    flipped = lambda x: wall_potential(jnp.array([-x[0], x[1]]))  # noqa: E731
    sign = np.diag([-1.0, 1.0])
    assert find_walls(jax.jit(flipped), sign @ x_map, sign @ cov @ sign) == ()


def test_a_wall_along_a_ridge_is_found_below_and_shortens_the_trajectories():
    """The conditional test misses a ridge bent in log r; the marginal probes find its wall
    below the MAP (1 / r linear), and NUTS through it takes fewer leapfrog steps."""
    x_map, cov = _map_and_covariance(ridge_potential, start=(0.0, 1.0))
    f = jax.jit(ridge_potential)
    assert find_walls(f, x_map, cov) == ()
    walls = choose_walls(f, x_map, cov)
    assert [(w.index, w.side) for w in walls] == [(0, -1.0)]
    assert (walls[0].side, walls[0].knee) in WALL_KINDS
    assert choose_walls(f, x_map, cov, candidates=()) == ()  # only the candidates are probed
    steps = []
    for chosen in ((), walls):
        smap = SamplerMap(x_map, cov, chosen)

        def potential(w, smap=smap):
            x, log_det = smap.x_and_log_det(w)
            return ridge_potential(x) - log_det

        mcmc = MCMC(NUTS(potential_fn=potential, dense_mass=True), num_warmup=500, num_samples=1000,
                    progress_bar=False)  # fmt: skip
        mcmc.run(jax.random.PRNGKey(1), init_params=jnp.zeros(2), extra_fields=("num_steps",))
        steps.append(float(mcmc.get_extra_fields()["num_steps"].mean()))
    assert steps[1] * RIDGE_STEP_GAIN < steps[0]


def test_the_map_is_whitening_plus_the_exact_log_jacobian():
    x_map, cov = _map_and_covariance(wall_potential)
    plain = SamplerMap(x_map, cov)
    w = jnp.array([0.7, -1.3])
    x, log_det = plain.x_and_log_det(w)
    np.testing.assert_allclose(x, x_map + np.linalg.cholesky(cov) @ np.asarray(w), rtol=1e-12)
    assert float(log_det) == 0.0
    # an index is a wall above with its knee at softplus = 1 (runs saved before walls had sides)
    assert SamplerMap(x_map, cov, (0,)).walls == (Wall(0, 1.0, float(np.log(np.e - 1.0))),)
    for wall in (0, Wall(0, -1.0, 4.0), Wall(1, 1.0, 4.0)):
        walled = SamplerMap(x_map, cov, (wall,))
        np.testing.assert_allclose(walled.x_and_log_det(jnp.zeros(2))[0], x_map, rtol=1e-12)
        for w in (jnp.array([0.7, -1.3]), jnp.array([-40.0, 2.0]), jnp.array([3.0, 0.0])):
            jac = jax.jacfwd(lambda v, walled=walled: walled.x_and_log_det(v)[0])(w)
            expected = np.linalg.slogdet(np.asarray(jac))[1] - np.log(np.linalg.det(walled.lower))
            assert abs(float(walled.x_and_log_det(w)[1]) - expected) < JACOBIAN_ATOL


@pytest.mark.parametrize("walls", [(), (0,), (Wall(0, -1.0, 4.0),)])
def test_nuts_through_the_map_samples_the_same_target(walls):
    """The moments of x_0 by NUTS through the map match quadrature, walls or not (a wall
    on the wrong side too: the map changes the coordinates, never the target)."""
    x_map, cov = _map_and_covariance(wall_potential)
    smap = SamplerMap(x_map, cov, walls)

    def potential(w):
        x, log_det = smap.x_and_log_det(w)
        return wall_potential(x) - log_det

    mcmc = MCMC(NUTS(potential_fn=potential), num_warmup=1000, num_samples=4000, progress_bar=False)
    mcmc.run(jax.random.PRNGKey(3), init_params=jnp.zeros(2))
    x0 = smap.x(np.asarray(mcmc.get_samples()))[:, 0]

    def density(x):
        return np.exp(-float(wall_potential(jnp.array([x, 0.3]))))

    z = integrate.quad(density, -30, 5, limit=200)[0]
    mean = integrate.quad(lambda x: x * density(x), -30, 5, limit=200)[0] / z
    sd = np.sqrt(integrate.quad(lambda x: (x - mean) ** 2 * density(x), -30, 5, limit=200)[0] / z)
    ess = float(az.ess(x0[None]))
    assert abs(x0.mean() - mean) < MC_SE * sd / np.sqrt(ess)
    assert abs(x0.std() - sd) < MC_SE * sd / np.sqrt(2 * ess)
