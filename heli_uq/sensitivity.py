r"""Structural (local) identifiability: rank and null space of the output sensitivities.

The angles :math:`(\theta, \psi)(t_k)` are differentiated with respect to the vector
``w`` of :class:`ParameterVector` (log of each free positive parameter, ``h`` in metres,
the initial state) by forward-mode autodiff through the simulator.  The numerical rank of
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

1. **Common scaling.**  Multiply ``m, J_bc, J_s`` and every ``K`` and ``D`` by the same
   factor ``lambda`` and keep ``r_c, h`` fixed: ``M11``, ``M22``, the gravity moment and
   every generalized force scale by ``lambda``, so both equations are multiplied by
   ``lambda`` and the solution is unchanged.  In log coordinates this is the direction
   with equal loadings on ``m, J_bc, J_s, K_*, D_*`` and none on ``r_c``, ``h`` or the
   initial state: unit loadings ``1/3`` each for the nine parameters.
2. **h = 0 trade.**  With ``h = 0`` the parameters enter only through ``M11 = J_bc +
   m r_c^2``, ``m r_c`` (gravity) and ``M22 = J_s + (J_bc + m r_c^2) s^2``.  So any change
   of ``(r_c, m, J_bc)`` that keeps ``m r_c`` and ``J_bc + m r_c^2`` fixed is invisible:
   ``d log m = -d log r_c = a`` gives ``d(m r_c^2) = -a m r_c^2``, compensated by
   ``d log J_bc = a m r_c^2 / J_bc``.  Direction ``(r_c, m, J_bc) ∝ (-1, 1, m r_c^2 /
   J_bc)``; together with 1. the null space is two-dimensional (any basis of it is
   equally valid).  With ``h != 0``, ``M22`` contains ``m (r_c s + h c)^2``, which
   breaks the trade: the rank goes up by one, but for small ``|h|`` the corresponding
   singular value is tiny (a practical, not structural, non-identifiability).
3. Nothing else: the ratios ``m g r_c / M11``, ``m (r_c^2 + h^2) / M11``, ``h / r_c``,
   ``J_s / M11``, ``K_* / M11``, ``D_* / M11`` and the initial state determine the
   solution and are (generically) identified; :func:`identifiable_combinations` checks
   that each is invariant along the computed null space.

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
import math
from collections.abc import Mapping, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from heli_uq.errors import ParameterError
from heli_uq.params import PARAM_NAMES
from heli_uq.simulate import solve

__all__ = [
    "ParameterVector",
    "X0_NAMES",
    "RANK_RTOL",
    "NAMED_TOL",
    "sensitivity_matrix",
    "analytic_null_directions",
    "identifiable_combinations",
    "describe_direction",
    "StructuralResult",
    "structural_analysis",
]

#: Names of the initial-state entries of the parameter vector.
X0_NAMES = ("theta0", "psi0", "omega_theta0", "omega_psi0")

#: Relative singular-value tolerance of the numerical rank (see the module docstring).
RANK_RTOL = 1e-12

#: A derived direction is "in" the computed null space when its distance to it is below this.
NAMED_TOL = 1e-6

#: Loadings smaller than this are left out of a direction's description.
LOADING_SHOWN = 0.05

_SCALED = ("m", "J_bc", "J_s", "K_theta_theta", "K_theta_psi", "K_psi_theta", "K_psi_psi",
           "D_theta", "D_psi")  # fmt: skip
_LINEAR = ("h",)  # parameters analysed on their own scale (they may be 0 or negative)


@dataclasses.dataclass(frozen=True, eq=False)
class ParameterVector:
    """The vector ``w`` in which identifiability is analysed.

    ``w`` holds, in order, the free Table 2 parameters (log of each positive one, ``h`` in
    metres) and, if ``include_x0``, the initial state ``theta0, psi0`` [rad],
    ``omega_theta0, omega_psi0`` [rad/s].  Names in reports are the plain parameter names;
    "log" is implied for every parameter but ``h`` and the initial state.

    Parameters
    ----------
    free : sequence of str
        Free Table 2 names, in Table 2 order after construction.
    base : mapping
        Values of all twelve parameters; the fixed ones keep these values.
    include_x0 : bool
    """

    free: tuple
    base: Mapping[str, float]
    include_x0: bool = True

    def __post_init__(self):
        unknown = [n for n in self.free if n not in PARAM_NAMES]
        if unknown:
            raise ParameterError(f"--free: unknown parameter(s) {', '.join(unknown)}; expected "
                                 f"names from {', '.join(PARAM_NAMES)}")  # fmt: skip
        if not self.free:
            raise ParameterError("--free: expected at least one parameter name")
        free = tuple(n for n in PARAM_NAMES if n in set(self.free))
        object.__setattr__(self, "free", free)
        for n in free:
            if n not in _LINEAR and not float(self.base[n]) > 0:
                raise ParameterError(f"{n} = {self.base[n]!r}: a free positive parameter must be > 0")

    @property
    def names(self) -> tuple[str, ...]:
        return self.free + (X0_NAMES if self.include_x0 else ())

    @property
    def dim(self) -> int:
        return len(self.names)

    def is_log(self, name: str) -> bool:
        """True if ``name`` enters ``w`` as a logarithm."""
        return name in PARAM_NAMES and name not in _LINEAR

    def to_model(self, w, x0_default=None):
        """``(params, x0)`` from ``w``: a dict of 12 jnp scalars and a (4,) array."""
        params = {n: jnp.asarray(float(v)) for n, v in self.base.items() if n in PARAM_NAMES}
        for i, n in enumerate(self.free):
            params[n] = jnp.exp(w[i]) if self.is_log(n) else w[i]
        if self.include_x0:
            x0 = w[len(self.free):]
        else:
            x0 = jnp.asarray(x0_default)
        return params, x0

    def from_model(self, params: Mapping[str, float], x0=None) -> np.ndarray:
        """``w`` of a parameter mapping (and initial state, if included)."""
        w = [math.log(float(params[n])) if self.is_log(n) else float(params[n]) for n in self.free]
        if self.include_x0:
            w += [float(v) for v in np.asarray(x0, dtype=float)]
        return np.asarray(w)


def sensitivity_matrix(pv: ParameterVector, w, u, dt: float, x0_default=None):
    """Output sensitivities ``d(theta, psi)(t_k) / dw``, shape (N, 2, P) [rad per unit of w].

    Forward-mode autodiff through the same RK4 scheme the likelihood uses (exact
    derivatives of the discrete solution).  Returns also the solution's ``ok`` flag.
    """

    def angles(wv):
        params, x0 = pv.to_model(wv, x0_default)
        sol = solve(params, x0, u, dt, gradients="autodiff")
        return sol.ys[:, :2], sol.ok

    jac, ok = jax.jacfwd(angles, has_aux=True)(jnp.asarray(w, dtype=jnp.float64))
    return np.asarray(jac), bool(ok)


def _unit(v):
    v = np.asarray(v, dtype=float)
    n = np.linalg.norm(v)
    return v / n if n > 0 else v


def analytic_null_directions(pv: ParameterVector, w) -> list[tuple[str, np.ndarray, str]]:
    """The directions derived in the module docstring, as unit vectors in ``w``.

    Returns ``(key, vector, description)`` for each candidate whose parameters are all
    free: ``common_scaling`` always, ``rc_m_Jbc_trade`` (a null direction only when
    ``h = 0``).  Whether each lies in the computed null space is checked by the caller.
    """
    names = pv.names
    out = []
    if all(n in names for n in _SCALED):
        v = np.array([1.0 if n in _SCALED else 0.0 for n in names])
        out.append(("common_scaling", _unit(v),
                    "m, J_bc, J_s, the four K and the two D scale together (the angles depend "
                    "only on their ratios to the pitch inertia M11); r_c, h and the initial "
                    "state do not move"))  # fmt: skip
    if all(n in names for n in ("r_c", "m", "J_bc")):
        params, _ = pv.to_model(jnp.asarray(w), np.zeros(4))
        ratio = float(params["m"] * params["r_c"] ** 2 / params["J_bc"])
        loads = {"r_c": -1.0, "m": 1.0, "J_bc": ratio}
        v = np.array([loads.get(n, 0.0) for n in names])
        out.append(("rc_m_Jbc_trade", _unit(v),
                    "r_c down, m up and J_bc up at fixed m r_c and J_bc + m r_c^2 (the "
                    "gravity moment and the pitch inertia); invisible when h = 0"))  # fmt: skip
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

    Returns one dict per combination: ``name``, ``value`` (SI), and ``null_leak`` =
    ``max |grad_w c . n| / |grad_w c|`` over the null basis vectors ``n`` (about 0 when the
    combination is invariant along the structural null space, i.e. can be identified).
    """

    def params_of(wv):
        return pv.to_model(wv, np.zeros(4))[0]

    def m11(p):
        return p["J_bc"] + p["m"] * (p["r_c"] ** 2 + p["h"] ** 2)

    combos = {"m g r_c / M11 [1/s^2]": lambda p: p["m"] * p["g"] * p["r_c"] / m11(p),
              "m (r_c^2 + h^2) / M11": lambda p: p["m"] * (p["r_c"] ** 2 + p["h"] ** 2) / m11(p),
              "h / r_c": lambda p: p["h"] / p["r_c"]}  # fmt: skip
    for n in _SCALED[2:]:
        combos[f"{n} / M11"] = lambda p, n=n: p[n] / m11(p)
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
                  log_sd: float = 0.2, h_sd: float = 0.005, max_tries: int = 200,
                  x0=None) -> list:  # fmt: skip
    """``w_ref`` and ``n - 1`` random points around it at which the simulation succeeds.

    Log parameters are perturbed by ``N(0, log_sd)``, ``h`` by ``N(0, h_sd)`` [m], the
    initial state is kept.  Points whose simulation fails or leaves |angle| < 50 rad are
    redrawn (so generic rank is measured where the model is usable).
    """
    rng = np.random.default_rng(seed)
    w_ref = np.asarray(w_ref, dtype=float)
    sim = jax.jit(lambda wv: solve(*pv.to_model(wv, x0), u, dt))
    out = [w_ref]
    for _ in range(max_tries):
        if len(out) >= n:
            break
        w = w_ref.copy()
        for i, name in enumerate(pv.free):
            w[i] += rng.normal(0, log_sd) if pv.is_log(name) else rng.normal(0, h_sd)
        sol = sim(jnp.asarray(w))
        if bool(sol.ok) and np.max(np.abs(np.asarray(sol.ys[:, :2]))) < 50:
            out.append(w)
    return out
