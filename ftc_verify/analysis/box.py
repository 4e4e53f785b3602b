r"""Mean-square stability over the whole box of uncertain rates, by branch and bound.

The detection (and false-alarm) rates are known to lie in a box
:math:`\mathcal B = \prod_r [\underline\rho_r, \overline\rho_r]`. The worst constant rate
vector need not be a vertex: the spectral abscissa of the second-moment generator is not
convex in the rates, and a loop can be stable at every vertex and unstable inside. So
the verdict is proved over sub-boxes.

**A sub-box is stable** if one stack :math:`P_s \succ 0` (one per joint state) has

.. math::

    -\mathcal L^*_\rho(P)_s = -\Bigl(A_s^T P_s + P_s A_s + \sum_t q_{st}(\rho) P_t\Bigr) \succ 0

for every :math:`\rho` in the sub-box and every :math:`s` (derived here: with
:math:`V = \xi^T P_{\theta}\xi`, Dynkin's formula gives
:math:`\tfrac{d}{dt}E V = E\,\xi^T \mathcal L^*_\rho(P)_\theta \xi \le -c\,E V`, so
:math:`E|\xi|^2` decays exponentially; the same holds when :math:`\rho` varies in time
inside the sub-box, since :math:`P` does not depend on it). Row :math:`s` of the generator
is affine in the few rates it contains (:meth:`~ftc_verify.model.chain.JointChain.row_rates`:
one :math:`\beta` for a detection state, the false-alarm rates out of :math:`i` for a
matched state), so the inequality holds on the sub-box iff it holds at the vertices of
those rates (the other rates do not enter block :math:`s`). The candidate :math:`P` is the
float solution of :math:`\mathcal L^*_c(P) = -I` at the sub-box's centre :math:`c`, in
the coordinates of :func:`~ftc_verify.analysis.conditioning.conditioning_transform`,
mapped back to the original coordinates and checked in ball arithmetic on the loop as
the user wrote it (:func:`~ftc_verify.analysis.exact.exact_loop`, the rates by
:func:`~ftc_verify.analysis.exact.ball_generator`).

**Not stable** is proved at one rate vector :math:`c` inside the box (a centre where the
float solution is not positive definite: then :math:`\mu(c) \ge 0` in float64) by
:meth:`~ftc_verify.analysis.verdict.StabilityProver.certify`, with a proved enclosure of
the abscissa there when one is found. A caller that knows a rate vector with
:math:`\mu \ge 0` in float64, or too close to 0 for float64 to tell
(:data:`SUSPECT_MARGIN`; the vertex search's worst, ``suspect``), has it tried
first: a loop unstable at a vertex of a wide box, with stable centres, had the whole
budget spent proving sub-boxes stable and was answered "undecided". Only the proof
counts; when it fails the branch and bound runs as without it (within the same budget:
none, no proof).

When the centre's candidate fails, the Theorem 3.1 LMI is solved on the sub-box
(Clarabel, :func:`~ftc_verify.analysis.lmi_analysis.mes_lmi`): the best common
:math:`P` of the sub-box, proved the same way. Loops too ill-conditioned for float64
candidates get, at the whole box, a candidate solved in ball arithmetic at 256 then 512
bits (:meth:`_Checker.check_precise`): first when the centre's float candidate is not
positive definite, after the LMI when it is (then the box's width, not float64, is what
failed, and the LMI costs a fraction of the ball solves).

**Branching.** A sub-box whose check fails is split in two along one rate: among the
rates of the rows that failed, the widest relative to the whole box (all rates when the
failing rows contain none); at the geometric mean when the rate spans more than a factor
4 and is positive, at the arithmetic mean otherwise. The boxes are taken widest first.
A budget of CPU seconds (:data:`BOX_BUDGET_SECONDS`), a number of sub-boxes and a
smallest width end the search with
"undecided" and the sub-box where it gave up. The root box is the one the user wrote,
rounded outward (:func:`~ftc_verify.analysis.exact.written_box`).

So "stable" means: mean-square stable for every constant rate vector of the box; and,
when the whole box was proved with one :math:`P` (``time_varying``), for rates that vary
in time inside it too.
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, replace
from functools import cached_property
from typing import Any

import numpy as np

from ..errors import FTCError
from ..jsonable import fields_dict
from ..limits import cpu_clock
from ..model.system import Matrix
from .closedloop import ClosedLoop
from .conditioning import Similarity
from .exact import ball_generator, ball_matrices, exact_loop, literals_of, written_box
from .rigorous import Ball, ball, precision, proven_positive_definite, proven_positive_definite_cholesky
from .verdict import SOLVE_LIMIT, StabilityProver, ball_lyapunov_solution, float_stack_solution

__all__ = ["BOX_BUDGET_SECONDS", "SUSPECT_MARGIN", "MAX_BOXES", "MIN_RELATIVE_WIDTH", "ROOT_LMI_DEFERRED", "RegionVerdict",
           "BoxVerdict", "box_stability"]

#: Budget of the branch and bound, the point proofs included, in CPU seconds
#: (:func:`~ftc_verify.limits.cpu_clock`: the verdict depends much less on the machine's
#: load than with a wall-clock budget).
BOX_BUDGET_SECONDS = 60.0
#: A negative float64 abscissa within this fraction of the largest conditioned mode's norm
#: does not rule the worst vertex out: its instability proof is tried first
#: (``illcond_marg1323``, written abscissa +5e-12: -1.0e-5 on one machine's OpenBLAS,
#: +1.6e-11 on another; the proof counts, not the estimate).
SUSPECT_MARGIN = 1e-4
#: The reason of an "undecided" verdict returned by ``box_stability(root_lmi=False)`` when
#: the whole box's centre candidate fails and its LMI is left to the caller.
ROOT_LMI_DEFERRED = ("the centre's P misses a vertex of the box; the whole box's Theorem 3.1 LMI is left to the "
                     "analysis's Theorem 3.1 stage")
#: Sub-boxes examined at most.
MAX_BOXES = 4096
#: A sub-box narrower than this (relative to the whole box, along every rate it can be
#: split along) is not split again.
MIN_RELATIVE_WIDTH = 1e-9


@dataclass(frozen=True)
class RegionVerdict:
    """What was proved over one region of the rate box (a sub-box, or a point when
    ``rate_min == rate_max``) and how; ``estimate`` is the float abscissa there when
    one was computed, ``enclosure`` a proved one."""

    rate_min: Matrix
    rate_max: Matrix
    verdict: str
    method: str
    precision_bits: int
    seconds: float
    estimate: float | None = None
    enclosure: tuple[float, float] | None = None

    def to_dict(self) -> dict[str, object]:
        """JSON-ready summary (the fields)."""
        return fields_dict(self)


@dataclass(frozen=True, eq=False)
class BoxVerdict:
    """The verdict over the whole box (module docstring) and the regions it rests on.

    ``regions`` are the proved sub-boxes (``"stable"``), or the one witness (``"not
    stable"``), or, for ``"undecided"``, the proved sub-boxes and last the region where
    the proof gave up. ``boxes`` counts the sub-boxes examined."""

    verdict: str
    regions: tuple[RegionVerdict, ...]
    boxes: int
    time_varying: bool
    seconds: float
    reason: str = ""

    @property
    def witness(self) -> RegionVerdict | None:
        """The rate vector at which instability was proved."""
        return self.regions[-1] if self.verdict == "not stable" else None

    @property
    def open_region(self) -> RegionVerdict | None:
        """The sub-box where the proof gave up."""
        return self.regions[-1] if self.verdict == "undecided" and self.regions else None


def _centre(lo: Matrix, hi: Matrix) -> Matrix:
    return 0.5 * (lo + hi)


def _split_value(lo: float, hi: float) -> float:
    """Where a rate interval is split (module docstring)."""
    if lo > 0 and hi > 4 * lo:
        return math.sqrt(lo * hi)
    return 0.5 * (lo + hi)


def _corners(centre: Matrix, lo: Matrix, hi: Matrix, rates: Sequence[tuple[int, ...]]) -> Iterator[Matrix]:
    """The rate arrays at every vertex of the sub-box's ``rates``, the other rates at ``centre``."""
    for corner in range(1 << len(rates)):
        point = centre.copy()
        for k, r in enumerate(rates):
            point[r] = hi[r] if corner >> k & 1 else lo[r]
        yield point


def _generator_at(chain: Any, point: Matrix, literals: Any, cache: dict[bytes, list[list[Any]]]) -> list[list[Any]]:
    """:func:`~ftc_verify.analysis.exact.ball_generator` at ``point``, made once per point."""
    key = point.tobytes()
    if key not in cache:
        cache[key] = ball_generator(chain, point, literals)
    return cache[key]


def _positive_definite(M: Ball, T: Matrix) -> bool:
    """Proved positive definite, preconditioned by the conditioning similarity or, when
    that fails, in the original coordinates (as in :mod:`ftc_verify.analysis.verdict`),
    or by a Cholesky factorisation in ball arithmetic (scales beyond float64)."""
    return (proven_positive_definite(M, T) or proven_positive_definite(M)
            or proven_positive_definite_cholesky(M))


def _float_positive(P: np.ndarray) -> bool:
    try:
        for p in P:
            np.linalg.cholesky(0.5 * (p + p.T))
    except np.linalg.LinAlgError:
        return False
    return True


@dataclass(frozen=True, eq=False)
class _Checker:
    """The proof of one sub-box (module docstring), with the loop's enclosures made once."""

    loop: ClosedLoop
    conditioned: ClosedLoop
    sim: Similarity
    A: tuple[Ball, ...]
    S: Ball  # T^-1, exact
    literals: Any
    row_rates: tuple[tuple[tuple[int, ...], ...], ...]
    column_rates: tuple[tuple[tuple[int, ...], ...], ...]

    @classmethod
    def build(cls, loop: ClosedLoop, sim: Similarity, uncertain: Sequence[tuple[int, ...]]) -> _Checker:
        nominal = loop.nominal()
        chain = nominal.chain
        with precision():
            A = ball_matrices(exact_loop(nominal).A)
            S = ball(sim.T_inv)
        rows: list[set[tuple[int, ...]]] = [set() for _ in range(chain.n_states)]
        columns: list[set[tuple[int, ...]]] = [set() for _ in range(chain.n_states)]
        for s, t, _, kind, index in chain.generator_terms():
            if kind == "rate" and index in uncertain:
                rows[s].add(index)  # Q[s, t] and the diagonal Q[s, s]
                columns[t].add(index)
                columns[s].add(index)
        return cls(nominal, sim.apply(nominal), sim, A, S, literals_of(nominal),
                   tuple(tuple(sorted(r)) for r in rows), tuple(tuple(sorted(c)) for c in columns))

    @cached_property
    def prover(self) -> StabilityProver:
        """The point prover of :meth:`prove_point`, built when first needed."""
        return StabilityProver.build(self.loop, self.sim)

    def prove_point(self, point: Matrix, deadline: float) -> tuple[Any, float, tuple[float, float] | None]:
        """The verified verdict at the rate vector ``point`` (the float64 abscissa as its
        estimate) and, when "not stable", a proved enclosure of the abscissa (or ``None``)."""
        from .moments.stability import spectral_abscissa

        prover = self.prover
        estimate = spectral_abscissa(self.conditioned, point)
        found = prover.certify(point, estimate=estimate, budget_seconds=max(0.0, deadline - cpu_clock()))
        if found.verdict != "not stable":
            return found, estimate, None
        left = max(0.0, deadline - cpu_clock())
        return found, estimate, prover.abscissa_enclosure(point, estimate, budget_seconds=left)

    def check(self, lo: Matrix, hi: Matrix) -> tuple[str, set[tuple[int, ...]]]:
        """``("stable", _)`` when the sub-box is proved; ``("unstable-centre", _)`` when
        the float candidate at the centre is not positive definite; otherwise
        ``("failed", rates)`` with the rates of the rows that failed (empty when a row
        without uncertain rates failed or ``P`` was not proved positive definite)."""
        c = _centre(lo, hi)
        # the adjoint L*_c(P) = -I: the second-moment operator with A_s and Q transposed
        Pt = float_stack_solution([a.T for a in self.conditioned.A], self.loop.chain.generator(c).T)
        if Pt is None or not _float_positive(Pt):
            return "unstable-centre", set()
        with precision():
            return self._prove([self.S.T @ ball(0.5 * (p + p.T)) @ self.S for p in Pt], lo, hi)

    def _prove(self, P: list[Ball], lo: Matrix, hi: Matrix,
               A: Sequence[Ball] | None = None) -> tuple[str, set[tuple[int, ...]]]:
        """The proof of the sub-box with the candidate ``P`` (original coordinates):
        ``P_s > 0`` and ``-L*_rho(P)_s > 0`` at every vertex of the rates of row ``s``
        (``A``: the loop's enclosures at the working precision, default 128 bits)."""
        chain = self.loop.chain
        T = self.sim.T
        c = _centre(lo, hi)
        failed: set[tuple[int, ...]] = set()
        if not all(_positive_definite(p, T) for p in P):
            return "failed", set()
        generators: dict[bytes, list[list[Any]]] = {}
        for s, As in enumerate(self.A if A is None else A):
            rates = self.row_rates[s]
            for point in _corners(c, lo, hi, rates):
                q = _generator_at(chain, point, self.literals, generators)[s]
                block = As.T @ P[s] + P[s] @ As
                for t in range(len(P)):
                    if t != s and q[t] != 0:
                        block = block + (P[t] - P[s]) * q[t]
                if not _positive_definite(-block, T):
                    if not rates:
                        return "failed", set()
                    failed.update(rates)
                    break
        return ("stable", set()) if not failed else ("failed", failed)

    def check_precise(self, lo: Matrix, hi: Matrix) -> tuple[str, int, str]:
        r"""The sub-box proved with candidates solved in ball arithmetic, for loops whose
        float candidate is too inaccurate (within
        :data:`~ftc_verify.analysis.verdict.SOLVE_LIMIT` rows): at 256 then 512 bits, the
        exact solution of :math:`\mathcal L^*_c(P) = -I` at the centre (its midpoints
        as ``P``, proved as in :meth:`check`), else of :math:`\mathcal L_c(X) = -I`
        (:meth:`_prove_columns`). ``(status, bits, form)``."""
        size = len(self.A) * self.loop.n * (self.loop.n + 1) // 2
        if size > SOLVE_LIMIT:
            return "failed", 0, ""
        c = _centre(lo, hi)
        for bits in (256, 512):
            with precision(bits):
                A = ball_matrices(exact_loop(self.loop).A)
                q = ball_generator(self.loop.chain, c, self.literals)
                qt = [[q[t][s] for t in range(len(q))] for s in range(len(q))]
            adjoint = ball_lyapunov_solution([a.T for a in A], qt, bits)
            if adjoint is not None:
                with precision(bits):
                    P = [Ball(p.value.mid()) for p in adjoint]
                    if self._prove(P, lo, hi, A)[0] == "stable":
                        return "stable", bits, "P"
            solution = ball_lyapunov_solution(A, q, bits)
            if solution is not None:
                with precision(bits):
                    if self._prove_columns([Ball(x.value.mid()) for x in solution], lo, hi, A):
                        return "stable", bits, "X"
        return "failed", 0, ""

    def _prove_columns(self, X: list[Ball], lo: Matrix, hi: Matrix, A: Sequence[Ball]) -> bool:
        """``X_s > 0`` and ``-L_rho(X)_s > 0`` at every vertex of the rates of column
        ``s`` of the generator (the rates into and out of ``s``), at the working precision."""
        chain = self.loop.chain
        c = _centre(lo, hi)
        if not all(proven_positive_definite_cholesky(x) for x in X):
            return False
        generators: dict[bytes, list[list[Any]]] = {}
        for s, As in enumerate(A):
            for point in _corners(c, lo, hi, self.column_rates[s]):
                q = _generator_at(chain, point, self.literals, generators)
                block = As @ X[s] + X[s] @ As.T
                for t in range(len(X)):
                    if q[t][s] != 0:
                        block = block + X[t] * q[t][s]
                if not proven_positive_definite_cholesky(-block):
                    return False
        return True


def _lmi_on(loop: ClosedLoop, lo: Matrix, hi: Matrix) -> bool:
    """Theorem 3.1 solved (Clarabel) and certified on the sub-box ``[lo, hi]``: the best
    common ``P`` of the sub-box, for boxes where the centre's candidate is too sensitive to
    the rates (:func:`~ftc_verify.analysis.lmi_analysis.mes_lmi`; its proof is the one of
    this module, on the loop as written)."""
    from .lmi_analysis import mes_lmi

    chain = loop.chain
    (b_lo, fa_lo), (b_hi, fa_hi) = chain.split(lo), chain.split(hi)
    try:
        sub = replace(chain, beta_min=b_lo, beta_max=b_hi, false_alarm_min=fa_lo, false_alarm_max=fa_hi)
        return mes_lmi(loop.nominal().with_chain(sub), solver="clarabel", second_opinion=False).certified
    except FTCError:  # a solver failure is not a proof either way
        return False


def _try_precise(checker: _Checker, lo: Matrix, hi: Matrix, proved: list[RegionVerdict], region: Any,
                 t0: float) -> bool:
    """:meth:`_Checker.check_precise` on the sub-box; records it when proved."""
    status, bits, form = checker.check_precise(lo, hi)
    if status != "stable":
        return False
    how = ("P from the exact solution at the centre, P > 0 and -L*(P) > 0 proved at the vertices of every "
           f"row's rates in {bits}-bit balls" if form == "P" else
           "X from the exact solution at the centre, X > 0 and -L(X) > 0 proved at the vertices of every "
           f"column's rates in {bits}-bit balls")
    proved.append(region(lo, hi, "stable", how, bits, t0))
    return True


def box_stability(loop: ClosedLoop, sim: Similarity, *, budget_seconds: float = BOX_BUDGET_SECONDS,
                  max_boxes: int = MAX_BOXES, root_lmi: bool = True, suspect: Matrix | None = None) -> BoxVerdict:
    """The verdict of ``loop`` (its nominal part) over the whole rate box (module
    docstring), in the coordinates ``sim`` for the float candidates.

    ``root_lmi=False``: when the whole box's centre candidate misses a vertex, "undecided"
    (:data:`ROOT_LMI_DEFERRED`) instead of the whole box's Theorem 3.1 LMI, for a caller
    that certifies that LMI anyway (:func:`~ftc_verify.analysis.analyze.analyze`).

    ``suspect``: a rate vector whose instability proof is tried first (module docstring)."""
    start = time.perf_counter()
    deadline = cpu_clock() + budget_seconds
    chain = loop.chain
    root_lo, root_hi = written_box(chain.rate_min, chain.rate_max)
    uncertain = tuple(r for r in chain.rate_indices if root_lo[r] != root_hi[r])
    root_width = {r: float(root_hi[r] - root_lo[r]) for r in uncertain}
    checker = _Checker.build(loop, sim, uncertain)
    proved: list[RegionVerdict] = []
    queue: deque[tuple[Matrix, Matrix]] = deque([(root_lo, root_hi)])
    boxes = 0

    def region(lo: Matrix, hi: Matrix, verdict: str, method: str, bits: int, t0: float,
               estimate: float | None = None, enclosure: tuple[float, float] | None = None) -> RegionVerdict:
        return RegionVerdict(lo.copy(), hi.copy(), verdict, method, bits, time.perf_counter() - t0, estimate,
                             enclosure)

    def give_up(lo: Matrix, hi: Matrix, why: str, t0: float) -> BoxVerdict:
        open_region = region(lo, hi, "undecided", why, 128, t0)
        return BoxVerdict("undecided", (*proved, open_region), boxes, False, time.perf_counter() - start, why)

    def point_verdict(point: Matrix, t0: float) -> tuple[BoxVerdict | None, Any]:
        found, estimate, enclosure = checker.prove_point(point, deadline)
        if found.verdict != "not stable":
            return None, found
        witness = region(point, point, "not stable", found.method, found.precision_bits, t0, estimate, enclosure)
        return BoxVerdict("not stable", (witness,), boxes, False, time.perf_counter() - start,
                          f"instability proved at {chain.rate_text(point)}"), found

    first = None if suspect is None or budget_seconds <= 0.0 else point_verdict(np.asarray(suspect, dtype=float), start)
    if first is not None and first[0] is not None:
        return first[0]
    while queue:
        lo, hi = queue.popleft()
        t0 = time.perf_counter()
        if boxes >= max_boxes:
            return give_up(lo, hi, f"{max_boxes} sub-boxes examined (the limit) before this one was decided", t0)
        if cpu_clock() >= deadline:
            return give_up(lo, hi, f"budget of {budget_seconds:g} CPU s spent before this sub-box was decided", t0)
        boxes += 1
        status, rates = checker.check(lo, hi)
        if status == "stable":
            proved.append(region(lo, hi, "stable", "P from the centre, P > 0 and -L*(P) > 0 proved at the vertices "
                                 "of every row's rates in 128-bit balls", 128, t0))
            continue
        # a centre candidate that is positive definite but misses some vertex: the box is too wide for it, not
        # float64 too inaccurate, so the sub-box's LMI (under a second) before the 256/512-bit solves (seconds to
        # tens of seconds at 300 rows)
        if status == "failed" and boxes == 1 and not root_lmi:
            return give_up(lo, hi, ROOT_LMI_DEFERRED, t0)
        if status == "failed" and _lmi_on(loop, lo, hi):
            proved.append(region(lo, hi, "stable", "P from the Theorem 3.1 LMI on the sub-box (Clarabel), P > 0 and "
                                 "-L*(P) > 0 proved at the vertices of every row's rates in 128-bit balls", 128, t0))
            continue
        if boxes == 1 and _try_precise(checker, lo, hi, proved, region, t0):  # float64 may be too inaccurate
            continue
        centre = _centre(lo, hi)
        splittable = [r for r in uncertain if hi[r] - lo[r] > MIN_RELATIVE_WIDTH * root_width[r]]
        if status == "unstable-centre" or not splittable:
            unstable, point = point_verdict(centre, t0)
            if unstable is not None:
                return unstable
            if not splittable and point.verdict == "stable" and np.array_equal(lo, hi):
                proved.append(region(lo, hi, "stable", point.method, point.precision_bits, t0, point.estimate))
                continue
            if point.verdict == "stable" and boxes > 1 and _try_precise(checker, lo, hi, proved, region, t0):
                continue  # float64 called the centre unstable, the balls proved it stable
            if not splittable:
                return give_up(lo, hi, f"sub-box too narrow to split and its centre {point.verdict} "
                                       f"({point.method})", t0)
        pick = [r for r in rates if r in splittable] or splittable
        r = max(pick, key=lambda k: (hi[k] - lo[k]) / root_width[k])
        cut = _split_value(float(lo[r]), float(hi[r]))
        left_hi, right_lo = hi.copy(), lo.copy()
        left_hi[r] = cut
        right_lo[r] = cut
        queue.append((lo, left_hi))
        queue.append((right_lo, hi))
    one_p = len(proved) == 1 and proved[0].method.startswith("P from")
    return BoxVerdict("stable", tuple(proved), boxes, one_p, time.perf_counter() - start,
                      "the whole box proved with one P" if one_p else f"{len(proved)} sub-boxes proved")
