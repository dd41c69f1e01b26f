"""Levenberg-Marquardt with fixed coordinates: the least-squares engine of the MAP's
first stage (:func:`heli_uq.inference.least_squares_fit`), the likelihood fit and the
profiles of the identifiability report (:mod:`heli_uq.identifiability`).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp

__all__ = ["masked_least_squares"]

#: Levenberg-Marquardt: stop when the relative decrease of the cost in an accepted step is below this.
LM_RTOL = 1e-9
#: Initial damping (relative to the diagonal of J^T J) and its factor after a rejected step.
LM_DAMPING0 = 1e-3
LM_DAMPING_FACTOR = 10.0
#: Give up (converged as far as the damping allows) above this damping.
LM_DAMPING_MAX = 1e10


@eqx.filter_jit
def masked_least_squares(residuals, w0, mask, w_fixed, max_steps: int = 200):
    """Levenberg-Marquardt fit of ``0.5 |r(w)|^2`` with some coordinates held fixed.

    ``residuals``: a callable ``w (P,) -> r (M,)``, forward-differentiable; pass a pytree
    module (e.g. :class:`heli_uq.identifiability.fisher.WhitenedResiduals`) to share one compilation
    between residuals that differ only in arrays.  Non-finite residuals make a step a
    rejection.

    Minimises over the coordinates where ``mask`` (bool, shape (P,)) is False; the others
    are taken from ``w_fixed``.  Returns ``(w, cost)``.  The residuals are an argument
    (a pytree), so one compilation serves the fit, every noise estimate and every
    profile point.

    The Jacobian is formed by forward mode (P tangents through the simulator) after each
    accepted step only; each step solves the damped least-squares problem
    ``[J; sqrt(lam D)] dw = [-r; 0]`` (Marquardt scaling ``D = diag(J^T J)``, floored) by a
    least-squares solve, so singular directions
    (structural null space, fixed coordinates) get ``dw = 0`` instead of round-off.  This
    is written out because ``optimistix.LevenbergMarquardt`` materialised the Jacobian
    through a linearise/transpose route about 10x slower per step on the full record.
    """
    mask = jnp.asarray(mask)
    free = (~mask).astype(jnp.float64)

    def res(w):
        return residuals(jnp.where(mask, w_fixed, w))

    def jacobian(w):
        return jax.jacfwd(res)(w) * free

    def body(carry):
        w, r, jac, c, lam, k, _ = carry
        d = jnp.sum(jac * jac, axis=0)
        d = jnp.maximum(d, 1e-12 * jnp.max(d))
        a = jnp.concatenate([jac, jnp.diag(jnp.sqrt(lam * d))], axis=0)
        b = jnp.concatenate([-r, jnp.zeros_like(w)])
        w_new = w + jnp.linalg.lstsq(a, b)[0] * free
        r_new = res(w_new)
        c_new = 0.5 * jnp.sum(r_new * r_new)
        better = jnp.isfinite(c_new) & (c_new < c)
        # The Jacobian is recomputed only after an accepted step (a rejected one only raises
        # the damping), so converged or flat points cost one Jacobian, not one per rejection.
        jac = jax.lax.cond(better, jacobian, lambda _: jac, w_new)
        done = (better & (c - c_new <= LM_RTOL * c)) | (lam > LM_DAMPING_MAX)
        return (jnp.where(better, w_new, w), jnp.where(better, r_new, r), jac,
                jnp.where(better, c_new, c),
                jnp.where(better, lam / LM_DAMPING_FACTOR, lam * LM_DAMPING_FACTOR), k + 1, done)

    def cond(carry):
        return (carry[5] < max_steps) & ~carry[6]

    w0 = jnp.where(mask, w_fixed, w0)
    r0 = res(w0)
    init = (w0, r0, jacobian(w0), 0.5 * jnp.sum(r0 * r0), jnp.asarray(LM_DAMPING0), 0,
            jnp.asarray(False))
    w, _, _, c, _, _, _ = jax.lax.while_loop(cond, body, init)
    return w, c
