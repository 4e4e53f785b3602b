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
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

from ..errors import ValidationError
from .chain import JointChain
from .names import SignalNames, mode_name
from .matrices import GENERATOR_RTOL, MAX_ENTRY, Matrix, arrays_equal as _arrays_equal, as_matrix

if TYPE_CHECKING:  # python-control is imported only where it is used (start-up time)
    import control

#: A signal of a ``control.StateSpace``: its label, a base name ``"u"`` standing for
#: ``"u[0]", "u[1]", ...``, or a 0-based index (python-control's convention).
Signal = str | int

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


_UNCERTAINTY_KEYS = ("A1", "A2", "B1", "B2")


def _signals(labels: Sequence[str], wanted: Signal | Sequence[Signal] | None, role: str, kind: str) -> list[int]:
    """0-based indices of the signals ``wanted`` (labels, base names or indices) among
    ``labels`` (mode 1's input or output labels), in the order given."""
    if isinstance(wanted, (str, int, np.integer)):
        items = [wanted]
    elif wanted is None or (isinstance(wanted, Sequence) and not isinstance(wanted, bytes)):
        items = list(wanted or ())
    else:
        raise ValidationError(f"{role}: expected {kind} labels or 0-based indices (one or a sequence), "
                              f"got {wanted!r:.80}")
    out: list[int] = []
    for item in items:
        if isinstance(item, (bool, np.bool_)) or not isinstance(item, (str, int, np.integer)):
            raise ValidationError(f"{role}: expected {kind} labels or 0-based indices, got {item!r}")
        if isinstance(item, str):
            found = ([labels.index(item)] if item in labels else
                     [k for k, lab in enumerate(labels) if lab.startswith(item + "[") and lab.endswith("]")])
            if not found:
                raise ValidationError(f"{role}: {item!r} is not an {kind} of mode 1 ({kind}s: {list(labels)})")
        else:
            if not 0 <= int(item) < len(labels):
                raise ValidationError(f"{role}: {kind} index {int(item)} out of range: mode 1 has "
                                      f"{len(labels)} {kind}s {list(labels)} (indices 0-based)")
            found = [int(item)]
        for k in found:
            if k in out:
                raise ValidationError(f"{role}: {kind} {labels[k]!r} named twice")
            out.append(k)
    if not out:
        raise ValidationError(f"{role}: no {kind} named (the FTC model needs at least one)")
    return out


def _split_inputs(labels: list[str], inputs: Signal | Sequence[Signal],
                  disturbances: Signal | Sequence[Signal]) -> tuple[list[int], list[int]]:
    """Column indices of ``u`` and ``w``: disjoint, and together every input."""
    u = _signals(labels, inputs, "inputs", "input")
    w = _signals(labels, disturbances, "disturbances", "input")
    both = [labels[c] for c in u if c in w]
    if both:
        raise ValidationError(f"inputs {both} named both as control inputs and as disturbances")
    unused = [lab for c, lab in enumerate(labels) if c not in u and c not in w]
    if unused:
        raise ValidationError(f"inputs {unused} of mode 1 are neither control inputs nor disturbances "
                              "(name each in inputs= or disturbances=)")
    return u, w


def _statespace_mode(k: int, sys: Any, ref: Any) -> None:
    """Check mode ``k`` (1-based): a continuous-time ``control.StateSpace`` with the
    states and signals of mode 1 (``ref``)."""
    import control

    if not isinstance(sys, control.StateSpace):
        hint = " (convert it with control.ss; its states are the model's x)" if isinstance(sys, control.LTI) else ""
        raise ValidationError(f"mode {k}: expected a control.StateSpace, got {type(sys).__name__}{hint}")
    if sys.isdtime(strict=True):
        raise ValidationError(f"mode {k}: {sys.name!r} is discrete-time (dt = {sys.dt}); the FTC model is "
                              "continuous-time (dt = 0)")
    if sys.nstates != ref.nstates:
        raise ValidationError(f"mode {k}: {sys.nstates} states differ from mode 1 ({ref.nstates})")
    for kind in ("input", "output"):
        mine, first = list(getattr(sys, f"{kind}_labels")), list(getattr(ref, f"{kind}_labels"))
        if mine != first:
            raise ValidationError(f"mode {k}: {kind}s {mine} differ from mode 1's {first} (every mode has "
                                  "the same signals, in the same order)")


def _uncertainty(value: Mapping[str, ArrayLike] | Sequence[Mapping[str, ArrayLike]] | None,
                 m: int) -> list[dict[str, ArrayLike]]:
    """One mapping of uncertainty weights per mode (one mapping given: every mode)."""
    if value is None:
        return [{} for _ in range(m)]
    per_mode = list(value) if not isinstance(value, Mapping) else [value] * m
    if len(per_mode) != m:
        raise ValidationError(f"uncertainty: {len(per_mode)} mappings given for {m} modes")
    for k, weights in enumerate(per_mode, start=1):
        if not isinstance(weights, Mapping):
            raise ValidationError(f"uncertainty: mode {k}: expected a mapping with keys {list(_UNCERTAINTY_KEYS)}, "
                                  f"got {type(weights).__name__}")
        unknown = set(weights) - set(_UNCERTAINTY_KEYS)
        if unknown:
            raise ValidationError(f"uncertainty: mode {k}: unknown keys {sorted(unknown)} "
                                  f"(allowed: {list(_UNCERTAINTY_KEYS)})")
    return [dict(w) for w in per_mode]


