"""Build a model from text: an effects list, a model file, or a stored description.

* ``"yaw:coulomb_friction,yaw:torque_offset"`` (the CLI's ``--effects``), one
  ``AXIS:EFFECT`` item per effect;
* a model file (``--model-file model.json``) for scripts::

      {"effects": ["yaw:coulomb_friction",
                   {"effect": "deadband", "axis": "yaw"},
                   {"effect": "coulomb_friction", "axis": "pitch", "omega_s": 0.001}],
       "mechanics": "closed_form"}

* :meth:`HeliModel.describe` output, stored with every result (``posterior.nc``
  attributes, ``summary.json``), which :func:`model_from_description` reads back.

Every error names the item, what was expected (the valid choices) and what was found.
"""

from __future__ import annotations

import dataclasses
import json
import os

from heli_uq.errors import ParameterError
from heli_uq.model.heli_model import HeliModel
from heli_uq.model.parameter import AXES
from heli_uq.model.terms import TERMS, ClosedFormMechanics, LagrangianMechanics, LinearTorque
from heli_uq.model.terms.base import AbstractInputMap

__all__ = ["parse_effects", "split_effects", "build_model", "model_from_description", "load_model_file",
           "with_effects"]

_MECHANICS = {"closed_form": ClosedFormMechanics, "lagrangian": LagrangianMechanics}
_FILE_KEYS = ("effects", "mechanics", "linear_torque")


#: What an option whose default is of this type must be given as.
_TYPE_WORDS = {bool: "true or false", float: "a number", str: "a string"}


def _option_type(default):
    """The type an option's value must have, from its default (None: not checked)."""
    if isinstance(default, bool):
        return bool
    if isinstance(default, (int, float)):
        return float
    return str if isinstance(default, str) else None


def _is(value, expected) -> bool:
    if expected is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    return isinstance(value, expected)


def _effect(item, where: str):
    """One effect term from ``"axis:effect"`` or ``{"effect": ..., "axis": ..., options}``."""
    if isinstance(item, str):
        axis, sep, name = (s.strip() for s in item.partition(":"))
        if not sep:
            raise ParameterError(f"{where}: effect {item!r}: expected AXIS:EFFECT, e.g. "
                                 f"yaw:coulomb_friction (axes: {', '.join(AXES)})")  # fmt: skip
        options = {}
    elif isinstance(item, dict):
        options = dict(item)
        name, axis = options.pop("effect", None), options.pop("axis", None)
        if name is None or axis is None:
            raise ParameterError(f"{where}: effect {item!r}: expected the keys 'effect' and 'axis'")
    else:
        raise ParameterError(f"{where}: effect {item!r}: expected 'AXIS:EFFECT' or an object")
    if not isinstance(name, str) or name not in TERMS:
        raise ParameterError(f"{where}: unknown effect {name!r}; expected one of "
                             f"{', '.join(TERMS)} (a new term is registered in TERMS, "
                             "heli_uq/model/terms/__init__.py)")  # fmt: skip
    if not isinstance(axis, str) or axis not in AXES:
        raise ParameterError(f"{where}: effect {name!r}: unknown axis {axis!r}; expected one of "
                             f"{', '.join(AXES)}")  # fmt: skip
    cls = TERMS[name]
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init and f.name != "axis"}
    bad = sorted(set(options) - set(fields))
    if bad:
        raise ParameterError(f"{where}: effect {name!r}: unknown option(s) {', '.join(bad)}; "
                             f"expected {', '.join(sorted(fields)) or 'none'}")  # fmt: skip
    for key, value in options.items():
        expected = _option_type(fields[key].default)
        if expected is not None and not _is(value, expected):
            raise ParameterError(f"{where}: effect {name!r}: option {key!r}: expected "
                                 f"{_TYPE_WORDS[expected]}, found {value!r}")  # fmt: skip
    try:
        return cls(axis=axis, **options)
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"{where}: effect {name!r}: {exc}") from None


