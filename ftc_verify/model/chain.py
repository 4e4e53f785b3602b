r"""The joint (true mode, FDI indication, detection phase) Markov chain and its uncertain rates.

The fault process is a Markov chain on the modes :math:`\{0, \dots, m-1\}` with generator
``alpha``. The FDI unit shows a mode :math:`l_t` that lags the true one :math:`r_t`. The
joint state is :math:`(r_t, l_t, p_t)`, where the phase :math:`p_t` counts the stages of a
detection under way; the controller sees :math:`l_t` only.

**Transitions** (0-based; ``k = delay_phases``; ``beta`` indexed ``[fdi, true]``,
``false_alarm`` indexed ``[true, reported]``):

* :math:`(i, i) \to (k', i, 0)`, :math:`k' \ne i`, at rate ``alpha[i, k']``: a fault, the
  FDI still shows the old mode;
* :math:`(i, i) \to (i, j, 0)`, :math:`j \ne i`, at rate ``false_alarm[i, j]``: a false
  alarm, the FDI reports ``j`` while the plant is in ``i``;
* :math:`(i, j, p) \to (i, j, p + 1)` for :math:`p < k - 1`, and
  :math:`(i, j, k - 1) \to (i, i)`, at rate :math:`k\,\beta_{ji}`: the detection advances
  through ``k`` exponential phases, so the delay (or the time to withdraw a false alarm)
  is Erlang-``k`` with mean :math:`1/\beta_{ji}` and variance :math:`1/(k \beta_{ji}^2)`;
  ``k = 1`` is the paper's exponential delay, ``k \to \infty`` a deterministic one;
* with ``fault_during_delay`` (a named variant, not the paper's model) also
  :math:`(i, j, p) \to (k', j, 0)` at rate ``alpha[i, k']``: a new fault restarts the
  detection (and lands on the matched state :math:`(j, j)` when :math:`k' = j`).

A false alarm lands on the same states as an undetected fault from ``j`` to ``i`` (true
``i``, FDI ``j``) and is withdrawn the same way; a ``beta`` of 0 is a **missed
detection**: the FDI never catches up with that fault at that vertex, and the state
:math:`(i, j)` keeps the mismatched loop for good.

**States** are numbered in the lexicographic order of ``(true, fdi, phase)``, the matched
pairs :math:`(i, i)` with one phase: :math:`m + m(m-1)k` states. With ``k = 1`` this is
the paper's numbering ``s = true * m + fdi`` and, without false alarms, the generator is
the paper's (the one implied by Theorem 3.1) entry for entry.

**Uncertain rates.** ``beta[j, i]`` lies in ``[beta_min, beta_max]`` and, when given,
``false_alarm[i, j]`` in ``[false_alarm_min, false_alarm_max]``. A point of that box is a
*rate array*: ``beta`` itself, shape ``(m, m)``, or with false alarms the stack
``[beta, false_alarm]``, shape ``(2, m, m)`` (:attr:`JointChain.rate_shape`). The
generator is affine in every rate, and each row depends on few of them: a detection row
on one ``beta``, a matched row on the false-alarm rates out of its mode; so an
inequality affine in one row holds on the whole box iff it holds at the vertices of
that row's rates (:meth:`JointChain.row_rate_points`).
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from ..errors import ValidationError
from .matrices import GENERATOR_RTOL, Matrix, arrays_equal, as_matrix

__all__ = ["JointChain", "MAX_DELAY_PHASES"]

#: Largest ``delay_phases`` accepted (the joint chain has ``m + m (m - 1) k`` states).
MAX_DELAY_PHASES = 64


def _rates(value: ArrayLike, m: int, name: str) -> Matrix:
    """A rate matrix ``(m, m)``, entries ``>= 0`` (the diagonal is not used, but a
    negative one, a generator's diagonal written by mistake, is refused)."""
    b = as_matrix(value, name)
    if b.shape != (m, m):
        raise ValidationError(f"{name}: expected shape {(m, m)} (as alpha), got {b.shape}")
    off = ~np.eye(m, dtype=bool)
    if np.any(b[off] < 0):
        r, c = (int(v) for v in np.argwhere((b < 0) & off)[0])
        raise ValidationError(f"{name}[{r + 1}][{c + 1}]: rates must be >= 0, got {b[r, c]}")
    if np.any(np.diag(b) < 0):  # a generator's diagonal written by mistake: refused, never ignored silently
        r = int(np.argmax(np.diag(b) < 0))
        raise ValidationError(f"{name}[{r + 1}][{r + 1}]: rates must be >= 0, got {b[r, r]} (this is a matrix "
                              "of rates, not a generator: its diagonal is not used; write 0)")
    return b


def _interval(lo: Matrix, hi: Matrix, m: int, names: tuple[str, str]) -> None:
    off = ~np.eye(m, dtype=bool)
    bad = (lo > hi) & off
    if np.any(bad):
        r, c = (int(v) for v in np.argwhere(bad)[0])
        raise ValidationError(f"{names[0]}[{r + 1}][{c + 1}] = {lo[r, c]} exceeds {names[1]}[{r + 1}][{c + 1}] = "
                              f"{hi[r, c]} (the interval is reversed)")


@dataclass(frozen=True, eq=False)
class JointChain:
    """Fault generator, FDI detection rates (and, optionally, false alarms and phase-type
    delays); the joint chain of the module docstring.

    Parameters
    ----------
    alpha : (m, m) array
        Generator of the fault process (non-negative off-diagonal, rows sum to zero
        within :data:`~ftc_verify.model.matrices.GENERATOR_RTOL`).
    beta_min, beta_max : (m, m) arrays
        Bounds of the detection rates (the reciprocal of the mean delay), indexed
        ``[fdi, true]``; the diagonal is ignored. A ``beta_min`` of 0 allows a missed
        detection.
    fault_during_delay : bool
        Named variant in which the fault keeps jumping while the FDI lags (not the
        paper's model). Default ``False``: the paper's model.
    delay_phases : int
        ``k >= 1``: Erlang-``k`` detection delays with mean ``1/beta`` (default 1, the
        paper's exponential delays).
    false_alarm_min, false_alarm_max : (m, m) arrays or None
        Bounds of the false-alarm rates, indexed ``[true, reported]`` (both or neither;
        default: no false alarms).
    """

    alpha: Matrix
    beta_min: Matrix
    beta_max: Matrix
    fault_during_delay: bool = False
    delay_phases: int = 1
    false_alarm_min: Matrix | None = None
    false_alarm_max: Matrix | None = None

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
            object.__setattr__(self, key, _rates(getattr(self, key), m, f"chain.{key}"))
        _interval(self.beta_min, self.beta_max, m, ("chain.beta_min", "chain.beta_max"))
        k = self.delay_phases
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 1 <= k <= MAX_DELAY_PHASES:
            raise ValidationError(f"chain.delay_phases: expected an integer from 1 to {MAX_DELAY_PHASES}, "
                                  f"got {k!r}")
        object.__setattr__(self, "delay_phases", int(k))
        given = [key for key in ("false_alarm_min", "false_alarm_max") if getattr(self, key) is not None]
        if len(given) == 1:
            missing = ({"false_alarm_min", "false_alarm_max"} - set(given)).pop()
            raise ValidationError(f"chain.{given[0]} is given without chain.{missing}: give both (an interval "
                                  "of false-alarm rates; equal ends for a known rate)")
        if given:
            for key in given:
                object.__setattr__(self, key, _rates(getattr(self, key), m, f"chain.{key}"))
            _interval(self.false_alarm_min, self.false_alarm_max, m,  # type: ignore[arg-type]
                      ("chain.false_alarm_min", "chain.false_alarm_max"))

    # ------------------------------------------------------------------ sizes and states
    @property
    def m(self) -> int:
        """Number of fault modes."""
        return int(self.alpha.shape[0])

    @property
    def has_false_alarms(self) -> bool:
        """True when false-alarm rates are given (even if all zero)."""
        return self.false_alarm_max is not None

    @property
    def is_paper_model(self) -> bool:
        """True for the paper's FDI model: exponential delays, no false alarms."""
        return self.delay_phases == 1 and not self.has_false_alarms

    @property
    def states(self) -> tuple[tuple[int, int, int], ...]:
        """The joint states ``(true, fdi, phase)`` in their order (module docstring)."""
        k = self.delay_phases
        return tuple((i, j, p) for i in range(self.m) for j in range(self.m) for p in range(1 if i == j else k))

    @property
    def n_states(self) -> int:
        """Number of joint states, ``m + m (m - 1) k``."""
        return self.m + self.m * (self.m - 1) * self.delay_phases

    @property
    def joint_modes(self) -> tuple[tuple[int, int], ...]:
        """``(true, fdi)`` of every joint state, in the state order (with ``k = 1``: the
        pairs in the order ``s = true * m + fdi``; a pair repeats once per phase)."""
        return tuple((i, j) for i, j, _ in self.states)

    def state_index(self, true: int, fdi: int, phase: int = 0) -> int:
        """The index of the joint state ``(true, fdi, phase)``."""
        m, k = self.m, self.delay_phases
        before = true * (1 + (m - 1) * k)  # states of the earlier true modes
        if fdi == true:
            return before + fdi * k
        return before + fdi * k + phase - (k - 1) * (fdi > true)

    def start_state(self, start: tuple[int, int]) -> int:
        """The state index of an initial joint mode ``(true, fdi)`` (phase 0), validated."""
        try:
            true, fdi = (int(v) for v in start)
        except (TypeError, ValueError):
            raise ValidationError(f"start: expected a joint mode (true, fdi), got {start!r}") from None
        if not (0 <= true < self.m and 0 <= fdi < self.m):
            raise ValidationError(f"start: joint mode {start} outside 0..{self.m - 1}")
        return self.state_index(true, fdi)

    @property
    def beta_pairs(self) -> tuple[tuple[int, int], ...]:
        """Index pairs ``(fdi, true)`` of the detection rates, ``fdi != true``."""
        return tuple((j, i) for j in range(self.m) for i in range(self.m) if i != j)

    # ------------------------------------------------------------------ uncertain rates
    @property
    def rate_shape(self) -> tuple[int, ...]:
        """Shape of a rate array: ``(m, m)`` (``beta``), or ``(2, m, m)`` with false alarms."""
        return (2, self.m, self.m) if self.has_false_alarms else (self.m, self.m)

    @property
    def rate_min(self) -> Matrix:
        """The lower corner of the rate box (a rate array)."""
        return self.beta_min if self.false_alarm_min is None else np.stack([self.beta_min, self.false_alarm_min])

    @property
    def rate_max(self) -> Matrix:
        """The upper corner of the rate box (a rate array)."""
        return self.beta_max if self.false_alarm_max is None else np.stack([self.beta_max, self.false_alarm_max])

    @property
    def rate_indices(self) -> tuple[tuple[int, ...], ...]:
        """Indices into a rate array of every uncertain rate: the ``beta`` pairs
        ``(fdi, true)`` first, then the false-alarm pairs ``(true, reported)``."""
        if not self.has_false_alarms:
            return self.beta_pairs
        return tuple((0, j, i) for j, i in self.beta_pairs) + tuple(
            (1, i, j) for i in range(self.m) for j in range(self.m) if i != j)

    @property
    def free_rate_indices(self) -> tuple[tuple[int, ...], ...]:
        """The :attr:`rate_indices` whose interval has width (upper end above the lower)."""
        lo, hi = self.rate_min, self.rate_max
        return tuple(idx for idx in self.rate_indices if hi[idx] > lo[idx])

    def split(self, rates: ArrayLike) -> tuple[Matrix, Matrix | None]:
        """``(beta, false_alarm)`` of a rate array (``false_alarm`` None without them)."""
        r = np.asarray(rates, dtype=float)
        return (r[0], r[1]) if self.has_false_alarms else (r, None)

    def check_beta(self, beta: ArrayLike, name: str = "beta") -> Matrix:
        """Validate a rate array (``beta[fdi, true]``, or ``[beta, false_alarm]``) inside the box."""
        shape = self.rate_shape
        if len(shape) == 3:
            b = np.stack([as_matrix(part, f"{name}[{k}]") for k, part in enumerate(np.asarray(beta, dtype=float))])
        else:
            b = as_matrix(beta, name)
        if b.shape != shape:
            raise ValidationError(f"{name}: expected shape {shape}, got {b.shape}")
        lo, hi = self.rate_min, self.rate_max
        slack = 1e-12 * max(1.0, float(np.max(hi)))
        for idx in self.rate_indices:
            if not lo[idx] - slack <= b[idx] <= hi[idx] + slack:
                where = "".join(f"[{v + 1}]" for v in idx[-2:])
                what = name if len(idx) == 2 else (f"{name} beta" if idx[0] == 0 else f"{name} false_alarm")
                raise ValidationError(f"{what}{where} = {b[idx]} outside [{lo[idx]}, {hi[idx]}]")
        return b

    def generator(self, beta: ArrayLike) -> Matrix:
        r"""Generator :math:`Q` of the joint chain at the rate array ``beta`` (module docstring).

        ``Q[s, s']`` is the rate from state ``s`` to ``s'``; rows sum to zero. With one
        phase and no false alarms this is the generator implied by Theorem 3.1: the
        coupling term of row ``(i, j)`` there,
        :math:`1_{i=j}\sum_k \alpha_{ik} P_{kj} + 1_{i\ne j}\beta_{ji}(P_{ii}-P_{ij})`,
        equals :math:`\sum_{s'} Q[s, s'] P_{s'}`.
        """
        point = self.check_beta(beta)
        q = np.zeros((self.n_states, self.n_states))
        for s, t, coef, kind, index in self.generator_terms():
            q[s, t] += coef * (self.alpha[index] if kind == "alpha" else point[index])
        for s in range(self.n_states):
            q[s, s] = -q[s].sum()
        return q

    def generator_terms(self) -> tuple[tuple[int, int, int, str, tuple[int, ...]], ...]:
        """The off-diagonal entries of :meth:`generator` as a sum of terms
        ``(s, t, coef, kind, index)``: ``Q[s, t] += coef * alpha[index]`` (``kind ==
        "alpha"``) or ``coef * rates[index]`` (``kind == "rate"``, an index into a rate
        array); ``coef`` is ``1`` or the number of phases ``k``. The diagonal is the
        negated row sum. One place for the chain's structure: the float generator and
        its ball enclosure (:func:`ftc_verify.analysis.exact.ball_generator`) are both
        built from it."""
        m, k, idx = self.m, self.delay_phases, self.state_index
        fa_index = self.has_false_alarms
        terms: list[tuple[int, int, int, str, tuple[int, ...]]] = []
        for s, (i, j, p) in enumerate(self.states):
            if i == j:
                for t in range(m):
                    if t != i:
                        terms.append((s, idx(t, i), 1, "alpha", (i, t)))
                        if fa_index:
                            terms.append((s, idx(i, t), 1, "rate", (1, i, t)))
            else:
                target = idx(i, j, p + 1) if p + 1 < k else idx(i, i)
                terms.append((s, target, k, "rate", (0, j, i) if fa_index else (j, i)))
                if self.fault_during_delay:
                    for t in range(m):
                        if t != i:
                            terms.append((s, idx(t, j), 1, "alpha", (i, t)))
        return tuple(terms)

    def vertices(self) -> Iterator[Matrix]:
        """All vertices of the rate box (``2**len(rate_indices)`` of them, degenerate
        intervals counted once), as rate arrays."""
        lo, hi = self.rate_min, self.rate_max
        choices = [sorted({float(lo[idx]), float(hi[idx])}) for idx in self.rate_indices]
        for combo in itertools.product(*choices):
            b = np.zeros(self.rate_shape)
            for idx, v in zip(self.rate_indices, combo):
                b[idx] = v
            yield b

    def vertex_count(self) -> int:
        """Number of distinct vertices of the rate box."""
        lo, hi = self.rate_min, self.rate_max
        return int(np.prod([1 + (lo[idx] != hi[idx]) for idx in self.rate_indices]))

    def midpoint(self) -> Matrix:
        """The centre of the rate box."""
        return 0.5 * (self.rate_min + self.rate_max)

    def row_rates(self, s: int) -> tuple[tuple[int, ...], ...]:
        """Indices (into a rate array) of the uncertain rates that enter row ``s`` of the
        generator: ``beta[j, i]`` for a detection state ``(i, j, p)``, the false-alarm
        rates out of ``i`` for a matched state ``(i, i)``; intervals of zero width left out."""
        i, j, _ = self.states[s]
        lo, hi = self.rate_min, self.rate_max
        if i != j:
            found: tuple[tuple[int, ...], ...] = ((0, j, i) if self.has_false_alarms else (j, i),)
        elif self.has_false_alarms:
            found = tuple((1, i, t) for t in range(self.m) if t != i)
        else:
            found = ()
        return tuple(r for r in found if lo[r] != hi[r])

    def row_rate_points(self, s: int) -> tuple[Matrix, ...]:
        """Rate arrays at every vertex of the rates that enter row ``s`` (the others at the
        box's midpoint): an inequality affine in row ``s`` of the generator holds on the
        whole box iff it holds at each (module docstring)."""
        mid, lo, hi = self.midpoint(), self.rate_min, self.rate_max
        indices = self.row_rates(s)
        points = []
        for combo in itertools.product(*[(lo[r], hi[r]) for r in indices]):
            point = mid.copy()
            for r, v in zip(indices, combo):
                point[r] = v
            points.append(point)
        return tuple(points)

    def row_label(self, s: int, point: ArrayLike) -> str:
        """The rates of :meth:`row_rates` at ``point``, for messages (1-based indices)."""
        parts = []
        point = np.asarray(point)
        for r in self.row_rates(s):
            name = "beta" if len(r) == 2 or r[0] == 0 else "false_alarm"
            parts.append(f"{name}[{r[-2] + 1}][{r[-1] + 1}]={float(point[r]):g}")
        return " ".join(parts)

    def row_generator(self, s: int, point: ArrayLike) -> Matrix:
        """Row ``s`` of the generator at the rate array ``point``."""
        return self.generator(point)[s]

    def rate_text(self, point: ArrayLike) -> str:
        """A rate array for messages: ``beta [[...]]`` (and ``false_alarm [[...]]``)."""
        b, fa = self.split(point)
        return f"beta {b.tolist()}" + ("" if fa is None else f", false_alarm {fa.tolist()}")

    def describe(self) -> str:
        """The FDI model in one line."""
        k = self.delay_phases
        delay = ("exponential detection delays (the paper's model)" if k == 1 else
                 f"Erlang-{k} detection delays ({k} phases; mean 1/beta, variance 1/({k} beta^2))")
        parts = [delay]
        if self.false_alarm_min is not None and self.false_alarm_max is not None:
            lo, hi = self.false_alarm_min, self.false_alarm_max
            off = ~np.eye(self.m, dtype=bool)
            parts.append(f"false alarms at rates in [{float(np.min(lo[off])):g}, {float(np.max(hi[off])):g}]")
        if np.any(self.beta_min[~np.eye(self.m, dtype=bool)] == 0):
            parts.append("missed detections (beta_min = 0: the FDI may never detect a fault)")
        if self.fault_during_delay:
            parts.append("faults during a delay (named variant)")
        return "FDI: " + ", ".join(parts)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, JointChain):
            return NotImplemented
        return (self.fault_during_delay == other.fault_during_delay and self.delay_phases == other.delay_phases
                and all(arrays_equal(getattr(self, k), getattr(other, k))
                        for k in ("alpha", "beta_min", "beta_max", "false_alarm_min", "false_alarm_max")))

    __hash__ = None  # type: ignore[assignment]
