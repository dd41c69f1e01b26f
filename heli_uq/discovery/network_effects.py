"""Named effects from a network of the states: which effects of the vocabulary a
FNN(u, x, v)'s posterior torque is made of.

A network of the voltages is named by a library of voltage features
(:mod:`heli_uq.discovery.network_equation`).  A network of the states can learn what the
effects table describes, a friction, a drag or a spring, so its library is the table
itself: for each effect on the network's axis, its *column* is the derivative of the
model's generalized force on that axis [N m] with respect to the effect's magnitude (its
first parameter: ``F_c``, ``c``, ``k``, ``k_q``, ``T_0``, ``delta``), with its other
parameters at their probe values and the physics at the posterior mean (so a dead band
acts through the fitted gains), at the network's grid (the training window's samples:
measured angles, smoothed rates, voltages; :func:`heli_uq.output.network.network_points`).

1. The columns are projected like the network (orthogonal to the span its physics owns,
   :meth:`~heli_uq.model.terms.NeuralTorque.basis`), scaled to unit RMS; a column the
   projection leaves nothing of (an offset where the constant is projected) is dropped,
   and a column equal to an earlier one up to scale is that one (``ties``: a dead band on
   voltages that never fall below it is a constant torque, named as the offset, the
   torques coming before the input maps in the default library).
2. Each posterior draw's torque is regressed on them by pysindy's stepwise sparse path,
   the least-BIC model of the path kept (:func:`~heli_uq.discovery.network_equation.bic_path_fit`).
3. An effect is *kept* by a draw when its coefficient, in the magnitude's unit, is nonzero
   and inside the magnitude's support (a negative friction is not a friction).  Its
   inclusion probability is the fraction of draws that keep it.
4. Those at :data:`~heli_uq.discovery.network_equation.INCLUDE` or more are fitted
   jointly to every draw by least squares; an effect is selected when its magnitude's 95 %
   interval over the draws excludes 0 (on the support's side).  The least-BIC path of a
   noise-free network curve adds features whenever they lower the residual, so on a
   posterior whose torque the draws do not agree on, some feature is kept by most draws
   with coefficients of both signs; the interval is what tells it from an effect.
   Together the credible effects must explain :data:`EXPLAINED_MIN` of the posterior-mean
   torque, else nothing is named (``unexplained``): the network learned something the
   table does not hold, or more than the effect (the credible ones are still candidates
   of the held-out check below).
   :func:`~heli_uq.discovery.network_equation.equation_model` puts the selected effects in
   place of the network for a refit.

Naming is not a model comparison: a draw's regression can keep an effect that a fit to the
record does not need (a spring beside a hidden friction, on a 24 s record).
:func:`~heli_uq.discovery.network_check.check_candidates` lists the named effects and their
ties (where nothing is named, the credible effects that explain too little) as the
candidates of a held-out check, :func:`heli_uq.discovery.discover` restricted to them
(``candidates``, ``max_effects`` = their number): it fits them alone and in pairs on part
of the training window, keeps only what beats the smaller model on held-out blocks of the
rest, and refits that with NUTS (:func:`~heli_uq.discovery.network_check.check_line`: the
command ``heli-uq sample`` prints).

The implied magnitudes are local: a column is a derivative at the probe values, so a dead
band's or a spring's rest angle is not estimated here, only named; the refit estimates it.

Layer 8 (discovery).
"""

from __future__ import annotations

import json
import warnings

import jax
import jax.numpy as jnp
import numpy as np

from heli_uq.discovery.network_equation import INCLUDE, bic_path_fit
from heli_uq.errors import ParameterError
from heli_uq.model.spec import with_effects
from heli_uq.model.terms import EFFECTS, NeuralTorque
from heli_uq.model.terms.base import AbstractInputMap, residual_projector
from heli_uq.probability.priors import fixed_values

__all__ = ["name_network_effects", "effect_columns", "network_effects_of", "input_dependence",
           "state_networks", "effects_sentence", "EXPLAINED_MIN"]  # fmt: skip

#: Grid inputs of a network of the states (coords of ``nn_point_<axis>``).
STATE_INPUTS = ("theta", "psi", "omega_theta", "omega_psi", "u_theta", "u_psi")
#: A column whose projected RMS is below this fraction of the largest is dropped.
FLAT = 1e-9
#: Two unit-RMS columns whose mean product reaches this are one column (the later effect
#: is reported as tied with the earlier one and not regressed on).
TIED = 1 - 1e-9
#: Quantile bins of :func:`input_dependence`.
DEPENDENCE_BINS = 10
#: Fraction of the posterior-mean torque the credible effects must explain together to be
#: named: below it the network learned something else, and effects that only cancel one
#: another's large coefficients (an offset against a quadratic thrust on voltages that stay
#: positive: 2 % on a synthetic record with a hidden spring) are not named.  A network's
#: torque also holds what its unconverged or unconstrained directions add, so the named part
#: can be well below 1 (a hidden yaw friction: 26 %); the refit in the network's place is
#: what judges it.
EXPLAINED_MIN = 0.2


