"""MAP machinery: the Newton polish converges where a gradient-norm criterion cannot."""

import jax.numpy as jnp
import numpy as np

from heli_uq.inference.density import LogDensity
from heli_uq.inference.map import newton_polish

#: Distance to the known optimum after the polish, relative to the smallest posterior sd.
OPTIMUM_TOL = 1e-6


def test_newton_polish_reaches_the_optimum_of_an_ill_conditioned_density():
    # -log p = 0.5 (x - m)^T A (x - m) + 0.25 sum (x - m)^4 with cond(A) = 1e9, as at the
    # rig's MAP (pitch gain vs gravity); the quartic makes it non-quadratic.
    rng = np.random.default_rng(0)
    q, _ = np.linalg.qr(rng.normal(size=(5, 5)))
    a = (q * np.logspace(0, 9, 5)) @ q.T
    m = rng.normal(size=5)

    def potential(x):
        d = x - m
        return 0.5 * d @ jnp.asarray(a) @ d + 0.25 * jnp.sum(d**4)

    density = LogDensity(None, potential, None, np.zeros(5))
    start = m + q[:, 0] * 0.3 + q[:, -1] * 1e-3  # off along the weakest and stiffest axes
    x, value, grad_max, decrement, steps = newton_polish(density, start)
    smallest_sd = 1.0 / np.sqrt(1e9)
    assert np.max(np.abs(x - m)) < OPTIMUM_TOL * smallest_sd
    assert decrement < 1e-12 and 0 < steps
    assert value <= float(potential(start))
