r"""The ``h_max`` scan's float64 engine: many periods from a few exponentials, and a cone
test instead of an eigenvalue problem at most of them.

:func:`~ftc_verify.analysis.moments.sampled.scan_periods` asks, at every period of a grid
spanning four or more decades and at every rate point of
:func:`~ftc_verify.analysis.moments.sampled.rate_points`, whether the float64 one-period
map :math:`T = \mathcal P e^{\mathcal L h} \mathcal R` has :math:`\rho(T) < 1`. Forming
:math:`T` and its eigenvalues at each of them (an exponential or a product of
``N x N`` matrices, ``N`` the moment generator's rows, and an eigenvalue problem of
:math:`T`'s size) was the scan's whole cost. This module needs, per rate point, about
30 products of ``N x N`` matrices in all, and per period and rate point a few dozen
matrix-vector products and ``S`` eigenvalue problems of size ``r x r`` (``S`` joint
states, ``r = n + n_c``).

**Periods** (derived here). The scan's periods stay
:math:`h_k = h_0 2^{k/8}` (:data:`~ftc_verify.analysis.moments.sampled.SCAN_PER_OCTAVE`),
so the scan, its stability intervals and the ``h_max`` bracket seeded from it are those
of the eigenvalue scan before, number for number (where the verdicts agree: everywhere
but at ties within :data:`MARGIN` of 1). Write :math:`h / h_0 = 2^m (1.b_1 b_2 \ldots)`
in binary and cut it after :data:`BITS` places: :math:`h = h_0 \sum_{l \in \Lambda}
2^{l - B} + \varepsilon` with :math:`0 \le \varepsilon < h 2^{-B}`
(:func:`binary_pieces`). With the ladder :math:`F_l = e^{\mathcal L h_0 2^{l - B}}`
(one exponential at :math:`h_0 2^{-B}` and one square per level, per rate point: about
30 squares of ``N x N`` matrices where the geometric ring needed eight per octave),

.. math::

    e^{\mathcal L h} u = \Bigl(\sum_{j \ge 0} \frac{(\varepsilon \mathcal L)^j}{j!}\Bigr)
    \prod_{l \in \Lambda} F_l\, u

(the factors commute), about ``B / 2`` matrix-vector products and a few Taylor terms,
stopped when a term is below ``1e-17`` of the sum (at most :data:`TAYLOR`; else the
eigenvalue route below).

**Cone test** (derived here). :math:`T` maps stacks of positive semidefinite matrices
:math:`Y = (Y_s)_s` to such stacks (:mod:`~ftc_verify.analysis.moments.sampled`). For such
a map and a stack with every :math:`Y_s \succ 0` (an interior point of the cone), the
Collatz--Wielandt bounds hold:

.. math::

    T(Y) \preceq c\, Y \ \Rightarrow\ \rho(T) \le c, \qquad
    T(Y) \succeq c\, Y,\ Y \ne 0 \ \Rightarrow\ \rho(T) \ge c,

(the first: :math:`T^k(Y) \preceq c^k Y` and every stack lies below a multiple of
:math:`Y`; the second: Krein--Rutman). The smallest :math:`c` of the first is
:math:`c_+ = \max_s \lambda_{\max}(Y_s^{-1/2} T(Y)_s Y_s^{-1/2})`, the largest of the
second :math:`c_- = \min_s \lambda_{\min}(\cdot)`: one application of :math:`T` and
``S`` symmetric ``r x r`` eigenvalue problems (after a Cholesky factor of each
:math:`Y_s`). The scan decides :math:`\rho < 1` when :math:`c_+ < 1 - \tau` and
:math:`\rho \ge 1` when :math:`c_- > 1 + \tau` (:data:`MARGIN`); otherwise, and when
a vector is not finite, it computes :math:`T` by one exponential and its eigenvalues as
before, and takes the Perron eigenvector of :math:`T` (the eigenvalue of largest real
part is :math:`\rho`) as the next test stack of that rate point (made positive definite
by a small shift). Near :math:`h \to 0`, :math:`T \approx I + h \mathcal L_{cl}` and
the test passes with a stack of the continuous loop's (:math:`\mathcal L_{cl}(Y) \prec 0`),
so the Perron vector of a small period serves a whole decade.

**Float error relied on.** Each square of the ladder doubles the relative error of the
flow before it, so :math:`F_l` carries about :math:`2^{l} \epsilon` (:math:`\epsilon =
2^{-53}`; ``l`` up to about 35 over the scan's decades) besides the exponential's own, and
:math:`T(Y)` inherits it: measured on the random ``n = 4, m = 3`` loop of
``benchmarks/sampled.py`` (seed 1, 116 periods from 1.9e-4 to 4.1), the flow applied to a
vector is within 1.0e-8 of ``expm`` relative (median 3e-10); on another random loop of
that size the radius was within 2.8e-8 (at h = 1.47).
:data:`MARGIN` :math:`\tau = 10^{-6}` is above that with a factor of 30 (tested:
``tests/test_sampled_scan_h31m.py`` holds the flow to :math:`\tau / 10`); periods with
:math:`|c - 1| \le \tau` go to the eigenvalue route, which forms :math:`T` from one
exponential at the period, so where the cone test decides, its verdict is the eigenvalue
route's. The scan only locates: every claim (the verdict at the period, the ``h_max`` bracket) is proved afterwards in
ball arithmetic (:mod:`~ftc_verify.analysis.moments.sampled_proof`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

from ...model.system import Matrix
from .sampled import SCAN_PER_OCTAVE, SampledLoop, assemble_map, rate_points
from .sampled_bracket import period_worst
from .sampled_taylor import resolvent_stack
from .stability import vech_order

__all__ = ["SCREEN_ASCENT_ROWS", "BITS", "TAYLOR", "MARGIN", "DENSE_SIZE", "POWER", "SHIFT", "ScanCount", "Flow", "scan_grid",
           "binary_pieces", "ladder", "cone_bounds", "perron_stack", "scan", "ring_scan", "octave_verdicts"]

#: Binary places of ``h / lo`` below its leading one taken from the ladder of squares
#: (:func:`binary_pieces`); the rest, below ``2^-BITS`` of the period, by a Taylor series.
BITS = 16
#: The most terms of that Taylor series before the eigenvalue route is taken instead.
TAYLOR = 12
#: :math:`\tau`: the cone test decides only when its bound is this far from 1 (module
#: docstring: 30 times the float error measured).
MARGIN = 1e-6
#: Maps with at most this many rows are scanned by eigenvalues (:func:`ring_scan`):
#: there an eigenvalue problem costs less than the cone test's few small ones (the paper
#: loop's map has 12 rows, the random ``n = 4, m = 3`` loop's 90).
DENSE_SIZE = 32
#: Power steps :math:`Y \\leftarrow T(Y)` tried when the cone test does not decide, before
#: the eigenvalue route.
POWER = 3
#: The shift, relative to the largest block's trace, that makes a Perron stack positive definite.
SHIFT = 1e-6


@dataclass
class ScanCount:
    """What the scan did (for benchmarks and tests): periods, rate-point evaluations,
    how many the cone test decided, and the exponentials, squares and eigenvalue
    problems of ``N x N`` / map size it computed."""

    periods: int = 0
    evaluations: int = 0
    cone: int = 0
    exponentials: int = 0
    squares: int = 0
    eigen: int = 0
    fallback_periods: list[float] = field(default_factory=list)


def scan_grid(lo: float, hi: float) -> Matrix:
    """The scan's periods: ``lo 2^{k/8}`` (:data:`~ftc_verify.analysis.moments.sampled.SCAN_PER_OCTAVE`
    per octave) up to the first at or above ``hi``, at least one octave."""
    K = SCAN_PER_OCTAVE
    count = max(K + 1, math.ceil(K * math.log2(hi / lo)) + 1)
    return np.asarray(lo * 2.0 ** (np.arange(count) / K))


def ladder(G: Matrix, lo: float, top: int) -> list[Matrix]:
    r"""The ladder of flows :math:`F_l = e^{G\, lo\, 2^{l - B}}`, ``l = 0 .. top - 1``
    (:data:`BITS` ``= B``): one exponential and ``top - 1`` squares."""
    F = [scipy.linalg.expm(G * math.ldexp(lo, -BITS))]
    for _ in range(top - 1):
        F.append(F[-1] @ F[-1])
    return F


def binary_pieces(h: float, lo: float) -> tuple[list[int], float]:
    """``(levels, rest)``: ``h = lo (sum_{l in levels} 2^{l - BITS}) + rest`` with the
    levels the binary digits of ``h / lo`` down to :data:`BITS` places below its leading
    one and ``0 <= rest < lo 2^{m - BITS}`` (up to rounding), ``2^m <= h / lo < 2^{m+1}``."""
    s = h / lo
    m = math.floor(math.log2(s))
    while 2.0 ** m > s:
        m -= 1
    while 2.0 ** (m + 1) <= s:
        m += 1
    q = math.floor(math.ldexp(s, BITS - m))
    levels = [m + k for k in range(BITS + 1) if (q >> k) & 1]
    return levels, h - lo * math.ldexp(q, m - BITS)


def _stack(loop: SampledLoop, y: Matrix) -> Matrix:
    """The ``(S, r, r)`` symmetric blocks of a stacked ``vech`` vector."""
    rows, cols = vech_order(loop.r)
    blocks = np.zeros((loop.states, loop.r, loop.r))
    v = y.reshape(loop.states, -1)
    blocks[:, rows, cols] = v
    blocks[:, cols, rows] = v
    return blocks


def cone_bounds(loop: SampledLoop, Y: Matrix, TY: Matrix) -> tuple[float, float]:
    """:math:`(c_-, c_+)` of the module docstring for stacks ``Y`` (each block positive
    definite) and ``TY`` (``(S, r, r)`` arrays); ``(-inf, inf)`` when a block of ``Y``
    has no Cholesky factor or ``TY`` is not finite."""
    if not np.all(np.isfinite(TY)):
        return -math.inf, math.inf
    try:
        L = np.linalg.cholesky(Y)
    except np.linalg.LinAlgError:
        return -math.inf, math.inf
    X = np.linalg.solve(L, TY)
    M = np.linalg.solve(L, X.transpose(0, 2, 1))
    lam = np.linalg.eigvalsh(0.5 * (M + M.transpose(0, 2, 1)))
    return float(lam.min()), float(lam.max())


def perron_stack(loop: SampledLoop, T: Matrix) -> tuple[float, Matrix | None]:
    """``(rho, Y)``: the float64 spectral radius of ``T`` and its Perron eigenvector as a
    stack of ``r x r`` blocks made positive definite (:data:`SHIFT`), ``None`` if that
    fails (the eigenvalue route alone then decides)."""
    lam, vec = scipy.linalg.eig(T, check_finite=False)
    rho = float(np.max(np.abs(lam)))
    v = vec[:, int(np.argmax(lam.real))]
    v = v * np.conj(v[int(np.argmax(np.abs(v)))])
    Y = _stack(loop, np.real(v))
    Y = _positive(loop, Y)  # the sign too: trace 1
    try:
        np.linalg.cholesky(Y)
    except np.linalg.LinAlgError:
        return rho, None
    return rho, Y


def _positive(loop: SampledLoop, Y: Matrix) -> Matrix:
    """``Y`` scaled to trace 1 and shifted (:data:`SHIFT`) into the cone's interior."""
    Y = Y / float(np.trace(Y, axis1=1, axis2=2).sum())
    return Y + SHIFT * float(np.max(np.abs(np.trace(Y, axis1=1, axis2=2)))) * np.eye(loop.r)


