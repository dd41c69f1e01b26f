"""Sampling coordinates: round trips, the invariances they make explicit, the prior Jacobian."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from heli_uq import TABLE1, simulate
from heli_uq.model import HeliModel, parse_effects
from heli_uq.probability import Coordinates, PriorSet

INVARIANCE_ATOL = 1e-9  # rad: angles unchanged along an unidentified coordinate
JACOBIAN_RTOL = 1e-6


BASE = HeliModel()
#: Every effect of the vocabulary once, so each kind of coordinate (ratio to M11 or M22,
#: log or linear, unscaled) appears.
EFFECTS = parse_effects("pitch:deadband,yaw:coulomb_friction,yaw:quadratic_drag,"
                        "yaw:torsional_spring,pitch:quadratic_thrust,yaw:torque_offset")
EFFECT_VALUES = {"h": 0.005, "delta_pitch": 0.2, "F_c_yaw": 0.004, "c_yaw": 0.002, "k_yaw": 0.003,
                 "psi_0_yaw": 0.8, "k_q_pitch": -0.01, "T_0_yaw": 0.002}  # fmt: skip


def test_the_model_of_this_file_holds_every_effect_of_the_vocabulary():
    """A new effect of the vocabulary joins :data:`EFFECTS` here, with values."""
    from heli_uq.model.terms import EFFECTS as VOCABULARY

    listed = {term.kind for term in EFFECTS.effects}
    assert set(VOCABULARY) <= listed, f"add {sorted(set(VOCABULARY) - listed)} to EFFECTS"
    names = {p.name for term in EFFECTS.effects for p in term.parameters()}
    assert names <= set(EFFECT_VALUES), f"add {sorted(names - set(EFFECT_VALUES))} to EFFECT_VALUES"


#: Mean voltages [V] of a rig-like record: the torque offset is sampled as the net
#: constant yaw torque at them.
U_REF = (1.3, 0.9)


def _priors(model, **changes):
    return PriorSet.default(model).updated(model, changes).params


@pytest.fixture(params=["h_free", "h_free_pitched", "h_zero", "log", "effects", "effects_log"])
def coords(request):
    if request.param == "h_free":
        return Coordinates(BASE, _priors(BASE))
    if request.param == "h_free_pitched":
        return Coordinates(BASE, _priors(BASE), yaw_theta_ref=0.3)
    if request.param == "h_zero":
        return Coordinates(BASE, _priors(BASE, h=0.0))
    if request.param == "effects":
        return Coordinates(EFFECTS, _priors(EFFECTS), yaw_theta_ref=-0.3, u_ref=U_REF)
    if request.param == "effects_log":
        return Coordinates(EFFECTS, _priors(EFFECTS), "log")
    return Coordinates(BASE, _priors(BASE), "log")


def _params(coords):
    p = dict(TABLE1)
    if coords.model is EFFECTS:
        p.update(EFFECT_VALUES)
    if not coords.priors["h"].free:
        p["h"] = 0.0
    return p


def test_round_trip(coords):
    p = _params(coords)
    back = coords.to_physical(jnp.asarray(coords.from_physical(p)))
    for k, v in p.items():
        assert abs(float(back[k]) - v) <= 1e-12 * max(1.0, abs(v)), k


def test_a_body_without_its_own_inertia_has_finite_coordinates():
    """A fit can push J_bc to 0 (body fraction 1, where the sigmoid of the coordinate
    rounds to 1): the coordinates stay finite and map back to J_bc ~ 0 and the rest."""
    from heli_uq.probability.coordinates import BODY_FRACTION_EPS

    coords = Coordinates(BASE, _priors(BASE))
    saturated = jnp.asarray(coords.from_physical(TABLE1)).at[2].set(60.0)  # sigmoid(60) == 1.0
    for p in ({**TABLE1, "J_bc": 0.0}, coords.to_physical(saturated)):
        z = coords.from_physical(p)
        assert np.all(np.isfinite(z))
        back = coords.to_physical(jnp.asarray(z))
        m11 = float(back["J_bc"] + back["J_s"] + back["m"] * (back["r_c"] ** 2 + back["h"] ** 2))
        assert float(back["J_bc"]) <= 2 * BODY_FRACTION_EPS * m11
        for k in ("r_c", "m", "h", "J_s", "K_psi_psi"):
            assert abs(float(back[k]) - float(p[k])) <= 1e-9 * max(1e-3, abs(float(p[k]))), k


def _angles(coords, z, u):
    return simulate(coords.to_physical(z), jnp.array([-0.5, 0.0, 0.3, -0.2]), u, 0.01,
                    model=coords.model, substeps=2)[:, :2]  # fmt: skip


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
    """The product of the physical priors in ``z``: log p(z) - sum log p_w(w(z)) equals
    log|det dw/dz|, computed here by finite differences.  (The identifiable coordinates'
    prior replaces the common scale's part of it:
    ``test_the_common_scale_has_the_prior_of_one_parameter``.)"""
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
    got = float(coords._log_prior_and_physical(jnp.asarray(z))[0])
    assert abs(got - expected) < JACOBIAN_RTOL * max(1.0, abs(expected))
    assert np.isfinite(float(jax.grad(coords.log_prior)(jnp.asarray(z)).sum()))


def test_the_closed_form_log_jacobian_is_the_dense_one(coords):
    """``log |det dw/dz|`` from the map's triangular structure equals the dense
    ``slogdet`` of the whole Jacobian (forward-mode autodiff of ``w(z)``), in value and
    gradient, away from the parameters too."""
    rng = np.random.default_rng(5)
    z0 = np.asarray(coords.from_physical(_params(coords)))

    def dense(z):
        return jnp.linalg.slogdet(jax.jacfwd(coords.prior_coordinates)(z))[1]

    for _ in range(4):
        z = jnp.asarray(z0 + rng.normal(0.0, 0.5, z0.size))
        got, expected = coords._log_jacobian(z), dense(z)
        assert abs(float(got) - float(expected)) < JACOBIAN_RTOL * max(1.0, abs(float(expected)))
        np.testing.assert_allclose(jax.grad(coords._log_jacobian)(z), jax.grad(dense)(z),
                                   rtol=JACOBIAN_RTOL, atol=JACOBIAN_RTOL)  # fmt: skip


def test_coordinates_of_effects_follow_their_declarations():
    """Scaled effect parameters get a ratio coordinate (to M22 on yaw, to M11 on pitch),
    unscaled ones their prior's own coordinate; no Table 2 name is needed for that."""
    coords = Coordinates(EFFECTS, _priors(EFFECTS))
    assert coords.resolved == "identifiable"
    for name in ("log_F_c_yaw_ratio", "log_c_yaw_ratio", "log_k_yaw_ratio", "T_0_yaw_ratio",
                 "k_q_pitch_ratio", "log_delta_pitch", "psi_0_yaw"):  # fmt: skip
        assert name in coords.names, name
    # a fixed scaled parameter breaks the scaling symmetry: plain coordinates instead
    fixed = Coordinates(EFFECTS, _priors(EFFECTS, F_c_yaw=0.004))
    assert fixed.resolved == "log" and fixed.unidentified == ()


