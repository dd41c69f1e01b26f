r"""Structural (local) identifiability: rank and null space of the output sensitivities.

The angles :math:`(\theta, \psi)(t_k)` are differentiated with respect to the vector
``w`` of :class:`ParameterVector` (log of each free parameter whose support is positive,
the others -- ``h``, a torque offset, a spring's rest angle -- on their own scale, and the
initial state) by forward-mode autodiff through the simulator of any model.  The numerical rank of
the ``(2N, P)`` sensitivity matrix at several parameter points and its null space, named
and checked against the directions derived below, are the structural result.

Derivation of the null space
----------------------------
Write ``M11 = J_bc + m (r_c^2 + h^2)`` (pitch inertia about the pivot).  The equations of
motion (Sec. 2.7 of the paper, with the derived h-term) are

.. math::

    M_{11} \ddot\theta + \tfrac12 \partial_\theta M_{22} \dot\psi^2
        + m g (r_c \cos\theta - h \sin\theta) = K_{\theta\theta} u_\theta
        + K_{\theta\psi} u_\psi - D_\theta \dot\theta,

    M_{22} \ddot\psi + \partial_\theta M_{22} \dot\theta\dot\psi
        = K_{\psi\theta} u_\theta + K_{\psi\psi} u_\psi - D_\psi \dot\psi,

with ``M22 = J_s + J_bc s^2 + m (r_c s + h c)^2``, ``s, c = sin, cos(theta)``.

1. **Common scaling.**  Multiply ``m, J_bc, J_s`` and every torque-type parameter (every
   ``K`` and ``D``, and any effect's friction level, drag, spring stiffness, offset...)
   by the same factor ``lambda`` and keep ``r_c, h`` (and dead-band widths, rest angles)
   fixed: ``M11``, ``M22``, the gravity moment and every generalized force scale by
   ``lambda``, so both equations are multiplied by ``lambda`` and the solution is
   unchanged.  The parameters that scale are those declared ``scales_with_inertia``; the
   direction is derived from these flags (:func:`scaling_direction`): loading 1 on a log
   coordinate, the value itself on a linear one (``d T_0 = T_0 d log lambda``).  For the
   paper's model: unit loadings ``1/3`` each for the nine scaled parameters.
2. **h = 0 trade.**  With ``h = 0`` the parameters enter only through ``M11 = J_bc +
   m r_c^2``, ``m r_c`` (gravity) and ``M22 = J_s + (J_bc + m r_c^2) s^2``.  So any change
   of ``(r_c, m, J_bc)`` that keeps ``m r_c`` and ``J_bc + m r_c^2`` fixed is invisible:
   ``d log m = -d log r_c = a`` gives ``d(m r_c^2) = -a m r_c^2``, compensated by
   ``d log J_bc = a m r_c^2 / J_bc``.  Direction ``(r_c, m, J_bc) ∝ (-1, 1, m r_c^2 /
   J_bc)``; together with 1. the null space is two-dimensional (any basis of it is
   equally valid).  With ``h != 0``, ``M22`` contains ``m (r_c s + h c)^2``, which
   breaks the trade: the rank goes up by one, but for small ``|h|`` the corresponding
   singular value is tiny (a practical, not structural, non-identifiability).
3. Nothing else for the paper's model: the ratios ``m g r_c / M11``,
   ``m (r_c^2 + h^2) / M11``, ``h / r_c`` and ``X / M11`` for every other scaled parameter,
   the unscaled parameters and the initial state determine the solution and are
   (generically) identified; :func:`identifiable_combinations` checks that each is
   invariant along the computed null space.  An effect can add a degenerate direction
   at a special value (a spring's rest angle when its stiffness is 0): such directions
   are found numerically and named ``X_without_effect``.

Rank tolerance
--------------
The invariances above are algebraic, so the RK4 map of the simulator inherits them
exactly and their singular values are pure floating-point round-off; the tolerance is
``RANK_RTOL * s_max``.  ``RANK_RTOL = 1e-12`` sits four decades above the round-off level
measured here (1e-18 to 1e-16 of ``s_max``, i.e. a few ``eps``) and three below the
smallest genuine singular values seen (about 5e-9 of ``s_max`` for ``h = 3 mm`` on a 4 s
record, ~1e-7 on the full record): the report prints the gap on both sides so a reader
can judge it.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from heli_uq.errors import ParameterError
from heli_uq.identifiability.parameter_vector import ParameterVector, sensitivity_matrix
from heli_uq.model.tables import X0_NAMES
from heli_uq.model.terms.rigid_body import identifiable_combinations as mechanics_combinations
from heli_uq.model.terms.rigid_body import mechanics_null_directions, pitch_inertia

__all__ = [
    "ParameterVector",
    "X0_NAMES",
    "RANK_RTOL",
    "NAMED_TOL",
    "sensitivity_matrix",
    "scaling_direction",
    "analytic_null_directions",
    "identifiable_combinations",
    "describe_direction",
    "StructuralResult",
    "structural_analysis",
]

#: Relative singular-value tolerance of the numerical rank (see the module docstring).
RANK_RTOL = 1e-12

#: A derived direction is "in" the computed null space when its distance to it is below this.
NAMED_TOL = 1e-6

#: Loadings smaller than this are left out of a direction's description.
LOADING_SHOWN = 0.05

#: Default perturbation of a parameter on its own scale in :func:`random_points` (SI).
LINEAR_SD = 0.005


def _unit(v):
    v = np.asarray(v, dtype=float)
    n = np.linalg.norm(v)
    return v / n if n > 0 else v


def scaling_direction(pv: ParameterVector, w) -> np.ndarray | None:
    """The common-scaling direction in ``w`` (unit vector), derived from the
    ``scales_with_inertia`` flags; None if a scaled parameter is not free (then the
    scaling is no symmetry of the likelihood)."""
    scaled = pv.model.scale_names
    if not all(n in pv.free for n in scaled):
        return None
    params, _ = pv.to_model(jnp.asarray(w), np.zeros(4))
    v = np.array([(1.0 if pv.is_log(n) else float(params[n])) if n in scaled else 0.0
                  for n in pv.names])  # fmt: skip
    return _unit(v)


def analytic_null_directions(pv: ParameterVector, w) -> list[tuple[str, np.ndarray, str]]:
    """The directions derived in the module docstring, as unit vectors in ``w``.

    Returns ``(key, vector, description)`` for each candidate whose parameters are all
    free: ``common_scaling``, and the mechanics' candidates (``rc_m_Jbc_trade``, a null
    direction only when ``h = 0``).  Whether each lies in the computed null space is
    checked by the caller.
    """
    out = []
    v = scaling_direction(pv, w)
    if v is not None:
        scaled = ", ".join(pv.model.scale_names)
        out.append(("common_scaling", v,
                    f"{scaled} scale together (the angles depend only on their ratios to the "
                    "inertias); the other parameters and the initial state do not move"))  # fmt: skip
    params, _ = pv.to_model(jnp.asarray(w), np.zeros(4))
    for key, loads, text in mechanics_null_directions({k: float(x) for k, x in params.items()}):
        if all(n in pv.free and pv.is_log(n) for n in loads):
            out.append((key, _unit([loads.get(n, 0.0) for n in pv.names]), text))
    return out


def describe_direction(loadings: Mapping[str, float]) -> str:
    """One sentence for a unit direction given by ``{name: loading}``."""
    big = {n: v for n, v in loadings.items() if abs(v) >= LOADING_SHOWN}
    if not big:
        return "no loading above the display threshold"
    vals = np.array(list(big.values()))
    if np.all(np.sign(vals) == np.sign(vals[0])) and np.ptp(np.abs(vals)) < 1e-3 * np.abs(vals).max():
        return f"{', '.join(big)} change together by a common factor"
    up = [n for n, v in big.items() if v * vals[0] > 0]
    down = [n for n, v in big.items() if v * vals[0] < 0]
    text = ", ".join(f"{n} {v:+.2f}" for n, v in big.items())
    if down:
        return f"a trade of {', '.join(up)} against {', '.join(down)} (loadings {text})"
    return f"{', '.join(up)} change together (loadings {text})"


def identifiable_combinations(pv: ParameterVector, w, null_basis: np.ndarray) -> list[dict]:
    """The ratios the dynamics depend on, with their invariance along the null space.

    The mechanics' ratios, plus ``X / M11`` for every other scaled parameter ``X``.
    Returns one dict per combination: ``name``, ``value`` (SI), and ``null_leak`` =
    ``max |grad_w c . n| / |grad_w c|`` over the null basis vectors ``n`` (about 0 when the
    combination is invariant along the structural null space, i.e. can be identified).
    """

    def params_of(wv):
        return pv.to_model(wv, np.zeros(4))[0]

    combos = dict(mechanics_combinations())
    mechanics = {par.name for par in pv.model.mechanics.parameters()}
    for n in pv.model.scale_names:
        if n not in mechanics:
            combos[f"{n} / M11"] = lambda p, n=n: p[n] / pitch_inertia(p)
    w = jnp.asarray(w)
    out = []
    for name, fn in combos.items():
        val, grad = jax.value_and_grad(lambda wv, fn=fn: fn(params_of(wv)))(w)
        grad = np.asarray(grad)
        gnorm = np.linalg.norm(grad)
        if gnorm == 0:
            continue  # depends on fixed parameters only
        leak = float(np.max(np.abs(null_basis.T @ grad)) / gnorm) if null_basis.size else 0.0
        out.append({"name": name, "value": float(val), "null_leak": leak})
    return out


@dataclasses.dataclass(frozen=True)
class StructuralResult:
    """Result of :func:`structural_analysis`.

    Attributes
    ----------
    names : tuple of str
        Entries of ``w``.
    rank : int
        Generic numerical rank (the largest rank over the points).
    singular_values : ndarray, shape (n_points, P)
        Singular values at each point, largest first.
    ranks : tuple of int
    null_basis : ndarray, shape (P, P - rank)
        Orthonormal basis of the null space at the reference (first) point.
    null_directions : list of dict
        ``{"key", "loadings": {name: value}, "description", "distance"}``: the derived
        directions found in the null space, then unexplained remaining directions.
    weakest : dict
        The right singular vector of the smallest singular value above the tolerance.
    points : ndarray, shape (n_points, P)
    """

    names: tuple
    rank: int
    singular_values: np.ndarray
    ranks: tuple
    null_basis: np.ndarray
    null_directions: list
    weakest: dict
    points: np.ndarray
    combinations: list
    rtol: float = RANK_RTOL

    @property
    def n_parameters(self) -> int:
        return len(self.names)

    def gap(self) -> tuple[float, float]:
        """``(largest relative singular value counted as zero, smallest counted as non-zero)``."""
        s = self.singular_values / self.singular_values[:, :1]
        zero = s[s < self.rtol]
        nonzero = s[s >= self.rtol]
        return (float(zero.max()) if zero.size else 0.0, float(nonzero.min()))


def _null_space(s, vt, rtol):
    keep = s >= rtol * s[0]
    return int(keep.sum()), vt[~keep].T


def structural_analysis(pv: ParameterVector, points: Sequence, u, dt: float, *,
                        rtol: float = RANK_RTOL, x0=None) -> StructuralResult:  # fmt: skip
    """Rank and named null space of the sensitivity matrix at each point of ``points``.

    Parameters
    ----------
    pv : ParameterVector
    points : sequence of arrays, shape (P,)
        Values of ``w``; the first is the reference point (e.g. the fit).  Points whose
        simulation fails are an error: choose them with :func:`random_points`.
    u : array, shape (N, 2)
        The record's voltages [V].
    dt : float
        Sample time [s].
    x0 : array, shape (4,), optional
        Initial state when ``pv`` does not include it.
    """
    svals, ranks, vts = [], [], []
    for w in points:
        jac, ok = sensitivity_matrix(pv, w, u, dt, x0)
        if not ok or not np.all(np.isfinite(jac)):
            raise ParameterError("structural analysis: the simulation fails at a requested point")
        _, s, vt = np.linalg.svd(jac.reshape(-1, pv.dim), full_matrices=False)
        svals.append(s)
        vts.append(vt)
        ranks.append(_null_space(s, vt, rtol)[0])
    rank_ref, basis = _null_space(svals[0], vts[0], rtol)
    directions = []
    explained = np.zeros((pv.dim, 0))
    for key, v, text in analytic_null_directions(pv, points[0]):
        dist = float(np.linalg.norm(v - basis @ (basis.T @ v))) if basis.size else 1.0
        if dist < NAMED_TOL:
            directions.append({"key": key, "loadings": dict(zip(pv.names, map(float, v))),
                               "description": text, "distance": dist})  # fmt: skip
            explained = np.column_stack([explained, v])
    params_ref, _ = pv.to_model(jnp.asarray(points[0]), np.zeros(4))
    for j, name in enumerate(pv.names):
        e = np.zeros(pv.dim)
        e[j] = 1.0
        dist = float(np.linalg.norm(e - basis @ (basis.T @ e))) if basis.size else 1.0
        if dist < NAMED_TOL and explained.shape[1] < basis.shape[1]:
            value = float(params_ref[name]) if name in params_ref else float(points[0][j])
            directions.append({"key": f"{name}_without_effect", "distance": dist,
                               "loadings": dict(zip(pv.names, map(float, e))),
                               "description": f"{name} alone has no effect on the angles at these "
                                              f"values ({name} = {value:.3g} at the reference "
                                              "point: a degenerate value, e.g. at a bound)"})
            explained = np.column_stack([explained, e])
    if explained.shape[1] < basis.shape[1]:
        # Directions of the null space not spanned by the derived ones: report them too.
        q, _ = np.linalg.qr(np.column_stack([explained, basis]))
        for v in q[:, explained.shape[1]:basis.shape[1]].T:
            v = v * np.sign(v[np.argmax(np.abs(v))])
            loads = dict(zip(pv.names, map(float, v)))
            directions.append({"key": "unexplained", "loadings": loads,
                               "description": describe_direction(loads), "distance": 0.0})  # fmt: skip
    s0, vt0 = svals[0], vts[0]
    k = rank_ref - 1
    weak = vt0[k] * np.sign(vt0[k][np.argmax(np.abs(vt0[k]))])
    weak_loads = dict(zip(pv.names, map(float, weak)))
    weakest = {"relative_singular_value": float(s0[k] / s0[0]), "loadings": weak_loads,
               "description": describe_direction(weak_loads)}  # fmt: skip
    return StructuralResult(
        names=pv.names, rank=max(ranks), singular_values=np.array(svals), ranks=tuple(ranks),
        null_basis=basis, null_directions=directions, weakest=weakest,
        points=np.array([np.asarray(p) for p in points]),
        combinations=identifiable_combinations(pv, points[0], basis), rtol=rtol,
    )  # fmt: skip


def random_points(pv: ParameterVector, w_ref, u, dt: float, n: int, *, seed: int = 0,
                  log_sd: float = 0.2, linear_sd=None, max_tries: int = 200,
                  x0=None) -> list:  # fmt: skip
    """``w_ref`` and ``n - 1`` random points around it at which the simulation succeeds.

    Log parameters are perturbed by ``N(0, log_sd)``, the others by ``N(0, sd)`` with
    ``sd = linear_sd[name]`` in their unit (default :data:`LINEAR_SD`, e.g. 5 mm for
    ``h``); the initial state is kept.  Points whose simulation fails or leaves |angle| < 50 rad are
    redrawn (so generic rank is measured where the model is usable).
    """
    rng = np.random.default_rng(seed)
    w_ref = np.asarray(w_ref, dtype=float)
    sim = jax.jit(lambda wv: pv.solve(wv, u, dt, x0, gradients="adjoint"))
    out = [w_ref]
    for _ in range(max_tries):
        if len(out) >= n:
            break
        w = w_ref.copy()
        for i, name in enumerate(pv.free):
            sd = log_sd if pv.is_log(name) else (linear_sd or {}).get(name, LINEAR_SD)
            w[i] += rng.normal(0, sd)
        sol = sim(jnp.asarray(w))
        if bool(sol.ok) and np.max(np.abs(np.asarray(sol.ys[:, :2]))) < 50:
            out.append(w)
    return out
