"""The one way results become JSON: typed, strict, and nothing numpy escapes.

Every ``to_dict`` of a result object and every JSON the command line prints or writes
goes through :func:`jsonable` (and :func:`dumps`), which converts recursively to the
built-in types JSON knows:

* ``dict`` (keys as ``str``), ``list`` (from lists, tuples and numpy arrays), ``str``,
  ``bool`` (also ``numpy.bool_``), ``int`` (also numpy integers), ``None``;
* ``float`` (also numpy floats) when finite, else ``None`` (strict JSON has no NaN or
  Infinity; the fields that can be infinite say so in their documentation);
* ``pathlib.Path`` as its text, complex numbers as ``[real, imag]``.

Anything else raises ``TypeError`` naming the value's type and where it sits (the chain
of keys and indices), so a new field of an unexpected type fails in the tests instead of
in a user's run.

A result that is its fields is written by :func:`fields_dict`, declared on the class:
field metadata :data:`OMIT` leaves a field out, :func:`renamed` writes it under another
key, and a class attribute ``JSON_PROPERTIES`` (a tuple of names) appends properties after
the fields. A ``to_dict`` that is then ``return fields_dict(self)`` says exactly that.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Iterable, Mapping
from pathlib import PurePath
from types import MappingProxyType
from typing import Any

__all__ = ["jsonable", "dumps", "fields_dict", "OMIT", "renamed", "JSON_KEY"]

#: The key of a dataclass field's metadata read by :func:`fields_dict`: the field's JSON
#: key, or ``None`` to leave the field out.
JSON_KEY = "json"
#: Field metadata (``dataclasses.field(metadata=OMIT)``): :func:`fields_dict` leaves the
#: field out.
OMIT: Mapping[str, Any] = MappingProxyType({JSON_KEY: None})


def jsonable(value: Any, where: str = "$") -> Any:
    """``value`` as JSON-ready built-ins (module docstring); ``where`` names its place in
    the error message."""
    import numpy as np  # here, not at import time: the command line's --help needs no numpy

    try:
        return _convert(value, np)
    except _Refused as exc:
        place = where + "".join(f"[{key}]" if isinstance(key, int) else f".{key}" for key in reversed(exc.keys))
        raise TypeError(f"{place}: a {type(exc.value).__module__}.{type(exc.value).__name__} cannot be written "
                        f"as JSON ({exc.value!r:.80})") from None


class _Refused(Exception):
    """A value of no JSON type; ``keys`` collects its place on the way out (innermost first)."""

    def __init__(self, value: Any) -> None:
        self.value = value
        self.keys: list[int | str] = []


def _convert(value: Any, np: Any) -> Any:
    if value is None or isinstance(value, (str, bool)):
        return value
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        v = float(value)
        return v if math.isfinite(v) else None
    if isinstance(value, (complex, np.complexfloating)):
        return [_convert(value.real, np), _convert(value.imag, np)]
    if isinstance(value, np.ndarray):
        return _convert(value.tolist(), np)
    if isinstance(value, PurePath):
        return str(value)
    items: Iterable[tuple[Any, Any]]
    out: dict[str, Any] | list[Any]
    if isinstance(value, dict):
        items, out = value.items(), {}
    elif isinstance(value, (list, tuple)):
        items, out = enumerate(value), []
    else:
        raise _Refused(value)
    for key, item in items:
        try:
            converted = _convert(item, np)
        except _Refused as exc:
            exc.keys.append(key)
            raise
        if isinstance(out, dict):
            out[str(key)] = converted
        else:
            out.append(converted)
    return out


def dumps(value: Any) -> str:
    """``value`` as strict JSON text (:func:`jsonable`, indented by 2)."""
    return json.dumps(jsonable(value), indent=2, allow_nan=False)


def renamed(key: str) -> Mapping[str, Any]:
    """Field metadata (``dataclasses.field(metadata=renamed("key"))``): :func:`fields_dict`
    writes the field under ``key``."""
    return MappingProxyType({JSON_KEY: key})


def fields_dict(obj: Any) -> dict[str, Any]:
    """The dataclass instance ``obj`` as a JSON-ready dict: its fields in their declared
    order, then the attributes named by the class's ``JSON_PROPERTIES`` (module docstring).

    A field whose metadata has :data:`JSON_KEY` is written under that key, or left out
    when it is ``None`` (:data:`OMIT`, :func:`renamed`). A dataclass among the values (also
    inside lists, tuples and dicts) is written by its ``to_dict()`` when it has one, else
    by this function; then everything goes through :func:`jsonable`.
    """
    if not dataclasses.is_dataclass(obj) or isinstance(obj, type):
        raise TypeError(f"fields_dict: a dataclass instance is needed, got a {type(obj).__name__}")
    out: dict[str, Any] = {}
    for f in dataclasses.fields(obj):
        key = f.metadata.get(JSON_KEY, f.name)
        if key is not None:
            out[key] = _nested(getattr(obj, f.name))
    for name in getattr(obj, "JSON_PROPERTIES", ()):
        out[name] = _nested(getattr(obj, name))
    return jsonable(out, type(obj).__name__)


def _nested(value: Any) -> Any:
    """``value`` with every dataclass in it (through lists, tuples, dicts) as its dict."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        to_dict = getattr(value, "to_dict", None)
        return to_dict() if callable(to_dict) else fields_dict(value)
    if isinstance(value, (list, tuple)):
        return [_nested(v) for v in value]
    if isinstance(value, dict):
        return {k: _nested(v) for k, v in value.items()}
    return value
