r"""Grid bookkeeping of the vectorised energies (all paths of one horizon at once).

The communication grid of a path (:func:`~ftc_verify.simulation.paths.communication_grid`)
is the *regular grid* ``reg[k] = k step`` (``k = 0..K``, the last point the horizon) with
the path's jump times added, a regular point within
:func:`~ftc_verify.simulation.spec.grid_snap_tolerance` of a jump replaced by it. The
trapezoidal rule of :func:`~ftc_verify.simulation.records.l2_norm` gives point :math:`t_g`
the weight :math:`\omega_g = (t_{g+1} - t_{g-1}) / 2` (halved at the ends), so

.. math::

    E_y = \sum_g \omega_g |y(t_g)|^2, \qquad E_w = \sum_g \omega_g |w(t_g)|^2 .

Vocabulary: *special intervals* ``(p, I)`` (regular interval ``I`` of path ``p`` that
contains a jump, is next to a regular point replaced by a jump, or is not full-length),
their *pieces* (split at the interior jumps) and *special points* (ends of special
intervals, whose weight or mode may differ from the standard one). Everything here is
index arithmetic on sorted integer keys ``I * P + p``; the :math:`E_w` terms of the jump
points and special points are added here, the :math:`E_y` terms while stepping
(:mod:`ftc_verify.simulation.vectorised`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ._common import PathArrays, full_intervals
from .paths import ChainPath, communication_grid
from .spec import grid_snap_tolerance

__all__ = ["RegularGrid", "Jumps", "Items", "Pieces", "Points", "regular_grid", "jumps", "items", "pieces",
           "points", "lookup", "unique"]


def unique(a: np.ndarray) -> np.ndarray:
    """Sorted unique values (sort based; faster than hashing for large integer arrays)."""
    if a.size == 0:
        return a
    s = np.sort(a)
    keep = np.empty(s.size, dtype=bool)
    keep[0] = True
    np.not_equal(s[1:], s[:-1], out=keep[1:])
    return s[keep]


def lookup(keys_sorted: np.ndarray, query: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Positions of ``query`` in the sorted ``keys_sorted`` and whether they are there."""
    if keys_sorted.size == 0:
        return np.zeros(query.size, dtype=np.int64), np.zeros(query.size, dtype=bool)
    loc = np.minimum(np.searchsorted(keys_sorted, query), keys_sorted.size - 1)
    return loc, keys_sorted[loc] == query


@dataclass(frozen=True)
class RegularGrid:
    """The jump-free grid, its standard trapezoid weights and the disturbance on it."""

    reg: np.ndarray  # (K+1,) points
    dreg: np.ndarray  # (K,) interval lengths
    wt_std: np.ndarray  # (K+1,) trapezoid weights
    full: np.ndarray  # (K,) full-length intervals
    Wreg: np.ndarray  # (K+1, nw) w at the points
    w2reg: np.ndarray  # (K+1,) |w|^2 at the points

    @property
    def K(self) -> int:
        """Number of regular intervals."""
        return int(self.reg.size - 1)


def regular_grid(m: int, horizon: float, step: float, wfun: Callable[[np.ndarray], np.ndarray]) -> RegularGrid:
    """The grid of a path without jumps (same floats as :func:`communication_grid`)."""
    dummy = ChainPath(np.zeros(1), np.zeros(1, dtype=np.int64), np.zeros(1, dtype=np.int64), np.zeros((m, m)), horizon)
    reg = communication_grid(dummy, step)[0]
    dreg = np.diff(reg)
    wt_std = np.zeros(reg.size)
    wt_std[:-1] += 0.5 * dreg
    wt_std[1:] += 0.5 * dreg
    Wreg = wfun(reg)
    return RegularGrid(reg, dreg, wt_std, full_intervals(reg, step), Wreg, np.sum(Wreg ** 2, axis=1))


