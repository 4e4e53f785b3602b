r"""FTC system model: plant modes, the fault chain and the delayed-FDI joint chain.

The plant in true fault mode :math:`r_t = i` is

.. math::

    \dot x = (A_i + A1_i \Delta_1 A2_i) x + (B_i + B1_i \Delta_2 B2_i) u + D_i w,
    \qquad y = C_i x, \qquad y_m = C_{y,i} x,

with :math:`\|\Delta_1\|, \|\Delta_2\| \le 1` (reference paper, eqs. (1) and (13); the
output uses :math:`C` of the *true* mode throughout, see READING-NOTES). ``y`` is the
performance output whose energy is the attenuation measure; ``y_m`` is what an output-
feedback controller measures (``Cy``, default ``C``).

The pair :math:`\theta_t = (r_t, l_t)` of true mode and FDI indication is a Markov
chain on :math:`S \times S` (paper, Section II and the generator implied by Theorem 3.1):

* :math:`(i, i) \to (k, i)`, :math:`k \ne i`, at rate ``alpha[i, k]`` (a fault occurs,
  the FDI still shows the old mode);
* :math:`(i, j) \to (i, i)`, :math:`i \ne j`, at rate ``beta[j, i]`` (the FDI catches up;
  ``beta`` is indexed ``[fdi, true]``);
* nothing else (the paper's assumption 2).

The *named variant* ``fault_during_delay=True`` (not the paper's model) also lets the
fault process jump while the FDI lags: :math:`(i, j) \to (k, j)` at rate ``alpha[i, k]``.

Joint modes are numbered ``s = i * m + j`` (0-based true mode ``i``, FDI mode ``j``).
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import ValidationError

__all__ = [
    "GENERATOR_RTOL",
    "MAX_ENTRY",
    "Mode",
    "JointChain",
    "FTCSystem",
    "as_matrix",
]

#: Relative tolerance for "a generator row sums to zero": ``|sum| <= GENERATOR_RTOL * max(1, max|alpha|)``.
GENERATOR_RTOL = 1e-9

#: Largest accepted magnitude of a matrix entry. The analyses square the matrices (second
#: moments, Lyapunov products, Hamiltonians); beyond this, overflow and LAPACK failures
#: replace answers, so such a model is refused with a request to rescale its units.
MAX_ENTRY = 1e15

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


def _arrays_equal(a: Matrix | None, b: Matrix | None) -> bool:
    if a is None or b is None:
        return a is None and b is None
    return a.shape == b.shape and bool(np.array_equal(a, b))


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
class JointChain:
    """Fault generator ``alpha`` and FDI detection-rate bounds; the joint (true, FDI) chain.

    Parameters
    ----------
    alpha : (m, m) array
        Generator of the fault process (non-negative off-diagonal, rows sum to zero
        within :data:`GENERATOR_RTOL`).
    beta_min, beta_max : (m, m) arrays
        Bounds of the detection rates, indexed ``[fdi, true]``; the diagonal is ignored.
    fault_during_delay : bool
        Named variant in which the fault keeps jumping while the FDI lags (not the
        paper's model). Default ``False``: the paper's model.
    """

    alpha: Matrix
    beta_min: Matrix
    beta_max: Matrix
    fault_during_delay: bool = False

    def __post_init__(self) -> None:
        alpha = as_matrix(self.alpha, "chain.alpha")
        m = alpha.shape[0]
        if alpha.shape != (m, m):
            raise ValidationError(f"chain.alpha: expected a square matrix, got shape {alpha.shape}")
        if m < 2:
            raise ValidationError(f"chain.alpha: at least two modes are needed, got {m}")
        off = ~np.eye(m, dtype=bool)
        if np.any(alpha[off] < 0):
            i, k = (int(v) for v in np.argwhere((alpha < 0) & off)[0])
            raise ValidationError(
                f"chain.alpha[{i + 1}][{k + 1}]: off-diagonal rates must be >= 0, got {alpha[i, k]}"
            )
        tol = GENERATOR_RTOL * max(1.0, float(np.max(np.abs(alpha))))
        sums = alpha.sum(axis=1)
        if np.any(np.abs(sums) > tol):
            i = int(np.argmax(np.abs(sums)))
            raise ValidationError(
                f"chain.alpha row {i + 1}: rows of a generator must sum to zero "
                f"(tolerance {tol:.1e}), got sum {float(sums[i]):.6g} for row {alpha[i].tolist()}"
            )
        object.__setattr__(self, "alpha", alpha)
        for key in ("beta_min", "beta_max"):
            b = as_matrix(getattr(self, key), f"chain.{key}")
            if b.shape != (m, m):
                raise ValidationError(f"chain.{key}: expected shape {(m, m)} (as alpha), got {b.shape}")
            if np.any(b[off] < 0):
                j, i = (int(v) for v in np.argwhere((b < 0) & off)[0])
                raise ValidationError(f"chain.{key}[{j + 1}][{i + 1}]: rates must be >= 0, got {b[j, i]}")
            object.__setattr__(self, key, b)
        bad = (self.beta_min > self.beta_max) & off
        if np.any(bad):
            j, i = (int(v) for v in np.argwhere(bad)[0])
            raise ValidationError(
                f"chain.beta_min[{j + 1}][{i + 1}] = {self.beta_min[j, i]} exceeds "
                f"chain.beta_max[{j + 1}][{i + 1}] = {self.beta_max[j, i]}"
            )

    @property
    def m(self) -> int:
        """Number of fault modes."""
        return int(self.alpha.shape[0])

    @property
    def joint_modes(self) -> tuple[tuple[int, int], ...]:
        """Joint modes ``(true, fdi)`` in the order ``s = true * m + fdi``."""
        return tuple(itertools.product(range(self.m), repeat=2))

    @property
    def beta_pairs(self) -> tuple[tuple[int, int], ...]:
        """Index pairs ``(fdi, true)`` of the detection rates, ``fdi != true``."""
        return tuple((j, i) for j in range(self.m) for i in range(self.m) if i != j)

    def check_beta(self, beta: ArrayLike, name: str = "beta") -> Matrix:
        """Validate a detection-rate matrix ``beta[fdi, true]`` inside the bounds."""
        b = as_matrix(beta, name)
        m = self.m
        if b.shape != (m, m):
            raise ValidationError(f"{name}: expected shape {(m, m)}, got {b.shape}")
        slack = 1e-12 * max(1.0, float(np.max(self.beta_max)))
        for j, i in self.beta_pairs:
            if not self.beta_min[j, i] - slack <= b[j, i] <= self.beta_max[j, i] + slack:
                raise ValidationError(
                    f"{name}[{j + 1}][{i + 1}] = {b[j, i]} outside "
                    f"[{self.beta_min[j, i]}, {self.beta_max[j, i]}]"
                )
        return b

    def generator(self, beta: ArrayLike) -> Matrix:
        r"""Generator :math:`Q` of the joint chain for detection rates ``beta[fdi, true]``.

        ``Q[s, s']`` is the rate from ``s = (i, j)`` to ``s'``; rows sum to zero. This is
        the generator implied by Theorem 3.1: the coupling term of row ``(i, j)`` there,
        :math:`1_{i=j}\sum_k \alpha_{ik} P_{kj} + 1_{i\ne j}\beta_{ji}(P_{ii}-P_{ij})`,
        equals :math:`\sum_{s'} Q[s, s'] P_{s'}`.
        """
        b = self.check_beta(beta)
        m = self.m
        q = np.zeros((m * m, m * m))
        for i, j in self.joint_modes:
            s = i * m + j
            if i == j or self.fault_during_delay:
                for k in range(m):
                    if k != i:
                        q[s, k * m + j] += self.alpha[i, k]
            if i != j:
                q[s, i * m + i] += b[j, i]
            q[s, s] = -q[s].sum()
        return q

    def vertices(self) -> Iterator[Matrix]:
        """All vertices of the ``beta`` box (``2**len(beta_pairs)`` of them, degenerate
        intervals counted once)."""
        choices = [
            sorted({float(self.beta_min[j, i]), float(self.beta_max[j, i])})
            for j, i in self.beta_pairs
        ]
        for combo in itertools.product(*choices):
            b = np.zeros((self.m, self.m))
            for (j, i), v in zip(self.beta_pairs, combo):
                b[j, i] = v
            yield b

    def vertex_count(self) -> int:
        """Number of distinct vertices of the ``beta`` box."""
        return int(
            np.prod([1 + (self.beta_min[j, i] != self.beta_max[j, i]) for j, i in self.beta_pairs])
        )

    def midpoint(self) -> Matrix:
        """The centre of the ``beta`` box."""
        return 0.5 * (self.beta_min + self.beta_max)

    def row_beta_ends(self, i: int, j: int) -> tuple[float, ...]:
        """Distinct values of the one rate that enters row ``(i, j)`` of the generator.

        Row ``(i, j)``, ``i != j``, depends on ``beta[j, i]`` only, and affinely; so an
        inequality affine in that row holds on the whole box iff it holds at both ends.
        Diagonal rows do not depend on ``beta`` (returns ``(nan,)``).
        """
        if i == j:
            return (float("nan"),)
        return tuple(sorted({float(self.beta_min[j, i]), float(self.beta_max[j, i])}))

    def row_generator(self, i: int, j: int, beta_ji: float) -> Matrix:
        """Row ``s = (i, j)`` of the generator with ``beta[j, i] = beta_ji`` (other rates
        irrelevant to this row)."""
        b = self.midpoint()
        if i != j:
            b = b.copy()
            b[j, i] = beta_ji
        return self.generator(b)[i * self.m + j]

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, JointChain):
            return NotImplemented
        return self.fault_during_delay == other.fault_during_delay and all(
            _arrays_equal(getattr(self, k), getattr(other, k)) for k in ("alpha", "beta_min", "beta_max")
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