def _base(model):
    """``model`` without its neural terms (the physics the columns are taken at)."""
    return with_effects(model, lambda e: e["effect"] != "neural_torque", where="network effects")


def effect_columns(model, params: dict, axis: str, points: dict, effects=None) -> dict:
    """Each effect's column on ``axis`` at the grid ``points`` (module docstring).

    Parameters
    ----------
    model : HeliModel
        The hybrid model (its neural terms are dropped) or its physics.
    params : dict
        The physics' parameter values (e.g. posterior means); missing ones take defaults.
    axis : {"pitch", "yaw"}
    points : dict
        ``{input: (k,)}`` for every name of :data:`STATE_INPUTS` [rad, rad/s, V].
    effects : sequence of str, optional
        Effect kinds, in order of preference among tied columns (default: the vocabulary,
        :data:`heli_uq.model.terms.EFFECTS`, its torques before its input maps); those the
        physics already has on ``axis`` are left out.

    Returns
    -------
    dict
        ``{kind: (parameter, column (k,))}``: the magnitude's full name (e.g. ``F_c_yaw``)
        and ``d T_axis / d magnitude`` [N m per unit of the magnitude].
    """
    base = _base(model)
    have = {(e["effect"], e["axis"]) for e in base.describe()["effects"]}
    # torques before input maps: of two tied columns the earlier is named (name_network_effects)
    library = effects or sorted(EFFECTS, key=lambda k: issubclass(EFFECTS[k], AbstractInputMap))
    kinds = [k for k in library if (k, axis) not in have]
    unknown = [k for k in kinds if k not in EFFECTS]
    if unknown:
        raise ParameterError(f"network effects: unknown effect(s) {unknown}; "
                             f"expected some of {', '.join(EFFECTS)}")  # fmt: skip
    x = jnp.stack([jnp.asarray(points["theta"]), jnp.asarray(points["psi"])], axis=1)
    v = jnp.stack([jnp.asarray(points["omega_theta"]), jnp.asarray(points["omega_psi"])], axis=1)
    u = jnp.stack([jnp.asarray(points["u_theta"]), jnp.asarray(points["u_psi"])], axis=1)
    index = 0 if axis == "pitch" else 1
    out = {}
    for kind in kinds:
        full = with_effects(base, add=[{"effect": kind, "axis": axis}], where="network effects")
        new = EFFECTS[kind](axis=axis).parameters()  # the magnitude first
        p = full.complete({**{k: float(val) for k, val in params.items() if k in base.names},
                           **{par.name: par.start_value() for par in new}})  # fmt: skip
        magnitude = new[0].name

        def force(value, xi, vi, ui, full=full, p=p, magnitude=magnitude):
            _, q = full.prepare({**p, magnitude: value})
            return full.force_vector(q, xi, vi, jnp.stack(full.input_voltages(q, ui)))[index]

        column = jax.vmap(jax.grad(force), in_axes=(None, 0, 0, 0))(jnp.asarray(p[magnitude]), x, v, u)
        out[kind] = (magnitude, np.asarray(column, dtype=float))
    return out