def _from_statespace(k: int, sys: Any, cols: Sequence[list[int]], rows: Sequence[list[int] | None],
                     weights: Mapping[str, ArrayLike]) -> Mode:
    """The :class:`Mode` of ``sys`` (mode ``k``, 1-based) from the selected input columns
    ``(u, w)`` and output rows ``(y, y_m or None)``; refuses a feedthrough among them."""
    mats = {key: np.asarray(getattr(sys, key)) for key in ("A", "B", "C", "D")}
    for key, value in mats.items():
        if np.iscomplexobj(value) and np.any(value.imag != 0):
            r, c = (int(i) for i in np.argwhere(value.imag != 0)[0])
            raise ValidationError(f"mode {k}: {key}[{r + 1}][{c + 1}] = {complex(value[r, c])!r} of {sys.name!r} "
                                  "is complex; the FTC model is real")
    A, B, C, D = (np.real(mats[key]).astype(float) for key in ("A", "B", "C", "D"))
    used_out = sorted({r for sel in rows if sel is not None for r in sel})
    used_in = sorted({c for sel in cols for c in sel})
    for r in used_out:
        for c in used_in:
            if D[r, c] != 0:
                raise ValidationError(
                    f"mode {k}: nonzero feedthrough D[{sys.output_labels[r]!r}, {sys.input_labels[c]!r}] = "
                    f"{float(D[r, c])!r} of {sys.name!r} (the FTC model has none: y = C x, y_m = Cy x)")
    u, w = cols
    y, ym = rows
    return Mode(A, B[:, u], C[y, :], B[:, w], Cy=None if ym is None else C[ym, :], label=f"mode {k}",
                **weights)  # type: ignore[arg-type]


