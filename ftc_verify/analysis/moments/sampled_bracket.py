r"""The sampled loop's proved ``h_max`` bracket: where the float64 crossing is, and which
periods around it to prove stable (over the rate box) and unstable (at a rate point).

**Where the crossing is.** The scan (:func:`~ftc_verify.analysis.moments.sampled.scan_periods`)
evaluates :func:`~ftc_verify.analysis.moments.sampled.rate_points`: every vertex of the
rate box when it has at most 16, else only its two corners and its midpoint. With more
rates the worst rate array is often another vertex (on the random ``n = 4, m = 3``
loop of ``benchmarks/sampled.py``, six detection rates, vertex ``(hi, lo, lo, lo, lo,
hi)`` has :math:`\rho = 1.003` where both corners have :math:`\rho < 0.9994`), and a
stable proof at the corners' crossing is bound to fail. :func:`worst_vertex` climbs
from the worst corner to a vertex no single flip of one rate improves (float64, a
heuristic: it only chooses where to look; every claim is proved), and
:func:`h_max_bracket` moves the crossing down while such a vertex is unstable there.

**Which periods.** A proof over the rate box near the crossing has a small margin and
needs many sub-boxes (:func:`~ftc_verify.analysis.moments.sampled_proof.box_verdict`),
so a failing attempt spends its whole budget; :func:`prove_below` orders the attempts
so that few fail. The budget is a count of sub-boxes fixed by the problem's sizes
(:func:`box_work`), not seconds: the same loop gets the same bracket on every machine.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence

import numpy as np

from ...model.system import Matrix
from ..solvers import ForkedCall
from .sampled import H_MAX_RTOL, SampledLoop, crossing, rate_points, spectral_radius, worst_radius
from .sampled_clock import clock_size, clock_stable
from .sampled_proof import box_verdict, prove_point_unstable

__all__ = ["LADDER", "COARSE", "TIGHT", "BRACKET_WORK", "CLOCK_LADDER", "CLOCK_FALLBACK", "CLOCK_SPLIT", "CLOCK_PIECES", "CLOCK_SIZE", "CLOCK_WORK",
           "generator_rows", "box_work", "envelope_work", "third_order_work", "prove_below", "clock_below", "worst_vertex", "period_worst", "worst_crossing", "h_max_bracket"]

#: Relative distances below the crossing tried after the tight one fails, easy first.
LADDER = (0.1, 0.03, 0.01, 3e-3)
#: ... and, when none of those is proved, these, closest first (a proved ``h_max`` far
#: below the crossing rather than none: the three-tank loop's box at ``0.9`` times its
#: crossing 39.56 took more than 131 sub-boxes, at ``0.7`` times one).
COARSE = (0.3, 0.5)

#: The first attempts' distances below the crossing, in units of ``rtol``, and their
#: shares of the budget: the unstable end is at most ``3 rtol / 16`` above the crossing,
#: so either bracket is within ``rtol``.
TIGHT = ((0.25, 1 / 6), (0.75, 1 / 2))

#: Distances below the crossing tried, easy first, by the clock-dependent certificate
#: (:mod:`~ftc_verify.analysis.moments.sampled_clock`, quadratic pieces) when the tight
#: sub-box attempts fail; with :data:`CLOCK_PIECES` pieces, on loops whose program has at
#: most :data:`CLOCK_SIZE` variables, with a budget of at least :data:`CLOCK_WORK` units.
#: When the first fails, :data:`CLOCK_FALLBACK` is tried instead (on the random
#: ``n = 4, m = 3`` loop two pieces prove 2 % below the crossing in 2.0 CPU s, fail at
#: 1.5 % and 1 % in 0.9 s each: starting at 2 % gives that bracket for less than the
#: old start at 3 % plus the failed 1 %; ``benchmarks/results/h31p.md``).
CLOCK_LADDER = (0.02, 0.01, 3e-3)
#: The easier distances tried, closest first, when the first of :data:`CLOCK_LADDER`
#: fails; the first proved is returned (a held-out ``n = 4, m = 3`` loop, seed 13 of
#: ``benchmarks/sampled.py``'s draw: the certificate fails at 3 % and 10 %, proves 30 %
#: below the crossing, where 20 sub-boxes do not even at 50 %).
CLOCK_FALLBACK = (0.03, 0.1, 0.3, 0.5)
#: When a fallback distance ``g`` is proved and the closer one tried before it, ``e``,
#: failed with ``g > CLOCK_SPLIT e``, one more attempt at their geometric mean
#: :math:`\sqrt{e g}` (the fallback's steps are about 3x: a 30 % bracket can become
#: 17 %; ``benchmarks/results/h31n.md``). One attempt, not a bisection: its cost is
#: one more clock program, fixed in advance.
CLOCK_SPLIT = 2.0
#: Quadratic pieces of the clock-dependent certificate in :func:`clock_below`.
CLOCK_PIECES = 2
#: The largest clock program (scalar variables) :func:`clock_below` solves.
CLOCK_SIZE = 4000
#: The smallest budget of an attempt (work units) with which :func:`prove_below` tries
#: :func:`clock_below` (one clock attempt on ``n = 4, m = 3``: about 4 CPU seconds).
CLOCK_WORK = 1000.0

#: The proof budget of one attempt of :func:`prove_below` in work units
#: (:func:`box_work`): about 3 s of one core of the machine ``benchmarks/sampled.py``
#: was calibrated on.
BRACKET_WORK = 3000.0


def generator_rows(loop: SampledLoop) -> int:
    """``N``: the rows of the moment generator inside a period, joint states times
    ``d (d + 1) / 2`` (``d`` the augmented state's dimension), the size the work units
    are calibrated on."""
    return loop.states * loop.d * (loop.d + 1) // 2


def box_work(loop: SampledLoop) -> float:
    """The work units one sub-box proof is charged, from the problem's sizes only (so the
    bracket is the same on every machine and under any load): ``5 + 3e-6 N^3 t`` with
    ``N`` the moment generator's rows and ``t = 1 + K`` (``+ K (K + 1) / 4`` where the
    second-order forms are used,
    :func:`~ftc_verify.analysis.moments.sampled_taylor.quadratic_forms`) the matrix
    products of a step of the sub-box's exponential, ``K`` the free rates -- about a
    millisecond each on the calibration machine (a sub-box's cost is mostly the products
    of its exponential, plus a few float exponentials and eigenvalue problems). The
    quarter: the Horner steps of the second-order exponential multiply by the sparse
    generator (:func:`~ftc_verify.analysis.moments.fast_balls.sparse_left`), so its
    :math:`K (K + 1) / 2` second-order terms cost about a quarter of a dense product each
    on average; calibrated on ``n = 4, m = 3`` (``N = 189``, ``K = 6``): 0.18 CPU s per
    affine sub-box, 0.48 per second-order one (147 and 359 units;
    ``benchmarks/results/h31w.md``)."""
    from .sampled_taylor import quadratic_forms

    K = len(loop.chain.free_rate_indices)
    N = generator_rows(loop)
    t = 1 + K + (K * (K + 1) / 4 if quadratic_forms(K, N) else 0)
    return 5.0 + 3e-6 * N ** 3 * t


def envelope_work(loop: SampledLoop) -> float:
    """The part of :func:`box_work` for a sub-box whose polynomial form is not computed
    (the ``h_max`` cover's sub-boxes where the form is not expected to prove,
    :func:`~ftc_verify.analysis.moments.sampled_cover.cover_box`): ``5 + 3e-6 N^3``, one
    product's worth for the upper envelope's map and the midpoint's (measured 0.005-0.05
    CPU s at ``N = 189``, ``benchmarks/results/split16.md``)."""
    N = generator_rows(loop)
    return 5.0 + 3e-6 * N ** 3


def third_order_work(loop: SampledLoop) -> float:
    """The work units one third-order form of a sub-box's map is charged
    (:func:`~ftc_verify.analysis.moments.cubic_balls.cubic_map`, computed by the cover
    where the second-order form's proofs failed): ``3e-6 N^3 K (K + 1) (K + 2) / 12``,
    the map's :math:`K (K + 1) (K + 2) / 6` third-order terms about half a dense product
    each over the squarings it takes; calibrated on ``n = 4, m = 3`` (``N = 189``,
    ``K = 6``): 0.72 CPU s for the form and the enclosure against 0.35 for the
    second-order form, 567 units (``benchmarks/results/split16.md``)."""
    K = len(loop.chain.free_rate_indices)
    N = generator_rows(loop)
    return 3e-6 * N ** 3 * K * (K + 1) * (K + 2) / 12


def prove_below(loop: SampledLoop, a: float, rtol: float, max_boxes: int, work: float = BRACKET_WORK,
                deadline: float = math.inf) -> float | None:
    """A period ``a (1 - f)`` below the float64 crossing ``a`` proved mean-square stable
    over the whole rate box, the closest to ``a`` of those tried (``None`` if none; no
    attempt starts after ``deadline``, ``time.perf_counter()``, a safety valve): first
    the :data:`TIGHT` distances (the bracket within ``rtol`` at once: ``f = rtol / 4``
    with a sixth of the budget, enough where one sub-box does, then ``3 rtol / 4`` with
    half of it); if both fail, the clock-dependent certificate without sub-boxes
    (:func:`clock_below`, with a budget of at least :data:`CLOCK_WORK`; computed in a forked
    child beside the tight attempts, so the same answer on a second core), then easy first -- ``f`` in :data:`LADDER` (the first with the
    full budget, the others with a third; only those closer than the clock's period, each
    with a third, when the clock proved one) -- stopping at the first failure (a smaller
    margin is harder: its proof would rarely succeed and would spend its whole budget);
    when none of those is proved, :data:`COARSE` (a third each; only those closer than a
    coarse period of the clock's), the first proved returned. The budget of an attempt is ``work`` units (:func:`box_work` per sub-box),
    at most ``max_boxes`` sub-boxes: a count that depends only on the problem, so the
    bracket does not depend on the machine or its load."""
    per_box = box_work(loop)

    def proved(f: float, share: float) -> bool:
        boxes = min(max_boxes, max(2, int(share * work / per_box)))
        return box_verdict(loop, a * (1 - f), max_boxes=boxes, max_seconds=math.inf, stable_only=True).verdict == "stable"

    # the clock certificate does not depend on the tight attempts: it runs beside them in a
    # forked child (a second core; the same answers as one after the other)
    ahead = (ForkedCall(lambda: clock_below(loop, a, deadline), "the clock-dependent certificate", group=True)
             if max_boxes > 0 and work >= CLOCK_WORK and clock_size(loop, CLOCK_PIECES, True) <= CLOCK_SIZE else None)
    try:
        for f, share in TIGHT:
            if time.perf_counter() > deadline:
                return None
            if proved(f * rtol, share):
                return a * (1 - f * rtol)
        best = None if ahead is None else ahead.result()
    finally:
        if ahead is not None:
            ahead.cancel()
    ladder = [f for f in LADDER if f > TIGHT[-1][0] * rtol and (best is None or a * (1 - f) > best)]
    for k, f in enumerate(ladder):
        if time.perf_counter() > deadline or not proved(f, 1.0 if k == 0 and best is None else 1 / 3):
            break
        best = a * (1 - f)
    for f in [f for f in COARSE if best is None or a * (1 - f) > best]:  # closer than a coarse clock period
        if time.perf_counter() > deadline:
            break
        if proved(f, 1 / 3):
            return a * (1 - f)
    return best


def clock_below(loop: SampledLoop, a: float, deadline: float = math.inf) -> float | None:
    """The closest period ``a (1 - f)``, ``f`` in :data:`CLOCK_LADDER` tried easy first and
    stopping at the first failure (when the first fails, :data:`CLOCK_FALLBACK` closest
    first, the first proved, then the geometric mean of it and the failed distance before
    it when they differ by more than :data:`CLOCK_SPLIT` times), proved stable over the whole rate box by one clock-dependent certificate
    (:func:`~ftc_verify.analysis.moments.sampled_clock.clock_stable`, :data:`CLOCK_PIECES`
    quadratic pieces, proved in ball arithmetic; no sub-boxes); ``None`` if none is, or the
    loop's program is larger than :data:`CLOCK_SIZE`. Deterministic: no time budget
    (``deadline`` only stops new attempts)."""
    if clock_size(loop, CLOCK_PIECES, True) > CLOCK_SIZE:
        return None

    def proved(f: float) -> bool:
        cert = clock_stable(loop, a * (1 - f), CLOCK_PIECES, quadratic=True)
        return cert is not None and cert.proved

    best = None
    for k, f in enumerate(CLOCK_LADDER):
        if time.perf_counter() > deadline:
            break
        if not proved(f):
            failed = f
            for g in CLOCK_FALLBACK if k == 0 else ():
                if time.perf_counter() > deadline:
                    break
                if proved(g):
                    mid = math.sqrt(failed * g)
                    if g > CLOCK_SPLIT * failed and proved(mid):  # part of the fallback: no deadline between
                        return a * (1 - mid)
                    return a * (1 - g)
                failed = g
            break
        best = a * (1 - f)
    return best


def worst_vertex(loop: SampledLoop, h: float, points: Sequence[Matrix]) -> tuple[float, Matrix]:
    """A vertex of the rate box with a large float64 :math:`\\rho(T)` at period ``h``
    and that radius: the worst of ``points`` that is a vertex (the corners of
    :func:`~ftc_verify.analysis.moments.sampled.rate_points`), then single flips of one
    rate to its other end while one raises :math:`\\rho` (module docstring)."""
    chain = loop.chain
    free = chain.free_rate_indices
    lo, hi = chain.rate_min, chain.rate_max

    def is_vertex(p: Matrix) -> bool:
        return all(p[idx] in (lo[idx], hi[idx]) for idx in free)

    start = [p for p in points if is_vertex(p)] or [np.array(lo, dtype=float)]
    best, where = worst_radius(loop, h, start)
    where = np.array(where, dtype=float)
    for _ in range(len(free)):
        moves = []
        for idx in free:
            p = where.copy()
            p[idx] = hi[idx] if p[idx] == lo[idx] else lo[idx]
            moves.append((spectral_radius(loop, h, p), p))
        rho, p = max(moves, key=lambda m: m[0])
        if not rho > best:
            break
        best, where = rho, p
    return best, where


def period_worst(loop: SampledLoop, h: float) -> tuple[float, Matrix]:
    """The largest float64 :math:`\\rho(T)` at period ``h`` and where: over
    :func:`~ftc_verify.analysis.moments.sampled.rate_points` and, when those are not every
    vertex (more than 16), the vertex ascent of :func:`worst_vertex` from them (a random
    ``n = 2, m = 3`` loop with 64 vertices: 0.8702 at a corner, 0.8741 at an inner vertex;
    above 1 there at a period where the corners were below it). No ascent when a corner is
    already above 1 (the verdict is then proved there); the ascent evaluates at most
    ``k (k + 1)`` vertices, ``k`` the uncertain rates."""
    points = list(rate_points(loop.chain))
    rho, where = worst_radius(loop, h, points)
    if rho < 1 and loop.chain.vertex_count() > len(points) - 1:  # above 1 the corner's radius decides
        ascent, vertex = worst_vertex(loop, h, points)
        if ascent > rho:
            rho, where = ascent, vertex
    return rho, where


def worst_crossing(loop: SampledLoop, stable_h: float, a: float, rtol: float, points: list[Matrix],
                   deadline: float) -> float:
    """The crossing ``a`` lowered while :func:`worst_vertex` finds a vertex unstable at it
    (added to ``points``); a few rounds, none after ``deadline``."""
    if loop.chain.vertex_count() <= 16:
        return a  # rate_points has every vertex
    for _ in range(4):
        if time.perf_counter() > deadline:
            break
        rho, v = worst_vertex(loop, a, points)
        if rho < 1.0:
            break
        points.append(v)
        lo, hi = stable_h, a
        while worst_radius(loop, lo, points)[0] >= 1.0:
            if lo < stable_h / 16:
                return a  # pragma: no cover - no stable period near: keep the corners' crossing
            lo, hi = lo * 2.0 ** -0.125, lo
        a = crossing(loop, lo, hi, True, rtol / 16, points)
    return a


def h_max_bracket(loop: SampledLoop, stable_h: float, unstable_h: float, *, rtol: float = H_MAX_RTOL,
                  max_boxes: int = 512, work: float = BRACKET_WORK,
                  deadline: float = math.inf) -> tuple[float | None, float | None, str]:
    """``(h_max, h_max_unstable, note)`` from a float64 bracket ``stable_h < unstable_h``
    of the crossing: a period proved mean-square stable over the whole rate box and a
    larger one proved unstable at some rate point.

    The crossing is bisected in float64 to ``rtol / 16`` over the scan's rate points,
    then lowered where :func:`worst_vertex` finds a worse vertex (module docstring);
    instability is proved at the worst point just above it, stability by
    :func:`prove_below` (the bracket within ``rtol``, or the closest period its budget
    reaches: ``work`` units, at most ``max_boxes`` sub-boxes per attempt -- a budget
    that depends only on the problem; then the note says the bracket is wider than
    ``rtol``). No new proof is started after ``deadline`` (``time.perf_counter()``, a
    safety valve; the note then says the time budget was spent). ``None`` where no
    proof was found."""
    pts = list(rate_points(loop.chain))
    a = crossing(loop, stable_h, unstable_h, True, rtol / 16, pts)
    a = worst_crossing(loop, stable_h, a, rtol, pts, deadline)
    b = a * (1 + rtol / 16)
    while worst_radius(loop, b, pts)[0] < 1.0 and b < unstable_h:  # pragma: no cover - float ties
        b = min(unstable_h, b * (1 + rtol / 16))
    proved_b = None
    for f in (0.0, 0.0625, 0.125):  # with a's first margins, the gap stays below rtol
        if time.perf_counter() > deadline:
            break
        hb = b * (1 + f * rtol)
        rho, where = worst_radius(loop, hb, pts)
        if rho > 1.0 and prove_point_unstable(loop, hb, where):
            proved_b = hb
            break
    proved_a = prove_below(loop, a, rtol, max_boxes, work, deadline)
    if proved_a is None or proved_b is None:
        missing = " and ".join(w for w, v in (("stability", proved_a), ("instability", proved_b)) if v is None)
        late = " (time budget spent)" if time.perf_counter() > deadline else ""
        return proved_a, proved_b, f"{missing} near the float64 crossing {a:.6g} not proved{late}"
    gap = (proved_b - proved_a) / proved_b
    if gap > rtol:
        return proved_a, proved_b, (f"proved stable over the rate box at {proved_a:.6g}, unstable at a rate point at "
                                    f"{proved_b:.6g}: the bracket ({gap:.1e} relative) is WIDER than {rtol:g} "
                                    f"(the sub-box budget ran out nearer the float64 crossing {a:.6g})")
    return proved_a, proved_b, (f"proved stable over the rate box at {proved_a:.6g}, proved unstable at a rate "
                                f"point at {proved_b:.6g} (relative gap {gap:.1e})")
