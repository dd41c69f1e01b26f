"""The held-out check of the effects named in a network of the states: its candidates and
the ``heli-uq discover`` command that runs it (:mod:`heli_uq.discovery.network_effects`
names them; ``heli-uq sample`` prints the command).

Naming is not a model comparison, so the named effects (and those tied to them) are
offered to :func:`heli_uq.discovery.discover` as its only candidates, on the training
window the network was fitted on, with the sampled model's other named effects as the
base.

Layer 8 (discovery).
"""

from __future__ import annotations

import shlex

from heli_uq.model import build_model

__all__ = ["check_candidates", "check_line"]


def check_candidates(found: dict) -> list[str]:
    """The effects ``"axis:kind"`` named on each axis, each followed by the effects tied to
    it (``found``: ``{axis: network_effects_of(...)}``,
    :func:`~heli_uq.discovery.network_effects.network_effects_of`): the candidates of the
    held-out check by :func:`heli_uq.discovery.discover` (module docstring).  On an axis
    where nothing is named, its credible effects that explain too little to be named
    (``unexplained``) are the candidates: the check, not
    :data:`~heli_uq.discovery.network_effects.EXPLAINED_MIN`, then judges them.  Empty if
    no effect is credible."""
    out = []
    for axis, named in found.items():
        for kind in named["selected"] or named.get("credible", []):
            for k in (kind, *named.get("ties", {}).get(kind, ())):
                if f"{axis}:{k}" not in out:
                    out.append(f"{axis}:{k}")
    return out


def check_line(data: str, found: dict, window, out, *, model=None, prior_options=()) -> str | None:
    """The line ``heli-uq sample`` prints after naming: the ``heli-uq discover`` command of
    the held-out check of the effects named in ``found`` (``{axis: network_effects_of(...)}``)
    on the training ``window`` ``(a, b)`` [s] of the record ``data``, writing to ``out``; or,
    for a window shorter than discovery's :data:`~heli_uq.discovery.workflow.MIN_SECONDS`,
    why there is none.  ``None`` if :func:`check_candidates` finds no candidate.

    ``model``: the sampled model, whose named effects are the check's ``--base-effects``
    (an effect whose options ``--base-effects`` cannot carry is named in the line);
    ``prior_options``: the run's prior options as words (``["--fix", "a_yaw=1"]``).
    """
    from heli_uq.discovery.workflow import MIN_SECONDS

    candidates = check_candidates(found)
    if not candidates:
        return None
    a, b = window
    if b - a < MIN_SECONDS:
        return (f"a check of them on held-out blocks (heli-uq discover) needs a training window of at "
                f"least {MIN_SECONDS:g} s; this one is {b - a:g} s")  # fmt: skip
    base, lost = _base_effects(model)
    words = ([f"--base-effects {','.join(base)}"] if base else []) + [shlex.quote(w) for w in prior_options]
    line = (f"check them on held-out blocks: heli-uq discover {data} --window {a:g}:{b:g} "
            + "".join(f"{w} " for w in words)
            + f"--candidates {','.join(candidates)} --max-effects {len(candidates)} --out {out}")  # fmt: skip
    if lost:
        line += (" (its base model takes each effect's default options; this run's differ for "
                 f"{', '.join(lost)})")
    return line


#: Terms that are not named effects of a base model (a network or a fitted function).
_NOT_BASE = ("neural_torque", "gp_torque", "feature_torque")


def _base_effects(model) -> tuple[list[str], list[str]]:
    """``(["axis:kind", ...], [those whose options are not the defaults])`` of ``model``'s
    named effects (``([], [])`` without a model)."""
    if model is None:
        return [], []
    base, lost = [], []
    for spec in model.describe()["effects"]:
        if spec["effect"] in _NOT_BASE:
            continue
        name = f"{spec['axis']}:{spec['effect']}"
        base.append(name)
        if build_model([name]).describe()["effects"][0] != spec:
            lost.append(name)
    return base, lost
