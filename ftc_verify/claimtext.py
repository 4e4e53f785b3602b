r"""Numbers that carry a claim, printed so that the printed number still carries it.

A certified gamma is an *upper* bound of the gain: printed to 6 significant digits by
rounding to nearest it can come out below the number that was proved (``0.4980004``
as ``0.498``), and the line would claim a gain bound nobody proved. So every proved
bound is printed rounded *outward*: an upper bound (a certified gamma, a proved-unstable
period) rounded up, a lower bound (a proved lower bound of the gain, a proved-stable
period ``h_max``) rounded down. The rounding is done on the exact binary value of the
float (:class:`decimal.Decimal`), so the printed decimal is on the safe side of the
float itself, not of a second rounding of it. JSON keeps the floats as computed.

>>> upper_text(0.49800041)
'0.498001'
>>> lower_text(0.49800049)
'0.498'
>>> upper_text(2.0)
'2'
>>> upper_text(None, 4)
'-'
"""

from __future__ import annotations

from decimal import ROUND_CEILING, ROUND_FLOOR, Decimal

__all__ = ["upper_text", "lower_text"]


def _outward(x: float | None, digits: int, up: bool, missing: str) -> str:
    if x is None:
        return missing
    exact = Decimal(x)
    if not exact.is_finite() or exact == 0:
        return f"{x:.{digits}g}"
    q = exact.quantize(Decimal(1).scaleb(exact.adjusted() - (digits - 1)),
                       rounding=ROUND_CEILING if up else ROUND_FLOOR)
    # q has `digits` significant digits (one more when rounding carried into a new
    # decade, 9.999995 -> 10.0000); the nearest float prints back as q under `.{digits}g`.
    return f"{float(q):.{digits}g}"


def upper_text(x: float | None, digits: int = 6, *, missing: str = "-") -> str:
    """``x`` to ``digits`` significant digits, rounded up: for a proved upper bound (a
    certified gamma, a proved-unstable period), never printed below the number proved.

    Parameters
    ----------
    x : float or None
        The proved bound (infinite or zero values are printed as they are; ``None``, no
        bound, as ``missing``).
    digits : int
        Significant digits (default 6, as every other number of the reports).
    missing : str
        The text for ``x = None`` (default ``-``, a table's empty cell).

    Returns
    -------
    str
        The smallest ``digits``-digit decimal not below ``x`` (``missing`` for ``None``).
    """
    return _outward(x, digits, True, missing)


def lower_text(x: float | None, digits: int = 6, *, missing: str = "-") -> str:
    """``x`` to ``digits`` significant digits, rounded down: for a proved lower bound (a
    proved lower bound of the gain, a proved-stable period ``h_max``), never printed
    above the number proved.

    Parameters
    ----------
    x : float or None
        The proved bound (infinite or zero values are printed as they are; ``None``, no
        bound, as ``missing``).
    digits : int
        Significant digits (default 6).
    missing : str
        The text for ``x = None`` (default ``-``).

    Returns
    -------
    str
        The largest ``digits``-digit decimal not above ``x`` (``missing`` for ``None``).
    """
    return _outward(x, digits, False, missing)
