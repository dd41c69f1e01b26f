"""Sampling coordinates in which the record's (non-)identifiable directions are explicit.

The angles depend on the parameters only through ratios to the pitch inertia
``M11 = J_bc + m r_c^2 + m h^2`` (divide both equations of motion by ``M11``; the yaw
equation by ``M22``, which is ``M11`` times a ratio too).  So, for the default free set
(every Table 2 parameter but ``g``), we sample

======================  ===============================  ==================================
coordinate              meaning                          identified by the angles?
======================  ===============================  ==================================
log_J_pitch             log M11 [kg m^2]                 no: common scale of m, J_bc, J_s,
                                                         K_*, D_* (its posterior = prior)
log_gravity_ratio       log(m g r_c / M11) [1/s^2]       yes
logit_body_fraction     logit(m (r_c^2 + h^2) / M11)     only through h: weak when h ~ 0,
                                                         none when h is fixed at 0
h_over_r_c              h / r_c                          yes (if h is free)
log_J_s_ratio           log(J_s / M11)                   yes, often weakly (see below)
log_<K>_ratio (2)       log(K / M11), pitch gains        yes
log_D_theta_ratio       log(D_theta / M11)               yes
log_<K>_yaw_ratio (2)   log(K / M22(theta_ref)),         yes
                        yaw gains K_psi_theta, K_psi_psi
log_D_psi_yaw_ratio     log(D_psi / M22(theta_ref))      yes
======================  ===============================  ==================================

The yaw torques act through the yaw inertia ``M22(theta) = J_bc c^2 + m (r_c c - h s)^2
+ J_s``, which the record identifies mainly at the pitch angles it visits.  Relative to
``M11`` the yaw gains trade against ``J_s / M11`` along a *curved* ridge (``K_psi / M11 ~
J_s / M11 + cos^2 theta``), and NUTS diverges where that ridge bends; relative to
``M22`` at a reference pitch ``theta_ref`` (``yaw_theta_ref``, by default the median
measured pitch of the training window, :func:`heli_uq.model.make_problem`) the ridge is
nearly straight and ``log_J_s_ratio`` is left with what only the pitch variation tells.

The two unidentified directions become straight coordinate axes, along which the
posterior is the (conditional) prior.  The common scale is handled *exactly*: ``m``,
``J_bc``, ``J_s``, ``K_*`` and ``D_*`` are ``M11`` times functions of the other
coordinates while ``r_c`` and ``h`` do not depend on ``M11``, so with log-normal priors
the conditional prior of ``log M11`` is Gaussian (:meth:`Coordinates.scale_conditional`).
The model integrates it out of the prior of the other coordinates and draws it as
``mean + sd * scale_noise`` with ``scale_noise ~ N(0, 1)``, a direction the likelihood
never sees: NUTS no longer has to explore a prior-wide ridge.  The priors stay the
user's priors on the *physical* parameters: the log
density includes ``log |det d w / d z|`` where ``w`` are the coordinates in which each
prior is Gaussian (log for log-normal priors).  Any other choice of free parameters
falls back to plain log coordinates (``strategy="log"``).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping

import jax
import jax.numpy as jnp
import numpy as np

from heli_uq.params import PARAM_NAMES
from heli_uq.priors import Prior

__all__ = ["Coordinates"]

_SCALED = ("J_s", "K_theta_theta", "K_theta_psi", "K_psi_theta", "K_psi_psi", "D_theta", "D_psi")
#: Scaled parameters of the yaw equation, sampled relative to ``M22(theta_ref)``.
_YAW = ("K_psi_theta", "K_psi_psi", "D_psi")
_BODY = ("r_c", "m", "J_bc")


@dataclasses.dataclass(frozen=True, eq=False)
class Coordinates:
    """Map between unconstrained sampling coordinates ``z`` and physical parameters.

    Parameters
    ----------
    priors : mapping of str to Prior
        One prior per Table 2 name; ``fixed`` priors are not sampled.
    strategy : {"auto", "identifiable", "log"}
        ``auto`` uses ``identifiable`` when the free set allows it.
    yaw_theta_ref : float
        Pitch angle [rad] at which the yaw inertia ``M22`` of the yaw-gain coordinates
        is taken (identifiable strategy only; any value gives a valid map).
    """

    priors: Mapping[str, Prior]
    strategy: str = "auto"
    yaw_theta_ref: float = 0.0

    def __post_init__(self):
        free = tuple(n for n in PARAM_NAMES if self.priors[n].free)
        object.__setattr__(self, "free", free)
        possible = (
            all(self.priors[n].kind == "lognormal" for n in _BODY + _SCALED)
            and not self.priors["g"].free
            and (self.priors["h"].kind == "normal"
                 or (self.priors["h"].kind == "fixed" and self.priors["h"].a == 0.0))
        )  # fmt: skip
        strategy = self.strategy
        if strategy == "auto":
            strategy = "identifiable" if possible else "log"
        if strategy == "identifiable" and not possible:
            raise ValueError(
                "identifiable coordinates need log-normal priors on r_c, m, J_bc, J_s, K_*, D_*,"
                " g fixed and h free (normal) or fixed at 0"
            )
        object.__setattr__(self, "resolved", strategy)
        if strategy == "identifiable":
            names = ["log_J_pitch", "log_gravity_ratio", "logit_body_fraction"]
            if self.priors["h"].free:
                names.append("h_over_r_c")
            names += [f"log_{n}_yaw_ratio" if n in _YAW else f"log_{n}_ratio" for n in _SCALED]
            unidentified = ("log_J_pitch",) + (() if self.priors["h"].free
                                               else ("logit_body_fraction",))  # fmt: skip
        else:
            names = [f"log_{n}" if self.priors[n].kind == "lognormal" else n for n in free]
            unidentified = ()
        object.__setattr__(self, "names", tuple(names))
        object.__setattr__(self, "unidentified", unidentified)

    @property
    def dim(self) -> int:
        return len(self.names)

    @property
    def marginal_scale(self) -> bool:
        """True when ``log_J_pitch`` is integrated out (identifiable strategy)."""
        return self.resolved == "identifiable"

    @property
    def sampled_names(self) -> tuple[str, ...]:
        """Coordinates the sampler moves in (``names`` without ``log_J_pitch`` if marginal)."""
        return self.names[1:] if self.marginal_scale else self.names

    def _scale_weights(self):
        """Per free parameter: 1 if its prior coordinate shifts with log M11, else 0."""
        return jnp.asarray([0.0 if n in ("r_c", "h") else 1.0 for n in self.free])

    def scale_conditional(self, z_rest):
        """Exact conditional prior of ``log M11`` given the other coordinates.

        Returns ``(log_marginal, mean, sd)``: the log prior density of ``z_rest`` with
        ``log M11`` integrated out (Jacobian included), and the Gaussian conditional.
        """
        z0 = jnp.concatenate([jnp.zeros(1), z_rest])
        w0 = self._prior_coordinates(z0)
        mu = jnp.asarray([self.priors[n].coordinate_mean for n in self.free])
        sd = jnp.asarray([self.priors[n].b for n in self.free])
        e = self._scale_weights()
        lam = jnp.sum(e / sd**2)
        b = jnp.sum(e * (mu - w0) / sd**2)
        base = jnp.sum(-0.5 * ((w0 - mu) / sd) ** 2 - jnp.log(sd) - 0.5 * jnp.log(2 * jnp.pi))
        _, logdet = jnp.linalg.slogdet(jax.jacfwd(self._prior_coordinates)(z0))
        log_marginal = base + 0.5 * b * b / lam - 0.5 * jnp.log(lam) + 0.5 * jnp.log(2 * jnp.pi)
        return log_marginal + logdet, b / lam, 1.0 / jnp.sqrt(lam)

    # ------------------------------------------------------------------ maps
    def to_physical(self, z) -> dict:
        """All twelve parameters (jnp scalars, SI) from coordinates ``z`` of shape (dim,)."""
        fixed = {n: jnp.asarray(p.a, dtype=jnp.float64) for n, p in self.priors.items()
                 if not p.free}  # fmt: skip
        if self.resolved == "log":
            out = dict(fixed)
            for i, n in enumerate(self.free):
                out[n] = jnp.exp(z[i]) if self.priors[n].kind == "lognormal" else z[i]
            return out
        g = fixed["g"]
        m11 = jnp.exp(z[0])
        gamma = jnp.exp(z[1])
        frac = jax.nn.sigmoid(z[2])
        i = 3
        if self.priors["h"].free:
            rho, i = z[3], 4
        else:
            rho = jnp.zeros(())
        mrc = gamma * m11 / g
        r_c = frac * m11 / ((1.0 + rho * rho) * mrc)
        out = dict(fixed)
        out.update(r_c=r_c, m=mrc / r_c, h=rho * r_c, J_bc=m11 * (1.0 - frac))
        for k, n in enumerate(_SCALED):
            if n not in _YAW:
                out[n] = m11 * jnp.exp(z[i + k])
        m22 = self._yaw_inertia(out)
        for k, n in enumerate(_SCALED):
            if n in _YAW:
                out[n] = m22 * jnp.exp(z[i + k])
        return out

    def _yaw_inertia(self, p):
        """``M22(yaw_theta_ref)`` [kg m^2] of a parameter mapping (numpy or jax)."""
        c, s = math.cos(self.yaw_theta_ref), math.sin(self.yaw_theta_ref)
        return p["J_bc"] * c * c + p["m"] * (p["r_c"] * c - p["h"] * s) ** 2 + p["J_s"]

    def from_physical(self, values: Mapping[str, float]) -> np.ndarray:
        """Coordinates of a full parameter mapping (inverse of :meth:`to_physical`)."""
        v = {n: float(values[n]) for n in PARAM_NAMES}
        if self.resolved == "log":
            return np.array([math.log(v[n]) if self.priors[n].kind == "lognormal" else v[n]
                             for n in self.free])  # fmt: skip
        m11 = v["J_bc"] + v["m"] * (v["r_c"] ** 2 + v["h"] ** 2)
        g = float(self.priors["g"].a)
        frac = v["m"] * (v["r_c"] ** 2 + v["h"] ** 2) / m11
        z = [math.log(m11), math.log(v["m"] * g * v["r_c"] / m11), math.log(frac / (1 - frac))]
        if self.priors["h"].free:
            z.append(v["h"] / v["r_c"])
        m22 = self._yaw_inertia(v)
        z += [math.log(v[n] / (m22 if n in _YAW else m11)) for n in _SCALED]
        return np.array(z)

    def _prior_coordinates(self, z):
        phys = self.to_physical(z)
        return jnp.stack([self.priors[n].to_coordinate(phys[n]) for n in self.free])

    def log_prior(self, z):
        """Log prior density of ``z``: the physical priors plus ``log |det dw/dz|``."""
        w = self._prior_coordinates(z)
        lp = sum(self.priors[n].log_density_coordinate(w[i]) for i, n in enumerate(self.free))
        if self.resolved == "log":
            return lp
        _, logdet = jnp.linalg.slogdet(jax.jacfwd(self._prior_coordinates)(z))
        return lp + logdet

