"""The thrust tilt term: the yaw torques' ``cos theta`` against the rig's geometry by
autodiff, the paper's model at tilt 0, the common scaling, its gradient, its description
and the refused pitch axis."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from heli_uq.errors import ParameterError
from heli_uq.model import EFFECTS, TABLE1, build_model, model_from_description
from heli_uq.model.terms import TERMS
from heli_uq.simulation import simulate

#: Agreement of the closed form with the geometry's generalized forces (both float64).
FORCE_RTOL = 1e-12
GRAD_RTOL = 1e-6
#: Arm length [m] of the yaw rotor in the geometry: any value, it cancels in the gains.
ARM = 0.3


def _motor_forces(theta, psi, u, gains):
    """Generalized forces ``(Q_theta, Q_psi)`` [N m] of the two motors from the geometry
    alone (the term's docstring derives the same by hand):

    * the yaw rotor's thrust ``F = K_psi_psi u_psi / ARM`` along the pitch axis
      ``(-sin psi, cos psi, 0)`` at the arm's point ``r(theta, psi)``, pushing the yaw
      negative: ``Q_q = -F e . dr/dq``, with ``dr/dq`` by ``jax.jacfwd``;
    * the pitch rotor's reaction torque ``K_psi_theta u_theta`` about its shaft, the body
      normal ``n(theta, psi)``: ``Q_q = tau n . w_q`` with ``w_q`` the unit rotation axis of
      coordinate ``q`` (the vertical for yaw, the pitch axis for pitch).

    At ``theta = 0`` these are the paper's torques, which defines the gains.
    """

    def position(q):
        th, ps = q
        return ARM * jnp.stack([jnp.cos(th) * jnp.cos(ps), jnp.cos(th) * jnp.sin(ps), jnp.sin(th)])

    q = jnp.array([theta, psi])
    dr = jax.jacfwd(position)(q)  # (3, 2): column j is dr/dq_j
    pitch_axis = jnp.array([-jnp.sin(psi), jnp.cos(psi), 0.0])
    thrust = -(gains["K_psi_psi"] * u[1] / ARM) * pitch_axis
    normal = jnp.array([-jnp.sin(theta) * jnp.cos(psi), -jnp.sin(theta) * jnp.sin(psi), jnp.cos(theta)])
    reaction = gains["K_psi_theta"] * u[0] * normal
    rotation_axes = jnp.stack([pitch_axis, jnp.array([0.0, 0.0, 1.0])])  # rows: theta, psi
    return np.asarray(thrust @ dr + rotation_axes @ reaction)


def _values(model, a):
    return model.complete({**TABLE1, "a_yaw": a, "D_theta": 0.0, "D_psi": 0.0})


def test_at_tilt_one_the_yaw_torques_are_the_geometrys_generalized_forces():
    """With the tilt 1 the model's yaw torque at rest equals the two motors' generalized
    force derived from the geometry at random angles and voltages; the term leaves the pitch
    torque alone (the geometry's pitch parts of these two motor forces are 0).  Tilt 0 is the
    paper's model, the geometry only at ``theta = 0``."""
    model = build_model(["yaw:thrust_tilt"])
    paper = build_model([])
    rng = np.random.default_rng(0)
    for _ in range(20):
        theta, psi = rng.uniform(-1.2, 1.2), rng.uniform(-np.pi, np.pi)
        u = rng.uniform([0.5, -1.0], [2.0, 2.0])
        x, v, uu = jnp.array([theta, psi]), jnp.zeros(2), jnp.asarray(u)
        p = _values(model, 1.0)
        got = np.asarray(model.force(p, x, v, uu))
        motors = _motor_forces(theta, psi, u, p)
        np.testing.assert_allclose(motors[0], 0.0, atol=1e-15)
        np.testing.assert_allclose(got[1], motors[1], rtol=FORCE_RTOL)
        q = paper.complete({**TABLE1, "D_theta": 0.0, "D_psi": 0.0})
        np.testing.assert_allclose(got[0], np.asarray(paper.force(q, x, v, uu))[0], rtol=FORCE_RTOL)
        np.testing.assert_allclose(np.asarray(model.force(_values(model, 0.0), x, v, uu)),
                                   np.asarray(paper.force(q, x, v, uu)), rtol=FORCE_RTOL)  # fmt: skip
    flat = _motor_forces(0.0, 0.3, np.array([1.3, 0.9]), TABLE1)[1]
    assert flat == pytest.approx(TABLE1["K_psi_theta"] * 1.3 - TABLE1["K_psi_psi"] * 0.9, rel=FORCE_RTOL)


def _steps(seed, n=4, hold=100):
    rng = np.random.default_rng(seed)
    return jnp.asarray(np.repeat(rng.uniform([1.25, 0.45], [1.5, 1.6], size=(n, 2)), hold, axis=0))


def test_the_common_scaling_leaves_the_angles_unchanged():
    """The tilt is dimensionless and multiplies the yaw gains, so scaling every inertia and
    torque-type parameter by one factor (the model's null direction) moves no angle."""
    model = build_model(["yaw:thrust_tilt"])
    values, x0, u = _values(model, 0.8), jnp.array([-0.5, 0.3, 0.0, 0.0]), _steps(1)
    assert "a_yaw" not in model.scale_names
    scaled = {n: v * (2.5 if n in model.scale_names else 1.0) for n, v in values.items()}
    a = np.asarray(simulate(values, x0, u, 0.01, model=model))
    b = np.asarray(simulate(scaled, x0, u, 0.01, model=model))
    np.testing.assert_allclose(a[:, :2], b[:, :2], atol=1e-10)
    c = np.asarray(simulate(_values(model, 0.0), x0, u, 0.01, model=model))
    assert np.max(np.abs(a[:, 1] - c[:, 1])) > 1e-3  # and the tilt does move the yaw


def test_gradient_in_the_tilt_matches_central_differences():
    model = build_model(["yaw:thrust_tilt"])
    values, x0, u = _values(model, 0.6), jnp.array([-0.5, 0.3, 0.0, 0.0]), _steps(2)

    def loss(a):
        return jnp.sum(simulate({**values, "a_yaw": a}, x0, u, 0.01, model=model)[:, 1] ** 2)

    grad, h = float(jax.grad(loss)(0.6)), 1e-6
    fd = (float(loss(0.6 + h)) - float(loss(0.6 - h))) / (2 * h)
    assert abs(fd) > 1e-3
    assert grad == pytest.approx(fd, rel=GRAD_RTOL)


def test_description_round_trip_support_and_not_a_discovery_candidate():
    model = build_model(["yaw:coulomb_friction", "yaw:thrust_tilt"])
    again = model_from_description(model.describe())
    assert again.describe() == model.describe()
    (par,) = again.effects[-1].parameters()
    assert (par.name, par.bare, par.unit, par.start) == ("a_yaw", "a", "1", 1.0)
    assert par.support == ("bounded", 0.0, 2.0) and not par.scales_with_inertia
    assert "thrust_tilt" in TERMS and "thrust_tilt" not in EFFECTS
    with pytest.raises(ParameterError, match="yaw torques only"):
        build_model(["pitch:thrust_tilt"])
    assert again.effects[-1].reads() == ("K_psi_theta", "K_psi_psi")
    with pytest.raises(ParameterError, match="reads K_psi_theta, K_psi_psi, which no term"):
        build_model(["yaw:thrust_tilt", "yaw:torque_offset"], linear_torque=False)
