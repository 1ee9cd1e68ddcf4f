"""A plan's stored parameters, written once for every plan dataclass.

A run stores its plan as JSON (``params``) so that a resume runs the same plan.
The conversion follows each field's declared type: a :class:`RobotSpec` is
stored by name and looked up again, tuples become lists and come back as
tuples (nested ones too), numbers are coerced to the declared kind; a field
missing from an older run's parameters takes its default.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from typing import Any, Mapping

from station.models.robots import RobotSpec, get_robot

__all__ = ["plan_params", "plan_from_params"]


def _to_json(value: Any) -> Any:
    if isinstance(value, RobotSpec):
        return value.name
    if isinstance(value, (tuple, list)):
        return [_to_json(v) for v in value]
    if isinstance(value, Mapping):
        return {k: _to_json(v) for k, v in value.items()}
    return value


def _from_json(tp: Any, value: Any) -> Any:
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        if value is None:
            return None
        inner = [a for a in args if a is not type(None)]
        return _from_json(inner[0], value) if len(inner) == 1 else value
    if tp is RobotSpec:
        return get_robot(value)
    if tp is float:
        return float(value)
    if tp is int:
        return int(value)
    if tp is str:
        return str(value)
    if tp is tuple or origin is tuple:
        if not args:
            return tuple(_from_json(tuple, v) if isinstance(v, list) else v for v in value)
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_from_json(args[0], v) for v in value)
        return tuple(_from_json(a, v) for a, v in zip(args, value))
    if tp is dict or origin is dict:
        if len(args) == 2:
            return {k: _from_json(args[1], v) for k, v in value.items()}
        return dict(value)
    return value


def plan_params(plan) -> dict:
    """The plan dataclass ``plan`` as JSON-able parameters (field name -> value)."""
    return {f.name: _to_json(getattr(plan, f.name)) for f in dataclasses.fields(plan)}


def plan_from_params(cls, p: Mapping):
    """The plan of class ``cls`` from stored parameters ``p`` (missing fields take their defaults)."""
    hints = typing.get_type_hints(cls)
    kw = {}
    for f in dataclasses.fields(cls):
        if f.name in p:
            kw[f.name] = _from_json(hints[f.name], p[f.name])
        elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise KeyError(f.name)
    return cls(**kw)
