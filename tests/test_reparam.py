"""Sampling coordinates: round trips, the invariances they make explicit, the prior Jacobian."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from heli_uq import TABLE1, simulate
from heli_uq.priors import default_priors, update_priors
from heli_uq.reparam import Coordinates

INVARIANCE_ATOL = 1e-9  # rad: angles unchanged along an unidentified coordinate
JACOBIAN_RTOL = 1e-6


@pytest.fixture(params=["h_free", "h_free_pitched", "h_zero", "log"])
def coords(request):
    if request.param == "h_free":
        return Coordinates(default_priors())
    if request.param == "h_free_pitched":
        return Coordinates(default_priors(), yaw_theta_ref=0.3)
    if request.param == "h_zero":
        return Coordinates(update_priors(default_priors(), {"h": 0.0}))
    return Coordinates(default_priors(), "log")


def _params(coords):
    p = dict(TABLE1)
    if not coords.priors["h"].free:
        p["h"] = 0.0
    return p


def test_round_trip(coords):
    p = _params(coords)
    back = coords.to_physical(jnp.asarray(coords.from_physical(p)))
    for k, v in p.items():
        assert abs(float(back[k]) - v) <= 1e-12 * max(1.0, abs(v)), k


def _angles(coords, z, u):
    return simulate(coords.to_physical(z), jnp.array([-0.5, 0.0, 0.3, -0.2]), u, 0.01)[:, :2]


def test_unidentified_coordinates_leave_the_angles_unchanged(coords):
    rng = np.random.default_rng(0)
    u = jnp.asarray(np.repeat(rng.uniform([1.2, 0.6], [1.42, 1.2], (6, 2)), 50, axis=0))
    z = jnp.asarray(coords.from_physical(_params(coords)))
    base = _angles(coords, z, u)
    expected = {"h_free": ("log_J_pitch",), "h_zero": ("log_J_pitch", "logit_body_fraction")}
    assert set(coords.unidentified) == set(expected.get(
        "h_free" if coords.resolved == "identifiable" and coords.priors["h"].free else
        "h_zero" if coords.resolved == "identifiable" else "none", ()))  # fmt: skip
    for name in coords.unidentified:
        i = coords.names.index(name)
        moved = _angles(coords, z.at[i].add(0.7), u)
        assert float(jnp.max(jnp.abs(moved - base))) < INVARIANCE_ATOL
    # ...while every identified coordinate does change them.
    for i, name in enumerate(coords.names):
        if name not in coords.unidentified:
            moved = _angles(coords, z.at[i].add(0.05), u)
            assert float(jnp.max(jnp.abs(moved - base))) > 1e3 * INVARIANCE_ATOL, name


def test_log_prior_includes_the_change_of_variables(coords):
    """log p(z) - sum log p_w(w(z)) equals log|det dw/dz|, computed here by finite differences."""
    z = np.asarray(coords.from_physical(_params(coords)))

    def w_of(zz):
        phys = coords.to_physical(jnp.asarray(zz))
        return np.array([float(coords.priors[n].to_coordinate(phys[n])) for n in coords.free])

    eps = 1e-6
    jac = np.column_stack([(w_of(z + eps * e) - w_of(z - eps * e)) / (2 * eps)
                           for e in np.eye(z.size)])  # fmt: skip
    w = w_of(z)
    base = sum(float(coords.priors[n].log_density_coordinate(w[i]))
               for i, n in enumerate(coords.free))  # fmt: skip
    expected = base + np.linalg.slogdet(jac)[1]
    got = float(coords.log_prior(jnp.asarray(z)))
    assert abs(got - expected) < JACOBIAN_RTOL * max(1.0, abs(expected))
    assert np.isfinite(float(jax.grad(coords.log_prior)(jnp.asarray(z)).sum()))


def test_scale_is_integrated_out_exactly():
    """log p(z_rest) = log of the integral over log M11 of p(z), by quadrature; and the
    conditional of log M11 is the Gaussian the model draws from."""
    coords = Coordinates(default_priors())
    z = jnp.asarray(coords.from_physical(TABLE1))
    log_marginal, mean, sd = coords.scale_conditional(z[1:])
    grid = np.linspace(float(mean) - 12 * float(sd), float(mean) + 12 * float(sd), 801)
    log_prior = jax.jit(jax.vmap(lambda s: coords.log_prior(z.at[0].set(s))))
    logp = np.asarray(log_prior(jnp.asarray(grid)))
    peak = logp.max()
    quad = peak + np.log(np.trapezoid(np.exp(logp - peak), grid))
    assert abs(quad - float(log_marginal)) < 1e-6
    # the conditional: log p(z) - log p(z_rest) is the Gaussian log density of log M11
    s = float(mean) + 0.7 * float(sd)
    cond = float(coords.log_prior(z.at[0].set(s))) - float(log_marginal)
    gauss = -0.5 * 0.7**2 - np.log(float(sd)) - 0.5 * np.log(2 * np.pi)
    assert abs(cond - gauss) < 1e-9


def test_yaw_gains_are_relative_to_the_yaw_inertia_at_the_reference_pitch():
    """At theta = yaw_theta_ref and omega_theta = 0 the yaw acceleration depends on the
    yaw-gain coordinates only: moving log_J_s_ratio (which changes M22) leaves it fixed,
    while the pitch acceleration (torques relative to M11) is unchanged too."""
    from heli_uq.dynamics import HelicopterModel
    from heli_uq.params import HeliParams

    theta_ref = -0.4
    coords = Coordinates(default_priors(), yaw_theta_ref=theta_ref)
    z = jnp.asarray(coords.from_physical(TABLE1))
    i = coords.names.index("log_J_s_ratio")
    y = jnp.array([theta_ref, 0.3, 0.0, 0.7])
    u = jnp.array([1.3, 0.9])

    def accel(zz, state=y):
        params = HeliParams.from_mapping(coords.to_physical(zz))
        return HelicopterModel()(0.0, state, (params, u))[2:]

    base = accel(z)
    moved = accel(z.at[i].add(1.5))
    np.testing.assert_allclose(moved, base, rtol=1e-12)
    # away from the reference pitch the same move does change the yaw acceleration
    y_off = y.at[0].set(theta_ref + 0.6)
    off, off_moved = accel(z, y_off)[1], accel(z.at[i].add(1.5), y_off)[1]
    assert abs(float(off_moved - off)) > 1e-3 * abs(float(off))
