"""``gp_torque``: a Gaussian-process torque of the voltages on one axis (model discrepancy).

The torque the model misses at each voltage pair is given a Gaussian-process prior over
the voltages (Kennedy & O'Hagan 2001, model discrepancy as a function of the inputs):

    f(u) ~ GP(0, tau^2 k(u, u')),   k(u, u') = exp(-|u - u'|^2 / (2 l^2))      [N m]
    T(u) = f(u) - (beta_0 + beta_1 u_theta + beta_2 u_psi)

with ``u = (u_theta, u_psi)`` [V] after any dead band, amplitude ``tau`` [N m] (sampled,
a torque-type parameter) and length scale ``l`` [V] (:data:`LENGTH_SCALE`, an option of the
term: the voltage distance over which the missing torque stays alike).

**Where the GP lives.**  The voltages of a staircase record take a few dozen distinct
pairs.  The term holds ``f`` at the distinct pairs of the *whole simulated span*
(training window and test window: the inputs are known, only the angles are held out),
non-centred: ``f(P) = tau L z`` with ``L L^T = k(P, P) + JITTER I`` and ``z_j ~ N(0, 1)``
(parameters ``gp_z_<j>_<axis>``).  Between the pairs ``f`` is the kernel interpolant
``f(u) = k(u, P) L^{-T} z tau``, which equals ``f(P)`` at the pairs.  A pair the
training window never holds keeps its own ``z_j``, which the likelihood does not see:
its posterior is the GP's conditional given the pairs that were fitted, so the predictive
of a test window at new voltages carries the spread a torque error of size ``tau`` there
would cause, instead of the narrow band of a model that assumes its gains hold at voltages
it has not seen.  (A record predicted at pairs that are not reference pairs gets the
interpolant only, the conditional mean: fit with a test window to get its spread.)

**Two forms of the same prior** (option ``form``).  ``"whitened"`` samples every pair's
``z_j`` as above.  Where the training window pins a pair's torque ``f_j``, its whitened
value is ``z_j ~ f_j / tau``: a curved ridge along ``log tau`` (a funnel) that NUTS
crosses with divergences.  ``"centred"`` (the default) samples the training pairs'
values ``f_t`` themselves (parameters ``gp_f_<j>_<axis>`` [N m], torque-type) with the
joint prior ``f_t ~ N(0, tau^2 K_tt)``, which the data dominate, and keeps the new pairs
whitened given them, where the prior dominates:

    f_n = K_nt K_tt^{-1} f_t + tau L_c z_n,   L_c L_c^T = K_nn - K_nt K_tt^{-1} K_tn

(``K`` with the nugget).  The joint prior is the term's own
(:meth:`GPTorque.joint_log_prior`, :meth:`GPTorque.draw_joint`); the declared prior of
each ``gp_f_j`` (normal, sd ``TAU_PRIOR_SD``: the joint prior's marginal variance
``E[tau^2] K_jj`` under the default half-normal ``tau``) only sets its sampling coordinate,
the least-squares start's scale and the identifiability report's prior variance.  Both
forms give ``f(P) ~ N(0, tau^2 K)``.

**Keeping the GP from absorbing the physics.**  As for
:class:`~heli_uq.model.terms.neural_torque.NeuralTorque`, ``beta`` is the least-squares
fit of ``f`` at the *training* pairs (weights: samples held) on ``{u_theta, u_psi}``
(``project="u"``) or ``{1, u_theta, u_psi}`` (``project="1,u"``, with a
``torque_offset`` on the axis), subtracted everywhere: the gains own the linear part.

Parameters are named ``gp_tau_<axis>``, ``gp_f_<j>_<axis>`` (centred form, the training
pairs) and ``gp_z_<j>_<axis>``.  The reference pairs, the number of them the training
window holds, the factor ``L^{-T}`` (whitened form) and the projection are set from the record
(:meth:`GPTorque.adapt_to`) and stored in the model's description.
"""

from __future__ import annotations

import functools
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from heli_uq.errors import ParameterError
from heli_uq.model.parameter import Parameter
from heli_uq.model.prior import Prior
from heli_uq.model.terms.base import AbstractEffect, AbstractTorque, float_tuple, gain_projection, on_axis

__all__ = ["GPTorque", "kernel", "LENGTH_SCALE", "TAU_PRIOR_SD", "MAX_PAIRS", "JITTER", "FORMS"]

