"""The contract every registered term keeps (README, "Adding a term"), so that a new term
that breaks it fails here, with its name, rather than in the CLI's help or in discovery.

Each check simulates the paper's model with the term added and compares it with the
paper's model alone on 2 s of voltage steps; a term at its "no effect" values must not
move the solution (the fixed-step solver is deterministic, so "not move" is to rounding).
"""

import numpy as np
import pytest

from heli_uq.model import TABLE1
from heli_uq.model.heli_model import HeliModel
from heli_uq.model.terms import EFFECTS, TERMS, AbstractInputMap, ClosedFormMechanics, LinearTorque
from heli_uq.model.terms.base import AbstractEffect
from heli_uq.simulation import simulate

#: A term at its "no effect" values leaves the angles of the paper's model to this [rad].
NO_EFFECT_TOL = 1e-12

_X0 = np.array([-0.5, 0.3, 0.0, 0.0])


def _steps(seed: int = 0) -> np.ndarray:
    """2 s at 0.01 s of voltage levels held 0.25 s, both signs, within the rig's ranges."""
    rng = np.random.default_rng(seed)
    levels = np.column_stack([rng.uniform(1.0, 1.6, 8), rng.uniform(-1.5, 1.5, 8)])
    return np.repeat(levels, 25, axis=0)


def _moves(term, values: dict) -> float:
    """Largest angle difference [rad] the term makes at ``values`` on :func:`_steps`."""
    u = _steps()
    base = np.asarray(simulate(dict(TABLE1), _X0, u, 0.01))
    maps = isinstance(term, AbstractInputMap)
    model = HeliModel(ClosedFormMechanics(), (term,) if maps else (),
                      (LinearTorque(),) if maps else (LinearTorque(), term))  # fmt: skip
    params = {**model.start_values(), **TABLE1, **values}
    with_term = np.asarray(simulate(params, _X0, u, 0.01, model=model))
    return float(np.max(np.abs(with_term[:, :2] - base[:, :2])))


@pytest.mark.parametrize("kind", sorted(TERMS))
def test_every_term_builds_from_its_defaults_and_its_defaults_are_no_effect(kind):
    """``cls()`` builds (the CLI lists every term's parameters from it), it has a line for
    the CLI's list, and at its declared defaults it does nothing."""
    cls = TERMS[kind]
    term = cls()
    assert isinstance(term, AbstractEffect) and term.kind == kind
    assert cls.summary.strip(), f"{kind}: no summary line for the CLI's list of terms"
    defaults = {p.name: p.default for p in term.parameters()}
    assert _moves(term, defaults) <= NO_EFFECT_TOL, f"{kind}: its defaults move the solution"


@pytest.mark.parametrize("kind", sorted(EFFECTS))
@pytest.mark.parametrize("axis", ["pitch", "yaw"])
def test_a_vocabulary_effect_builds_on_either_axis_and_its_first_parameter_switches_it_off(kind, axis):
    """Discovery tries every effect of the vocabulary on both axes, and names an effect by
    the derivative of its torque in its first parameter: that parameter at its default
    switches the effect off whatever the others are, and away from it the effect acts."""
    term = EFFECTS[kind](axis=axis)
    first, *_ = term.parameters()
    starts = {p.name: p.start_value() for p in term.parameters()}
    off = {**starts, first.name: first.default}
    # on: the first parameter at its start value, or 0.01 (SI) where that is the default
    # (a signed effect such as an offset starts at 0)
    on = {**starts, first.name: starts[first.name] if starts[first.name] != first.default else 0.01}
    assert _moves(term, off) <= NO_EFFECT_TOL, f"{kind}({axis}): {first.name} at its default leaves an effect"
    assert _moves(term, on) > 1e3 * NO_EFFECT_TOL, f"{kind}({axis}): {first.name} = {on[first.name]} acts not"


def test_the_cli_lists_every_term_and_a_term_that_cannot_be_built_breaks_only_its_line():
    """The CLI's list of terms is made from :data:`TERMS` when it is imported (every
    command): a new term whose field lacks a default gave a traceback on every command,
    ``--help`` included.  Now its line says why, and the other lines stay."""
    from typing import ClassVar

    import equinox as eqx

    from heli_uq.cli.options import EFFECTS_HELP, _effects_help
    from heli_uq.model.terms import AbstractTorque

    for kind, cls in TERMS.items():
        assert f"  {kind} " in EFFECTS_HELP and cls.summary[:40] in EFFECTS_HELP

    class NoDefault(AbstractEffect, AbstractTorque):  # a field without a default: cls() raises
        kind: ClassVar[str] = "no_default"
        summary: ClassVar[str] = "a term without a default axis"
        axis: str = eqx.field(static=True)

        def _declare(self):
            return ()

        def __call__(self, p, x, v, u):
            return 0.0, 0.0

    import heli_uq.model.terms as terms

    broken = {**TERMS, "no_default": NoDefault}
    original = terms.TERMS
    terms.TERMS = broken
    try:
        text = _effects_help()
    finally:
        terms.TERMS = original
    (line,) = [x for x in text.splitlines() if x.startswith("  no_default ")]
    assert "cannot list its parameters: TypeError" in line
    assert all(f"  {kind} " in text for kind in TERMS)