@dataclass(frozen=True)
class Jumps:
    """All jumps (sorted by path then time) and the regular points they replace."""

    P: int
    jt: np.ndarray  # times
    jp: np.ndarray  # path of each jump
    jd_new: np.ndarray  # dynamics id after the jump
    jd_old: np.ndarray  # dynamics id before the jump
    anchor: np.ndarray  # regular point a jump replaces (-1: none)
    interior: np.ndarray  # jumps that are no grid point of their own special interval's ends
    j_interval: np.ndarray  # special interval of each jump
    ep_key: np.ndarray  # sorted keys k * P + p of the replaced regular points
    ep_t: np.ndarray  # their replacing jump times
    ep_d: np.ndarray  # and dynamics ids

    def replaced(self, reg: np.ndarray, p: np.ndarray, k: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For regular points ``k`` of paths ``p``: replaced by a jump?, the grid point's
        time, and the replacing jump's ``d`` (valid where replaced)."""
        loc, found = lookup(self.ep_key, k * self.P + p)
        t = reg[k].copy()
        t[found] = self.ep_t[loc[found]]
        return found, t, self.ep_d[loc] if self.ep_d.size else np.zeros(p.size, dtype=np.int64)


def jumps(pa: PathArrays, seg_d: np.ndarray, grid: RegularGrid, step: float) -> Jumps:
    """Locate every jump on the regular grid; the first jump within
    :func:`~ftc_verify.simulation.spec.grid_snap_tolerance` of a regular point (not the
    ends) replaces it."""
    P, K, reg = pa.count.size, grid.K, grid.reg
    tol = grid_snap_tolerance(step)
    is_jump = np.ones(pa.times.size, dtype=bool)
    is_jump[pa.off] = False
    jidx = np.flatnonzero(is_jump)
    jt = pa.times[jidx]
    jp = np.repeat(np.arange(P), pa.count - 1)
    jd_new = seg_d[jidx]
    kj = np.searchsorted(reg, jt, side="right") - 1  # reg[kj] <= jt < reg[kj + 1]
    near_left = (jt - reg[kj] <= tol) & (kj > 0)
    near_right = (reg[kj + 1] - jt <= tol) & (kj + 1 < K)
    anchor = np.where(near_right, kj + 1, np.where(near_left, kj, -1))
    anchored = anchor >= 0
    akey = anchor * P + jp
    prev_same = np.zeros(jt.size, dtype=bool)
    prev_same[1:] = anchored[1:] & anchored[:-1] & (akey[1:] == akey[:-1])
    endpoint = anchored & ~prev_same  # first jump near a regular point: the grid point there
    eo = np.argsort(akey[endpoint])
    return Jumps(P, jt, jp, jd_new, seg_d[jidx - 1], anchor, ~endpoint, np.where(anchored, anchor, kj),
                 akey[endpoint][eo], jt[endpoint][eo], jd_new[endpoint][eo])


@dataclass(frozen=True)
class Items:
    """Special intervals ``(I, p)``, sorted by step then path."""

    key: np.ndarray  # I * P + p
    I: np.ndarray
    p: np.ndarray
    rep: np.ndarray  # start point replaced by a jump?
    t0: np.ndarray  # start time
    repd: np.ndarray  # dynamics id of the replacing jump
    t1: np.ndarray  # end time


def items(jmp: Jumps, grid: RegularGrid) -> Items:
    """The special intervals: those with an interior jump, both sides of a replaced
    regular point, and every path's intervals that are not full-length."""
    P = jmp.P
    endpoint = ~jmp.interior
    ep_p, ep_a = jmp.jp[endpoint], jmp.anchor[endpoint]
    in_key = jmp.j_interval[jmp.interior] * P + jmp.jp[jmp.interior]
    parts = [in_key, (ep_a - 1) * P + ep_p, ep_a * P + ep_p]
    notfull = np.flatnonzero(~grid.full)
    if notfull.size:
        parts.append((notfull[:, None] * P + np.arange(P)[None, :]).ravel())
    key = unique(np.concatenate(parts))
    it_I, it_p = np.divmod(key, P)
    rep, t0, repd = jmp.replaced(grid.reg, it_p, it_I)
    _, t1, _ = jmp.replaced(grid.reg, it_p, it_I + 1)
    return Items(key, it_I, it_p, rep, t0, repd, t1)


@dataclass(frozen=True)
class Pieces:
    """Pieces of the special intervals: per item the start piece, then one piece per
    interior jump in time order. ``d`` of the start pieces is filled while stepping."""

    count: np.ndarray  # (nitem,) pieces per item
    off: np.ndarray  # (nitem,) first piece of each item
    last: np.ndarray  # (nitem,) last piece of each item
    in_pos: np.ndarray  # piece of each interior jump
    d: np.ndarray  # (nsub,) dynamics id (mutable: start pieces set per chunk)
    dt: np.ndarray  # (nsub,) lengths
    w: np.ndarray  # (nsub, nw) w held over the piece: its value at the period's sample
    wt: np.ndarray  # (nsub,) trapezoid weights of the interior jump points
    item: np.ndarray  # (nsub,) special interval of each piece


def pieces(jmp: Jumps, it: Items, wfun: Callable[[np.ndarray], np.ndarray], Ew: np.ndarray) -> Pieces:
    """Split the special intervals at their interior jumps (consecutive in the jump
    order) and add the interior jump points' :math:`E_w` terms to ``Ew``. Every piece
    holds the disturbance of its interval's start (the sample)."""
    in_key = jmp.j_interval[jmp.interior] * jmp.P + jmp.jp[jmp.interior]
    in_item, found = lookup(it.key, in_key)
    if not np.all(found):  # pragma: no cover - a bookkeeping error, not an input error
        raise RuntimeError("energies_reference: interior jump outside every special interval")
    count = 1 + np.bincount(in_item, minlength=it.key.size)
    off = (np.cumsum(count) - count).astype(np.int64)  # empty when no interval is special
    last = off + count - 1
    nsub = int(count.sum())
    run_start = np.ones(in_item.size, dtype=bool)
    run_start[1:] = in_item[1:] != in_item[:-1]
    first_of_run = np.maximum.accumulate(np.where(run_start, np.arange(in_item.size), 0)) if in_item.size else in_item
    in_pos = off[in_item] + 1 + (np.arange(in_item.size) - first_of_run)
    t0 = np.empty(nsub)
    t0[off] = it.t0
    t0[in_pos] = jmp.jt[jmp.interior]
    d = np.empty(nsub, dtype=np.int64)
    d[in_pos] = jmp.jd_new[jmp.interior]
    t1 = np.empty(nsub)
    t1[:-1] = t0[1:]
    t1[last] = it.t1
    dt = t1 - t0
    item = np.repeat(np.arange(it.key.size), count)
    w = wfun(t0[off])[item] if nsub else wfun(t0)
    wt = np.zeros(nsub)
    wt[in_pos] = 0.5 * (dt[in_pos - 1] + dt[in_pos])
    w_in = wfun(t0[in_pos])  # the physical w at the interior jump points, for E_w
    Ew += np.bincount(jmp.jp[jmp.interior], wt[in_pos] * np.sum(w_in ** 2, axis=1), minlength=jmp.P)
    return Pieces(count, off, last, in_pos, d, dt, w, wt, item)


@dataclass(frozen=True)
class Points:
    """Special points (ends of special intervals), sorted by point then path."""

    k: np.ndarray  # regular point index
    p: np.ndarray  # path
    rep: np.ndarray  # replaced by a jump?
    repd: np.ndarray  # dynamics id of the replacing jump
    weight: np.ndarray  # trapezoid weight


def points(jmp: Jumps, it: Items, pc: Pieces, grid: RegularGrid, wfun: Callable[[np.ndarray], np.ndarray],
           Ew: np.ndarray) -> Points:
    """The special points with their true weights; their :math:`E_w` terms replace the
    standard ones in ``Ew``."""
    P, K = jmp.P, grid.K
    spk = unique(np.concatenate((it.key, it.key + P)))
    spt_k, spt_p = np.divmod(spk, P)
    rep, spt_t, repd = jmp.replaced(grid.reg, spt_p, spt_k)
    locL, fL = lookup(it.key, spk - P)
    locR, fR = lookup(it.key, spk)
    fL &= spt_k > 0
    fR &= spt_k < K
    dreg = grid.dreg
    dtL = np.where(fL, pc.dt[pc.last[locL]], np.where(spt_k > 0, dreg[np.maximum(spt_k - 1, 0)], 0.0))
    dtR = np.where(fR, pc.dt[pc.off[locR]], np.where(spt_k < K, dreg[np.minimum(spt_k, K - 1)], 0.0))
    weight = 0.5 * (dtL + dtR)
    w2sp = np.sum(wfun(spt_t) ** 2, axis=1)
    Ew += np.bincount(spt_p, weight * w2sp - grid.wt_std[spt_k] * grid.w2reg[spt_k], minlength=P)
    return Points(spt_k, spt_p, rep, repd, weight)
