"""Where a NUTS run's divergent transitions are: by chain, and by position in the posterior.

A divergence says the integrator met curvature its step size cannot follow (Betancourt
2017, Sec. 6.2).  Its count flags a run; *where* it happens says what to change: a
funnel between a scale and what it scales, a stiff corner of a friction law, one chain
whose warm-up ended with too large a step.  Stan's users find it from pair plots; this
module gives it as numbers a health line can carry.

**By chain.**  Divergences per chain.  When they sit in one chain that chain's adapted
step size is usually the cause, not the posterior (seen on the rig: 17 of 19 in the
chain whose step size ended largest).

**By position.**  Every scalar of the posterior (each parameter, each sampling coordinate
``z[...]``, each component of a vector quantity) is replaced by its *normal score*, the
rank-normalised value ``Phi^-1((rank - 3/8) / (N + 1/4))`` over all ``N`` draws of all
chains (the transform of rank-normalised R-hat, Vehtari et al. 2021).  A scalar where
divergences concentrate has divergent draws with a mean score far from 0.  Divergences
come in runs (a chain stuck in a funnel's neck diverges draw after draw) and the scalars
are autocorrelated, so the mean score of ``n`` divergent draws varies far more than
``1/sqrt(n)`` even where divergences do not depend on the scalar.  The null is therefore
built from the run itself: the divergence indicators of each chain are shifted
circularly along that chain (:data:`SHIFTS` random shifts, a fixed seed), which keeps
their runs and each chain's count and breaks only their alignment with the draws; ``z``
is the observed mean score less the shifts' mean, over the shifts' sd.  Scalars with
``|z| >=`` :data:`Z_NAMED` are named, largest first, with the side ("low"/"high"); a
sampling coordinate with the same scores as a parameter (a monotone map of it) is left to
the parameter.  Scores are invariant to any monotone map of the scalar, so a parameter and
its log give the same answer.  The named scalars say where divergences were, as a guide
to what to reparametrise, not a test; the stored draw is the accepted state of the
transition, near where its trajectory diverged, not the point of divergence itself.
"""

from __future__ import annotations

import numpy as np
from scipy.special import ndtri
from scipy.stats import rankdata

__all__ = ["divergence_sites", "divergence_text", "normal_scores", "Z_NAMED", "MAX_NAMED", "SHIFTS",
           "CHAIN_SHARE"]

#: A scalar is named where ``|z|`` of its divergent draws' mean normal score reaches this.
Z_NAMED = 3.0
#: At most this many scalars are named.
MAX_NAMED = 3
#: Circular shifts of the divergence indicators that make the null (module docstring).
SHIFTS = 200
#: The health line names the chain that holds at least this share of the divergences.
CHAIN_SHARE = 0.75


def normal_scores(values: np.ndarray) -> np.ndarray:
    """Rank-normalised scores of ``values`` (shape (N,)): ``Phi^-1((r - 3/8) / (N + 1/4))``,
    ``r`` the average rank (ties share it); mean ~0, sd ~1."""
    ranks = rankdata(np.asarray(values, dtype=float), method="average")
    return ndtri((ranks - 0.375) / (len(ranks) + 0.25))


def _scalars(posterior) -> dict[str, np.ndarray]:
    """Every scalar of an arviz posterior group, flattened over (chain, draw): ``{name: (N,)}``."""
    out = {}
    for var, da in posterior.data_vars.items():
        extra = [d for d in da.dims if d not in ("chain", "draw")]
        values = np.asarray(da.transpose("chain", "draw", *extra).values, dtype=float)
        flat = values.reshape(values.shape[0] * values.shape[1], -1)
        if not extra:
            out[str(var)] = flat[:, 0]
            continue
        if len(extra) == 1:  # named coordinates, e.g. z[log_D_psi_yaw_ratio]
            labels = [str(c) for c in da[extra[0]].values]
        else:
            labels = [", ".join(str(c) for c in combo) for combo in np.ndindex(*values.shape[2:])]
        for j, label in enumerate(labels):
            out[f"{var}[{label}]"] = flat[:, j]
    return out


