"""The vector ``w`` of an identifiability analysis and the output sensitivities to it.

``w`` holds the free model parameters (log of each one whose support is positive or
non-negative, the others -- ``h``, a torque offset, a spring's rest angle -- on their own
scale) and the initial state.  :func:`sensitivity_matrix` differentiates the simulated
angles with respect to ``w`` by forward-mode autodiff through the simulator.
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
from heli_uq.model.tables import X0_NAMES
from heli_uq.simulation.solver import solve

__all__ = ["ParameterVector", "sensitivity_matrix"]


@dataclasses.dataclass(frozen=True, eq=False)
class ParameterVector:
    """The vector ``w`` in which identifiability is analysed.

    ``w`` holds, in order, the free model parameters (log of each one whose support is
    positive or non-negative, the others on their own scale) and, if ``include_x0``, the
    initial state ``theta0, psi0`` [rad], ``omega_theta0, omega_psi0`` [rad/s].  Names in
    reports are the plain parameter names; "log" is implied where :meth:`is_log` says so.

    Parameters
    ----------
    model : HeliModel
    free : sequence of str
        Free parameter names, in model order after construction.
    base : mapping
        Values of all model parameters; the fixed ones keep these values.
    include_x0 : bool
    substeps : int
        RK4 substeps per sample of every simulation.
    """

    model: HeliModel
    free: tuple
    base: Mapping[str, float]
    include_x0: bool = True
    substeps: int = 1

    def __post_init__(self):
        names = self.model.names
        unknown = [n for n in self.free if n not in names]
        if unknown:
            raise ParameterError(f"free: unknown parameter(s) {', '.join(unknown)}; expected "
                                 f"names from {', '.join(names)}")  # fmt: skip
        if not self.free:
            raise ParameterError("free: expected at least one parameter name")
        free = tuple(n for n in names if n in set(self.free))
        object.__setattr__(self, "free", free)
        object.__setattr__(self, "base", {n: float(v) for n, v in self.model.complete(self.base).items()})
        for n in free:
            if self.is_log(n) and not self.base[n] > 0:
                raise ParameterError(f"{n} = {self.base[n]!r}: a free parameter analysed in log "
                                     "coordinates must be > 0")  # fmt: skip

    @property
    def names(self) -> tuple[str, ...]:
        return self.free + (X0_NAMES if self.include_x0 else ())

    @property
    def dim(self) -> int:
        return len(self.names)

    def is_log(self, name: str) -> bool:
        """True if ``name`` enters ``w`` as a logarithm."""
        if name not in self.model.names:
            return False
        par = self.model.parameter(name)
        return par.support in ("positive", "nonnegative") or (
            isinstance(par.support, tuple) and par.support[1] >= 0)

    def to_model(self, w, x0_default=None):
        """``(params, x0)`` from ``w``: a dict of jnp scalars and a (4,) array."""
        params = {n: jnp.asarray(v) for n, v in self.base.items()}
        for i, n in enumerate(self.free):
            params[n] = jnp.exp(w[i]) if self.is_log(n) else w[i]
        x0 = w[len(self.free):] if self.include_x0 else jnp.asarray(x0_default)
        return params, x0

    def from_model(self, params: Mapping[str, float], x0=None) -> np.ndarray:
        """``w`` of a parameter mapping (and initial state, if included)."""
        w = [math.log(float(params[n])) if self.is_log(n) else float(params[n]) for n in self.free]
        if self.include_x0:
            w += [float(v) for v in np.asarray(x0, dtype=float)]
        return np.asarray(w)

    def solve(self, w, u, dt, x0_default=None, gradients="autodiff"):
        """The model's :class:`~heli_uq.simulation.Solution` at ``w``."""
        params, x0 = self.to_model(w, x0_default)
        return solve(params, x0, u, dt, model=self.model, substeps=self.substeps,
                     gradients=gradients)  # fmt: skip


def sensitivity_matrix(pv: ParameterVector, w, u, dt: float, x0_default=None):
    """Output sensitivities ``d(theta, psi)(t_k) / dw``, shape (N, 2, P) [rad per unit of w].

    Forward-mode autodiff through the same RK4 scheme the likelihood uses (exact
    derivatives of the discrete solution).  Returns also the solution's ``ok`` flag.
    """

    def angles(wv):
        sol = pv.solve(wv, u, dt, x0_default)
        return sol.ys[:, :2], sol.ok

    jac, ok = jax.jacfwd(angles, has_aux=True)(jnp.asarray(w, dtype=jnp.float64))
    return np.asarray(jac), bool(ok)