def _apply(loop: SampledLoop, lifts: Matrix, Y: Matrix) -> Matrix:
    """:math:`\\mathcal R Y` (the stacked ``vech`` of the reset moments, length ``S vd``)."""
    rows, cols = vech_order(loop.r)
    return np.einsum("sab,sb->sa", lifts, Y[:, rows, cols]).ravel()


def _restrict(loop: SampledLoop, w: Matrix) -> Matrix:
    """:math:`\\mathcal P w` as ``(S, r, r)`` blocks."""
    return _stack(loop, (w.reshape(loop.states, -1) @ loop.restrict_map.T).ravel())


def scan(loop: SampledLoop, lo: float, hi: float, points: Sequence[Matrix] | None = None,
         count: ScanCount | None = None) -> tuple[Matrix, Matrix]:
    """``(hs, rho)``: :func:`scan_grid`'s periods and at each a worst float64 value of
    :math:`\\rho(T)` over ``points`` (default :func:`rate_points`) as far as it decides
    :math:`\\rho < 1`: where every point's cone test passes, the largest bound
    :math:`c_+ < 1`; at the first point found unstable (tried first at the next period),
    a value ``>= 1`` (:math:`c_-` or the eigenvalue radius; ``inf`` on overflow); where
    the test cannot decide, the eigenvalue radius as before."""
    pts = list(rate_points(loop.chain) if points is None else points)
    count = ScanCount() if count is None else count
    if loop.size <= DENSE_SIZE:
        return ring_scan(loop, lo, hi, pts, count)
    hs = scan_grid(lo, hi)
    vd = loop.d * (loop.d + 1) // 2
    gens = [loop.modes_part + np.kron(loop.chain.generator(p).T, np.eye(vd)) for p in pts]
    top = max(binary_pieces(float(hs[-1]), lo)[0]) + 1
    ladders: list[list[Matrix]] = []
    with np.errstate(over="ignore", invalid="ignore"):
        for G in gens:
            ladders.append(ladder(G, lo, top))
        count.exponentials += len(gens)
        count.squares += len(gens) * (top - 1)
        tests: list[Matrix | None] = [None] * len(pts)
        rho = np.zeros(hs.size)
        order = list(range(len(pts)))
        for k, h in enumerate(hs):
            count.periods += 1
            lifts = loop.lifts(float(h))
            pieces = binary_pieces(float(h), lo)
            worst = -1.0
            for idx in list(order):
                count.evaluations += 1
                flow = Flow(gens[idx], ladders[idx], *pieces)
                value = _evaluate(loop, flow, tests, idx, float(h), lifts, count)
                worst = max(worst, value)
                if not value < 1.0:
                    order.remove(idx)
                    order.insert(0, idx)
                    break
            rho[k] = worst
    return hs, rho


