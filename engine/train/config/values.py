"""Type-checked config values: a value is checked and converted against its dataclass field's
type hint (ints are floats, lists are tuples), so a new field needs no checker of its own.

Generic over the config class (nothing here knows :class:`TrainConfig`): ``train_config.py``
checks a config built in code with :func:`check_types`, ``overrides.py`` converts the values
that arrive by name.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import types
import typing
from typing import Any, Literal

from sparsesplat.engine.errors import ConfigError

BACKGROUND_NAMES: dict[str, tuple[float, float, float]] = {
    "white": (1.0, 1.0, 1.0),
    "black": (0.0, 0.0, 0.0),
    "gray": (0.5, 0.5, 0.5),
    "grey": (0.5, 0.5, 0.5),
}
"""Names accepted for ``background``."""
MEAN_BACKGROUND: Literal["mean"] = "mean"
"""The ``background`` setting for the training photos' mean colour (resolved per run)."""


class Mismatch(Exception):
    """A value does not fit a type hint (turned into a ConfigError naming the field)."""


@functools.cache
def _hints(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls)


@functools.cache
def sections(cls: type) -> dict[str, type]:
    """Section name → its dataclass (the fields of config class ``cls`` that are dataclasses)."""
    return {
        name: hint
        for name, hint in _hints(cls).items()
        if isinstance(hint, type) and dataclasses.is_dataclass(hint)
    }


@functools.cache
def settable_fields(cls: type) -> dict[str, Any]:
    """Every settable name of config class ``cls``, dotted for section fields, → its hint."""
    out: dict[str, Any] = {}
    parts = sections(cls)
    for name, hint in _hints(cls).items():
        if name in parts:
            for sub, sub_hint in _hints(parts[name]).items():
                out[f"{name}.{sub}"] = sub_hint
        else:
            out[name] = hint
    return out


def parse_background(value: Any) -> tuple[float, float, float] | Literal["mean"] | None:
    """``None``, :data:`MEAN_BACKGROUND`, a name from :data:`BACKGROUND_NAMES` or 3 numbers in
    [0, 1] -> that setting as an RGB tuple (or ``"mean"``); anything else raises
    :class:`ConfigError` saying what is accepted."""
    if value is None:
        return None
    if isinstance(value, str):
        key = value.strip().lower()
        if key == MEAN_BACKGROUND:
            return MEAN_BACKGROUND
        if key in BACKGROUND_NAMES:
            return BACKGROUND_NAMES[key]
    else:
        try:
            rgb = tuple(float(v) for v in value)
        except (TypeError, ValueError):
            rgb = ()
        if len(rgb) == 3 and all(math.isfinite(c) and 0.0 <= c <= 1.0 for c in rgb):
            return (rgb[0], rgb[1], rgb[2])
    raise ConfigError(
        f"background must be white, black, gray, mean or 3 numbers in [0, 1] like [1, 1, 1], "
        f"got {value!r}"
    )


def describe(hint: Any) -> str:
    """A type hint in words for a message (``int | None``, ``'neural' or 'sh'``)."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin is Literal:
        listed = [repr(a) for a in args]
        return f"{', '.join(listed[:-1])} or {listed[-1]}" if len(listed) > 1 else listed[0]
    if origin in (typing.Union, types.UnionType):
        return " | ".join(describe(a) for a in args)
    if hint is type(None):
        return "None"
    if origin is not None:
        inner = ", ".join("..." if a is Ellipsis else describe(a) for a in args)
        return f"{origin.__name__}[{inner}]"
    return getattr(hint, "__name__", str(hint))


_SCALARS: dict[Any, Any] = {bool: bool, int: int, float: int | float, str: str}
"""Scalar field type -> the value types it takes (an int widens to float)."""


def coerce(hint: Any, value: Any) -> Any:
    """``value`` checked against ``hint`` and converted (int → float, list → tuple); raises
    ``Mismatch`` when it does not fit."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if hint is Any:
        return value
    if origin is Literal:
        if any(value == a and type(value) is type(a) for a in args):
            return value
        raise Mismatch
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        for arg in args:
            if arg is type(None):
                continue
            try:
                return coerce(arg, value)
            except Mismatch:
                pass
        raise Mismatch
    if hint in _SCALARS:
        # bool is an int subclass: neither an int nor a float field takes one.
        if isinstance(value, _SCALARS[hint]) and (hint is bool or not isinstance(value, bool)):
            return float(value) if hint is float else value
        raise Mismatch
    if origin is tuple:
        if not isinstance(value, list | tuple):
            raise Mismatch
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(coerce(args[0], v) for v in value)
        if len(value) != len(args):
            raise Mismatch
        return tuple(coerce(a, v) for a, v in zip(args, value, strict=True))
    if origin is dict:
        if not isinstance(value, dict):
            raise Mismatch
        return {coerce(args[0], k): coerce(args[1], v) for k, v in value.items()}
    raise Mismatch


def checked(name: str, hint: Any, value: Any) -> Any:
    """``value`` for field ``name`` checked against ``hint`` and converted (:func:`coerce`);
    :class:`ConfigError` naming the field and the type otherwise."""
    try:
        return coerce(hint, value)
    except Mismatch:
        raise ConfigError(f"{name} must be {describe(hint)}, got {value!r}") from None


def check_types(config: object) -> None:
    """Raise :class:`ConfigError` naming the first field of ``config`` (a config dataclass)
    whose value does not fit its type hint (a config built in code rather than from values
    read by name)."""
    cls: type = type(config)
    for name, hint in settable_fields(cls).items():
        section, _, sub = name.partition(".")
        value = getattr(getattr(config, section), sub) if sub else getattr(config, section)
        if name == "background":
            continue
        checked(name, hint, value)
