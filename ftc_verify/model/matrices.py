"""Matrices of the model: validated read-only float arrays and the bounds they must respect."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import ValidationError

__all__ = ["GENERATOR_RTOL", "MAX_ENTRY", "Matrix", "as_matrix", "arrays_equal"]

#: Relative tolerance for "a generator row sums to zero": ``|sum| <= GENERATOR_RTOL * max(1, max|alpha|)``.
GENERATOR_RTOL = 1e-9

#: Largest accepted magnitude of a matrix entry. The analyses square the matrices (second
#: moments, Lyapunov products, Hamiltonians); beyond this, overflow and LAPACK failures
#: replace answers, so such a model is refused with a request to rescale its units.
MAX_ENTRY = 1e15

#: A float64 NumPy array: the annotation of the matrices (and vectors) of the package.
Matrix = NDArray[np.float64]


def _short(value: object, limit: int = 120) -> str:
    text = repr(value)
    return text if len(text) <= limit else text[:limit] + "..."


def as_matrix(value: ArrayLike, name: str, *, allow_empty: bool = False) -> Matrix:
    """Return ``value`` as a read-only 2-D float array, or raise naming ``name``.

    Rejects ragged input, entries that are not numbers (strings and booleans included),
    other than 2-D shapes, empty matrices (unless ``allow_empty``), NaN/inf entries and
    entries larger than :data:`MAX_ENTRY` in magnitude (integers too large for a float
    included). Entry indices in messages are 1-based, as in the paper.
    """
    try:
        raw = np.array(value, dtype=object)
        arr = np.array(value, dtype=float)
    except OverflowError:
        raise ValidationError(f"{name}: an integer entry is too large for a float (more than 308 digits)") from None
    except (TypeError, ValueError) as exc:
        raise ValidationError(f"{name}: not a numeric matrix ({_short(value)}): {exc}") from None
    for entry in raw.flat:
        if isinstance(entry, (bool, np.bool_)) or not isinstance(entry, (int, float, np.integer, np.floating)):
            raise ValidationError(f"{name}: entries must be numbers, got {entry!r} in {_short(value)}")
    if arr.ndim != 2:
        raise ValidationError(f"{name}: expected a 2-D matrix, got shape {arr.shape} ({_short(value)})")
    if arr.size == 0 and not allow_empty:
        raise ValidationError(f"{name}: empty matrix (shape {arr.shape})")
    if not np.all(np.isfinite(arr)):
        bad = tuple(int(k) for k in np.argwhere(~np.isfinite(arr))[0])
        raise ValidationError(f"{name}: non-finite entry {arr[bad]} at [{bad[0] + 1}][{bad[1] + 1}]")
    if arr.size and float(np.max(np.abs(arr))) > MAX_ENTRY:
        bad = tuple(int(k) for k in np.argwhere(np.abs(arr) > MAX_ENTRY)[0])
        raise ValidationError(
            f"{name}: entry {arr[bad]:.6g} at [{bad[0] + 1}][{bad[1] + 1}] exceeds {MAX_ENTRY:g} in magnitude; "
            "rescale the model (units of states, inputs or time)"
        )
    arr.setflags(write=False)
    return arr


def arrays_equal(a: Matrix | None, b: Matrix | None) -> bool:
    if a is None or b is None:
        return a is None and b is None
    return a.shape == b.shape and bool(np.array_equal(a, b))
