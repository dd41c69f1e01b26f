"""The discovery screen: the Ljung-Box test against its null distribution and a smooth
residual, white axes per window, and which axes an effect acts on (against the Jacobian
of the generalized force in the effect's parameters)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

from heli_uq.discovery.screen import P_WHITE, ljung_box, screen_text, screened, white_axes
from heli_uq.model import AXES, RIG_FIT, build_model
from heli_uq.model.terms import TERMS
from heli_uq.model.terms.base import AbstractEffect

#: Kolmogorov-Smirnov p-value above which the white-noise p-values pass as uniform.
KS_P_MIN = 0.01
#: A smooth residual of this RMS relative to the noise is about the weakest that the
#: decision's margin (0.009 nats per held-out sample) can pass: n (a / sigma)^2 / 2 per n.
MARGIN_AMPLITUDE = 0.134
#: A derivative counts as nonzero above this [N m per unit parameter].
NONZERO = 1e-12
DT = 0.01


def test_ljung_box_is_chi_square_on_white_noise():
    rng = np.random.default_rng(5)
    lags = 20
    p = [ljung_box(rng.standard_normal(2000), lags)[1] for _ in range(400)]
    assert stats.kstest(p, "uniform").pvalue > KS_P_MIN


def test_ljung_box_finds_a_smooth_residual_at_the_margin_and_an_offset():
    rng = np.random.default_rng(6)
    n, sigma = 9170, 0.003  # a 91.7 s fitting window of pitch
    t = np.arange(n) * DT
    smooth = np.sin(2 * np.pi * t / 7.0) + 0.5 * np.sin(2 * np.pi * t / 2.3 + 1.0)
    smooth *= MARGIN_AMPLITUDE * sigma / np.sqrt(np.mean(smooth**2))
    noise = sigma * rng.standard_normal(n)
    lags = round(1.0 / DT)
    assert ljung_box(noise, lags)[1] > P_WHITE
    assert ljung_box(noise + smooth, lags)[1] < 1e-6
    # about zero, not about the mean: an offset of 0.2 sigma is structure
    assert ljung_box(noise + 0.2 * sigma, lags)[1] < 1e-6


def test_an_axis_is_white_only_if_every_window_is():
    rng = np.random.default_rng(7)
    n = 6000
    resid = rng.standard_normal((n, 2)) * (0.003, 0.008)
    resid[4000:, 1] += 0.004 * np.sin(np.arange(2000) * DT)  # yaw drifts on the held-out part
    windows = {"train": (0, 4000), "test": (4000, n)}
    white = white_axes(resid, windows, DT)
    assert white["lags"] == 100
    assert white["pitch"]["white"] and min(white["pitch"]["p"].values()) >= P_WHITE
    assert not white["yaw"]["white"] and white["yaw"]["p"]["train"] >= P_WHITE > white["yaw"]["p"]["test"]
    short = white_axes(resid, {"train": (0, 4000), "test": (4000, 4050)}, DT)  # 50 samples < 100 lags
    assert short["pitch"]["p"]["test"] is None and not short["pitch"]["white"]
    resid[10, 0] = np.nan
    assert not white_axes(resid, windows, DT)["pitch"]["white"]
    # as the log and the report read it: an underflowed tail is not "p = 0"
    resid[:, 1] += 0.01  # an offset larger than the noise
    text = screen_text(white_axes(resid, windows, DT))
    assert text.startswith("Ljung-Box p over 100 lags: pitch – (train), ") and "yaw <1e-300 (train)" in text


def _effects():
    out = []
    for kind, cls in TERMS.items():
        if not issubclass(cls, AbstractEffect) or cls.record_keys:
            continue  # a discrepancy term is set up from a record, never a candidate
        for axis in AXES:
            try:
                build_model([f"{axis}:{kind}"])
            except Exception:  # noqa: BLE001 - a term defined on one axis only
                continue
            out.append(f"{axis}:{kind}")
    return out


@pytest.mark.parametrize("effect", _effects())
def test_an_effect_acts_on_the_axes_whose_force_its_parameters_move(effect):
    """The generalized force's Jacobian in the effect's own parameters, at a moving state
    after a varying voltage sequence (through every input map and sequence filter), is
    nonzero exactly on the axes ``acts_on`` names."""
    model = build_model([effect])
    term = model.effects[0]
    values = model.complete({**RIG_FIT, **model.start_values()})
    names = [p.name for p in term.parameters()]
    rng = np.random.default_rng(8)
    u_seq = jnp.asarray(np.column_stack([rng.uniform(0.5, 2.0, 60), rng.uniform(-1.5, 1.5, 60)]))
    x, v = (0.3, 0.7), (0.01, -0.015)  # rates near the breakaway width of stiction (0.02 rad/s)

    def force(vec):
        _, p = model.prepare({**values, **dict(zip(names, vec))})
        u = model.input_voltages(p, model.filtered_voltages(p, u_seq, DT)[-1])
        return model.force_vector(p, x, v, u)

    jac = np.asarray(jax.jacfwd(force)(jnp.asarray([values[n] for n in names], dtype=float)))
    moved = tuple(a for i, a in enumerate(AXES) if np.any(np.abs(jac[i]) > NONZERO))
    assert moved == term.acts_on()


def test_the_screen_keeps_a_motor_effect_until_both_axes_are_white():
    def white(pitch, yaw):
        return {"lags": 100, "p_white": P_WHITE,
                **{a: {"white": w, "p": {"train": 0.5 if w else 1e-9}} for a, w in zip(AXES, (pitch, yaw))}}

    pool = ["pitch:coulomb_friction", "pitch:deadband", "yaw:torque_offset", "yaw:axis_tilt"]
    assert set(screened(pool, white(True, False))) == {"pitch:coulomb_friction"}
    assert set(screened(pool, white(False, True))) == {"yaw:torque_offset"}
    assert set(screened(pool, white(True, True))) == set(pool)
    assert screened(pool, white(False, False)) == {}
    why = screened(pool, white(True, False))["pitch:coulomb_friction"]
    assert why.startswith("not fitted: it acts on pitch, where the base model's residuals are white")