def ring_scan(loop: SampledLoop, lo: float, hi: float, pts: Sequence[Matrix], count: ScanCount) -> tuple[Matrix, Matrix]:
    """:func:`scan` for a small map (at most :data:`DENSE_SIZE` rows), as the scan was
    before this module: the flows of the first octave are exponentials, every later one
    the square of the one an octave before, and the eigenvalues of :math:`T` decide."""
    K = SCAN_PER_OCTAVE
    hs = scan_grid(lo, hi)
    vd = loop.d * (loop.d + 1) // 2
    rho = np.zeros(hs.size)
    gens = [loop.modes_part + np.kron(loop.chain.generator(p).T, np.eye(vd)) for p in pts]
    rings: list[list[Matrix]] = [[] for _ in gens]  # the last octave's flows, flow k at k % K
    with np.errstate(over="ignore", invalid="ignore"):  # an overflow is a result: rho inf
        for k, h in enumerate(hs):
            count.periods += 1
            for G, ring in zip(gens, rings):
                if k < K:
                    F = scipy.linalg.expm(G * float(h))
                    ring.append(F)
                    count.exponentials += 1
                else:
                    F = ring[k % K] @ ring[k % K]
                    ring[k % K] = F
                    count.squares += 1
                if rho[k] >= 1.0:
                    continue  # unstable at this period already: the other points cannot change that
                count.evaluations += 1
                count.eigen += 1
                T = assemble_map(loop, F, float(h))
                r = float(np.max(np.abs(scipy.linalg.eigvals(T, check_finite=False)))) if np.all(np.isfinite(T)) else math.inf
                rho[k] = max(rho[k], r)
    return hs, rho


