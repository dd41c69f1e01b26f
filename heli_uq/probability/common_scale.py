"""The prior of the common scale ``log M11``, which no record identifies.

Written out, the product of the priors would make the common scale ``s = log M11`` far
narrower than any one prior and would let the other priors move it:

- *width*: ten log-normal priors of sd 2 give ``s`` a conditional sd of 0.67, counting
  ten times the one thing they share (the defaults are one fit's values, whose scale was
  as arbitrary as any: two fits of the rig, the paper's Table 1 and ``RIG_FIT``, differ
  32x in ``M22``);
- *pull*: a half-normal or normal prior on a torque ``X = e^s r`` in N m adds ``+s`` per
  parameter through its Jacobian until ``X`` reaches the prior's scale, so the effect
  priors (half-normal 0.05 N m) and a network's output weights set the scale.

On a 15 s record made from Table 1's values with a yaw friction hidden, the two put the
truth's ``M22`` at the 2.5 % quantile of its posterior and every friction level, offset
and spring at the edge of its physical interval
(``studies/notes/posterior.md#where-the-common-scale-lands``).  So the prior of ``s``
given ``z_rest`` is ``N(mean, sd)`` with ``mean`` the log-normal product's conditional
mean and ``sd`` the *tightest single* log-normal scaled prior's (2 by default: the scale
is known as well as one parameter is; a tight prior still pins it given the ratios, and
the physical values as far as the record identifies that parameter's ratio: a
calibrated gain does, a weighed mass does not, its ratio to ``M11`` trading with the
pitch gain), and the priors that are not log-normal are evaluated at the scale's
conditional mean: a friction level's prior is on its size relative to the inertias the
other priors imply.  When every scaled prior is log-normal, the ratios' prior is exactly
the product's.  Only the physical values of scaled parameters change; angles, ratios,
predictions and their scores do not depend on ``s``.

These are methods of :class:`heli_uq.probability.Coordinates` (a mixin: they use its
map, priors and declarations).
"""

from __future__ import annotations

from collections.abc import Mapping

import jax.numpy as jnp
import numpy as np

__all__ = ["CommonScale"]


