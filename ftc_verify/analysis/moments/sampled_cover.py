r"""The ``h_max`` refinement by covers of the rate box: the stage behind
``analyze --h-max-work`` and ``verify --h-max-work``
(:func:`~ftc_verify.analysis.moments.sampled_refine.refine_result`).

**A rung** is a period :math:`h = h_u (1 - f)`, :math:`h_u` the proved-unstable end of
the bracket, proved mean-square stable for every rate array of the box by a *cover*: a
list of sub-boxes whose union is the box, each proved in ball arithmetic by any sound
argument: its own one-period map
(:func:`~ftc_verify.analysis.moments.sampled_proof.subbox_stable`: the upper envelope,
then the map's polynomial form in the rates with the enclosure of its Perron eigenpair,
:mod:`~ftc_verify.analysis.moments.sampled_eigen`), tried first (a few hundred work
units), or else its own cubic clock certificate
(:func:`~ftc_verify.analysis.moments.sampled_cubic.cubic_stable`, thousands). Every
constant rate array lies in some sub-box, whose proof puts the spectral radius of its
one-period map below 1; where two sub-boxes meet, both cover the shared face (each proof
holds on its closed sub-box, the shared split value enclosed by the same ball in both).

**Why sub-boxes.** A certificate common to the whole box also holds for rates that
change in time inside it, near ``h_max`` worse than any constant rate (seed-1 ``n = 4,
m = 3`` loop: 1.5e-3 below the crossing, its worst vertex 5e-4; ``h31r.md``).

**The moving enclosure's route.** On boxes of :data:`CUBIC_RATES` free rates or more
(where :func:`~ftc_verify.analysis.moments.cubic_balls.cubic_forms` allows), a
sub-box's form is the third-order one proved by
:func:`~ftc_verify.analysis.moments.sampled_eigen3.cubic_radius_bound`: at six rates it
proves sub-boxes at the worst vertex 4 times wider in four rates than the second-order
enclosure (``benchmarks/results/eig19.md``). There the rungs have no
pieces: each sub-box is tried by its map's proof, then, where its enclosure did not
contract (reach above :data:`REACH_MAX`), by a bulk certificate (below), and else halved
by :func:`map_split`. Elsewhere the search below.

**The search.** Depth first; a sub-box not proved is halved along its widest rate
(relative to the box; on ties the one that moves the float64 radius most near the
worst vertex) up to :data:`COVER_DEPTH` halvings along a path (cubic certificates of
the rung's pieces tried), then along :func:`map_split`'s rate (map proofs only) up to
:data:`MAP_DEPTH`; it stops where a sub-box's midpoint has a float64 radius >= 1. The
half holding the corner nearest to the worst vertex is tried first, and a sub-box whose
cubic certificate fails first has its *probe* tried (:func:`probe_box`: the sub-box the
cover would reach first :data:`COVER_DEPTH` below it), and where that fails the *deeper
probe* (:data:`PROBE_DEPTH` halvings down, below :data:`COVER_DEPTH` by
:func:`map_split`: thin in the rates that move the radius, wide in the others;
``benchmarks/results/split17.md``). A certificate of a sub-box holds on each sub-box
inside it, so when the probes fail no certificate of the rung's pieces is tried below
that sub-box again, and when a probe is proved the shallowest proved sub-box on its path
is found by bisection of the depth (``_shallowest``), the cover going on with it and the
other halves along the path.

**Bulk certificates.** Where only map proofs are tried (below a failed probe, on a rung
whose probes no pieces prove, on the moving enclosure's route), a sub-box whose map
proof fails gets a certificate of :data:`BULK_PIECES` pieces (on boxes of
:data:`BULK_RATES` free rates or more) when its float64 margin :math:`1 - \rho` at the
corner nearest to the worst vertex is :data:`BULK_MARGIN` times the worst vertex's (on
the moving enclosure's route: where its enclosure did not contract) and, below one that
failed, :data:`BULK_RETRY` times the margin where it failed (``_bulk``;
``benchmarks/results/bulk18.md``).

**The ladder.** Rungs ``f = g/4, g/16, ...`` (``g`` the default bracket's relative width)
down to the target ``0.9 rtol``, easy first; each rung starts from the previous rung's
cover (its sub-boxes, not the whole box again), with the fewest pieces of :data:`PIECES`
(at least the last covered rung's, and 4 below :data:`FINE_FROM`) that prove its probe
below the previous cover's sub-box holding the worst vertex, or else its deeper probe
(:func:`rung_pieces`). A rung's cover may spend :data:`RUNG_SHARE` of the budget left, the target's rung all of
it. Once a rung is not covered within the budget or the depth, the next is at the
geometric mean of the last covered and the closest failed distance, while these are more
than :data:`BISECT` apart; the result is the last rung covered. Every attempt is charged
*before* it is solved, from the problem's size only (:func:`cubic_work` per cubic
certificate, :func:`~ftc_verify.analysis.moments.sampled_bracket.box_work` per map proof
with its form, :func:`~ftc_verify.analysis.moments.sampled_bracket.envelope_work`
without, :func:`~ftc_verify.analysis.moments.sampled_bracket.third_order_work` per
third-order form), and none is started that the budget cannot pay: the same loop and
budget give the same bracket on every machine.

**Where forms are computed.** Away from the worst vertex the second-order enclosure fails
for want of contraction until the sub-box is small (``benchmarks/results/split16.md``),
so on its route a sub-box gets a form only where its expected reach (its parent's
:func:`~ftc_verify.analysis.moments.sampled_eigen.enclosure_reach`, or expectation,
times :data:`REACH_SHRINK`) is at most :data:`REACH_MAX`; a third-order form
(:func:`~ftc_verify.analysis.moments.cubic_balls.cubic_map`) after it only where it
costs no more than a second-order form (two or three rates). On the moving enclosure's
route every sub-box whose envelope fails gets its form (that enclosure's reach falls
by factors up to 5 in one halving).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ...model.system import Matrix
from ..rigorous import precision
from .cubic_balls import cubic_forms
from .sampled import SampledLoop, rate_points, spectral_radius
from .sampled_bracket import box_work, envelope_work, generator_rows, third_order_work, worst_vertex
from .sampled_cubic import cubic_size, cubic_stable
from .sampled_proof import MapParts, split_rate, subbox_stable
from .sampled_taylor import FormSpend

__all__ = ["COVER_DEPTH", "PROBE_DEPTH", "MAP_DEPTH", "ASPECT", "RUNG_SHARE", "REACH_MAX", "REACH_SHRINK", "BULK_PIECES", "BULK_MARGIN", "BULK_RETRY", "BULK_RATES", "CUBIC_RATES", "PIECES", "FINE_FROM", "BISECT", "CoverResult", "map_split",
           "cubic_work", "cubic_memory", "cover_rungs", "rung_pieces", "probe_box", "cover_box", "cover_h_max"]

#: The most halvings along a path where cubic certificates are tried (the widest rate).
COVER_DEPTH = 10
#: The depth of the deeper probe (:func:`probe_box`; held-out seed 9, 1.25e-3 below the
#: proved-unstable end: four cubic pieces prove the one 16 halvings down, not 14).
PROBE_DEPTH = 16
#: The most halvings along one path in all: the map covers of the last rungs go 14-18
#: halvings deep (``benchmarks/results/eig14.md``).
MAP_DEPTH = 24
#: :func:`map_split`: a rate more than this many times as wide (relative to the box) as
#: :func:`~ftc_verify.analysis.moments.sampled_proof.split_rate`'s choice is halved first.
ASPECT = 4.0
#: The share of the budget left a rung's cover may spend (the target's rung: all of it),
#: so that one that fails leaves some for closer rungs (``benchmarks/results/split15.md``).
RUNG_SHARE = 0.5
#: The cubic pieces a rung may use, fewest first (:func:`rung_pieces`); not 8, which cost
#: 2.3 times 4 and failed where map proofs covered (``benchmarks/results/split17.md``).
PIECES = (2, 4)
#: Below this distance a rung uses at least 4 pieces: the seed-1 loop's sub-boxes needed 4
#: at 1.25e-3 and 9e-4 where 2 sufficed for the worst vertex alone.
FINE_FROM = 3e-3
#: After a rung fails, rungs at the geometric mean of the last covered and the closest
#: failed distance while these are more than this factor apart (from 4x: three more).
BISECT = 1.25


#: The largest expected reach (the radius of the enclosure's Lipschitz matrix, below 1 where
#: it contracts) for a form (module docstring, "Where forms are computed").
REACH_MAX = 1.0
#: A half's expected reach: its parent's (estimate, or expectation) times this (on seed
#: 31's sub-boxes the estimate fell by 0.6-0.9 per halving).
REACH_SHRINK = 0.85
#: On boxes of at least this many free rates, the moving enclosure's route (module
#: docstring).
CUBIC_RATES = 4
#: The pieces of a *bulk* certificate: two prove wide sub-boxes away from the worst vertex
#: (held-out seed 13, 9e-4 below the crossing: 16 of 16 random quarter-width ones).
BULK_PIECES = 2
#: A bulk certificate is tried only where the float64 margin ``1 - rho`` at the sub-box's
#: corner nearest to the worst vertex is at least this many times the worst vertex's.
BULK_MARGIN = 2.0
#: Below a sub-box whose bulk certificate failed, one is tried again only where that
#: corner's margin is more than this many times the margin where it failed.
BULK_RETRY = 1.5
#: Bulk certificates only on boxes of this many free rates or more (a two-rate loop 1e-3
#: below its crossing: 12 sub-boxes, 137 units; with 4 failed bulk certificates 2,936).
BULK_RATES = 4


def _costs(loop: SampledLoop) -> tuple[float, float, float | None, bool]:
    """``(envelope, form, third-order form, cubic)``: the units of a sub-box's envelope,
    of its form and of a third-order form after it (``None``: never, where it is dearer
    than the second-order one), and whether the form is the third-order one with the
    moving enclosure (:data:`CUBIC_RATES`; then charged as a third-order form, with none
    after it; module docstring, "Where forms are computed")."""
    per_map, third = envelope_work(loop), third_order_work(loop)
    K = len(loop.chain.free_rate_indices)
    if K >= CUBIC_RATES and cubic_forms(K, generator_rows(loop)):
        return per_map, third, None, True
    per_form = box_work(loop) - per_map
    return per_map, per_form, third if third <= per_form else None, False


def _spend(expected: float, seen: list[float], pay: Callable[[float], bool], costs: tuple[float, float, float | None, bool]) -> FormSpend:
    """A sub-box's :class:`~ftc_verify.analysis.moments.sampled_taylor.FormSpend` in
    :func:`cover_box`: its form only when its expected reach is at most
    :data:`REACH_MAX`, each form paid by ``pay`` at its ``costs`` (``_costs``); the reach
    of a form that proves nothing appended to ``seen`` (where it is not estimated, its
    halves expect what it expected)."""
    _, per_form, per_third, cubic = costs
    third = None if per_third is None else (lambda: pay(per_third))
    return FormSpend(lambda: expected <= REACH_MAX and pay(per_form), third, seen.append, cubic)


def map_split(loop: SampledLoop, h: float, lo: Matrix, hi: Matrix) -> tuple[int, ...] | None:
    """The rate along which the cover halves a sub-box below :data:`COVER_DEPTH`
    halvings (on the way to a deeper probe too) and every sub-box that only map proofs
    are tried on: :func:`~ftc_verify.analysis.moments.sampled_proof.split_rate`'s (where
    the float64 radius moves most), unless the widest rate relative to the box is more than
    :data:`ASPECT` times as wide, then that one. The map's proofs lose margin to the
    products of all the widths (the form's terms of degree three), also of rates along
    which the radius hardly moves (held-out seed 13, 1.08e-2 below the proved-unstable
    end: the probe's sub-box was proved after 15 halvings by ``split_rate``, with one rate
    left at half the box's width until the last, and after 7 with this rule;
    ``benchmarks/results/split15.md``). Only where the proofs look next depends on it."""
    r = split_rate(loop, h, lo, hi)
    if r is None:
        return None
    full = loop.chain.rate_max - loop.chain.rate_min
    rel = {q: float((hi[q] - lo[q]) / full[q]) for q in loop.chain.rate_indices if full[q] > 0 and hi[q] > lo[q]}
    wide = max(rel, key=lambda q: rel[q])
    return wide if rel[wide] > ASPECT * rel[r] else r


def cubic_work(loop: SampledLoop, pieces: int) -> float:
    """The units one attempt (program, solve and proof) is charged: ``0.15 V^1.3`` for a
    program of ``V`` variables (:func:`~ftc_verify.analysis.moments.sampled_cubic.cubic_size`),
    about a millisecond of one core each (seed-1 loop: two pieces ``V = 3483``, 4 CPU s,
    6000 units; four ``V = 6777``, 10-13 CPU s, 14300 units; ``benchmarks/results/h31r.md``).
    Every sub-box has as many row vertices as the box, so the same size (a single rate
    array is charged as much)."""
    return 0.15 * float(cubic_size(loop, pieces)) ** 1.3


def cubic_memory(loop: SampledLoop, pieces: int = PIECES[-1]) -> float:
    """Estimated peak memory (bytes) of one attempt from the program's size, as measured
    for the quadratic clock programs (``2.8e9 (V / 22365)^2.2 + 2e8``: 2.8 GB at ``V =
    22365``, ``benchmarks/results/h31e.md``; four cubic pieces on ``n = 4, m = 3``, ``V =
    6777``: estimated 0.40 GB, measured 0.43 GB peak for the whole process); the cover
    never holds two programs at once, so this is the stage's peak whatever the budget."""
    return 2.8e9 * (float(cubic_size(loop, pieces)) / 22365.0) ** 2.2 + 2.0e8


def cover_rungs(gap: float, rtol: float) -> tuple[float, ...]:
    """The distances ``f`` of the ladder (module docstring) from a default bracket of
    relative width ``gap``: ``gap / 4^k`` while above ``0.9 rtol``, then ``0.9 rtol``."""
    target = 0.9 * rtol
    out: list[float] = []
    f = gap / 4.0
    while f > target:
        out.append(f)
        f /= 4.0
    if gap > target:
        out.append(target)
    return tuple(out)


def rung_pieces(loop: SampledLoop, h: float, lo: Matrix, hi: Matrix, fewest: int,
                budget: float) -> tuple[int | None, float, int]:
    """The fewest cubic pieces of :data:`PIECES`, at least ``fewest``, whose certificate
    is found and proved for the rates in ``[lo, hi]`` at period ``h`` (the rung's probe,
    :func:`probe_box`: what the clock needs there; a cover cannot do with fewer, its
    sub-boxes near the worst vertex are no larger); ``(pieces or None, units charged,
    attempts)``, ``None`` when none is (or the budget ran out)."""
    spent, attempts = 0.0, 0
    for n in [n for n in PIECES if n >= fewest]:
        cost = cubic_work(loop, n)
        if spent + cost > budget:
            break
        spent += cost
        attempts += 1
        cert = cubic_stable(loop, h, n, lo, hi)
        if cert is not None and cert.proved:
            return n, spent, attempts
    return None, spent, attempts


@dataclass(frozen=True)
class CoverResult:
    """What :func:`cover_h_max` did: ``h_max`` the closest period covered (``None``: no
    rung), ``boxes`` the sub-boxes of its cover, ``pieces`` their cubic certificates'
    pieces (``None``: the rung's worst vertex was not proved by any, its cover is by the
    one-period map alone), ``work`` the units charged, ``attempts`` the cubic
    certificates tried, ``maps`` the sub-boxes tried by their one-period map, ``rungs``
    one ``(period, covered)`` per rung tried."""

    h_max: float | None
    boxes: int
    pieces: int | None
    work: float
    attempts: int
    maps: int
    rungs: tuple[tuple[float, bool], ...]


Box = tuple[Matrix, Matrix, int]


def _key(lo: Matrix, hi: Matrix) -> tuple[bytes, bytes]:
    return np.asarray(lo, dtype=float).tobytes(), np.asarray(hi, dtype=float).tobytes()


def _corner(lo: Matrix, hi: Matrix, worst: Matrix) -> Matrix:
    """The corner of ``[lo, hi]`` nearest to ``worst`` (the box's worst vertex)."""
    return np.where(np.abs(worst - lo) <= np.abs(worst - hi), lo, hi)


def _bulk(loop: SampledLoop, h: float, box: Box, worst: Matrix, failed: float,
          pay: Callable[[float], bool], wide: bool | None = None) -> tuple[bool | None, float]:
    """A bulk certificate of ``box`` where :data:`BULK_MARGIN` (or, given ``wide``, the
    moving enclosure's reach: too wide for the map's proofs), :data:`BULK_RETRY`
    (``failed``: the margin where one above it failed, else 0) and ``pay`` allow:
    ``(proved or None when not tried, the failed margin its halves inherit)``."""
    lo, hi, _ = box
    margin = 1.0 - spectral_radius(loop, h, _corner(lo, hi, worst))
    if wide is None:
        wide = margin >= BULK_MARGIN * (1.0 - spectral_radius(loop, h, worst))
    if not wide or margin <= BULK_RETRY * failed or not pay(cubic_work(loop, BULK_PIECES)):
        return None, failed
    cert = cubic_stable(loop, h, BULK_PIECES, lo, hi)
    return (True, failed) if cert is not None and cert.proved else (False, margin)


def _widest(loop: SampledLoop, h: float, lo: Matrix, hi: Matrix, v: Matrix) -> tuple[int, ...] | None:
    """The widest free rate of ``[lo, hi]`` relative to the box, among those the one that
    moves the float64 radius most at the sub-box's corner ``v`` when flipped to the
    sub-box's other end (``None``: no rate is free)."""
    chain = loop.chain
    free = [r for r in chain.rate_indices if hi[r] > lo[r]]
    if not free:
        return None
    base = spectral_radius(loop, h, v)
    full = chain.rate_max - chain.rate_min

    def score(r: tuple[int, ...]) -> tuple[float, float]:
        p = v.copy()
        p[r] = hi[r] if v[r] == lo[r] else lo[r]
        change = abs(spectral_radius(loop, h, p) - base)
        return (round(float((hi[r] - lo[r]) / full[r]), 12), change if np.isfinite(change) else 0.0)

    return max(free, key=score)


def _split(loop: SampledLoop, h: float, lo: Matrix, hi: Matrix, depth: int, worst: Matrix,
           cubic: bool = True) -> tuple[Box, Box] | None:
    """The two halves of ``[lo, hi]`` (``None``: no rate is free): along its widest rate
    (``_widest``) when cubic certificates may be tried below it (``cubic``) and it is less
    than :data:`COVER_DEPTH` halvings deep, else along :func:`map_split`'s (module
    docstring). The half holding ``v``, the sub-box's corner nearest to ``worst`` (the
    worst vertex of the box), first (the harder one: the cover tries it first, so that a
    rung it cannot cover fails early). Only the order of the splits depends on it; every
    sub-box is proved in ball arithmetic."""
    v = _corner(lo, hi, worst)
    r = _widest(loop, h, lo, hi, v) if cubic and depth < COVER_DEPTH else map_split(loop, h, lo, hi)
    if r is None:
        return None
    mid = 0.5 * (lo[r] + hi[r])
    lo2, hi1 = lo.copy(), hi.copy()
    hi1[r] = mid
    lo2[r] = mid
    low, high = (lo, hi1, depth + 1), (lo2, hi, depth + 1)
    return (low, high) if v[r] == lo[r] else (high, low)


def _path(loop: SampledLoop, h: float, box: Box, worst: Matrix, until: int = PROBE_DEPTH) -> list[tuple[Box, Box]]:
    """The splits of ``box`` the cover meets first, down to ``until`` halvings: per
    halving, ``(the harder half, the other)`` (``_split``), each harder half split
    next."""
    out: list[tuple[Box, Box]] = []
    lo, hi, depth = box
    while depth < until:
        halves = _split(loop, h, lo, hi, depth, worst)
        if halves is None:
            break
        out.append(halves)
        lo, hi, depth = halves[0]
    return out


def probe_box(loop: SampledLoop, h: float, box: Box, worst: Matrix, depth: int = COVER_DEPTH) -> Box:
    """The sub-box of ``box`` at ``depth`` halvings (:data:`COVER_DEPTH`, or
    :data:`PROBE_DEPTH` for the deeper probe) along the harder half of every split
    (``_split``: the corner nearest to ``worst``), ``box`` itself when it is that deep:
    the hardest sub-box a cubic certificate of the cover must prove below ``box`` (a
    certificate of a larger sub-box also holds on it), so it is tried first (module
    docstring, "Hardest first")."""
    path = _path(loop, h, box, worst, depth)
    return path[-1][0] if path else box


def cover_box(loop: SampledLoop, h: float, pieces: int | None, boxes: list[Box], budget: float,
              worst: Matrix | None = None,
              proved: frozenset[tuple[bytes, bytes]] = frozenset(), bulk: bool = True) -> tuple[list[Box] | None, float, int, int]:
    """A cover of the union of ``boxes`` at period ``h`` (module docstring), depth first,
    the harder half of each split first: ``(sub-boxes, units charged, cubic attempts, map
    proofs)``, the sub-boxes ``None`` when the budget or :data:`MAP_DEPTH` ran out first
    or the float64 radius at a sub-box's midpoint is not below 1. Each sub-box: the
    one-period map's proof (:func:`~ftc_verify.analysis.moments.sampled_proof.subbox_stable`,
    each part charged before it is computed: module docstring), then, up to
    :data:`COVER_DEPTH`, a cubic certificate of ``pieces`` pieces (where given) with its
    probes, or below a failed probe (or without ``pieces``) a bulk certificate
    (``_bulk``; none when ``bulk`` is false or below :data:`BULK_RATES`); halved as
    ``_split`` says. ``worst``: the box's worst vertex (float64, found here when not
    given); ``proved``: sub-boxes already proved at ``h`` (by ``_key``), leaves as they are."""
    cost = 0.0 if pieces is None else cubic_work(loop, pieces)
    bulk = bulk and len(loop.chain.free_rate_indices) >= BULK_RATES
    costs = _costs(loop)
    stack = list(reversed(boxes))
    leaves: list[Box] = []
    done = set(proved)
    maps_only: set[tuple[bytes, bytes]] = set()
    reach: dict[tuple[bytes, bytes], float] = {}  # a sub-box's expected reach (REACH_MAX), from its parent
    bulk_failed: dict[tuple[bytes, bytes], float] = {}  # the margin where a bulk certificate above it failed
    spent, attempts, maps = 0.0, 0, 0
    with precision(64):
        parts = MapParts.build(loop, h)

    def pay(units: float) -> bool:  # charged before the work, never beyond the budget
        nonlocal spent
        if spent + units > budget:
            return False
        spent += units
        return True

    while stack:
        lo, hi, depth = stack.pop()
        key = _key(lo, hi)
        if key in done:
            leaves.append((lo, hi, depth))
            continue
        if spent + costs[0] > budget:
            return None, spent, attempts, maps
        spent += costs[0]
        maps += 1
        expected, failed = reach.pop(key, 0.0), bulk_failed.pop(key, 0.0)
        seen: list[float] = []  # the reach of its form, when computed and not proved
        if subbox_stable(loop, h, parts, lo, hi, spend=_spend(expected, seen, pay, costs)):
            leaves.append((lo, hi, depth))
            continue
        if spectral_radius(loop, h, 0.5 * (lo + hi)) >= 1.0:  # no proof can hold there: before any cubic is paid
            return None, spent, attempts, maps
        if worst is None:
            worst = worst_vertex(loop, h, rate_points(loop.chain))[1]
        if pieces is not None and depth <= COVER_DEPTH and spent + cost <= budget and key not in maps_only:
            spent += cost
            attempts += 1
            cert = cubic_stable(loop, h, pieces, lo, hi)
            if cert is not None and cert.proved:
                leaves.append((lo, hi, depth))
                continue
            path = _path(loop, h, (lo, hi, depth), worst)
            if path:  # the hardest sub-box below it first, then the shallowest one proved on its path
                found = _shallowest(loop, h, pieces, path, done, budget - spent)
                spent += cost * found[1]
                attempts += found[1]
                if found[0] is not None:
                    stack.extend(other for _, other in path[:found[0] + 1])
                    stack.append(path[found[0]][0])
                    continue
                maps_only.add(key)  # no certificate for its probe: map proofs (and bulk certificates) below it
        elif bulk and depth <= COVER_DEPTH:  # map proofs alone here, but a bulk certificate where the margin is wide
            wide = (bool(seen) and seen[0] > REACH_MAX) if costs[3] else None  # the moving enclosure's rule
            tried, failed = _bulk(loop, h, (lo, hi, depth), worst, failed, pay, wide)
            attempts += tried is not None
            if tried:
                leaves.append((lo, hi, depth))
                continue
        if depth >= MAP_DEPTH:
            return None, spent, attempts, maps
        halves = _split(loop, h, lo, hi, depth, worst, pieces is not None and key not in maps_only)
        if halves is None:
            return None, spent, attempts, maps
        first, second = halves
        if key in maps_only:
            maps_only.update({_key(first[0], first[1]), _key(second[0], second[1])})
        for child in (first, second):
            reach[_key(child[0], child[1])] = 0.0 if costs[3] else REACH_SHRINK * (seen[0] if seen else expected)
            bulk_failed[_key(child[0], child[1])] = failed
        stack.extend((second, first))
    return leaves, spent, attempts, maps


def _shallowest(loop: SampledLoop, h: float, pieces: int, path: list[tuple[Box, Box]], done: set[tuple[bytes, bytes]],
                budget: float) -> tuple[int | None, int]:
    """``(i, attempts)``: the harder half ``path[i][0]`` proved by a cubic certificate of
    ``pieces`` pieces (added to ``done``), ``i`` the smallest found: the box above the path
    is not proved; the probe (the path's sub-box at :data:`COVER_DEPTH`) is tried first,
    then ``path[0][0]`` (where the sub-boxes are easy, one program as the top-down cover),
    then by bisection; where the probe is not proved, the deeper probe ``path[-1][0]``
    (:data:`PROBE_DEPTH`), the result when proved; ``None`` when neither is proved or the
    budget cannot pay an attempt. A certificate of a sub-box holds on every sub-box inside
    it, so along the path the proved ones are the
    deepest: about ``log2`` of the path's length attempts instead of one per halving (the
    budget spent on the failing halvings near the worst vertex,
    ``benchmarks/results/h31v.md``)."""
    cost = cubic_work(loop, pieces)
    deep = len(path) - 1
    last = max((i for i, (b, _) in enumerate(path) if b[2] <= COVER_DEPTH), default=deep)
    attempts, fail, good = 0, -1, last

    def proves(i: int) -> bool | None:  # None: the budget cannot pay it
        nonlocal attempts
        lo, hi, _ = path[i][0]
        if _key(lo, hi) not in done:
            if (attempts + 1) * cost > budget:
                return None
            attempts += 1
            cert = cubic_stable(loop, h, pieces, lo, hi)
            if cert is None or not cert.proved:
                return False
        done.add(_key(lo, hi))
        return True

    order = [last, 0]  # the probe, then the top (where sub-boxes are easy), then bisection
    while True:
        i = order.pop(0) if order else (fail + good) // 2
        proved = proves(i)
        if proved is None:
            return None, attempts
        if proved:
            good = i
        elif i == last:  # the probe: the deeper one at the path's end instead, a leaf if proved
            return (deep if deep != last and proves(deep) else None), attempts
        else:
            fail = i
        if good - fail <= 1:
            return good, attempts


def _next_rung(last: float, failed: float | None, todo: list[float]) -> list[float]:
    """The distances left to try: the ladder's until a rung fails, then the geometric
    mean of the last covered distance ``last`` and the closest failed one while they are
    more than :data:`BISECT` apart."""
    if failed is None:
        return todo
    return [math.sqrt(last * failed)] if last > BISECT * failed else []


def cover_h_max(loop: SampledLoop, h_max: float, h_max_unstable: float, work: float, rtol: float) -> CoverResult:
    """A period closer to ``h_max_unstable`` than ``h_max``, proved mean-square stable
    for every rate of the box by a cover of sub-boxes, each proved by its one-period
    map or a cubic clock certificate (module docstring), within ``work`` units;
    deterministic. Each rung first proves its probe (:func:`probe_box` of the previous
    cover's sub-box holding the worst vertex) with the fewest pieces it needs
    (:func:`rung_pieces`); once a rung fails, the distances are halved geometrically
    between the last covered and the closest failed one (``_next_rung``)."""
    gap = (h_max_unstable - h_max) / h_max_unstable
    boxes: list[Box] = [(np.array(loop.chain.rate_min, dtype=float), np.array(loop.chain.rate_max, dtype=float), 0)]
    spent, attempts, maps = 0.0, 0, 0
    best: tuple[float, int, int | None] | None = None
    rungs: list[tuple[float, bool]] = []
    worst = worst_vertex(loop, h_max_unstable, rate_points(loop.chain))[1]
    cubic = _costs(loop)[3]  # the moving enclosure's route: no rung pieces, bulk certificates where it is too wide
    pieces, hopeless = PIECES[0], 0.0  # no pieces proved the probe at distance `hopeless`: none will closer
    todo, last, failed = list(cover_rungs(gap, rtol)), gap, None
    while todo:
        f = todo.pop(0)
        h = h_max_unstable * (1.0 - f)
        found: int | None = None
        proved: frozenset[tuple[bytes, bytes]] = frozenset()
        if f > hopeless and not cubic:
            home = next(b for b in boxes if np.all((b[0] <= worst) & (worst <= b[1])))
            for depth in (COVER_DEPTH, PROBE_DEPTH):  # the deeper probe where the first fails
                plo, phi, _ = probe_box(loop, h, home, worst, depth)
                found, used, n = rung_pieces(loop, h, plo, phi, max(pieces, 4 if f < FINE_FROM else 2), work - spent)
                spent += used
                attempts += n
                if found is not None:
                    proved = frozenset({_key(plo, phi)})
                    break
            hopeless = f if found is None else hopeless
        share = 1.0 if f <= 0.9 * rtol else RUNG_SHARE  # the target's rung may spend all that is left
        leaves, used, n, k = cover_box(loop, h, found, boxes, share * (work - spent), worst, proved)
        spent += used
        attempts += n
        maps += k
        rungs.append((h, leaves is not None))
        if leaves is None:
            failed = f if failed is None else max(failed, f)
        else:
            best, boxes, last = (h, len(leaves), found), leaves, f
            pieces = found if found is not None else pieces
        todo = _next_rung(last, failed, todo)
    if best is None:
        return CoverResult(None, 0, None, spent, attempts, maps, tuple(rungs))
    return CoverResult(best[0], best[1], best[2], spent, attempts, maps, tuple(rungs))