def build_model(effects=(), *, mechanics: str = "closed_form", linear_torque: bool = True,
                where: str = "effects") -> HeliModel:  # fmt: skip
    """A :class:`HeliModel` with the paper's mechanics and linear torque plus ``effects``.

    Parameters
    ----------
    effects : iterable
        Items ``"axis:effect"`` or ``{"effect", "axis", options...}``.
    mechanics : {"closed_form", "lagrangian"}
    linear_torque : bool
        Include ``F = K u - D v`` (default True).
    """
    if not isinstance(mechanics, str) or mechanics not in _MECHANICS:
        raise ParameterError(f"{where}: unknown mechanics {mechanics!r}; expected one of "
                             f"{', '.join(_MECHANICS)}")  # fmt: skip
    terms = [_effect(item, where) for item in effects]
    inputs = tuple(t for t in terms if isinstance(t, AbstractInputMap))
    torques = tuple(t for t in terms if not isinstance(t, AbstractInputMap))
    base = (LinearTorque(),) if linear_torque else ()
    if not base + torques:
        raise ParameterError(f"{where}: the model needs at least one torque term")
    try:
        return HeliModel(_MECHANICS[mechanics](), inputs, base + torques)
    except ParameterError as err:  # e.g. an effect twice: said for the option that gave it
        raise ParameterError(f"{where}: {str(err).removeprefix('model: ')}") from None


#: Options of a stored term that were derived from its record (a network's input scaling and
#: projection); a rebuilt model adapts to its record again.
_RECORD_OPTIONS = ("center", "scale", "projection", "reference", "whiten")


def with_effects(model: HeliModel, keep=lambda effect: True, add=(), *, where: str = "model") -> HeliModel:
    """``model`` with only the effects ``keep`` accepts, then ``add``.

    Parameters
    ----------
    model : HeliModel
    keep : callable
        Called with each effect's description dict (``{"effect", "axis", options...}``).
    add : iterable
        Effects appended, as in :func:`build_model`.

    The mechanics and the linear torque are ``model``'s; options derived from a record (a
    network's scaling and projection) are dropped, so the result adapts to its record.
    """
    desc = model.describe()
    effects = [{k: v for k, v in e.items() if k not in _RECORD_OPTIONS} for e in desc["effects"] if keep(e)]
    return build_model(effects + list(add), mechanics=desc.get("mechanics", "closed_form"),
                       linear_torque=desc.get("linear_torque", True), where=where)  # fmt: skip


def parse_effects(text: str | None, *, where: str = "effects") -> HeliModel:
    """The model of ``"yaw:coulomb_friction,yaw:torque_offset"`` (empty: the paper's model)."""
    return build_model(split_effects(text, where=where), where=where)


def split_effects(text: str | None, *, where: str = "effects") -> list[str]:
    """``"yaw:coulomb_friction, yaw:torque_offset"`` as a list of its items (empty: none);
    an empty item between commas is refused (a typo, not "no effect")."""
    items = [s.strip() for s in (text or "").split(",")]
    if len(items) > 1 and not all(items):
        raise ParameterError(f"{where}: an empty item in {text!r}; expected AXIS:EFFECT,AXIS:EFFECT,...")
    return [s for s in items if s]


def model_from_description(desc, *, where: str = "model description") -> HeliModel:
    """The model of a :meth:`HeliModel.describe` dict (or its JSON text)."""
    if isinstance(desc, str):
        try:
            desc = json.loads(desc)
        except json.JSONDecodeError as exc:
            raise ParameterError(f"{where}: invalid JSON ({exc.msg})") from None
    if not isinstance(desc, dict):
        raise ParameterError(f"{where}: expected a JSON object with keys {', '.join(_FILE_KEYS)}")
    bad = sorted(set(desc) - set(_FILE_KEYS))
    if bad:
        raise ParameterError(f"{where}: unknown key(s) {', '.join(bad)}; expected "
                             f"{', '.join(_FILE_KEYS)}")  # fmt: skip
    effects = desc.get("effects", [])
    if not isinstance(effects, list):
        raise ParameterError(f"{where}: 'effects' must be a list, found {effects!r}")
    linear_torque = desc.get("linear_torque", True)
    if not isinstance(linear_torque, bool):
        raise ParameterError(f"{where}: 'linear_torque' must be true or false, found {linear_torque!r}")
    return build_model(effects, mechanics=desc.get("mechanics", "closed_form"),
                       linear_torque=linear_torque, where=where)  # fmt: skip


def load_model_file(path: str | os.PathLike) -> HeliModel:
    """The model described by a JSON model file (module docstring)."""
    from heli_uq.io import read_json_object

    path = os.fspath(path)
    return model_from_description(read_json_object(path, "model"), where=path)
