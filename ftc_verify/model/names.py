"""The names a user gave the plant's modes and signals, kept for the way back.

A system built from python-control (:meth:`ftc_verify.model.system.FTCSystem.from_statespace`)
knows its fault modes by the StateSpaces' names (``nominal``, ``faulty``) and its signals by
their labels (states ``pos``, ``vel``; disturbance ``gust``; performance output ``pos_err``).
:class:`SignalNames` keeps them, the closed loop carries them, and
:meth:`ftc_verify.analysis.closedloop.ClosedLoop.to_statespace` labels its frozen loops
with them. A system read from a TOML file has none: :meth:`SignalNames.default` gives
the package's own (``mode 1``, ``x[0]``, ``w[0]``, ``z[0]``, all indices of modes 1-based
as everywhere the tool prints them, signal indices 0-based as python-control's).
Names never enter a computation or an equality of systems.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass

__all__ = ["SignalNames", "mode_name"]

#: python-control's automatic system name (``sys[3]``): not a name the user gave.
_AUTOMATIC = re.compile(r"sys\[\d+\]")


def mode_name(name: str | None, k: int) -> str:
    """The name of fault mode ``k`` (1-based): the user's, or ``"mode k"`` when python-control
    made one up (``sys[N]``) or there is none."""
    return f"mode {k}" if not name or _AUTOMATIC.fullmatch(name) else name


@dataclass(frozen=True)
class SignalNames:
    """Names of the fault modes and of the plant's signals, in matrix order.

    Attributes
    ----------
    modes : tuple of str
        One per fault mode (rows of ``chain.alpha``).
    states : tuple of str
        The plant states ``x`` (rows of ``A``).
    inputs, disturbances : tuple of str
        The control inputs ``u`` (columns of ``B``) and disturbances ``w`` (columns of ``D``).
    performance, measured : tuple of str
        The performance outputs ``y`` (rows of ``C``) and the measured outputs ``y_m``
        (rows of ``Cy``; the performance outputs when the system has no ``Cy``).
    """

    modes: tuple[str, ...]
    states: tuple[str, ...]
    inputs: tuple[str, ...]
    disturbances: tuple[str, ...]
    performance: tuple[str, ...]
    measured: tuple[str, ...]

    @classmethod
    def default(cls, m: int, dims: Sequence[int], ny_measured: int) -> SignalNames:
        """The package's names for ``m`` modes of dimensions ``(n, nu, ny, nw)``.

        >>> SignalNames.default(2, (2, 1, 1, 1), 1).modes
        ('mode 1', 'mode 2')
        """
        n, nu, ny, nw = dims
        return cls(tuple(f"mode {k}" for k in range(1, m + 1)), tuple(f"x[{k}]" for k in range(n)),
                   tuple(f"u[{k}]" for k in range(nu)), tuple(f"w[{k}]" for k in range(nw)),
                   tuple(f"z[{k}]" for k in range(ny)), tuple(f"y_m[{k}]" for k in range(ny_measured)))