#: Default length scale [V] of the squared-exponential kernel over the voltages.
LENGTH_SCALE = 0.1
#: Prior sd [N m] of the half-normal prior on the amplitude ``tau``.
TAU_PRIOR_SD = 0.01
#: Start value [N m] of ``tau`` (at ``z = 0`` the torque is zero whatever ``tau`` is).
TAU_START = 0.002
#: Largest number of reference pairs (the most-held pairs of the span are kept).
MAX_PAIRS = 80
#: Nugget added to the kernel matrix's diagonal (relative to tau^2) before its Cholesky factor.
JITTER = 1e-6
#: The spans projected out (module docstring).
PROJECTIONS = ("u", "1,u", "none")
#: The parameterisations of the values at the pairs (module docstring).
FORMS = ("centred", "whitened")


def kernel(a, b, length_scale: float):
    """Squared-exponential correlation ``exp(-|a - b|^2 / (2 l^2))`` of voltage pairs
    ``a`` (n, 2) and ``b`` (k, 2) [V]; shape (n, k).  Works on numpy and jax arrays."""
    xp = jnp if isinstance(a, jnp.ndarray) or isinstance(b, jnp.ndarray) else np
    d2 = ((a[:, None, :] - b[None, :, :]) ** 2).sum(axis=-1)
    return xp.exp(-0.5 * d2 / length_scale**2)


def _reference_pairs(u_train, u_span, max_pairs: int) -> np.ndarray:
    """The distinct voltage pairs (J, 2) [V]: the training window's first, then the span's
    others (each group sorted; at most ``max_pairs``, the most-held kept).  With the
    training pairs first, the Cholesky factor is block lower-triangular: the fitted values
    depend on the training pairs' ``z`` only, and a new pair's ``z`` is left to its prior,
    so its posterior is exactly the GP's conditional given the fitted values."""
    train, train_counts = np.unique(u_train, axis=0, return_counts=True)
    span, span_counts = np.unique(u_span, axis=0, return_counts=True)
    seen = {tuple(p) for p in train}
    new = np.array([tuple(p) not in seen for p in span])
    pairs = np.concatenate([train, span[new]])
    counts = np.concatenate([train_counts, span_counts[new]])
    if len(pairs) > max_pairs:
        pairs = pairs[np.sort(np.argsort(-counts, kind="stable")[:max_pairs])]
    return pairs


def _gram(pairs: np.ndarray, length_scale: float) -> np.ndarray:
    """The kernel matrix of reference pairs (J, 2) [V] with the nugget, ``K + JITTER I``."""
    return kernel(pairs, pairs, length_scale) + JITTER * np.eye(len(pairs))


@functools.lru_cache(maxsize=16)
def _centred_factors(reference: tuple, length_scale: float, n_fitted: int) -> dict:
    """Matrices of the centred form (module docstring) for reference pairs (J, 2) [V] whose
    first ``n_fitted`` the training window holds: ``lower_tt`` (Cholesky of ``K_tt``),
    ``cond_mean`` (``K_nt K_tt^{-1}``), ``lower_c`` (Cholesky of the conditional
    covariance) and ``gram_inv`` (``K^{-1}``, the kernel weights of ``f(P)``)."""
    gram = _gram(np.asarray(reference, dtype=float), length_scale)
    t = n_fitted
    lower_tt = np.linalg.cholesky(gram[:t, :t])
    cond_mean = np.linalg.solve(gram[:t, :t], gram[:t, t:]).T
    cond_cov = gram[t:, t:] - cond_mean @ gram[:t, t:]
    return {"lower_tt": lower_tt, "cond_mean": cond_mean,
            "lower_c": np.linalg.cholesky(0.5 * (cond_cov + cond_cov.T)),
            "gram_inv": np.linalg.inv(gram)}  # fmt: skip