def name_network_effects(torque, columns: dict, basis, *, supports=None, include: float = INCLUDE) -> dict:
    """Sparse regression of each draw's network torque on the effects' columns.

    Parameters
    ----------
    torque : array, shape (S, k)
        Network torque [N m] of ``S`` posterior draws at the ``k`` grid points.
    columns : dict
        ``{kind: (parameter, column (k,))}`` (:func:`effect_columns`).
    basis : array, shape (k, m)
        The span the network is orthogonal to, at the grid (its :meth:`basis`).
    supports : dict, optional
        ``{parameter: support}`` (``"nonnegative"``, ``"positive"`` or ``"real"``); a draw
        keeps an effect only with a coefficient inside it (default: any sign).
    include : float
        Inclusion probability from which an effect is selected.

    Returns
    -------
    dict
        ``effects`` (the kinds regressed on), ``ties`` (kind -> the later kinds whose
        column is its own, not regressed on), ``inclusion`` (kind -> probability),
        ``explained`` (kind -> fraction of the posterior-mean torque its column alone
        explains), ``selected`` (kinds, most included first), ``credible`` (the kinds included
        often enough whose magnitude's interval excludes 0 on its support's side: the
        selected ones, or those that explain too little to be named), ``magnitudes``
        (credible kind -> ``{parameter, mean, ci95}`` of its magnitude when the credible
        columns are fitted to each draw by least squares [its unit]), ``not_credible`` (kinds included often
        enough whose magnitude's 95 % interval in that joint fit holds 0, or lies on the
        wrong side of it: not selected), ``r2`` (of the selected columns' fit to the
        posterior-mean torque; of the credible ones when none is selected), ``unexplained``
        (credible effects that explain less than :data:`EXPLAINED_MIN` of it: not named)
        and ``draws``.
    """
    torque = np.atleast_2d(np.asarray(torque, dtype=float))
    k = torque.shape[1]
    basis = np.asarray(basis, dtype=float).reshape(k, -1)
    proj = residual_projector(basis, np.ones(k))
    kinds = list(columns)
    cols = proj @ np.column_stack([columns[c][1] for c in kinds]) if kinds else np.zeros((k, 0))
    rms = np.sqrt(np.mean(cols**2, axis=0))
    keep = rms > FLAT * max(rms.max(initial=0.0), 1e-300)
    kinds, cols, rms = [c for c, kp in zip(kinds, keep) if kp], cols[:, keep], rms[keep]
    x = cols / rms
    ties = _ties(x, kinds)  # a column equal to an earlier one's (up to scale) is that one
    use = [i for i, c in enumerate(kinds) if not any(c in tied for tied in ties.values())]
    kinds, x, rms = [kinds[i] for i in use], x[:, use], rms[use]
    y = torque @ proj.T
    coefs = np.zeros((len(y), len(kinds)))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for s in range(len(y) if kinds else 0):
            coefs[s] = bic_path_fit(x, y[s]) / rms
    supports = supports or {}
    signed = np.array([supports.get(columns[c][0], "real") in ("nonnegative", "positive")
                       for c in kinds], dtype=bool)  # fmt: skip
    kept = (coefs != 0) & (~signed[None, :] | (coefs > 0))
    inclusion = {c: float(kept[:, i].mean()) for i, c in enumerate(kinds)}
    target = y.mean(0)
    explained = {c: float(_r2(x[:, [i]], target)) for i, c in enumerate(kinds)}
    candidates = sorted((c for c in kinds if inclusion[c] >= include), key=lambda c: -inclusion[c])
    # the joint refit over draws: a selected magnitude is credibly nonzero, on its support's side
    magnitudes = _magnitudes(x, y, rms, kinds, candidates, columns)
    credible = [c for c in candidates if _credible(magnitudes[c]["ci95"], signed[kinds.index(c)])]
    r2 = float(_r2(x[:, [kinds.index(c) for c in credible]], target)) if credible else float("nan")
    selected = credible if credible and r2 >= EXPLAINED_MIN else []
    return {"effects": kinds, "ties": ties, "inclusion": inclusion, "explained": explained,
            "selected": selected, "credible": credible,
            "not_credible": [c for c in candidates if c not in credible],
            "magnitudes": _magnitudes(x, y, rms, kinds, credible, columns), "r2": r2,
            "unexplained": bool(credible) and not selected, "draws": int(len(y))}


def _ties(x: np.ndarray, kinds: list) -> dict:
    """``{kind: [later kinds whose unit-RMS column is +-its own]}`` (at :data:`TIED`)."""
    ties, taken = {}, set()
    for i, c in enumerate(kinds):
        if c in taken:
            continue
        for j in range(i + 1, len(kinds)):
            if kinds[j] not in taken and abs(np.mean(x[:, i] * x[:, j])) >= TIED:
                ties.setdefault(c, []).append(kinds[j])
                taken.add(kinds[j])
    return ties


def _r2(x: np.ndarray, target: np.ndarray) -> float:
    """Fraction of ``target`` (k,) the least-squares fit on the columns ``x`` (k, m) explains."""
    fit = x @ np.linalg.lstsq(x, target, rcond=None)[0]
    return 1 - np.sum((target - fit) ** 2) / max(np.sum(target**2), 1e-300)


def _magnitudes(x, y, rms, kinds, chosen, columns) -> dict:
    """``{kind: {parameter, mean, ci95}}``: the chosen columns fitted jointly to every draw."""
    if not chosen:
        return {}
    sel = [kinds.index(c) for c in chosen]
    fits = np.linalg.lstsq(x[:, sel], y.T, rcond=None)[0].T / rms[sel][None, :]
    return {c: {"parameter": columns[c][0], "mean": float(fits[:, j].mean()),
                "ci95": [float(np.quantile(fits[:, j], 0.025)), float(np.quantile(fits[:, j], 0.975))]}
            for j, c in enumerate(chosen)}  # fmt: skip