@dataclass(frozen=True)
class Flow:
    """:math:`e^{\\mathcal L h}` at one rate point as the product of the ladder's flows at
    ``levels`` and the exponential of the ``rest`` (:func:`binary_pieces`), applied to vectors."""

    generator: Matrix
    ladder: Sequence[Matrix]
    levels: Sequence[int]
    rest: float

    def apply(self, u: Matrix) -> Matrix | None:
        """:math:`e^{\\mathcal L h} u`; ``None`` when the Taylor series of the rest's
        exponential does not reach float64 accuracy in :data:`TAYLOR` terms."""
        w = u
        for level in self.levels:
            w = self.ladder[level] @ w
        term, total = w, w
        for k in range(1, TAYLOR + 1):
            term = (self.rest / k) * (self.generator @ term)
            total = total + term
            if not np.linalg.norm(term) > 1e-17 * np.linalg.norm(total):
                return total
        return None


def _evaluate(loop: SampledLoop, flow: Flow, tests: list[Matrix | None], idx: int, h: float, lifts: Matrix,
              count: ScanCount) -> float:
    """One rate point at one period: the cone test with the point's stack (or the last
    refreshed one) and up to :data:`POWER` power steps, else the eigenvalue route, which
    refreshes the stack."""
    Y = tests[idx] if tests[idx] is not None else next((t for t in tests if t is not None), None)
    for _ in range(POWER + 1 if Y is not None else 0):
        assert Y is not None
        w = flow.apply(_apply(loop, lifts, Y))
        if w is None:
            break
        TY = _restrict(loop, w)
        c_lo, c_hi = cone_bounds(loop, Y, TY)
        if c_hi < 1.0 - MARGIN or c_lo > 1.0 + MARGIN:
            count.cone += 1
            tests[idx] = Y
            return c_hi if c_hi < 1.0 else c_lo
        if not math.isfinite(c_hi):
            break
        Y = _positive(loop, TY)  # a power step towards the Perron stack
    count.exponentials += 1
    count.eigen += 1
    count.fallback_periods.append(h)
    T = assemble_map(loop, scipy.linalg.expm(flow.generator * h), h)
    if not np.all(np.isfinite(T)):
        return math.inf
    rho, Y = perron_stack(loop, T)
    if Y is not None:
        tests[idx] = Y
    return rho