@pytest.mark.parametrize("model", [BASE, EFFECTS], ids=["paper", "effects"])
def test_scale_is_integrated_out_exactly(model):
    """log p(z_rest) = log of the integral over log M11 of p(z), by quadrature; and the
    conditional of log M11 is the Gaussian the model draws from (exactly so when every
    scaled prior is log-normal; with half-normal and normal effect priors the remainder is
    evaluated at the drawn scale, and the joint density is still exact)."""
    coords = Coordinates(model, _priors(model))
    values = dict(TABLE1, **(EFFECT_VALUES if model is EFFECTS else {}))
    z = jnp.asarray(coords.from_physical(values))
    # the joint density of (z_rest, eps) is p(z_rest, s) ds/deps at s = mean + sd eps
    _, mean, sd = coords.scale_conditional(z[1:])
    for eps in (-1.3, 0.0, 0.8):
        lp, z_full = coords.marginal_log_prior(z[1:], jnp.asarray(eps))
        joint = float(lp) - 0.5 * eps**2 - 0.5 * np.log(2 * np.pi)
        direct = float(coords.log_prior(z_full)) + np.log(float(sd))
        assert abs(joint - direct) < 1e-9, (eps, joint, direct)
    if model is EFFECTS:
        return
    # only log-normal scaled priors: the rest of the prior does not depend on the scale, so
    # the marginal is exact for any eps, and log M11 | z_rest is exactly Gaussian.
    log_marginal = coords.marginal_log_prior(z[1:], jnp.asarray(0.3))[0]
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