@dataclass(frozen=True, eq=False)
class FTCSystem:
    """An FTC plant: one :class:`Mode` per fault mode and the :class:`JointChain`.

    All modes share ``n, nu, ny, nw``; there are as many modes as rows of ``alpha``.
    ``names`` are the user's names of the modes and signals (:class:`SignalNames`; set by
    :meth:`from_statespace`, ``None`` for a system file): they never enter a computation
    or the equality of two systems; :attr:`signal_names` gives them or the defaults.
    """

    name: str
    modes: tuple[Mode, ...]
    chain: JointChain
    #: The numbers of the system file as written (float read -> decimal texts), set by
    #: :func:`~ftc_verify.model.files.load_system`; ``None`` when the floats are the data.
    literals: Mapping[float, tuple[str, ...]] | None = field(default=None, compare=False, repr=False)
    names: SignalNames | None = None

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
        if self.names is not None:
            want = SignalNames.default(len(modes), dims0, modes[0].ny_measured)
            for key in ("modes", "states", "inputs", "disturbances", "performance", "measured"):
                got = getattr(self.names, key)
                if len(got) != len(getattr(want, key)):
                    raise ValidationError(f"names.{key}: {len(got)} names {list(got)} for "
                                          f"{len(getattr(want, key))} {key}")

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
    ) -> FTCSystem:
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

    @classmethod
    def from_statespace(
        cls,
        *,
        modes: Sequence[control.StateSpace],
        chain: JointChain,
        inputs: Signal | Sequence[Signal],
        disturbances: Signal | Sequence[Signal],
        performance: Signal | Sequence[Signal],
        measured: Signal | Sequence[Signal] | None = None,
        uncertainty: Mapping[str, ArrayLike] | Sequence[Mapping[str, ArrayLike]] | None = None,
        name: str = "python-control",
    ) -> FTCSystem:
        r"""Build from one continuous-time ``control.StateSpace`` per fault mode.

        Mode :math:`i` is :math:`\dot x = A_i x + \bar B_i v`, :math:`o = \bar C_i x + \bar D_i v`
        with inputs :math:`v` and outputs :math:`o`. The inputs are split, by name or index,
        into the control inputs :math:`u` (``inputs``) and the disturbances :math:`w`
        (``disturbances``); the outputs named ``performance`` are :math:`y` and those
        named ``measured`` are :math:`y_m`. With :math:`P_u, P_w` selecting columns and
        :math:`S_y, S_m` selecting rows,

        .. math::

            B_i = \bar B_i P_u, \quad D_i = \bar B_i P_w, \quad
            C_i = S_y \bar C_i, \quad C_{y,i} = S_m \bar C_i

        give the plant of the module docstring (``D`` is this project's disturbance input
        matrix, not python-control's feedthrough). The FTC model has no
        feedthrough, so :math:`S_o \bar D_i P_v = 0` is required for every selected
        output and input. python-control is imported here, not with :mod:`ftc_verify.model`;
        the way back is :meth:`ftc_verify.analysis.closedloop.ClosedLoop.to_statespace`.

        Parameters
        ----------
        modes : sequence of control.StateSpace
            One per fault mode, in order (as many as rows of ``chain.alpha``), all
            continuous-time (``dt = 0``; ``dt = None``, python-control's "unspecified",
            is taken as continuous), with the same number of states and the same input
            and output labels in the same order.
        chain : JointChain
            The fault and FDI chain.
        inputs, disturbances : label, index or sequence of them
            The control inputs :math:`u` and the disturbances :math:`w`, in the order of
            the columns of ``B`` and ``D``. A label is one of the StateSpace's
            ``input_labels``; a base name ``"u"`` stands for ``"u[0]", "u[1]", ...``
            (python-control's vector signals); an integer is a 0-based index. Every input
            is one or the other (an input left out would silently be held at zero).
        performance : label, index or sequence of them
            The performance outputs :math:`y` (rows of ``C``), whose energy is the
            attenuation measure.
        measured : label, index, sequence of them, or None
            The measured outputs :math:`y_m` (rows of ``Cy``), read by an output-feedback
            controller; may overlap ``performance``. ``None`` (default): no ``Cy``, the
            controller measures :math:`y`. Outputs named in neither are ignored.
        uncertainty : mapping or sequence of mappings, optional
            Norm-bounded uncertainty weights ``A1, A2, B1, B2`` (in pairs, as in a system
            file): one mapping for every mode or one per mode.
        name : str
            The system's name.

        Raises
        ------
        ValidationError
            Naming the mode (1-based) and the offending signal or value: not a
            StateSpace, discrete-time (with its ``dt``), different states or signals
            from mode 1, an unknown label or out-of-range index, a signal named twice
            or both as control input and disturbance, an input named in neither, a
            nonzero feedthrough (with its output and input), a complex entry, or any check of
            :class:`Mode` and :class:`FTCSystem`.
        """
        import control

        if isinstance(modes, control.LTI) or not isinstance(modes, Sequence) or not modes:
            raise ValidationError(f"modes: expected a non-empty sequence of control.StateSpace, got {modes!r:.80}")
        if not isinstance(chain, JointChain):
            raise ValidationError(f"chain: expected a JointChain, got {type(chain).__name__}")
        for k, sys in enumerate(modes, start=1):
            _statespace_mode(k, sys, modes[0] if k > 1 else sys)
        u, w = _split_inputs(list(modes[0].input_labels), inputs, disturbances)
        outs = list(modes[0].output_labels)
        y = _signals(outs, performance, "performance", "output")
        ym = None if measured is None else _signals(outs, measured, "measured", "output")
        weights = _uncertainty(uncertainty, len(modes))
        built = tuple(_from_statespace(k, sys, (u, w), (y, ym), weights[k - 1])
                      for k, sys in enumerate(modes, start=1))
        ins = list(modes[0].input_labels)
        names = SignalNames(tuple(mode_name(sys.name, k) for k, sys in enumerate(modes, start=1)),
                            tuple(modes[0].state_labels), tuple(ins[c] for c in u), tuple(ins[c] for c in w),
                            tuple(outs[r] for r in y), tuple(outs[r] for r in (y if ym is None else ym)))
        return cls(name=name, modes=built, chain=chain, names=names)

    @property
    def m(self) -> int:
        """Number of fault modes."""
        return self.chain.m

    @property
    def signal_names(self) -> SignalNames:
        """``names``, or the defaults of :meth:`SignalNames.default` when there are none."""
        return self.names or SignalNames.default(self.m, self.dims, self.ny_measured)

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

    def nominal(self) -> FTCSystem:
        """The same system without uncertainty weights."""
        modes = tuple(Mode(md.A, md.B, md.C, md.D, Cy=md.Cy, label=md.label) for md in self.modes)
        return FTCSystem(self.name, modes, self.chain, names=self.names)

    def with_measured_output(self, Cy: ArrayLike | Sequence[ArrayLike]) -> FTCSystem:
        """The same plant measured through ``y_m = Cy x``: one matrix for every mode, or one
        per mode (checked like a system file's ``Cy``)."""
        cys: list[Any] = [Cy] * self.m
        if isinstance(Cy, (list, tuple)) and len(Cy) > 0 and np.ndim(Cy[0]) == 2:
            cys = list(Cy)
        if len(cys) != self.m:
            raise ValidationError(f"Cy: {len(cys)} matrices given for {self.m} modes")
        modes = tuple(Mode(md.A, md.B, md.C, md.D, md.A1, md.A2, md.B1, md.B2, Cy=c, label=md.label)
                      for md, c in zip(self.modes, cys))
        names = None if self.names is None else replace(  # new measured outputs: the default names
            self.names, measured=tuple(f"y_m[{k}]" for k in range(modes[0].ny_measured)))
        return FTCSystem(self.name, modes, self.chain, names=names)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, FTCSystem):
            return NotImplemented
        return self.name == other.name and self.modes == other.modes and self.chain == other.chain

    __hash__ = None  # type: ignore[assignment]
