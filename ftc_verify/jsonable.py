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
"""

from __future__ import annotations

import json
import math
from pathlib import PurePath
from typing import Any

__all__ = ["jsonable", "dumps"]


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
        self.value, self.keys = value, []


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