def divergence_sites(idata, *, z_named: float = Z_NAMED, max_named: int = MAX_NAMED) -> dict | None:
    """Divergent transitions by chain and by position (module docstring).

    Parameters
    ----------
    idata : arviz.InferenceData
        With ``sample_stats.diverging`` (chains, draws) and a ``posterior`` group.
    z_named, max_named : float, int
        A scalar is named if ``|z| >= z_named``; at most ``max_named`` of them.

    Returns
    -------
    dict or None
        None without divergences (or without NUTS statistics).  Else ``per_chain`` (list of
        counts), ``count``, ``named`` (list of ``{variable, side, mean_score, z}``, largest
        ``|z|`` first; scalars that do not vary are skipped), ``scalars`` (how many were
        examined) and ``z_named``.
    """
    if "sample_stats" not in idata.groups() or "diverging" not in idata.sample_stats:
        return None
    div = np.asarray(idata.sample_stats["diverging"].transpose("chain", "draw").values, dtype=bool)
    n = int(div.sum())
    if n == 0:
        return None
    chains, draws = div.shape
    per_chain = [int(c) for c in div.sum(axis=1)]
    # Draw indices of the divergences, observed (row 0) and under each circular shift.
    rng = np.random.default_rng(0)
    shifts = np.concatenate([[[0] * chains], rng.integers(1, max(draws, 2), size=(SHIFTS, chains))])
    chain_of, draw_of = np.nonzero(div)
    index = chain_of * draws + (draw_of[None, :] + shifts[:, chain_of]) % draws  # (1 + SHIFTS, n)
    rows = []
    scalars = _scalars(idata.posterior)
    for name, values in scalars.items():
        if not np.all(np.isfinite(values)) or np.ptp(values) == 0:
            continue
        means = normal_scores(values)[index].mean(axis=1)
        spread = means[1:].std()
        z = (means[0] - means[1:].mean()) / spread if spread > 0 else 0.0
        if abs(z) >= z_named:
            rows.append({"variable": name, "side": "low" if z < 0 else "high",
                         "mean_score": float(means[0]), "z": float(z)})  # fmt: skip
    # A sampling coordinate z[...] that is a monotone map of one parameter has that
    # parameter's scores: name the parameter only.
    rows.sort(key=lambda r: (-abs(r["z"]), r["variable"].startswith("z[")))
    rows = [r for i, r in enumerate(rows) if i == 0 or r["mean_score"] != rows[i - 1]["mean_score"]]
    return {"count": n, "per_chain": per_chain, "named": rows[:max_named], "scalars": len(scalars),
            "z_named": z_named}


def divergence_text(sites: dict | None) -> str:
    """One clause for a health line, e.g. ``"12 of 14 in chain 1; at high
    z[log_D_psi_yaw_ratio] (mean normal score +1.93, z +5.7), ..."`` (the rig's 2-unit
    FNN(u) posterior); empty without divergences."""
    if not sites:
        return ""
    parts = []
    chains = sites["per_chain"]
    worst = int(np.argmax(chains))
    if len(chains) > 1 and chains[worst] >= CHAIN_SHARE * sites["count"]:
        count, held = sites["count"], chains[worst]
        share = "" if count == 1 else f"all {count} " if held == count else f"{held} of {count} "
        parts.append(f"{share}in chain {worst}")
    if sites["named"]:
        parts.append("at " + ", ".join(f"{r['side']} {r['variable']} (mean normal score "
                                       f"{r['mean_score']:+.2f}, z {r['z']:+.1f})" for r in sites["named"]))
    elif sites["count"] >= 2:
        parts.append(f"at no scalar in particular (|z| < {sites['z_named']:g} on all {sites['scalars']})")
    return "; ".join(parts)
