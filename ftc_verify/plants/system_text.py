"""The ``resources/system.txt`` file of the ``LinearJumpPlant`` FMU and the FMU's dimensions.

This module implements the text format the FMU's C reader (``ljp_system_read`` in
``fmus/LinearJumpPlant/model.c``) reads at instantiation: :func:`system_text` writes it for
an :class:`~ftc_verify.model.FTCSystem`, :func:`parse_system_text` reads it back with the
C reader's rules, and :func:`fmu_dims` gives the ten dimensions (:class:`FMUDims`) that fix
the FMU's variables. The format is documented in ``fmus/README.md``; version
:data:`FORMAT_VERSION` must equal ``LJP_FORMAT_VERSION`` in ``model.h``.

Format version 2 added the measured output ``ym = Cy x``: the dimension ``nym`` (after
``p2``) and a matrix ``Cy`` (``nym x n``) after ``D`` in every mode (``C`` when the mode
gives no ``Cy``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .. import __version__
from ..errors import FMUError, ValidationError
from ..model.system import FTCSystem

__all__ = [
    "MODEL_IDENTIFIER",
    "FORMAT_VERSION",
    "FMUDims",
    "fmu_dims",
    "system_text",
    "parse_system_text",
]

#: Model identifier: name of the shared library, of the C sources folder, and the magic
#: word of the system file.
MODEL_IDENTIFIER = "LinearJumpPlant"
#: Version of the ``resources/system.txt`` format (must equal LJP_FORMAT_VERSION in model.h).
FORMAT_VERSION = 2


@dataclass(frozen=True)
class FMUDims:
    """Dimensions that fix the FMU's variables: ``Delta1`` is ``q1 x p1`` and ``Delta2``
    is ``q2 x p2`` (0 when the channel is absent in every mode); ``nym`` measured outputs
    ``ym = Cy x`` (None: ``ny``, the default ``Cy = C``)."""

    n: int
    nu: int
    ny: int
    nw: int
    m: int
    q1: int = 0
    p1: int = 0
    q2: int = 0
    p2: int = 0
    nym: int | None = None

    def __post_init__(self) -> None:
        if self.nym is None:
            object.__setattr__(self, "nym", self.ny)

    def as_tuple(self) -> tuple[int, ...]:
        """The ten dimensions in the order of the system file (``DIM_NAMES``)."""
        return (self.n, self.nu, self.ny, self.nw, self.m, self.q1, self.p1, self.q2, self.p2,
                int(self.nym))  # type: ignore[arg-type]


#: The dimension keywords of the system file, in order.
DIM_NAMES = ("n", "nu", "ny", "nw", "m", "q1", "p1", "q2", "p2", "nym")


def _channel_shape(system: FTCSystem, left: str, right: str) -> tuple[int, int]:
    shapes = {}
    for k, md in enumerate(system.modes, start=1):
        lv, rv = getattr(md, left), getattr(md, right)
        if lv is not None:
            shapes[k] = (int(lv.shape[1]), int(rv.shape[0]))
    if not shapes:
        return 0, 0
    first_mode, first = next(iter(shapes.items()))
    for k, shp in shapes.items():
        if shp != first:
            delta = "Delta1" if left == "A1" else "Delta2"
            raise ValidationError(
                f"{system.name}: mode {k}: {left} ({shp[0]} columns) / {right} ({shp[1]} rows) "
                f"imply a {shp[0]} x {shp[1]} {delta}, but mode {first_mode} implies "
                f"{first[0]} x {first[1]}; the FMU has one {delta} input shared by all modes"
            )
    return first


def fmu_dims(system: FTCSystem) -> FMUDims:
    """The FMU dimensions of ``system``; raises :class:`~ftc_verify.errors.ValidationError`
    when the modes' uncertainty weights imply different ``Delta`` shapes."""
    n, nu, ny, nw = system.dims
    q1, p1 = _channel_shape(system, "A1", "A2")
    q2, p2 = _channel_shape(system, "B1", "B2")
    return FMUDims(n, nu, ny, nw, system.m, q1, p1, q2, p2, system.ny_measured)


def _fmt(v: float) -> str:
    return repr(float(v))  # shortest round-trip representation; C's strtod reads it exactly


def _mode_shapes(d: FMUDims) -> dict[str, tuple[int, int]]:
    """The matrices of one mode, in file order, with their shapes."""
    shapes = {"A": (d.n, d.n), "B": (d.n, d.nu), "C": (d.ny, d.n), "D": (d.n, d.nw),
              "Cy": (int(d.nym), d.n)}  # type: ignore[arg-type]
    if d.q1:
        shapes.update(A1=(d.n, d.q1), A2=(d.p1, d.n))
    if d.q2:
        shapes.update(B1=(d.n, d.q2), B2=(d.p2, d.nu))
    return shapes