def _parabola(log_density, z, steps=(-1.0, 0.0, 1.0, 2.5)):
    """Vertex, sd and the misfit at the last step of the parabola through the first three
    values of ``log_density`` along ``z[0]`` (the misfit is 0 for an exact Gaussian)."""
    f = [float(log_density(z.at[0].add(d))) for d in steps]
    a, b, c = np.polyfit(steps[:3], f[:3], 2)
    return float(z[0]) - b / (2 * a), 1.0 / np.sqrt(-2 * a), f[3] - np.polyval([a, b, c], steps[3])


@pytest.mark.parametrize("case", ["defaults", "weighed_mass", "effects"])
def test_the_common_scale_has_the_prior_of_one_parameter(case):
    """The prior of ``log M11`` given the other coordinates is a Gaussian centred where the
    product of the log-normal priors puts it, as wide as the tightest *single* log-normal
    scaled prior (sigma_log 2 by default, where the product's is 0.67; a weighed mass,
    sigma_log 0.05, still pins it given the ratios), and untouched by the half-normal and
    normal priors of the effects, which pull the product's towards their own scale.  The
    product is written out here (physical priors and the Jacobian of the map)."""
    model = EFFECTS if case == "effects" else BASE
    changes = {"m": {"lognormal": [TABLE1["m"], 0.05]}} if case == "weighed_mass" else {}
    priors = _priors(model, **changes)
    where = {"yaw_theta_ref": -0.3, "u_ref": U_REF} if model is EFFECTS else {}
    coords = Coordinates(model, priors, **where)
    values = dict(TABLE1, **(EFFECT_VALUES if model is EFFECTS else {}))
    z = jnp.asarray(coords.from_physical(values))

    def product(zz):
        phys = coords.to_physical(zz)
        w = jnp.stack([priors[n].to_coordinate(phys[n]) for n in coords.free])
        jac = jnp.linalg.slogdet(jax.jacfwd(coords.prior_coordinates)(zz))[1]
        return sum(priors[n].log_density_coordinate(w[i]) for i, n in enumerate(coords.free)) + jac

    mean, sd, misfit = _parabola(coords.log_prior, z)
    assert abs(misfit) < JACOBIAN_RTOL
    tightest = min(priors[n].b for n in coords.free
                   if model.parameter(n).scales_with_inertia and priors[n].kind == "lognormal")  # fmt: skip
    assert abs(sd - tightest) < JACOBIAN_RTOL
    assert tightest == (0.05 if case == "weighed_mass" else 2.0)
    product_mean, product_sd, product_misfit = _parabola(product, z)
    if model is BASE:  # only log-normal scaled priors: the product is Gaussian in log M11
        assert abs(product_misfit) < JACOBIAN_RTOL and abs(mean - product_mean) < JACOBIAN_RTOL
        assert product_sd < (0.7 if case == "defaults" else 0.05)
    else:  # half-normal and normal torques bend the product's and pull it up
        assert abs(product_misfit) > 1e3 * JACOBIAN_RTOL and product_mean > mean


