r"""Vectorised energies of the sampled-data loop: all paths advanced together.

Per path :math:`E_y = \int_0^T |y|^2 dt` and :math:`E_w = \int_0^T |w|^2 dt` by the
trapezoidal rule of :func:`ftc_verify.simulation.records.l2_norm` on the communication grid,
for the loop of :mod:`ftc_verify.simulation.reference` (the fast path for Monte Carlo, no
trajectories kept). On the augmented state :math:`z = (x, x_c)`, :math:`z_0 = (x_0, 0)`,
every grid interval of length :math:`h` in dynamics id :math:`d` (joint mode
:math:`(i, j)`, controller entry :math:`e`, one :math:`\Delta` value) is

.. math::

    z_{k+1} = F_d(h)\, z_k + G_d(h)\, w_k, \qquad
    F_d = \begin{bmatrix} \Phi + \Gamma B D_{c,e} M_i & \Gamma B C_{c,e} \\
                          \Gamma_c M_i & \Phi_c \end{bmatrix}, \qquad
    G_d = \begin{bmatrix} \Gamma D_i \\ 0 \end{bmatrix}, \qquad
    y_k = [C_i\ \ 0]\, z_k,

(``ftc_verify.simulation._vectorised_maps``), which for static state feedback
(:math:`n_c = 0`) is :math:`x_{k+1} = (\Phi + \Gamma B K_j) x_k + \Gamma D_i w_k`, and

.. math::

    E_y = \sum_g \omega_g |y(t_g)|^2, \qquad \omega_g = (t_{g+1} - t_{g-1}) / 2
    \ \text{(halved ends)}.

All paths advance together over the regular points ``k step``
(``ftc_verify.simulation._vectorised_grid`` for the bookkeeping):

* an interval ``[k step, (k+1) step]`` without a jump is one map :math:`F_d, G_d` at
  ``h = step``, one table entry per dynamics id. With few ids, all paths take one matrix
  product ``[[G_d, F_d], [0, C_d]] @ [w_k; z]`` over all ids and gather their own id's
  rows (next state and present output at once); with many ids (``Delta`` kind
  ``random``) a gathered batched product;
* an interval cut by jumps (or a shorter last interval) is the composition of the maps of
  its pieces, the plant switching at the jumps while the controller's output, entry and
  input and the disturbance stay those of the interval's start, the sample
  (``held_maps`` of ``ftc_verify.simulation._vectorised_maps``:
  :math:`z^+ = F_a z + F_b z_0 + g`); their exponentials are made in batches per chunk of
  steps (:func:`~ftc_verify.simulation.discretise.phi_gamma`; the full-step tables come
  from it too, so this path never calls :func:`scipy.linalg.expm`, agreeing with it to
  rounding); the states at the jump points, needed for their trapezoid terms, are
  recomputed from the stored state at the interval's start;
* the trapezoid terms of the grid points whose weight or mode differs from the regular
  ones (next to a cut interval) are taken from stored states, the others are summed as
  the steps go.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import cast

import numpy as np
from numpy.typing import ArrayLike

from ..controllers.controller import Controller
from ..model.system import FTCSystem, Matrix
from . import _vectorised_grid as eg
from ._common import (
    PathArrays,
    check_controller,
    delta_key,
    initial_state,
    path_arrays,
    path_list,
)
from ._vectorised_maps import Tables, full_maps, held_maps, tables
from .delta import DeltaSchedule, delta_segments, delta_shapes
from .paths import ChainPath, disturbance as disturbance_fn
from .records import DIVERGENCE_BOUND
from .spec import SimulationSpec, spec_from
from ..errors import ValidationError

__all__ = ["energies_reference", "output_peaks_reference"]

#: Joint tables up to this size use the "all modes, then select" kernel.
_SELECT_LIMIT = 16
#: Target number of doubles of one chunk of the state history.
_CHUNK_DOUBLES = 4_000_000


def energies_reference(
    system: FTCSystem,
    controller: Controller,
    paths: ChainPath | Sequence[ChainPath],
    *,
    spec: SimulationSpec | None = None,
    step: float | None = None,
    disturbance: str | None = None,
    delta: DeltaSchedule | str | None = None,
    x0: ArrayLike | None = None,
    rng: np.random.Generator | None = None,
    quadrature: str = "grid",
) -> tuple[np.ndarray, np.ndarray]:
    r"""Per path :math:`\int_0^T |y|^2 dt` and :math:`\int_0^T |w|^2 dt` of the sampled loop.

    Same loop, grid, ``Delta`` draws (each path's own stream; ``rng``, default
    :meth:`~ftc_verify.simulation.spec.SimulationSpec.generator`, for paths without one,
    in path order) and trapezoidal rule as
    :func:`~ftc_verify.simulation.reference.simulate_reference` followed by
    ``record.y_norm ** 2, record.w_norm ** 2``, without keeping trajectories (module
    docstring). The parameters are those of ``simulate_reference`` (the shorthand
    keywords without ``seed``); ``controller`` is validated by :meth:`Controller.check`;
    paths may have different horizons. A regular point within
    :func:`~ftc_verify.simulation.spec.grid_snap_tolerance` of a jump is replaced by the
    jump, as in :func:`~ftc_verify.simulation.paths.communication_grid`.
    ``quadrature="samples"``: ``Ey`` is the trapezoidal sum over the control samples
    ``k step`` only (:func:`~ftc_verify.simulation.paths.sample_points`; the horizon is
    the last point), :math:`\sum_k \omega_k |y(t_k)|^2` with the regular weights -- the
    quantity whose expectation
    :func:`~ftc_verify.analysis.moments.sampled_energy.sample_trapezoid` gives exactly;
    ``Ew`` is unchanged.

    Returns
    -------
    (Ey, Ew) : two (P,) arrays
        ``Ey`` is ``inf`` for a path that diverged: the loop state ``(x, x_c)`` left the
        ball of radius ``DIVERGENCE_BOUND`` (or was not finite) at a grid point, the test
        ``simulate_reference`` stops a path on.
    """
    if quadrature not in ("grid", "samples"):
        raise ValidationError(f"quadrature: {quadrature!r} is not 'grid' or 'samples'")
    spec = spec_from(spec, {"step": step, "disturbance": disturbance, "delta": delta, "x0": x0})
    Ey, Ew, _, _ = _engine(system, controller, paths, spec, rng, peaks=False, samples_only=quadrature == "samples")
    return Ey, Ew


def output_peaks_reference(
    system: FTCSystem,
    controller: Controller,
    paths: ChainPath | Sequence[ChainPath],
    *,
    spec: SimulationSpec,
    rng: np.random.Generator | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    r"""Per path the largest :math:`|y|^2` and the largest value of every output channel
    :math:`y_r` over the grid points of the sampled loop.

    The loop, grid, ``Delta`` draws and arguments of :func:`energies_reference`; the
    output at a grid point :math:`t_g` is :math:`y(t_g) = C_i x(t_g)` with :math:`i` the
    true mode of the interval starting there (at the horizon: of the last interval), as
    in the records of :func:`~ftc_verify.simulation.reference.simulate_reference`, so that
    ``max_g |record.y[g]|^2`` and ``record.y.max(axis=0)`` are what this returns, without
    keeping trajectories (``ftc_verify.risk`` passes a system whose ``C`` are its
    envelope's rows).

    Returns
    -------
    (peak_sq, peak) : (P,) and (ny, P) arrays
        ``inf`` (every entry) for a path that diverged (as in :func:`energies_reference`).
    """
    _, _, peak_sq, peak = _engine(system, controller, paths, spec, rng, peaks=True)
    return peak_sq, peak


def _engine(system: FTCSystem, controller: Controller, paths: ChainPath | Sequence[ChainPath],
            spec: SimulationSpec, rng: np.random.Generator | None, peaks: bool, samples_only: bool = False
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(Ey, Ew, peak_sq, peak)`` of :func:`energies_reference` and
    :func:`output_peaks_reference` (the peaks are tracked only with ``peaks``)."""
    step = spec.step
    controller = check_controller(system, controller)
    plist = path_list(paths)
    pa = path_arrays(system, plist)
    schedule = spec.schedule
    x0v = initial_state(system, spec.x0)
    wfun = disturbance_fn(spec.disturbance, system.dims[3])
    gen = spec.generator(rng)
    tab, seg_d = _dynamics_ids(system, controller, plist, pa, schedule, gen)
    z0 = np.concatenate((x0v, np.zeros(controller.n_c)))
    P = len(plist)
    Ey = np.zeros(P)
    Ew = np.zeros(P)
    ny = system.dims[2]
    peak_sq, peak = np.full(P, -np.inf), np.full((ny, P), -np.inf)
    with np.errstate(over="ignore", invalid="ignore"):  # a diverging path: caught below
        for hz in np.unique(pa.horizon):
            sel = np.flatnonzero(pa.horizon == hz)
            if sel.size == P:
                sub_pa, sub_seg_d = pa, seg_d
            else:
                sub_pa, sub_seg_d = pa.select(sel), seg_d[pa.segments(sel)]
            Ey[sel], Ew[sel], ps, pk = _same_horizon(system, tab, sub_pa, sub_seg_d, float(hz), step, wfun, z0,
                                                     samples_only, peaks)
            if ps is not None and pk is not None:
                peak_sq[sel], peak[:, sel] = ps, pk
    return Ey, Ew, peak_sq, peak


def _dynamics_ids(system: FTCSystem, controller: Controller, plist: list[ChainPath], pa: PathArrays,
                  schedule: DeltaSchedule, gen: np.random.Generator) -> tuple[Tables, np.ndarray]:
    """The tables and the dynamics id of every segment. Kind ``random``: one id per
    segment; the deterministic kinds depend on the segment index only, so one
    :func:`delta_segments` call on the longest path gives the distinct values, and the
    ids are ``(value, joint mode)``."""
    m = system.m
    s1, s2 = delta_shapes(system)
    if schedule.kind == "random":
        flat = [d for p in plist for d in delta_segments(system, p, schedule, gen)]
        d1 = None if s1 is None else np.stack([cast(Matrix, d[0]) for d in flat])
        d2 = None if s2 is None else np.stack([cast(Matrix, d[1]) for d in flat])
        seg_d = np.arange(pa.times.size)
        return tables(system, controller, pa.true, d1, pa.true, pa.fdi, d2, seg_d), seg_d
    segs0 = delta_segments(system, plist[int(np.argmax(pa.count))], schedule, gen)
    keymap: dict[tuple[bytes, bytes], int] = {}
    key_of = np.array([keymap.setdefault(delta_key(*d), len(keymap)) for d in segs0], dtype=np.int64)
    first = {v: k for k, v in reversed(list(enumerate(key_of.tolist())))}
    values = [segs0[first[v]] for v in range(len(keymap))]
    nk = len(values)
    a_key, a_true = np.divmod(np.arange(nk * m), m)
    d_key, d_joint = np.divmod(np.arange(nk * m * m), m * m)
    d_true, d_fdi = np.divmod(d_joint, m)
    d1 = None if s1 is None else np.stack([values[k][0] for k in a_key])
    d2 = None if s2 is None else np.stack([values[k][1] for k in d_key])
    tab = tables(system, controller, a_true, d1, d_true, d_fdi, d2, d_key * m + d_true)
    seg_index = np.arange(pa.times.size) - np.repeat(pa.off, pa.count)  # local segment index
    return tab, key_of[seg_index] * m * m + pa.true * m + pa.fdi


def _same_horizon(system: FTCSystem, tab: Tables, pa: PathArrays, seg_d: np.ndarray, horizon: float,
                  step: float, wfun: Callable[[np.ndarray], np.ndarray],
                  z0: np.ndarray, samples_only: bool = False, peaks: bool = False
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
    """The engine for paths sharing one horizon (vocabulary of
    ``ftc_verify.simulation._vectorised_grid``); returns ``(Ey, Ew, peak_sq, peak)``
    (the peaks ``None`` without ``peaks``)."""
    grid = eg.regular_grid(system.m, horizon, step, wfun)
    Ew = np.full(pa.count.size, float(np.sum(grid.wt_std * grid.w2reg)))
    jmp = eg.jumps(pa, seg_d, grid, step)
    it = eg.items(jmp, grid)
    pc = eg.pieces(jmp, it, wfun, Ew)
    pt = eg.points(jmp, it, pc, grid, wfun, Ew)
    stepper = _Stepper(tab, pa, seg_d, grid, jmp, it, pc, pt, step, z0)
    stepper.samples_only = samples_only
    stepper.peaks = _Peaks(tab.Cz.shape[1], jmp.P) if peaks else None
    Ey = stepper.run()
    gone = ~(stepper.zmax <= DIVERGENCE_BOUND ** 2)
    Ey[gone] = np.inf  # diverged (or NaN): records would stop there
    if stepper.peaks is None:
        return Ey, Ew, None, None
    stepper.peaks.sq[gone] = np.inf
    stepper.peaks.signed[:, gone] = np.inf
    return Ey, Ew, stepper.peaks.sq, stepper.peaks.signed


class _Peaks:
    """Running maxima per path of :math:`|y|^2` (``sq``) and of every channel (``signed``)."""

    def __init__(self, ny: int, P: int) -> None:
        self.sq = np.full(P, -np.inf)
        self.signed = np.full((ny, P), -np.inf)

    def take(self, y: np.ndarray, where: np.ndarray | None = None) -> None:
        """Outputs ``y`` (``(ny, P')``) of the paths ``where`` (all paths when ``None``;
        a path may repeat)."""
        if where is None:
            np.maximum(self.sq, np.sum(np.square(y), axis=0), out=self.sq)
            np.maximum(self.signed, y, out=self.signed)
            return
        np.maximum.at(self.sq, where, np.sum(np.square(y), axis=0))
        for r in range(y.shape[0]):
            np.maximum.at(self.signed[r], where, y[r])


@dataclass(frozen=True)
class _ChunkMaps:
    """Maps of the pieces of a chunk's special intervals (pieces ``s0..``,
    ``z -> Fa z + Fb z_0 + g`` with ``z_0`` the state at the interval's sample:
    :func:`~ftc_verify.simulation._vectorised_maps.held_maps`) and their compositions over
    each interval (``z(start) -> Ftot z + gtot``)."""

    Fa: np.ndarray
    Fb: np.ndarray
    gs: np.ndarray
    Ftot: np.ndarray
    gtot: np.ndarray
    cnt: np.ndarray  # pieces per interval
    s0: int


class _Stepper:
    """Time stepping of one horizon, one chunk of regular steps at a time.

    Mutable by design: it owns the reused buffers -- the state ``B`` with rows
    ``[w; z; y]`` per path (two buffers swapped every step), the dynamics id of every path
    at the chunk's points ``dtab``, the states stored at special points and special
    interval starts -- and accumulates ``Ey``.
    """

    def __init__(self, tab: Tables, pa: PathArrays, seg_d: np.ndarray, grid: eg.RegularGrid, jmp: eg.Jumps,
                 it: eg.Items, pc: eg.Pieces, pt: eg.Points, step: float, z0: np.ndarray) -> None:
        self.tab, self.grid, self.it, self.pc, self.pt = tab, grid, it, pc, pt
        P, K, nz = jmp.P, grid.K, tab.nz
        self.P, self.K, self.nz = P, K, nz
        self.nw = grid.Wreg.shape[1]
        self.ny = tab.Cz.shape[1]
        self.rows = nz + self.ny
        self.Ffull, self.Gfull = full_maps(tab, step)
        self.select = tab.d_true.size <= _SELECT_LIMIT
        if self.select:
            self._select_kernel()
        j0 = np.searchsorted(grid.reg, jmp.jt, side="left")  # first regular point at or after the jump
        jorder = np.argsort(j0, kind="stable")
        self.j0s, self.jps, self.jdelta = j0[jorder], jmp.jp[jorder], (jmp.jd_new - jmp.jd_old)[jorder]
        self.d_cur = seg_d[pa.off].astype(np.int64)  # d at the chunk's first point
        self.L = max(1, min(K, _CHUNK_DOUBLES // max(1, P * self.rows)))
        self.Ba = np.empty((self.nw + nz + self.ny, P))
        self.Ba[self.nw:self.nw + nz] = z0[:, None]
        self.Bb = np.empty_like(self.Ba)
        self.Ey = np.zeros(P)
        self.samples_only = False  # Ey over the control samples only (energies_reference's quadrature)
        self.peaks: _Peaks | None = None
        self.zmax = np.zeros(P)  # largest |z|^2 at the regular points (divergence test)
        self.dtab = np.empty((self.L + 1, P), dtype=np.int64)
        self.idx = np.empty((self.L, self.rows, P), dtype=np.int64) if self.select else None
        self.it_x = np.empty((it.key.size, nz))  # z at the start point of each special interval
        self.spt_x = np.empty((pt.k.size, nz))  # z at the special points
        self.spt_d = np.empty(pt.k.size, dtype=np.int64)
        self.sp_bounds = np.searchsorted(pt.k, np.arange(K + 2))
        self.it_bounds = np.searchsorted(it.I, np.arange(K + 1))

    def _select_kernel(self) -> None:
        """Rows of ``Faug`` per id ``d``: ``[G_d | F_d]`` (the next state) and
        ``[0 | C_true(d)]`` (the output now)."""
        tab, nz, nw, rows, P = self.tab, self.nz, self.nw, self.rows, self.P
        Dn = tab.d_true.size
        Faug = np.zeros((Dn, rows, nw + nz))
        Faug[:, :nz, :nw] = self.Gfull
        Faug[:, :nz, nw:] = self.Ffull
        Faug[:, nz:, nw:] = tab.Cz[tab.d_true]
        self.Faug = Faug.reshape(Dn * rows, nw + nz)
        self.Y = np.empty((Dn * rows, P))
        self.idx_off = (np.arange(rows) * P)[:, None] + np.arange(P)[None, :]  # (rows, P)

    def run(self) -> np.ndarray:
        """Step every chunk, then add the last point and the special points; ``Ey``."""
        K, L = self.K, self.L
        npts = 1
        for c0 in range(0, K, L):
            c1 = min(K, c0 + L)
            p1 = c1 + 1 if c1 == K else c1  # points c0 .. p1-1, intervals c0 .. c1-1
            npts = p1 - c0
            self._chunk_modes(c0, c1, p1)
            i0, i1 = int(self.it_bounds[c0]), int(self.it_bounds[c1])
            maps = self._composite(c0, i0, i1) if i1 > i0 else None
            if self.idx is not None:
                np.add(self.dtab[:c1 - c0, None, :] * (self.rows * self.P), self.idx_off[None],
                       out=self.idx[:c1 - c0])
            self._steps(c0, c1, i0, maps)
            if maps is not None:
                self._interior(i0, i1, maps)
        self._last_point(npts)
        return self.Ey

    def _chunk_modes(self, c0: int, c1: int, p1: int) -> None:
        """``d`` of every path at the chunk's regular points (``dtab``), at the next
        chunk's first point (``d_cur``) and at the chunk's special points (``spt_d``)."""
        dtab, jps, jdelta = self.dtab, self.jps, self.jdelta
        npts = p1 - c0
        dtab[0] = self.d_cur
        lo = np.searchsorted(self.j0s, c0 + 1)
        bnd = np.searchsorted(self.j0s, np.arange(c0 + 1, c1 + 2), side="right")
        for r in range(1, npts):
            dtab[r] = dtab[r - 1]
            hi = bnd[r - 1]
            if hi > lo:
                np.add.at(dtab[r], jps[lo:hi], jdelta[lo:hi])
                lo = hi
        if p1 == c1:
            self.d_cur = dtab[npts - 1].copy()
            hi = bnd[npts - 1]
            np.add.at(self.d_cur, jps[lo:hi], jdelta[lo:hi])
        pt = self.pt
        a0, a1 = self.sp_bounds[c0], self.sp_bounds[p1]
        self.spt_d[a0:a1] = np.where(pt.rep[a0:a1], pt.repd[a0:a1], dtab[pt.k[a0:a1] - c0, pt.p[a0:a1]])

    def _composite(self, c0: int, i0: int, i1: int) -> _ChunkMaps:
        """Maps of the pieces of the chunk's special intervals ``i0:i1`` and their
        compositions ``z(start) -> z(end)``."""
        it, pc = self.it, self.pc
        pc.d[pc.off[i0:i1]] = np.where(it.rep[i0:i1], it.repd[i0:i1], self.dtab[it.I[i0:i1] - c0, it.p[i0:i1]])
        s0, s1 = int(pc.off[i0]), int(pc.last[i1 - 1] + 1)
        d0 = pc.d[pc.off[pc.item[s0:s1]]]  # the id at each piece's sample
        Fa, Fb, gs = held_maps(self.tab, pc.d[s0:s1], d0, pc.dt[s0:s1], pc.w[s0:s1])
        cnt = pc.count[i0:i1]
        Ftot = Fa[pc.off[i0:i1] - s0] + Fb[pc.off[i0:i1] - s0]
        gtot = gs[pc.off[i0:i1] - s0]
        for r in range(1, int(cnt.max())):
            a = np.flatnonzero(cnt > r)
            si = pc.off[i0 + a] + r - s0
            Ftot[a] = Fa[si] @ Ftot[a] + Fb[si]
            gtot[a] = np.einsum("pij,pj->pi", Fa[si], gtot[a]) + gs[si]
        return _ChunkMaps(Fa, Fb, gs, Ftot, gtot, cnt, s0)

    def _steps(self, c0: int, c1: int, i0: int, maps: _ChunkMaps | None) -> None:
        """The regular steps ``c0 .. c1-1``: ``Ey`` terms of the standard points, states
        at the special points, composite maps over the special intervals."""
        nw, nz, Ey, Wreg, wt_std = self.nw, self.nz, self.Ey, self.grid.Wreg, self.grid.wt_std
        select, idx, dtab = self.select, self.idx, self.dtab
        Ffull, Gfull, Cz, d_true = self.Ffull, self.Gfull, self.tab.Cz, self.tab.d_true
        if select:
            Faug, Y = self.Faug, self.Y
            Yflat = Y.reshape(-1)
        spt_p, sp_bounds, spt_x = self.pt.p, self.sp_bounds, self.spt_x
        it_p, it_bounds, it_x = self.it.p, self.it_bounds, self.it_x
        ysq, zsq, zmax = np.empty(self.P), np.empty(self.P), self.zmax
        Ba, Bb = self.Ba, self.Bb
        for k in range(c0, c1):
            kk = k - c0
            X = Ba[nw:nw + nz]
            np.einsum("ip,ip->p", X, X, out=zsq)
            np.maximum(zmax, zsq, out=zmax)  # a NaN propagates: diverged
            Ba[:nw] = Wreg[k][:, None]
            if idx is not None:
                np.matmul(Faug, Ba[:nw + nz], out=Y)
                np.take(Yflat, idx[kk], out=Bb[nw:])
                yk = Bb[nw + nz:]
            else:
                dcol = dtab[kk]
                Bb[nw:nw + nz] = ((Ffull[dcol] @ X.T[:, :, None])[:, :, 0] + Gfull[dcol] @ Wreg[k]).T
                yk = np.einsum("pij,jp->ip", Cz[d_true[dcol]], X)
            if yk.shape[0] == 1:
                np.square(yk[0], out=ysq)
            else:
                np.sum(np.square(yk), axis=0, out=ysq)
            b0, b1 = sp_bounds[k], sp_bounds[k + 1]
            if self.peaks is not None:  # the special points: in _last_point, with their own mode
                self._take_regular(yk, spt_p[b0:b1])
            if b1 > b0:
                pp = spt_p[b0:b1]
                spt_x[b0:b1] = X[:, pp].T
                ysq[pp] = 0.0
            ysq *= wt_std[k]
            Ey += ysq
            b0, b1 = it_bounds[k], it_bounds[k + 1]
            if b1 > b0:
                Ftot, gtot = maps.Ftot, maps.gtot  # type: ignore[union-attr]
                pp = it_p[b0:b1]
                xs = X[:, pp]
                it_x[b0:b1] = xs.T
                Bb[nw:nw + nz, pp] = (np.einsum("pij,jp->pi", Ftot[b0 - i0:b1 - i0], xs) + gtot[b0 - i0:b1 - i0]).T
            Ba, Bb = Bb, Ba
        self.Ba, self.Bb = Ba, Bb

    def _take_regular(self, yk: np.ndarray, special: np.ndarray) -> None:
        """Peaks of the regular points of a step, the paths with a special point there left out."""
        assert self.peaks is not None
        if special.size == 0:
            self.peaks.take(yk)
            return
        keep = np.ones(self.P, dtype=bool)
        keep[special] = False
        idx = np.flatnonzero(keep)
        self.peaks.take(yk[:, idx], idx)

    def _interior(self, i0: int, i1: int, maps: _ChunkMaps) -> None:
        """``Ey`` terms of the interior jump points of the special intervals ``i0:i1``,
        from the stored state at each interval's start."""
        Fa, Fb, gs, cnt, s0 = maps.Fa, maps.Fb, maps.gs, maps.cnt, maps.s0
        pc, Cz, d_true = self.pc, self.tab.Cz, self.tab.d_true
        z0 = self.it_x[i0:i1]
        xi = z0.copy()
        for r in range(1, int(cnt.max())):
            a = np.flatnonzero(cnt > r)
            si = pc.off[i0 + a] + r  # the piece starting at the point
            q = si - 1 - s0
            xi[a] = np.einsum("pij,pj->pi", Fa[q], xi[a]) + np.einsum("pij,pj->pi", Fb[q], z0[a]) + gs[q]
            np.maximum.at(self.zmax, self.it.p[i0 + a], np.einsum("pi,pi->p", xi[a], xi[a]))  # jump points
            yi = np.einsum("pij,pj->pi", Cz[d_true[pc.d[si]]], xi[a])
            if self.peaks is not None:
                self.peaks.take(yi.T, self.it.p[i0 + a])
            if self.samples_only:  # interior jump points are no samples
                continue
            qi = np.square(yi).sum(axis=1)
            self.Ey += np.bincount(self.it.p[i0 + a], pc.wt[si] * qi, minlength=self.P)

    def _last_point(self, npts: int) -> None:
        """``Ey`` terms of the last point ``t_N = horizon`` and of the special points."""
        Cz, d_true, pt, b = self.tab.Cz, self.tab.d_true, self.pt, self.sp_bounds
        X = self.Ba[self.nw:self.nw + self.nz]
        np.maximum(self.zmax, np.einsum("ip,ip->p", X, X), out=self.zmax)
        yK = np.einsum("pij,jp->pi", Cz[d_true[self.dtab[npts - 1]]], X)
        qK = np.square(yK).sum(axis=1)
        b0, b1 = b[self.K], b[self.K + 1]
        if self.peaks is not None:
            self._take_regular(yK.T, pt.p[b0:b1])
        if b1 > b0:
            self.spt_x[b0:b1] = X[:, pt.p[b0:b1]].T
            qK[pt.p[b0:b1]] = 0.0
        self.Ey += self.grid.wt_std[self.K] * qK
        ys = np.einsum("pij,pj->pi", Cz[d_true[self.spt_d]], self.spt_x)
        if self.peaks is not None and ys.size:
            self.peaks.take(ys.T, pt.p)
        q = np.square(ys).sum(axis=1)
        weight = self.grid.wt_std[pt.k] if self.samples_only else pt.weight
        self.Ey += np.bincount(pt.p, weight * q, minlength=self.P)
