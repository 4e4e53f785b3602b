r"""FTC system model: plant modes, the fault chain and the delayed-FDI joint chain.

The plant in true fault mode :math:`r_t = i` is

.. math::

    \dot x = (A_i + A1_i \Delta_1 A2_i) x + (B_i + B1_i \Delta_2 B2_i) u + D_i w,
    \qquad y = C_i x, \qquad y_m = C_{y,i} x,

with :math:`\|\Delta_1\|, \|\Delta_2\| \le 1` (reference paper, eqs. (1) and (13); the
output uses :math:`C` of the *true* mode throughout, see READING-NOTES). ``y`` is the
performance output whose energy is the attenuation measure; ``y_m`` is what an output-
feedback controller measures (``Cy``, default ``C``).

The true mode, the FDI indication and the phase of a detection under way form the joint
Markov chain of :mod:`ftc_verify.model.chain` (:class:`JointChain`): with the paper's FDI
model its states are the pairs ``(true, fdi)``, numbered ``s = true * m + fdi``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from ..errors import ValidationError
from .chain import JointChain
from .matrices import GENERATOR_RTOL, MAX_ENTRY, Matrix, arrays_equal as _arrays_equal, as_matrix

__all__ = [
    "GENERATOR_RTOL",
    "MAX_ENTRY",
    "Mode",
    "JointChain",
    "FTCSystem",
    "as_matrix",
]

@dataclass(frozen=True, eq=False)
class Mode:
    """One fault mode of the plant: nominal ``A, B, C, D``, the measured output ``Cy``
    (optional, default ``C``) and optional uncertainty weights.

    ``A1, A2`` (both or neither) give :math:`A = A + A1 \\Delta_1 A2`; ``B1, B2`` (both or
    neither) give :math:`B = B + B1 \\Delta_2 B2`. ``label`` is used in error messages.
    """

    A: Matrix
    B: Matrix
    C: Matrix
    D: Matrix
    A1: Matrix | None = None
    A2: Matrix | None = None
    B1: Matrix | None = None
    B2: Matrix | None = None
    Cy: Matrix | None = None
    label: str = field(default="mode", compare=False)

    def __post_init__(self) -> None:
        for key in ("A", "B", "C", "D"):
            object.__setattr__(self, key, as_matrix(getattr(self, key), f"{self.label}.{key}"))
        for key in ("A1", "A2", "B1", "B2", "Cy"):
            val = getattr(self, key)
            if val is not None:
                object.__setattr__(self, key, as_matrix(val, f"{self.label}.{key}"))
        n = self.A.shape[0]
        self._check(self.A.shape == (n, n), "A", self.A, f"square, got {self.A.shape}")
        self._check(self.B.shape[0] == n, "B", self.B, f"{n} rows (as A), got {self.B.shape}")
        self._check(self.C.shape[1] == n, "C", self.C, f"{n} columns (as A), got {self.C.shape}")
        self._check(self.D.shape[0] == n, "D", self.D, f"{n} rows (as A), got {self.D.shape}")
        if self.Cy is not None:
            self._check(self.Cy.shape[1] == n, "Cy", self.Cy, f"{n} columns (as A), got {self.Cy.shape}")
        for left, right, width in (("A1", "A2", n), ("B1", "B2", self.B.shape[1])):
            lv, rv = getattr(self, left), getattr(self, right)
            if (lv is None) != (rv is None):
                missing = right if rv is None else left
                raise ValidationError(
                    f"{self.label}.{missing}: missing while {left if rv is None else right} is given "
                    "(uncertainty weights come in pairs)"
                )
            if lv is None:
                continue
            self._check(lv.shape[0] == n, left, lv, f"{n} rows, got {lv.shape}")
            self._check(rv.shape[1] == width, right, rv, f"{width} columns, got {rv.shape}")

    def _check(self, ok: bool, key: str, value: Matrix, expected: str) -> None:
        if not ok:
            raise ValidationError(f"{self.label}.{key}: expected {expected}: {value.tolist()}")

    @property
    def n(self) -> int:
        """State dimension."""
        return int(self.A.shape[0])

    @property
    def dims(self) -> tuple[int, int, int, int]:
        """``(n, nu, ny, nw)``: states, control inputs, outputs, disturbances."""
        return self.n, int(self.B.shape[1]), int(self.C.shape[0]), int(self.D.shape[1])

    @property
    def measured(self) -> Matrix:
        """The measured-output matrix: ``Cy`` when given, else ``C``."""
        return self.C if self.Cy is None else self.Cy

    @property
    def ny_measured(self) -> int:
        """Number of measured outputs (rows of :attr:`measured`)."""
        return int(self.measured.shape[0])

    @property
    def uncertain(self) -> bool:
        """True when any uncertainty channel is present."""
        return self.A1 is not None or self.B1 is not None

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Mode):
            return NotImplemented
        return all(
            _arrays_equal(getattr(self, k), getattr(other, k))
            for k in ("A", "B", "C", "D", "A1", "A2", "B1", "B2", "Cy")
        )

    __hash__ = None  # type: ignore[assignment]


@dataclass(frozen=True, eq=False)
class FTCSystem:
    """An FTC plant: one :class:`Mode` per fault mode and the :class:`JointChain`.

    All modes share ``n, nu, ny, nw``; there are as many modes as rows of ``alpha``.
    """

    name: str
    modes: tuple[Mode, ...]
    chain: JointChain

    def __post_init__(self) -> None:
        modes = tuple(self.modes)
        object.__setattr__(self, "modes", modes)
        if len(modes) != self.chain.m:
            raise ValidationError(
                f"mode: {len(modes)} mode tables given but chain.alpha has {self.chain.m} rows"
            )
        dims0 = modes[0].dims
        names = ("n (rows of A)", "nu (columns of B)", "ny (rows of C)", "nw (columns of D)")
        for k, mode in enumerate(modes[1:], start=2):
            for name, a, b in zip(names, dims0, mode.dims):
                if a != b:
                    raise ValidationError(f"mode {k}: {name} = {b} differs from mode 1 ({a})")
            if mode.ny_measured != modes[0].ny_measured:
                raise ValidationError(
                    f"mode {k}: {mode.ny_measured} measured outputs (rows of Cy) differ from "
                    f"mode 1 ({modes[0].ny_measured})"
                )

    @classmethod
    def from_arrays(
        cls,
        *,
        name: str,
        modes: Sequence[Mapping[str, ArrayLike]],
        alpha: ArrayLike,
        beta_min: ArrayLike,
        beta_max: ArrayLike,
        fault_during_delay: bool = False,
    ) -> "FTCSystem":
        """Build from plain arrays; ``modes`` are mappings with keys ``A, B, C, D`` and
        optionally ``Cy, A1, A2, B1, B2``."""
        allowed = {"A", "B", "C", "D", "A1", "A2", "B1", "B2", "Cy"}
        built = []
        for k, md in enumerate(modes, start=1):
            unknown = set(md) - allowed
            if unknown:
                raise ValidationError(f"mode {k}: unknown keys {sorted(unknown)}")
            missing = {"A", "B", "C", "D"} - set(md)
            if missing:
                raise ValidationError(f"mode {k}: missing keys {sorted(missing)}")
            built.append(Mode(**{key: md[key] for key in md}, label=f"mode {k}"))  # type: ignore[arg-type]
        chain = JointChain(alpha, beta_min, beta_max, fault_during_delay)  # type: ignore[arg-type]
        return cls(name=name, modes=tuple(built), chain=chain)

    @property
    def m(self) -> int:
        """Number of fault modes."""
        return self.chain.m

    @property
    def dims(self) -> tuple[int, int, int, int]:
        """``(n, nu, ny, nw)``."""
        return self.modes[0].dims

    @property
    def ny_measured(self) -> int:
        """Number of measured outputs ``y_m`` (rows of ``Cy``, default ``C``)."""
        return self.modes[0].ny_measured

    @property
    def has_measured_output(self) -> bool:
        """True when some mode gives ``Cy`` (measurement distinct from the performance output)."""
        return any(md.Cy is not None for md in self.modes)

    @property
    def uncertain(self) -> bool:
        """True when some mode has an uncertainty channel."""
        return any(md.uncertain for md in self.modes)

    def nominal(self) -> "FTCSystem":
        """The same system without uncertainty weights."""
        modes = tuple(Mode(md.A, md.B, md.C, md.D, Cy=md.Cy, label=md.label) for md in self.modes)
        return FTCSystem(self.name, modes, self.chain)

    def with_measured_output(self, Cy: ArrayLike | Sequence[ArrayLike]) -> "FTCSystem":
        """The same plant measured through ``y_m = Cy x``: one matrix for every mode, or one
        per mode (checked like a system file's ``Cy``)."""
        per_mode = isinstance(Cy, (list, tuple)) and len(Cy) > 0 and np.ndim(Cy[0]) == 2
        cys = list(Cy) if per_mode else [Cy] * self.m  # type: ignore[arg-type]
        if len(cys) != self.m:
            raise ValidationError(f"Cy: {len(cys)} matrices given for {self.m} modes")
        modes = tuple(Mode(md.A, md.B, md.C, md.D, md.A1, md.A2, md.B1, md.B2, Cy=c, label=md.label)
                      for md, c in zip(self.modes, cys))
        return FTCSystem(self.name, modes, self.chain)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, FTCSystem):
            return NotImplemented
        return self.name == other.name and self.modes == other.modes and self.chain == other.chain

    __hash__ = None  # type: ignore[assignment]