@pytest.mark.parametrize("model", [BASE, EFFECTS], ids=["paper", "effects"])
def test_prior_draws_follow_the_common_scale_prior(model):
    """``joint_draws`` turns draws of the product of the priors into draws of the
    coordinates' prior: ``eps`` (:meth:`Coordinates.scale_noise`) is the standard normal
    it was given, every ratio of a log-normal parameter is the product draw's (so the
    angles are), and the parameters whose priors are not log-normal keep their product
    draws when ``eps`` is 0, i.e. at the scale's conditional mean, where their priors hold."""
    priors = PriorSet.default(model)
    coords = Coordinates(model, priors.params)
    assert coords.resolved == "identifiable"
    rng = np.random.default_rng(3)
    for _ in range(5):
        product = {n: float(v) for n, v in priors.draw(model, rng).items()}
        product.update({n: float(p.a) for n, p in priors.params.items() if not p.free})
        eps = rng.standard_normal()
        joint = coords.joint_draws(product, eps)
        assert abs(coords.scale_noise(coords.from_physical(joint)) - eps) < 1e-9
        at_mean = coords.joint_draws(product, 0.0)
        z_product, z_joint = coords.from_physical(product), coords.from_physical(joint)
        for i, name in enumerate(coords.names[1:], 1):
            parameter = coords._specs[i][1]
            if parameter is None or priors.params[parameter].kind == "lognormal":
                assert abs(z_joint[i] - z_product[i]) < 1e-9, name
            else:
                assert abs(at_mean[parameter] - product[parameter]) <= 1e-12 * abs(product[parameter])
    assert coords.joint_draws(product, 0.0).keys() == product.keys()


def test_yaw_gains_are_relative_to_the_yaw_inertia_at_the_reference_pitch():
    """At theta = yaw_theta_ref and omega_theta = 0 the yaw acceleration depends on the
    yaw-gain coordinates only: moving log_J_s_ratio (which changes M22) leaves it fixed,
    while the pitch acceleration (torques relative to M11) is unchanged too."""
    theta_ref = -0.4
    coords = Coordinates(BASE, _priors(BASE), yaw_theta_ref=theta_ref)
    z = jnp.asarray(coords.from_physical(TABLE1))
    i = coords.names.index("log_J_s_ratio")
    y = jnp.array([theta_ref, 0.3, 0.0, 0.7])
    u = jnp.array([1.3, 0.9])

    def accel(zz, state=y):
        return BASE(0.0, state, (coords.to_physical(zz), u))[2:]

    base = accel(z)
    moved = accel(z.at[i].add(1.5))
    np.testing.assert_allclose(moved, base, rtol=1e-12)
    # away from the reference pitch the same move does change the yaw acceleration
    y_off = y.at[0].set(theta_ref + 0.6)
    off, off_moved = accel(z, y_off)[1], accel(z.at[i].add(1.5), y_off)[1]
    assert abs(float(off_moved - off)) > 1e-3 * abs(float(off))


def test_a_constant_torque_is_sampled_as_the_net_torque_at_the_mean_voltages():
    """Moving a yaw gain's coordinate keeps ``T_0 + K_psi_theta u_theta - K_psi_psi u_psi``
    at the mean voltages (the straightened offset-gain ridge); without ``u_ref`` the offset
    keeps its plain ratio coordinate."""
    coords = Coordinates(EFFECTS, _priors(EFFECTS), u_ref=U_REF)
    assert "T_0_yaw_net_ratio" in coords.names and "T_0_yaw_ratio" not in coords.names
    assert "T_0_yaw_ratio" in Coordinates(EFFECTS, _priors(EFFECTS)).names

    def net(p):
        return float(p["T_0_yaw"] + p["K_psi_theta"] * U_REF[0] - p["K_psi_psi"] * U_REF[1])

    z = jnp.asarray(coords.from_physical(dict(TABLE1, **EFFECT_VALUES)))
    before = coords.to_physical(z)
    after = coords.to_physical(z.at[coords.names.index("log_K_psi_theta_yaw_ratio")].add(0.4))
    assert float(after["K_psi_theta"]) > 1.4 * float(before["K_psi_theta"])
    assert abs(net(after) - net(before)) < 1e-12
