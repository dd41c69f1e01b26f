"""Sampling coordinates in which the record's (non-)identifiable directions are explicit.

The angles depend on the parameters only through ratios to the inertias: divide the
pitch equation by ``M11 = J_bc + m r_c^2 + m h^2`` and the yaw equation by ``M22``,
which is ``M11`` times a ratio too.  Every parameter flagged ``scales_with_inertia``
(masses, inertias, torque-type parameters of any term) enters only through such a
ratio, so multiplying all of them by one factor leaves the angles unchanged.  The
``identifiable`` strategy samples

======================  ===============================  ==================================
coordinate              meaning                          identified by the angles?
======================  ===============================  ==================================
log_J_pitch             log M11 [kg m^2]                 no: the common scale (its
                                                         posterior = its conditional prior)
log_gravity_ratio       log(m g r_c / M11) [1/s^2]       yes
logit_body_fraction     logit(m (r_c^2 + h^2) / M11)     only through h: weak when h ~ 0,
                                                         none when h is fixed at 0
h_over_r_c              h / r_c                          yes (if h is free)
log_<X>_ratio           log(X / M11) for every other     yes (some weakly, e.g. J_s)
                        scaled parameter X of the pitch
                        axis (``X_ratio`` for a prior
                        on the real line, e.g. T_0)
log_<X>_yaw_ratio       log(X / M22(theta_ref)) for the  yes
                        yaw axis
<T>_net_ratio           (T + sum_j s_j K_j u_j) / M      yes
                        for a constant torque T (torque
                        offset), K_j the gains of its
                        axis, s_j their signs: the net
                        constant torque at the mean
                        voltages u
log_<Y>, <Y>, logit_<Y> every unscaled parameter Y        as the data allow
                        (r_c excepted), by its prior's
                        support (log, identity, logit)
======================  ===============================  ==================================

The first four are the mechanics' :data:`~heli_uq.model.terms.rigid_body.BODY_COORDINATES`;
the rest follow from each parameter's declaration (``scales_with_inertia``, ``axis``)
and prior, so an effect added to the model gets its coordinate without code here.

A constant torque and the gains of its axis trade off: the pitch voltage barely varies on
the rig, so ``K_psi_theta u_theta`` is nearly a yaw offset too.  In ``T / M22`` and
``log(K / M22)`` that trade-off is an exponentially curved ridge (a hidden yaw offset on a
21 s record: NUTS took 217 leapfrog steps per draw, step size 0.07); sampling the net
constant torque at the mean voltages ``u_ref`` of the training window makes it straight.

The yaw torques act through the yaw inertia ``M22(theta)``, which the record identifies
mainly at the pitch angles it visits.  Relative to ``M11`` the yaw gains trade against
``J_s / M11`` along a *curved* ridge, and NUTS diverges where that ridge bends; relative
to ``M22`` at a reference pitch ``theta_ref`` (``yaw_theta_ref``, by default the median
measured pitch of the training window) the ridge is nearly straight.

**The common scale is integrated out exactly.**  Every scaled parameter ``X`` is ``M11``
times a function of the other coordinates, so its log is ``s + c_X(z_rest)`` with
``s = log M11``.  The log-normal priors among them make the conditional prior of ``s``
Gaussian; :meth:`Coordinates.marginal_log_prior` returns the log prior with
``s = mean + sd * eps``, where ``eps ~ N(0, 1)`` is a separate site and the Gaussian part
is integrated analytically.  ``eps`` is independent of the data and of every other
coordinate, a direction the likelihood never sees, and its posterior is its prior.

**The common scale's prior** is not the product of the priors: its width is one
parameter's, and the priors that are not log-normal cannot move it
(:mod:`heli_uq.probability.common_scale`, whose methods :class:`Coordinates` inherits).

Otherwise the priors are the user's priors on the *physical* parameters: the log density
includes ``log |det dw/dz|`` where ``w`` are the coordinates in which each prior's
density is written (:meth:`heli_uq.model.Prior.log_density_coordinate`).  Priors that
do not allow the ratio map (e.g. a fixed scaled parameter, which breaks the symmetry)
fall back to plain per-parameter coordinates (``strategy="log"``).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping

import jax
import jax.numpy as jnp
import numpy as np

from heli_uq.errors import ParameterError
from heli_uq.model.heli_model import HeliModel
from heli_uq.model.terms.rigid_body import (
    BODY_PARAMETERS,
    body_coordinates,
    body_from_ratios,
    body_log_jacobian,
    body_to_ratios,
    pitch_inertia,
    ratio_coordinates_allowed,
    yaw_inertia,
)
from heli_uq.probability.common_scale import CommonScale

__all__ = ["Coordinates", "STRATEGIES"]

STRATEGIES = ("auto", "identifiable", "log")
#: The body fraction ``m (r_c^2 + h^2) / M11`` is kept this far inside (0, 1) when it is
#: turned into its logit: an optimiser can push ``J_bc`` to 0, where the sigmoid of a
#: large coordinate rounds to exactly 1 and the logit of the values is infinite.
BODY_FRACTION_EPS = 1e-12
_PREFIX = {"log": "log_", "identity": "", "logit": "logit_"}


def _coordinate_name(name: str, transform: str, suffix: str = "") -> str:
    return f"{_PREFIX[transform]}{name}{suffix}"


@dataclasses.dataclass(frozen=True, eq=False)
class Coordinates(CommonScale):
    """Map between unconstrained sampling coordinates ``z`` and the model's parameters.

    Parameters
    ----------
    model : HeliModel
    priors : mapping of str to Prior
        One prior per model parameter; ``fixed`` priors are not sampled.
    strategy : {"auto", "identifiable", "log"}
        ``auto`` uses ``identifiable`` when the model and priors allow it.
    yaw_theta_ref : float
        Pitch angle [rad] at which the yaw inertia of the yaw-ratio coordinates is taken.
    u_ref : (float, float)
        Voltages [V] (by default none, ``(0, 0)``; :func:`heli_uq.probability.make_problem`
        uses the training window's means) at which a constant torque is sampled as the net
        constant torque of its axis (``<T>_net_ratio``).

    Attributes
    ----------
    free : tuple of str
        Free parameter names, in model order.
    names : tuple of str
        Coordinate names; ``log_J_pitch`` first for the identifiable strategy.
    unidentified : tuple of str
        Coordinates the angles do not depend on.
    resolved : str
        The strategy in use.
    """

    model: HeliModel
    priors: Mapping
    strategy: str = "auto"
    yaw_theta_ref: float = 0.0
    u_ref: tuple = (0.0, 0.0)

    def __post_init__(self):
        if self.strategy not in STRATEGIES:
            raise ParameterError(f"strategy: expected one of {STRATEGIES}, found {self.strategy!r}")
        params = self.model.parameters()
        missing = [p.name for p in params if p.name not in self.priors]
        if missing:
            raise ParameterError(f"priors: no prior for {', '.join(missing)}")
        for term in self.model.terms:
            term.check_priors(self.priors)
        free = tuple(p.name for p in params if self.priors[p.name].free)
        object.__setattr__(self, "free", free)
        possible = self._ratio_map_possible()
        strategy = ("identifiable" if possible else "log") if self.strategy == "auto" else self.strategy
        if strategy == "identifiable" and not possible:
            raise ParameterError(
                "identifiable coordinates need the closed-form mechanics, log-normal priors on "
                "r_c, m, J_bc, g fixed, h normal or fixed at 0, every inertia-scaled parameter "
                "free and none with a uniform prior"
            )
        object.__setattr__(self, "resolved", strategy)
        decl = {p.name: p for p in params}
        specs = []  # (coordinate name, parameter name, kind) kind: body | ratio | plain
        if strategy == "identifiable":
            body, unidentified = body_coordinates(self.priors)
            specs += [(c, None, "body") for c in body]
            for n in free:
                if n in BODY_PARAMETERS:
                    continue
                tr = self.priors[n].transform
                if decl[n].scales_with_inertia:
                    # "_yaw_ratio": relative to M22; effect names already end in "_yaw"
                    yaw = decl[n].axis == "yaw" and not n.endswith("_yaw")
                    suffix = "_yaw_ratio" if yaw else "_ratio"
                    if decl[n].constant_torque and tr == "identity" and any(self.u_ref):
                        specs.append((f"{n}_net_ratio", n, "net"))
                    else:
                        specs.append((_coordinate_name(n, tr, suffix), n, "ratio"))
                else:
                    specs.append((_coordinate_name(n, tr), n, "plain"))
        else:
            specs = [(_coordinate_name(n, self.priors[n].transform), n, "plain") for n in free]
            unidentified = ()
        object.__setattr__(self, "_specs", tuple(specs))
        object.__setattr__(self, "_decl", decl)
        object.__setattr__(self, "names", tuple(s[0] for s in specs))
        object.__setattr__(self, "unidentified", unidentified)

    def _ratio_map_possible(self) -> bool:
        if not getattr(self.model.mechanics, "ratio_coordinates", False):
            return False
        if not ratio_coordinates_allowed(self.priors):
            return False
        scaled = [p for p in self.model.parameters() if p.scales_with_inertia]
        return all(self.priors[p.name].free and self.priors[p.name].kind != "uniform" for p in scaled)

    # ---------------------------------------------------------------- facts
    @property
    def dim(self) -> int:
        return len(self.names)

    @property
    def marginal_scale(self) -> bool:
        """True when ``log_J_pitch`` is integrated out (identifiable strategy)."""
        return self.resolved == "identifiable"

    def samples_yaw_momentum(self, prior) -> bool:
        """True when a free initial yaw rate of prior ``prior`` is sampled as its momentum
        ratio ``p_psi0_ratio`` (a normal prior, identifiable strategy;
        :mod:`heli_uq.probability.numpyro_model`)."""
        return self.resolved == "identifiable" and prior.kind == "normal"

    def yaw_inertia_ratio(self, p, theta):
        """``M22(theta) / M22(theta_ref)`` (dimensionless) of the parameters ``p`` (jnp
        scalars) at the pitch ``theta`` [rad]: the initial yaw rate's momentum factor."""
        return yaw_inertia(p, theta) / self._inertia(p, "yaw")

    @property
    def sampled_names(self) -> tuple[str, ...]:
        """Coordinates the sampler moves in (``names`` without ``log_J_pitch`` if marginal)."""
        return self.names[1:] if self.marginal_scale else self.names

    def _inertia(self, p, axis):
        if axis == "pitch":
            return pitch_inertia(p)
        # the record's reference pitch as an array element: an argument of the compiled
        # program, not a constant in it (records of one length share programs; _jax_config)
        return yaw_inertia(p, jnp.asarray([self.yaw_theta_ref])[0])

    # ------------------------------------------------------------------ maps
    def to_physical(self, z) -> dict:
        """Every model parameter (jnp scalars, SI) from coordinates ``z`` of shape (dim,)."""
        return self._physical_and_scales(z)[0]

    @property
    def _n_body(self) -> int:
        return sum(1 for s in self._specs if s[2] == "body")

    def _physical_and_scales(self, z) -> tuple[dict, dict]:
        """:meth:`to_physical` and, for every coordinate ``i`` after the body's, the factor
        ``S_i`` in ``x = S_i F(z_i) - offset`` (``F`` its prior's ``from_coordinate``; 1 for
        an unscaled parameter, the axis inertia for a ratio or net torque), by parameter
        name.  ``S_i`` and ``offset`` depend only on coordinates before ``i`` in the order
        of evaluation here (body, unscaled and pitch ratios, yaw ratios, net torques)."""
        out = {n: jnp.asarray(pr.a, dtype=jnp.float64) for n, pr in self.priors.items()
               if not pr.free}  # fmt: skip
        scales, later, net = {}, [], []
        start = self._n_body
        if start:
            out.update(body_from_ratios(jnp.exp(z[0]), jnp.exp(z[1]), jax.nn.sigmoid(z[2]),
                                        z[3] if start == 4 else jnp.zeros(()), out))  # fmt: skip
        for i, (_, n, kind) in enumerate(self._specs[start:], start):
            if kind == "plain":
                scales[n] = jnp.ones(())
            elif kind == "net":
                net.append((i, n))  # needs the gains of its axis first
                continue
            elif self._decl[n].axis == "yaw":
                later.append((i, n))  # needs M22, i.e. J_s and the body, first
                continue
            else:
                scales[n] = pitch_inertia(out)
            out[n] = scales[n] * self.priors[n].from_coordinate(z[i])
        for i, n in later:
            scales[n] = self._inertia(out, "yaw")
            out[n] = scales[n] * self.priors[n].from_coordinate(z[i])
        for i, n in net:
            scales[n] = self._inertia(out, self._decl[n].axis)
            out[n] = scales[n] * z[i] - self._gain_torque(out, n)
        return out, scales

    def _gain_torque(self, values, name):
        """``sum_j s_j K_j u_ref_j`` over the gains of ``name``'s axis [N m]."""
        axis = self._decl[name].axis
        return sum(par.input[1] * values[g] * self.u_ref[par.input[0]]
                   for g, par in self._decl.items() if par.input is not None and par.axis == axis)

    def from_physical(self, values: Mapping[str, float]) -> np.ndarray:
        """Coordinates of a full parameter mapping (inverse of :meth:`to_physical`)."""
        v = {n: float(values[n]) for n in self.priors}
        z = []
        if self.resolved == "identifiable":
            m11, gamma, frac, rho = body_to_ratios(v)
            frac = min(max(frac, BODY_FRACTION_EPS), 1.0 - BODY_FRACTION_EPS)
            z += [math.log(m11), math.log(gamma), math.log(frac / (1.0 - frac)), rho]
            z = z[: sum(1 for s in self._specs if s[2] == "body")]
        for _, n, kind in self._specs:
            if kind == "body":
                continue
            if kind == "net":
                axis = self._decl[n].axis
                z.append((v[n] + float(self._gain_torque(v, n))) / float(self._inertia(v, axis)))
                continue
            x = v[n] if kind == "plain" else v[n] / float(self._inertia(v, self._decl[n].axis))
            z.append(float(self.priors[n].to_coordinate(x)))
        return np.asarray(z, dtype=float)

    # ----------------------------------------------------------------- prior
    def prior_coordinates(self, z):
        """``w`` of every free parameter: the coordinate its prior density is written in."""
        phys = self.to_physical(z)
        return jnp.stack([self.priors[n].to_coordinate(phys[n]) for n in self.free])

    def _log_jacobian(self, z, mapped=None):
        """``log |det dw/dz|``, in closed form from the triangular structure of the map.

        Each coordinate after the body's enters one parameter, ``x = S F(z_i) - offset``,
        whose ``S`` and ``offset`` depend only on earlier coordinates
        (:meth:`_physical_and_scales`): in that order ``dw/dz`` is block lower-triangular,
        with the body's 3 x 3 or 4 x 4 block (:func:`body_log_jacobian`, closed form) and
        the scalars ``T'(x) S F'(z_i)`` on the diagonal (``T`` the prior's
        ``to_coordinate``).  The dense ``slogdet(jacfwd(prior_coordinates))``, which
        differentiated the whole map in every direction, made a sixth of the log
        density's compiled gradient and a third of NUTS's compile time
        (``studies/bench_nuts_trace.py``; tests check that the two agree).  ``mapped``: the
        result of :meth:`_physical_and_scales` at ``z`` when the caller has it.
        """
        if self.resolved == "log":  # w = z
            return jnp.zeros(())
        out, scales = self._physical_and_scales(z) if mapped is None else mapped
        start = self._n_body
        log_det = body_log_jacobian(out, with_h=start == 4)
        for i, (_, n, _) in enumerate(self._specs[start:], start):
            pr = self.priors[n]
            slope = jax.grad(pr.to_coordinate)(out[n]) * scales[n] * jax.grad(pr.from_coordinate)(z[i])
            log_det = log_det + jnp.log(jnp.abs(slope))
        return log_det

    def _log_prior_and_physical(self, z, skip=()):
        """``(log prior of z without the free parameters at the indices skip, parameters)``
        from one evaluation of the map.  Parameters under a term's joint prior
        (:attr:`HeliModel.joint_names`, normal declared priors: ``w = x``) take that prior
        instead of their own."""
        mapped = self._physical_and_scales(z)
        out = mapped[0]
        joint = set(self.model.joint_names)
        own = [n for i, n in enumerate(self.free) if i not in skip and n not in joint]
        lp = sum((self.priors[n].log_density_coordinate(self.priors[n].to_coordinate(out[n])) for n in own),
                 jnp.zeros(()))  # fmt: skip
        if joint:
            lp = lp + self.model.joint_log_prior(out)
        return lp + self._log_jacobian(z, mapped), out

    def prior_moments(self) -> tuple[np.ndarray, np.ndarray]:
        """Mean and sd of each free parameter's prior in its coordinate ``w`` (model order)."""
        m = np.array([self.priors[n].coordinate_moments() for n in self.free])
        return m[:, 0], m[:, 1]

    def describe(self) -> dict:
        """JSON facts: strategy, coordinate names, unidentified ones, ``yaw_theta_ref``,
        ``u_ref``."""
        return {"strategy": self.resolved, "names": list(self.names),
                "unidentified": list(self.unidentified), "yaw_theta_ref": self.yaw_theta_ref,
                "u_ref": list(self.u_ref)}  # fmt: skip