def system_text(system: FTCSystem, guid: str | None = None) -> str:
    """The ``resources/system.txt`` of ``system`` (format in ``fmus/README.md``).

    Modes without an uncertainty channel that other modes have get zero weights; every
    mode gets ``Cy`` (its measured-output matrix, ``C`` when the mode gives none).
    """
    d = fmu_dims(system)
    name = " ".join(str(system.name).split())
    lines = [
        f"# {MODEL_IDENTIFIER} system file (format {FORMAT_VERSION}), written by "
        f"ftc-verify {__version__}",
        f"# system: {name}",
        f"{MODEL_IDENTIFIER} {FORMAT_VERSION}",
    ]
    if guid is not None:
        if not guid or any(ch.isspace() for ch in guid):
            raise ValueError(f"guid must be a non-empty word, got {guid!r}")
        lines.append(f"guid {guid}")
    lines += [f"{key} {val}" for key, val in zip(DIM_NAMES, d.as_tuple())]
    for k, md in enumerate(system.modes, start=1):
        lines.append(f"mode {k}")
        for key, (rows, cols) in _mode_shapes(d).items():
            value = md.measured if key == "Cy" else getattr(md, key)
            arr = np.zeros((rows, cols)) if value is None else np.asarray(value, dtype=float)
            if arr.shape != (rows, cols):
                raise ValidationError(f"{system.name}: mode {k}: {key} is {arr.shape}, expected {(rows, cols)}")
            lines.append(f"{key} {rows} {cols}")
            lines.extend("  " + " ".join(_fmt(v) for v in row) for row in arr)
    lines.append("end")
    return "\n".join(lines) + "\n"


class _Tokens:
    """The whitespace-separated tokens of a system file, with their line numbers."""

    def __init__(self, text: str, source: str) -> None:
        self.source = source
        self.items: list[tuple[str, int]] = []
        for lineno, line in enumerate(text.splitlines(), start=1):
            self.items.extend((tok, lineno) for tok in line.split("#", 1)[0].split())
        self.pos = 0

    def peek(self) -> str | None:
        return self.items[self.pos][0] if self.pos < len(self.items) else None

    def next(self, what: str) -> tuple[str, int]:
        if self.pos >= len(self.items):
            raise FMUError(f"{self.source}: unexpected end of file, expected {what}")
        self.pos += 1
        return self.items[self.pos - 1]

    def word(self, expected: str) -> None:
        tok, line = self.next(f"'{expected}'")
        if tok != expected:
            raise FMUError(f"{self.source}:{line}: expected '{expected}', got '{tok}'")

    def integer(self, what: str) -> int:
        tok, line = self.next(what)
        try:
            return int(tok)
        except ValueError:
            raise FMUError(f"{self.source}:{line}: {what}: expected an integer, got '{tok}'") from None

    def matrix(self, key: str, k: int, rows: int, cols: int) -> np.ndarray:
        self.word(key)
        r, c = self.integer(f"{key} rows"), self.integer(f"{key} columns")
        if (r, c) != (rows, cols):
            raise FMUError(f"{self.source}: mode {k}: {key} is {r} x {c}, expected {rows} x {cols}")
        nums = []
        for _ in range(rows * cols):
            tok, line = self.next(f"an entry of {key}")
            try:
                nums.append(float(tok))
            except ValueError:
                raise FMUError(f"{self.source}:{line}: mode {k}: {key}: not a number: '{tok}'") from None
        return np.array(nums, dtype=float).reshape(rows, cols)


def parse_system_text(text: str, source: str = "system.txt") -> dict[str, Any]:
    """Read a system file written by :func:`system_text` (the C reader's rules, in Python).

    Returns ``{"guid": str | None, "dims": FMUDims, "modes": [ {key: ndarray} ]}``; raises
    :class:`FMUError` naming ``source`` and the line on malformed input.
    """
    toks = _Tokens(text, source)
    toks.word(MODEL_IDENTIFIER)
    version = toks.integer("format version")
    if version != FORMAT_VERSION:
        raise FMUError(f"{source}: format version {version} is not supported (this reader reads {FORMAT_VERSION})")
    guid = None
    if toks.peek() == "guid":
        toks.pos += 1
        guid = toks.next("the guid")[0]
    values = []
    for key in DIM_NAMES:
        toks.word(key)
        values.append(toks.integer(key))
    dims = FMUDims(*values)
    modes = []
    for k in range(1, dims.m + 1):
        toks.word("mode")
        if toks.integer("mode number") != k:
            raise FMUError(f"{source}: modes must be listed in order 1..{dims.m}")
        modes.append({key: toks.matrix(key, k, rows, cols) for key, (rows, cols) in _mode_shapes(dims).items()})
    toks.word("end")
    if toks.pos != len(toks.items):
        tok, line = toks.items[toks.pos]
        raise FMUError(f"{source}:{line}: unexpected text after 'end': '{tok}'")
    return {"guid": guid, "dims": dims, "modes": modes}