class GPTorque(AbstractEffect, AbstractTorque):
    """Gaussian-process torque ``T(u)`` on ``axis`` (module docstring).

    Parameters
    ----------
    axis : {"pitch", "yaw"}
    length_scale : float
        Kernel length scale [V], > 0.
    project : {"u", "1,u", "none"}
    reference : tuple of tuple of float
        Reference voltage pairs (J, 2) [V]; empty until :meth:`adapt_to`.
    whiten : tuple of tuple of float
        ``L^{-T}`` (J, J), with ``L`` the Cholesky factor of the reference pairs' kernel matrix.
    projection : tuple of tuple of float
        (3, J) rows: ``beta = projection @ f(P)`` (zero columns at pairs outside the
        training window); empty for ``project="none"``.
    form : {"centred", "whitened"}
        How the values at the pairs are sampled (module docstring).
    n_fitted : int
        How many of the reference pairs (the first) the training window holds.
    """

    kind: ClassVar[str] = "gp_torque"
    summary: ClassVar[str] = (
        "model discrepancy: a Gaussian-process torque of the voltages (gp_tau; gp_f_J at each voltage"
        " pair of the training window, gp_z_J whitened at the test window's new pairs); options "
        "length_scale [V], project and form (centred | whitened) in a model file")
    record_keys: ClassVar[tuple[str, ...]] = ("reference", "whiten", "projection", "n_fitted")
    input_only: ClassVar[bool] = True
    axis: str = eqx.field(static=True, default="yaw")
    length_scale: float = eqx.field(static=True, default=LENGTH_SCALE)
    project: str = eqx.field(static=True, default="u")
    reference: tuple = eqx.field(static=True, default=(), converter=float_tuple)
    whiten: tuple = eqx.field(static=True, default=(), converter=float_tuple)
    projection: tuple = eqx.field(static=True, default=(), converter=float_tuple)
    form: str = eqx.field(static=True, default="centred")
    n_fitted: int = eqx.field(static=True, default=0)

    def __check_init__(self):
        if isinstance(self.length_scale, bool) or not self.length_scale > 0:
            raise ParameterError(f"gp_torque: length_scale must be > 0 V, found {self.length_scale!r}")
        if self.project not in PROJECTIONS:
            raise ParameterError(f"gp_torque: project must be one of {', '.join(PROJECTIONS)}, "
                                 f"found {self.project!r}")  # fmt: skip
        if self.form not in FORMS:
            raise ParameterError(f"gp_torque: form must be one of {', '.join(FORMS)}, found {self.form!r}")
        if self.reference and self.form == "centred" and not 0 < self.n_fitted <= len(self.reference):
            raise ParameterError(f"gp_torque: n_fitted must be in 1..{len(self.reference)} (the "
                                 f"reference pairs the training window holds), found "
                                 f"{self.n_fitted!r} (a description written before the centred "
                                 'form needs "form": "whitened")')  # fmt: skip
        if self.reference and self.form == "whitened" and len(self.whiten) != len(self.reference):
            raise ParameterError(f"gp_torque: whiten needs {len(self.reference)} rows (one per "
                                 f"reference pair), found {len(self.whiten)}")  # fmt: skip

    @property
    def awaits_record(self) -> bool:
        return not self.reference  # adapt_to sets the voltage pairs

    @property
    def n_pairs(self) -> int:
        return len(self.reference)

    @property
    def _n_centred(self) -> int:
        """Pairs whose value is sampled in torque units (the first ones)."""
        return self.n_fitted if self.form == "centred" else 0

    def _declare(self):
        pars = [Parameter("gp_tau", "N m", 0.0, Prior("halfnormal", TAU_PRIOR_SD), "nonnegative", True,
                          None, "GP torque amplitude", TAU_START)]  # fmt: skip
        pars += [Parameter(f"gp_f_{j}", "N m", 0.0, Prior("normal", 0.0, TAU_PRIOR_SD), "real", True, None,
                           f"GP torque at reference pair {j} (joint prior N(0, gp_tau^2 K))", 0.0)
                 for j in range(self._n_centred)]  # fmt: skip
        pars += [Parameter(f"gp_z_{j}", "1", 0.0, Prior("normal", 0.0, 1.0), "real", False, None,
                           f"GP torque, whitened value at reference pair {j}", 0.0)
                 for j in range(self._n_centred, self.n_pairs)]  # fmt: skip
        return tuple(pars)

    # ------------------------------------------------------- the joint prior
    def _factors(self) -> dict:
        return _centred_factors(self.reference, self.length_scale, self.n_fitted)

    def joint_names(self) -> tuple[str, ...]:
        """The centred values ``gp_f_j``: their prior is :meth:`joint_log_prior`."""
        return tuple(self.name(f"gp_f_{j}") for j in range(self._n_centred))

    def joint_log_prior(self, p):
        """``log N(f_t; 0, tau^2 K_tt)`` of the centred values (0 in the whitened form)."""
        if not self._n_centred:
            return 0.0
        f = jnp.stack([p[n] for n in self.joint_names()])
        tau = p[self.name("gp_tau")]
        lower = self._factors()["lower_tt"]
        r = jax.scipy.linalg.solve_triangular(jnp.asarray(lower), f, lower=True) / tau
        t = self._n_centred
        return (-0.5 * jnp.sum(r * r) - t * jnp.log(tau) - np.sum(np.log(np.diag(lower)))
                - 0.5 * t * np.log(2.0 * np.pi))  # fmt: skip

    def check_priors(self, priors) -> None:
        """The centred form needs ``tau > 0``: fixed at 0 the values' joint prior is a point
        mass, which has no density (the whitened form is simply switched off)."""
        tau = priors[self.name("gp_tau")]
        if self._n_centred and not tau.free and tau.a <= 0:
            raise ParameterError(f"{self.name('gp_tau')} fixed at {tau.a:g} switches the GP torque off, "
                                 "and its centred values then have no prior density: leave gp_torque "
                                 'out of the model (or give it "form": "whitened")')  # fmt: skip

    def draw_joint(self, values: dict, rng: np.random.Generator) -> dict:
        """Draws of the centred values given draws of ``gp_tau`` in ``values`` (any
        shape S): ``{gp_f_j: array S}``, ``f_t = tau L_tt w`` with ``w ~ N(0, I)``."""
        if not self._n_centred:
            return {}
        tau = np.asarray(values[self.name("gp_tau")], dtype=float)
        w = rng.standard_normal(tau.shape + (self._n_centred,))
        f = tau[..., None] * (w @ self._factors()["lower_tt"].T)
        return {n: f[..., j] for j, n in enumerate(self.joint_names())}

    # ------------------------------------------------------------ the record
    def adapt_to(self, u, y, dt, span_u=None) -> GPTorque:
        """This term with the reference pairs of the span ``span_u`` (M, 2) [V] (default
        the training window's ``u`` (N, 2)) and the projection over the training window's
        pairs.  A term that already has them is returned unchanged."""
        if self.reference:
            return self
        u = np.asarray(u, dtype=float)
        span = u if span_u is None else np.asarray(span_u, dtype=float)
        pairs = _reference_pairs(u, span, MAX_PAIRS)
        train_pairs, counts = np.unique(u, axis=0, return_counts=True)
        seen = {tuple(q) for q in train_pairs}
        n_fitted = sum(tuple(p) in seen for p in pairs)  # the first ones (_reference_pairs)
        whiten = ()
        if self.form == "whitened":
            whiten = np.linalg.inv(np.linalg.cholesky(_gram(pairs, self.length_scale))).T
        projection = ()
        if self.project != "none":
            weights = np.zeros(len(pairs))
            index = {tuple(p): j for j, p in enumerate(pairs)}
            for p, c in zip(train_pairs, counts):
                if tuple(p) in index:
                    weights[index[tuple(p)]] = c
            projection = gain_projection(pairs, weights, self.project == "1,u")
        return GPTorque(self.axis, self.length_scale, self.project, pairs, whiten, projection, self.form,
                        n_fitted)  # fmt: skip

    # ---------------------------------------------------------------- physics
    def _alpha(self, p):
        """Kernel weights ``K^{-1} f(P)`` (J,) [N m]: ``tau L^{-T} z`` in the whitened form."""
        tau = p[self.name("gp_tau")]
        t = self._n_centred
        new = range(t, self.n_pairs)
        z = jnp.stack([p[self.name(f"gp_z_{j}")] for j in new]) if len(new) else None
        if not t:
            return tau * (jnp.asarray(self.whiten) @ z)
        m = self._factors()
        f = jnp.stack([p[n] for n in self.joint_names()])
        if z is not None:
            f = jnp.concatenate([f, jnp.asarray(m["cond_mean"]) @ f + tau * (jnp.asarray(m["lower_c"]) @ z)])
        return jnp.asarray(m["gram_inv"]) @ f

    def values_at(self, p, u):
        """``f(u)`` [N m] before the projection, at voltage pairs ``u`` (k, 2) [V]."""
        if not self.reference:
            return jnp.zeros(jnp.shape(u)[0])
        return kernel(jnp.asarray(u), jnp.asarray(self.reference), self.length_scale) @ self._alpha(p)

    def derived(self, p) -> dict:
        """Once per solve: the kernel weights and the projection coefficients ``beta``."""
        if not self.reference:
            return {}
        alpha = self._alpha(p)
        out = {self.name("gp_alpha"): alpha}
        if self.projection:
            f_ref = jnp.asarray(kernel(np.asarray(self.reference), np.asarray(self.reference),
                                       self.length_scale)) @ alpha  # fmt: skip
            out[self.name("gp_beta")] = jnp.asarray(self.projection) @ f_ref
        return out

    def torque(self, p, u):
        """``T(u)`` [N m] at one voltage pair ``u`` (2,)."""
        if not self.reference:
            return 0.0
        derived = p if self.name("gp_alpha") in p else {**p, **self.derived(p)}
        alpha = derived[self.name("gp_alpha")]
        pair = jnp.stack([u[0], u[1]])[None, :]
        out = kernel(pair, jnp.asarray(self.reference), self.length_scale)[0] @ alpha
        if self.projection:
            beta = derived[self.name("gp_beta")]
            out = out - (beta[0] + beta[1] * u[0] + beta[2] * u[1])
        return out

    def __call__(self, p, x, v, u):
        return on_axis(self.axis, self.torque(p, u))

    def describe(self) -> dict:
        return {"effect": self.kind, "axis": self.axis, "length_scale": self.length_scale,
                "project": self.project, "reference": [list(r) for r in self.reference],
                "whiten": [list(r) for r in self.whiten],
                "projection": [list(r) for r in self.projection], "form": self.form,
                "n_fitted": self.n_fitted}  # fmt: skip