class CommonScale:
    """The common scale's prior and draws: methods of
    :class:`~heli_uq.probability.Coordinates` (module docstring)."""

    def log_prior(self, z):
        """Log prior density of ``z`` (all coordinates).  In the ``log`` strategy: the
        physical priors plus ``log |det dw/dz|``; in the identifiable one that with the
        common scale's prior of the module docstring (:meth:`prior_and_physical` and the
        Gaussian of ``log M11``)."""
        return self._full_prior_and_physical(z)[0]

    def _full_prior_and_physical(self, z):
        """``(log prior, parameters)`` of full coordinates ``z``, one evaluation of the map."""
        if not self.marginal_scale:
            return self._log_prior_and_physical(z)
        _, mean, sd = self.scale_conditional(z[1:])
        eps = (z[0] - mean) / sd
        rest, _, out = self.prior_and_physical(z[1:], eps)
        return rest - 0.5 * eps**2 - 0.5 * jnp.log(2 * jnp.pi) - jnp.log(sd), out

    def _gaussian_scale_terms(self):
        """Free parameters whose log-normal prior coordinate is ``log M11 + c(z_rest)``."""
        return [i for i, n in enumerate(self.free)
                if self._decl[n].scales_with_inertia and self.priors[n].kind == "lognormal"]  # fmt: skip

    def scale_conditional(self, z_rest):
        """Gaussian conditional prior of ``log M11`` given the other coordinates.

        Returns ``(log_marginal, mean, sd)``: the log density of the log-normal scaled
        priors with ``log M11`` integrated out; the mean of ``log M11`` given ``z_rest``
        that their product implies; and the sd of the tightest one of them, not the
        product's (module docstring).
        """
        idx = self._gaussian_scale_terms()
        z0 = jnp.concatenate([jnp.zeros(1), z_rest])
        c = self.prior_coordinates(z0)[jnp.asarray(idx)]
        mu = jnp.asarray([self.priors[self.free[i]].coordinate_moments()[0] for i in idx])
        sd = jnp.asarray([self.priors[self.free[i]].b for i in idx])
        lam = jnp.sum(1.0 / sd**2)
        b = jnp.sum((mu - c) / sd**2)
        base = jnp.sum(-0.5 * ((c - mu) / sd) ** 2 - jnp.log(sd) - 0.5 * jnp.log(2 * jnp.pi))
        log_marginal = base + 0.5 * b * b / lam - 0.5 * jnp.log(lam) + 0.5 * jnp.log(2 * jnp.pi)
        return log_marginal, b / lam, jnp.asarray(self.scale_sd)

    @property
    def scale_sd(self) -> float:
        """sd of ``log M11`` given the other coordinates: the tightest log-normal scaled
        prior's sigma_log (module docstring)."""
        return min(self.priors[self.free[i]].b for i in self._gaussian_scale_terms())

    def marginal_log_prior(self, z_rest, eps):
        """Log prior of ``(z_rest, eps)`` with ``log M11 = mean + sd eps`` (module docstring).

        Returns ``(log density without the N(0, 1) of eps, full z)``.
        """
        log_density, z, _ = self.prior_and_physical(z_rest, eps)
        return log_density, z

    def prior_and_physical(self, z, eps=None):
        """``(log prior, full z, parameters)`` from one evaluation of the map: of the full
        coordinates ``z`` (``eps`` None), or of ``(z_rest, eps)`` as
        :meth:`marginal_log_prior`.  The parameters are :meth:`to_physical` of the full z:
        in the identifiable strategy every scaled one is its value at the scale's
        conditional mean times ``exp(sd eps)``, where the priors are evaluated."""
        if eps is None:
            log_prior, out = self._full_prior_and_physical(z)
            return log_prior, z, out
        log_marginal, mean, sd = self.scale_conditional(z)
        at_mean = jnp.concatenate([mean[None], z])
        rest, out = self._log_prior_and_physical(at_mean, skip=set(self._gaussian_scale_terms()))
        factor = jnp.exp(sd * eps)
        out = {n: v * factor if self._decl[n].scales_with_inertia else v for n, v in out.items()}
        return log_marginal + rest, at_mean.at[0].add(sd * eps), out

    def joint_draws(self, draws: Mapping, eps) -> dict:
        """Draws from the prior of these coordinates, made from draws of the product of the
        priors (:meth:`heli_uq.probability.PriorSet.draw`, name -> array) and standard
        normal ``eps`` of their shape.

        In the identifiable strategy the log-normal scaled parameters are moved along the
        common scale to its conditional mean (``log M11`` moves by the precision-weighted
        mean of ``log(median_X / X)`` over them), where the other priors hold, and every
        scaled parameter then by ``exp(sd eps)`` (module docstring); unscaled ones are
        kept.  In the ``log`` strategy the draws are returned unchanged.
        """
        if not self.marginal_scale:
            return dict(draws)
        idx = self._gaussian_scale_terms()
        names = [self.free[i] for i in idx]
        precision = {n: 1.0 / self.priors[n].b ** 2 for n in names}
        shift = sum(precision[n] * (self.priors[n].coordinate_moments()[0] - np.log(draws[n]))
                    for n in names) / sum(precision.values())  # fmt: skip
        factor = {n: np.exp(self.scale_sd * np.asarray(eps)) for n in draws
                  if self._decl[n].scales_with_inertia}  # fmt: skip
        for n in names:
            factor[n] = factor[n] * np.exp(shift)
        return {n: v * factor[n] if n in factor else v for n, v in draws.items()}

    def scale_noise(self, z) -> float:
        """``eps`` of full coordinates ``z`` (inverse of the map in :meth:`marginal_log_prior`)."""
        _, mean, sd = self.scale_conditional(jnp.asarray(z[1:]))
        return float((z[0] - mean) / sd)