def _credible(ci95, signed: bool) -> bool:
    """A 95 % interval that excludes 0 (above it, for a magnitude that cannot be negative)."""
    lo, hi = ci95
    return lo > 0 or (not signed and hi < 0)


def network_effects_of(idata, model, axis: str = "yaw", effects=None, *, include: float = INCLUDE) -> dict:
    """:func:`name_network_effects` for a stored posterior of a network of the states.

    Parameters
    ----------
    idata : arviz.InferenceData
        A hybrid posterior with ``nn_torque_<axis>`` on its grid (``nn_point_<axis>`` with
        the coords of :data:`STATE_INPUTS`).
    model : HeliModel
        Its model (:func:`heli_uq.output.inference_data.load_posterior`).
    axis, effects, include
        As in :func:`effect_columns` and :func:`name_network_effects`.

    Returns
    -------
    dict
        :func:`name_network_effects`'s, and ``depends_on``: :func:`input_dependence` of
        the posterior-mean torque (what the network learned, named or not).
    """
    term = next((t for t in model.torques if isinstance(t, NeuralTorque) and t.axis == axis), None)
    post = idata.posterior
    name = f"nn_torque_{axis}"
    if term is None or term.inputs == "u" or name not in post:
        raise ParameterError(f"network effects: the posterior has no network of the states on {axis} "
                             f"(a network of u is named by recover_equation)")  # fmt: skip
    points = {q: np.asarray(post[f"nn_point_{axis}_{q}"], dtype=float) for q in STATE_INPUTS}
    means = {**fixed_values(json.loads(post.attrs.get("priors", "{}"))),
             **{v: float(post[v].mean()) for v in post.data_vars if post[v].ndim == 2}}
    torque = np.asarray(post[name], dtype=float).reshape(-1, len(points["psi"]))
    columns = effect_columns(model, means, axis, points, effects)
    supports = {par: EFFECTS[kind](axis=axis).parameters()[0].support for kind, (par, _) in columns.items()}
    basis = term.basis(points, np) if term.projection else np.zeros((len(torque.T), 0))
    out = name_network_effects(torque, columns, basis, supports=supports, include=include)
    return {**out, "depends_on": input_dependence(torque.mean(axis=0), points)}


def input_dependence(torque, points: dict, bins: int = DEPENDENCE_BINS) -> dict:
    """What a torque is a function of, one input at a time: ``{input: fraction of the
    variance of torque (k,) that its mean within each of ``bins`` quantile bins of the
    input explains}`` (1: a function of that input alone; about ``bins / k`` for an input
    it does not depend on)."""
    torque = np.asarray(torque, dtype=float)
    spread = np.sum((torque - torque.mean()) ** 2)
    out = {}
    for name in STATE_INPUTS:
        fit = np.empty_like(torque)
        for group in np.array_split(np.argsort(points[name], kind="stable"), bins):
            fit[group] = torque[group].mean()
        out[name] = float(1 - np.sum((torque - fit) ** 2) / max(spread, 1e-300))
    return out


def state_networks(model) -> list[str]:
    """The axes of ``model``'s neural terms that read the states (``inputs`` other than ``u``)."""
    return [t.axis for t in model.torques if isinstance(t, NeuralTorque) and t.inputs != "u"]


def effects_sentence(axis: str, found: dict) -> str:
    """One line for a person: what :func:`network_effects_of` found on ``axis``."""
    where = max(found["depends_on"], key=found["depends_on"].get) if found.get("depends_on") else None
    depends = (f"; its torque depends most on {where} ({found['depends_on'][where]:.0%} of its "
               f"variance by that input alone)") if where else ""  # fmt: skip
    if found["selected"]:
        named = ", ".join(f"{kind} (in {found['inclusion'][kind]:.0%} of the draws)"
                          for kind in found["selected"])  # fmt: skip
        return (f"the network of the states on {axis} is made of: {named}; together "
                f"{found['r2']:.0%} of its torque{depends}")  # fmt: skip
    best = max(found["explained"], key=found["explained"].get) if found["explained"] else None
    best = f" (the best, {best}, explains {found['explained'][best]:.0%} of it)" if best else ""
    weak = (f"; credible but too small a part of it to name: {', '.join(found['credible'])} (together "
            f"{found['r2']:.0%})") if found.get("credible") else ""  # fmt: skip
    return f"the network of the states on {axis} is no effect of the table{best}{weak}{depends}"
