"""Where the proved lower bounds (:mod:`~ftc_verify.analysis.lower_bound`) look: the candidate
rate vectors, and on small loops a vertex ascent on the float gain."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..model.system import Matrix
from .closedloop import ClosedLoop
from .conditioning import stationary_distribution
from .exact import written_box
from .moments.stability import generator_size

__all__ = ["ASCENT_MARGIN", "ASCENT_PASSES", "ASCENT_RATES", "ASCENT_ROWS", "candidate_rates", "stationary_at",
           "vertex_ascent"]


def candidate_rates(loop: ClosedLoop, worst: Matrix | None, ascended: tuple[Matrix, float] | None = None) -> list[Matrix]:
    """The rate vectors :func:`~ftc_verify.analysis.lower_bound.gain_lower_bound` tries first:
    just inside the box's lowest and highest corners (as written), its centre, and ``worst``
    (the worst spectral-abscissa vertex) clipped into the box, and ``ascended`` (the vertex
    of :func:`vertex_ascent`); no duplicates."""
    chain = loop.chain
    lo, hi = written_box(chain.rate_min, chain.rate_max)
    inner_lo = np.where(lo < hi, np.nextafter(lo, np.inf), lo)  # strictly inside the box as written
    inner_hi = np.where(lo < hi, np.nextafter(hi, -np.inf), hi)
    points = [inner_lo, 0.5 * (lo + hi), inner_hi]
    if worst is not None:
        points.append(np.clip(np.asarray(worst, dtype=float), inner_lo, inner_hi))
    if ascended is not None:
        points.append(ascended[0])
    out: list[Matrix] = []
    for p in points:
        if not any(np.array_equal(p, o) for o in out):
            out.append(p)
    return out


def stationary_at(Q: Matrix) -> Matrix | None:
    """:func:`~ftc_verify.analysis.conditioning.stationary_distribution` if the balance equations hold."""
    pi = stationary_distribution(Q)
    return pi if np.all(np.isfinite(pi)) and np.abs(Q.T @ pi).max() < 1e-9 * max(1.0, np.abs(Q).max()) else None


#: The vertex ascent runs on loops of at most this many moment rows (``S n (n + 1) / 2``)...
ASCENT_ROWS = 120
#: ... with at most this many free rates (each pass one float comparison per free rate).
ASCENT_RATES = 16
#: Sweeps of the ascent at most.
ASCENT_PASSES = 2
#: A flip is taken when the float gain there is above the best so far by this (relative):
#: a comparison at that level, then a bisection of this width from it.
ASCENT_MARGIN = 1e-4


def vertex_ascent(loop: ClosedLoop, A: Sequence[Matrix], start: Matrix | None,
                  upper: float | None) -> tuple[Matrix, float] | None:
    """A vertex of the box (strictly inside it as written) where the float gain of the loop
    with state matrices ``A`` (``loop``'s ``Bw``, ``Cz``) is large: from the vertex nearest
    ``start`` (default the highest rates; its gain by bisection from ``upper``), one free
    rate at a time flipped to its other end, kept when the gain there exceeds the best so
    far by :data:`ASCENT_MARGIN` (:func:`~ftc_verify.analysis.lower_bound.exceeds`, then a
    bisection from that level, :func:`~ftc_verify.analysis.lower_bound.float_gain`); at
    most :data:`ASCENT_PASSES` sweeps. Returns the vertex and its float gain (the upper end
    of a bisection of relative width :data:`ASCENT_MARGIN`); ``None`` above :data:`ASCENT_ROWS` rows or
    :data:`ASCENT_RATES` free rates, or when the start has no gain. A local search on
    floats: a candidate of :func:`~ftc_verify.analysis.lower_bound.gain_lower_bound`,
    whose bound is proved (or not) like any other's."""
    from .lower_bound import exceeds, float_gain  # that module imports this one

    def gain(rates: Matrix, level: float | None) -> float | None:
        found = float_gain(A, loop.Bw, loop.Cz, loop.chain.generator(rates), upper=upper, above=level,
                           rtol=ASCENT_MARGIN, climb=10 * ASCENT_MARGIN, converge=False)
        return None if found is None else found[0]

    lo, hi = written_box(loop.chain.rate_min, loop.chain.rate_max)
    free = np.flatnonzero(lo < hi)
    if generator_size(loop) > ASCENT_ROWS or not 0 < free.size <= ASCENT_RATES:
        return None
    inner_lo, inner_hi = np.nextafter(lo, np.inf), np.nextafter(hi, -np.inf)
    mid = 0.5 * (lo + hi)
    centre = mid if start is None else np.asarray(start, dtype=float)
    top = (centre >= mid) if start is not None else np.ones(lo.shape, dtype=bool)
    vertex = np.where(lo < hi, np.where(top, inner_hi, inner_lo), lo)
    best = gain(vertex, None)
    if best is None:
        return None
    for _ in range(ASCENT_PASSES):
        improved = False
        for k in free:
            trial = vertex.copy()
            trial.flat[k] = inner_lo.flat[k] if trial.flat[k] == inner_hi.flat[k] else inner_hi.flat[k]
            level = best * (1.0 + ASCENT_MARGIN)
            if not exceeds(A, loop.Bw, loop.Cz, loop.chain.generator(trial), level):
                continue
            found = gain(trial, level)
            if found is not None and found > best:
                best, vertex, improved = found, trial, True
        if not improved:
            break
    return vertex, best
