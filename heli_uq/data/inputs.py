"""Which voltage pairs a window of a record holds that another window never does."""

from __future__ import annotations

import numpy as np

__all__ = ["unseen_inputs"]


def unseen_inputs(u_seen, u) -> np.ndarray:
    """Which samples of ``u`` hold a voltage pair that ``u_seen`` never holds.

    A model fitted on one window predicts another by extrapolating in the inputs at these
    samples: a gain error or an input nonlinearity (a network of ``u`` above all) is
    unconstrained there.

    Parameters
    ----------
    u_seen : array_like, shape (M, 2)
        Voltages [V] of the window a model was fitted on.
    u : array_like, shape (N, 2)
        Voltages [V] of the window it predicts.

    Returns
    -------
    ndarray of bool, shape (N,)
        True where the pair ``u[k]`` is not a row of ``u_seen`` (exact equality: the
        voltages of a record are read from the same printed values).
    """
    u_seen, u = np.asarray(u_seen, dtype=float).reshape(-1, 2), np.asarray(u, dtype=float).reshape(-1, 2)
    seen = {tuple(q) for q in np.unique(u_seen, axis=0)}
    return np.array([tuple(q) not in seen for q in u], dtype=bool)