#: Largest one-period map (rows) on which :func:`octave_verdicts` runs the vertex ascent.
SCREEN_ASCENT_ROWS = 256


def octave_verdicts(loop: SampledLoop, hi: float, octaves: int) -> list[tuple[float, bool]]:
    r"""Float64 verdicts at the periods :math:`h_k = hi\, 2^{-k}`, ``k = octaves, ..., 0``
    (smallest first): ``True`` where every rate point of
    :func:`~ftc_verify.analysis.moments.sampled.rate_points` passes the test below and, on
    a box with more than 16 vertices, the vertex ascent finds none unstable (last
    paragraph). A screen for warnings (``synthesize`` without ``--period``), never a claim.

    Per rate point one exponential at the smallest period and one square per octave
    (:math:`e^{\mathcal L 2h} = (e^{\mathcal L h})^2`); per period, instead of the
    eigenvalues of :math:`T`, one LU: :math:`Y = (I - T)^{-1} I` with every block
    :math:`Y_s \succ 0` (float64). Derived here: then :math:`Y - T(Y) = I \succ 0`, so
    :math:`\rho(T) < 1` (the "Stable" argument of
    :mod:`~ftc_verify.analysis.moments.sampled_proof`); conversely :math:`\rho(T) < 1`
    gives :math:`Y = \sum_k T^k(I) \succeq I \succ 0` (:math:`T` maps positive
    semidefinite stacks to such stacks). The test is
    :func:`~ftc_verify.analysis.moments.sampled_taylor.resolvent_stack` with no margin
    and without the residual :math:`Y - T(Y)`. On slow plants, whose :math:`\rho` at short
    periods is within ``1e-6`` of 1, :func:`scan`'s cone test cannot decide and every
    period costs an eigenvalue problem; this test does not depend on that margin. Only the
    octaves are screened: a loop unstable only between two of them is not seen.

    When the rate box has more vertices than :func:`rate_points` lists (more than 16: its
    corners and midpoint only), a period the LU test passes is also screened by
    :func:`~ftc_verify.analysis.moments.sampled_bracket.period_worst` (the vertex ascent
    of the verdict at a period; float64 eigenvalues, at most ``k (k + 1)`` vertices for
    ``k`` uncertain rates), and is not stable where that radius is ``>= 1``: the worst
    vertex is often an inner one (``tests/test_octave_left11.py``: a 64-vertex loop
    unstable at 0.1 only at an inner vertex, every rate point stable there). Only on maps
    of at most :data:`SCREEN_ASCENT_ROWS` rows: the three-tank tutorial's output-feedback
    loop (576 rows, 4096 vertices) took 6.3 s per ascent, 28 s for the screen, against
    4 s for its synthesis; larger maps get the corners and the midpoint.
    """
    hs = [math.ldexp(hi, -k) for k in range(octaves, -1, -1)]
    points = rate_points(loop.chain)
    stable = [True] * len(hs)
    vd = loop.d * (loop.d + 1) // 2
    with np.errstate(over="ignore", invalid="ignore"):  # an overflow is a result: not stable
        for p in points:
            F = scipy.linalg.expm((loop.modes_part + np.kron(loop.chain.generator(p).T, np.eye(vd))) * hs[0])
            for k, h in enumerate(hs):
                if k:
                    F = F @ F
                if stable[k]:
                    T = assemble_map(loop, F, h)
                    stable[k] = resolvent_stack(T, loop.states, loop.r, margin=0.0, residual=False) is not None
    wide = loop.chain.vertex_count() > len(points) - 1  # rate_points has only the corners and the midpoint
    if wide and loop.states * vd <= SCREEN_ASCENT_ROWS:
        stable = [ok and period_worst(loop, h)[0] < 1.0 for h, ok in zip(hs, stable)]
    return list(zip(hs, stable))
