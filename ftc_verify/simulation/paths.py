r"""Sample paths of the joint (fault, FDI, phase) chain and the communication grid on them.

Both simulators -- the FMU co-simulation supervisor and the numpy reference -- consume
the same :class:`ChainPath` and the same :func:`communication_grid`, so that on equal
paths they integrate exactly the same sampled-data loop:

* the joint chain (:mod:`ftc_verify.model.chain`: states ``(true, fdi, phase)``, Erlang-k
  detection delays, false alarms) is sampled exactly: from state ``s`` the holding time
  is exponential with rate :math:`-Q_{ss}` and the next state is drawn with probabilities
  :math:`Q_{ss'}/(-Q_{ss})` (the generator of :meth:`JointChain.generator`, so the
  paper's model, the named ``fault_during_delay`` variant or a richer FDI model);
* a path exposes only the joint mode ``(true, fdi)`` per segment: consecutive states with
  the same ``(true, fdi)`` (a detection advancing by one phase) are one segment, so the
  simulators see exactly the switches of the true mode and of the FDI indication;
* the rate array (``beta``, or ``[beta, false_alarm]``) is fixed by the caller or drawn
  once per path, uniformly in its box;
* every path has its own random stream, a child of ``numpy.random.SeedSequence(seed)``
  (:func:`sample_paths`), for its chain and its ``Delta`` draws: a path is the same
  whatever else is drawn or simulated with it, serially or on a cluster;
* the communication grid is the union of the control instants ``k h`` and the jump
  times; on each interval ``[t_k, t_{k+1})`` the joint mode and ``Delta`` are constant;
  the controller reads ``x`` (``y_m``) and the FDI report only at the samples
  (:func:`sample_points`) and holds ``u`` (and the disturbance value) until the next
  one, across the jumps inside the period (sample-and-hold, zero-order hold).

Randomness only through ``numpy.random.SeedSequence`` streams and the generators made
from them.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, overload

import numpy as np

from ..errors import ValidationError
from ..model.system import JointChain, Matrix
from .spec import delta_stream, grid_snap_tolerance, path_streams, seed_sequence

#: Exponential and uniform draws a path takes from its stream at a time (another block
#: when it jumps more often).
DRAW_BLOCK = 32

__all__ = [
    "DRAW_BLOCK",
    "snap_to_grid",
    "ChainPath",
    "sample_paths",
    "path_streams",
    "sample_path_range",
    "PathSpec",
    "communication_grid",
    "sample_points",
    "Disturbance",
    "disturbance",
    "DISTURBANCES",
]


@dataclass(frozen=True, eq=False)
class ChainPath:
    """One path of the joint chain on ``[0, horizon]``.

    ``times[0] = 0``; ``true[k], fdi[k]`` (0-based) hold on ``[times[k], times[k+1])``
    (the last one up to ``horizon``); consecutive segments differ in ``true`` or ``fdi``.
    ``beta`` is the rate array used (:attr:`JointChain.rate_shape`: the detection rates
    ``beta[fdi, true]``, or the stack ``[beta, false_alarm]``).
    ``stream``: the path's own ``numpy.random.SeedSequence`` (:func:`sample_paths`), from
    which it was drawn and from which its ``Delta`` values are drawn
    (:meth:`delta_generator`).
    """

    times: np.ndarray
    true: np.ndarray
    fdi: np.ndarray
    beta: Matrix
    horizon: float
    stream: np.random.SeedSequence | None = None

    def delta_generator(self) -> np.random.Generator | None:
        """The generator of this path's ``Delta`` draws: the first child of
        ``stream`` (independent of the chain's draws), new at every call so that every
        simulator sees the same draws; ``None`` for a path without a stream."""
        if self.stream is None:
            return None
        return np.random.default_rng(delta_stream(self.stream))

    @property
    def fault_switches(self) -> int:
        """Number of changes of the true mode."""
        return int(np.count_nonzero(np.diff(self.true)))

    @property
    def fdi_switches(self) -> int:
        """Number of changes of the FDI indication."""
        return int(np.count_nonzero(np.diff(self.fdi)))

    def mode_at(self, t: float) -> tuple[int, int]:
        """``(true, fdi)`` at time ``t`` (right-continuous)."""
        k = int(np.searchsorted(self.times, t, side="right")) - 1
        return int(self.true[k]), int(self.fdi[k])


def _check_horizon(horizon: float) -> float:
    if not (isinstance(horizon, (int, float)) and math.isfinite(horizon) and horizon > 0):
        raise ValidationError(f"horizon: must be a positive finite number, got {horizon!r}")
    return float(horizon)


def _targets(chain: JointChain) -> np.ndarray:
    """Per state the states it can jump to anywhere in the rate box, ascending, padded
    with ``-1`` to a common width ``W`` (``(N, W)``).

    Every off-diagonal entry of the generator is a fault rate, a false-alarm rate or
    ``k beta``, non-decreasing in every rate, so it can be positive somewhere in the box
    iff it is positive at the upper corner :attr:`JointChain.rate_max`."""
    q = chain.generator(chain.rate_max)
    np.fill_diagonal(q, 0.0)
    nz = q > 0.0
    width = max(1, int(nz.sum(axis=1).max()))
    out = np.full((q.shape[0], width), -1, dtype=np.int64)
    for s in range(q.shape[0]):
        cols = np.flatnonzero(nz[s])
        out[s, :cols.size] = cols
    return out


def _jump_tables(q: np.ndarray, targets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    r"""``(rates, cdf)`` of generators ``q`` (``(P, N, N)``): the exit rates
    :math:`-Q_{ss}` (``(P, N)``) and the cumulative jump probabilities over
    ``_targets`` (``(P, N, W)``, the last entry of a row with a jump exactly 1)."""
    rows = np.arange(q.shape[1])
    rates = -q[:, rows, rows]
    return rates, _cdf(np.clip(q[:, rows[:, None], np.maximum(targets, 0)], 0.0, None), targets)


def _cdf(probs: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """Cumulative, normalised jump probabilities; padding entries carry no mass."""
    probs = np.where(targets[None] >= 0, probs, 0.0)
    cdf = np.cumsum(probs, axis=2)
    cdf /= np.where(cdf[..., -1:] > 0.0, cdf[..., -1:], 1.0)  # the last entry exactly 1
    return cdf


def _generators(chain: JointChain, rates: np.ndarray, targets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    r"""The ``(rates, cdf)`` of :func:`_jump_tables` of :meth:`JointChain.generator` at
    every rate array ``rates[p]`` at once, without the ``(P, N, N)`` generators.

    ``Q`` is affine in the rate array ``r``: :math:`Q(r) = Q(r_{min}) + \sum_{\iota}
    (r_\iota - r^{min}_\iota)\,\partial Q/\partial r_\iota` over
    :attr:`JointChain.rate_indices` :math:`\iota`, each derivative the difference of two
    calls of :meth:`JointChain.generator` at valid points of the box divided by the width.
    Only the diagonal and the entries of ``_targets`` are formed (each by the same
    floating-point operations, in the same order, as on the full matrix).
    """
    lo, hi = chain.rate_min, chain.rate_max
    rows = np.arange(targets.shape[0])
    cols = np.maximum(targets, 0)
    q_lo = chain.generator(lo)
    diag = np.broadcast_to(q_lo[rows, rows], (rates.shape[0], rows.size)).copy()
    off = np.broadcast_to(q_lo[rows[:, None], cols], (rates.shape[0], *targets.shape)).copy()
    for idx in chain.rate_indices:
        width = hi[idx] - lo[idx]
        if width > 0.0:
            top = lo.copy()
            top[idx] = hi[idx]
            dq = (chain.generator(top) - q_lo) / width
            column: tuple[slice | int, ...] = (slice(None), *idx)
            coef = rates[column] - lo[idx]
            diag += coef[:, None] * dq[rows, rows][None]
            off += coef[:, None, None] * dq[rows[:, None], cols][None]
    return -diag, _cdf(np.clip(off, 0.0, None), targets)


def _draw_rates(chain: JointChain, gens: list[np.random.Generator]) -> np.ndarray:
    """A rate array per path, uniform in the box: the first ``m*m`` uniforms of each
    stream for ``beta``, then (with false alarms only) ``m*m`` for the false-alarm rates."""
    lo, hi = chain.rate_min, chain.rate_max
    rates = lo + np.stack([g.random(chain.rate_shape) for g in gens]) * (hi - lo)
    diag = np.arange(chain.m)
    rates[..., diag, diag] = 0.0
    return rates


def sample_paths(
    chain: JointChain,
    horizon: float,
    count: int,
    seed: int | np.random.SeedSequence,
    *,
    beta: Matrix | None = None,
    start: tuple[int, int] = (0, 0),
) -> list[ChainPath]:
    r"""``count`` independent exact paths of the joint chain on ``[0, horizon]``.

    Path ``k`` draws only from its own stream, child ``k`` of
    ``numpy.random.SeedSequence(seed).spawn(count)`` (a ``SeedSequence`` given as
    ``seed`` is spawned from, so successive calls continue its numbering), and carries it
    as ``ChainPath.stream``. A path therefore does not depend on how many paths are
    drawn with it, nor on where or in which batch it is simulated. ``beta`` is a rate
    array (:meth:`JointChain.check_beta`); ``beta=None`` draws it uniformly in its box per
    path (``_draw_rates``: the first ``m*m`` uniforms of its stream for ``beta``, as
    in the paper's model, then ``m*m`` more for the false-alarm rates when the chain has
    them). ``start`` is the initial ``(true, fdi)`` (default: no fault, FDI agrees).

    Exact sampling of the generator :math:`Q` (:meth:`JointChain.generator`) on the
    ``N = n_states`` states: from state ``s`` the holding time is :math:`E/(-Q_{ss})`
    with :math:`E` standard exponential, and the next state is the smallest ``s'`` whose
    cumulative jump probability :math:`\sum_{r\le s'} Q_{sr}/(-Q_{ss})` (``r != s``)
    exceeds a uniform :math:`U` (the sum runs over the states ``s`` can reach,
    ``_targets``; the others add exact zeros). Each path draws :math:`E` and
    :math:`U` in blocks of :data:`DRAW_BLOCK` from its stream; the jump recursion then
    advances all paths together in numpy. Each state is reported as its ``(true, fdi)``
    (:attr:`JointChain.states`) and consecutive equal modes are merged (a phase of a
    detection is not a mode switch).
    """
    _check_chain(chain)
    horizon = _check_horizon(horizon)
    count = _check_count(count)
    s_start = chain.start_state(start)
    return _sample(chain, horizon, seed_sequence(seed).spawn(count), beta, s_start)


def _check_chain(chain: Any) -> None:
    if not isinstance(chain, JointChain):
        hint = " (a system's chain is its .chain)" if hasattr(chain, "chain") else ""
        raise ValidationError(f"chain: expected a JointChain, got {type(chain).__name__}{hint}")


def _check_count(count: int) -> int:
    if isinstance(count, bool) or not (isinstance(count, (int, np.integer)) and count >= 1):
        raise ValidationError(f"paths: must be a positive integer, got {count!r}")
    return int(count)


def sample_path_range(
    chain: JointChain,
    horizon: float,
    seed: int | np.random.SeedSequence,
    first: int,
    stop: int,
    *,
    beta: Matrix | None = None,
    start: tuple[int, int] = (0, 0),
) -> list[ChainPath]:
    """Paths ``first .. stop - 1`` of a run of :func:`sample_paths` with this ``seed``,
    sampled on their own: exactly ``sample_paths(chain, horizon, count, seed, ...)[first:stop]``
    for any ``count >= stop`` (every path draws only from its stream,
    :func:`~ftc_verify.simulation.spec.path_streams`),
    so that a Dask worker can sample its batch itself. ``seed`` is not advanced."""
    _check_chain(chain)
    horizon = _check_horizon(horizon)
    if stop <= first:
        raise ValidationError(f"first, stop: path range {first} .. {stop} - 1 is empty (stop must exceed first)")
    return _sample(chain, horizon, path_streams(seed, first, stop), beta, chain.start_state(start))


def _sample(chain: JointChain, horizon: float, streams: list[np.random.SeedSequence], beta: Matrix | None,
            s_start: int) -> list[ChainPath]:
    """The paths of ``streams`` (one per path), from state ``s_start`` (:func:`sample_paths`)."""
    count = len(streams)
    gens = [np.random.default_rng(k) for k in streams]
    targets = _targets(chain)
    if beta is None:
        betas = _draw_rates(chain, gens)
        rates, cdf = _generators(chain, betas, targets)
        row = np.arange(count)
    else:
        betas = np.broadcast_to(chain.check_beta(beta), (count, *chain.rate_shape))
        rates, cdf = _jump_tables(chain.generator(betas[0])[None], targets)
        row = np.zeros(count, dtype=np.int64)
    path_of, times, states = _run(rates, cdf, targets, row, gens, s_start, horizon)
    true_of, fdi_of = (np.array(v, dtype=np.int64) for v in zip(*chain.joint_modes))
    true, fdi = true_of[states], fdi_of[states]
    keep = np.ones(times.size, dtype=bool)  # a path's first segment, or a change of (true, fdi)
    keep[1:] = (path_of[1:] != path_of[:-1]) | (true[1:] != true[:-1]) | (fdi[1:] != fdi[:-1])
    path_of, times, true, fdi = path_of[keep], times[keep], true[keep], fdi[keep]
    bounds = np.searchsorted(path_of, np.arange(count + 1))
    out = []
    for p in range(count):
        seg = slice(bounds[p], bounds[p + 1])
        out.append(ChainPath(times[seg], true[seg], fdi[seg], np.array(betas[p]), horizon, streams[p]))
    return out


def _run(rates: np.ndarray, cdf: np.ndarray, targets: np.ndarray, row: np.ndarray,
         gens: list[np.random.Generator], s_start: int, horizon: float) -> tuple[np.ndarray, ...]:
    """The jump recursion of :func:`sample_paths`; ``(path, time, state)`` of every
    segment, ordered by path and, within a path, by time."""
    count = len(gens)
    E = U = np.empty((count, 0))
    state = np.full(count, s_start, dtype=np.int64)
    t = np.zeros(count)
    alive = np.arange(count)
    jump_t: list[np.ndarray] = []  # per jump k: the paths that jumped, their times, their new states
    jump_p: list[np.ndarray] = []
    jump_s: list[np.ndarray] = []
    k = 0
    while alive.size:
        b = k % DRAW_BLOCK
        if b == 0:  # every live path takes its next block of draws from its own stream
            E = np.zeros((count, DRAW_BLOCK))
            U = np.zeros((count, DRAW_BLOCK))
            for p in alive.tolist():
                E[p] = gens[p].standard_exponential(DRAW_BLOCK)
                U[p] = gens[p].random(DRAW_BLOCK)
        r = rates[row[alive], state[alive]]
        t_next = t[alive] + np.where(r > 0.0, E[alive, b] / np.where(r > 0.0, r, 1.0), np.inf)
        inside = t_next < horizon
        alive, t_next = alive[inside], t_next[inside]
        t[alive] = t_next
        pick = np.count_nonzero(cdf[row[alive], state[alive]] <= U[alive, b, None], axis=1)
        state[alive] = targets[state[alive], pick]
        jump_p.append(alive)
        jump_t.append(t_next)
        jump_s.append(state[alive])
        k += 1
    path_of = np.concatenate([np.arange(count), *jump_p])
    order = np.argsort(path_of, kind="stable")  # per path, jumps in time order
    times = np.concatenate([np.zeros(count), *jump_t])[order]
    states = np.concatenate([np.full(count, s_start), *jump_s])[order]
    return path_of[order], times, states


@dataclass(frozen=True, eq=False)
class PathSpec(Sequence[ChainPath]):
    """The paths of ``sample_paths(chain, horizon, n_paths, seed, beta=beta, start=start)``
    as a recipe instead of a list: small to ship (a Dask task gets the recipe and the
    indices of its batch and samples its paths itself, :func:`sample_path_range`), and a
    sequence of :class:`ChainPath` whose items are sampled when asked for (``spec[k]``,
    ``spec[a:b]``: the same paths as the list). A ``SeedSequence`` seed is copied, not
    advanced."""

    chain: JointChain
    horizon: float
    n_paths: int
    seed: int | np.random.SeedSequence
    beta: Matrix | None = None
    start: tuple[int, int] = (0, 0)

    def __post_init__(self) -> None:
        object.__setattr__(self, "horizon", _check_horizon(self.horizon))
        object.__setattr__(self, "n_paths", _check_count(self.n_paths))
        s = seed_sequence(self.seed)
        seed = int(self.seed) if not isinstance(self.seed, np.random.SeedSequence) else np.random.SeedSequence(
            s.entropy, spawn_key=s.spawn_key, pool_size=s.pool_size, n_children_spawned=s.n_children_spawned)
        object.__setattr__(self, "seed", seed)
        if self.beta is not None:
            object.__setattr__(self, "beta", self.chain.check_beta(self.beta))
        self.chain.start_state(self.start)

    def sample(self, first: int = 0, stop: int | None = None) -> list[ChainPath]:
        """Paths ``first .. stop - 1`` (all by default), sampled now."""
        stop = self.n_paths if stop is None else min(int(stop), self.n_paths)
        return sample_path_range(self.chain, self.horizon, self.seed, first, stop, beta=self.beta, start=self.start)

    def __len__(self) -> int:
        return self.n_paths

    @overload
    def __getitem__(self, k: int) -> ChainPath: ...

    @overload
    def __getitem__(self, k: slice) -> list[ChainPath]: ...

    def __getitem__(self, k: int | slice) -> ChainPath | list[ChainPath]:
        if isinstance(k, slice):
            idx = range(self.n_paths)[k]
            if idx.step == 1:
                return self.sample(idx.start, idx.stop) if len(idx) else []
            return [self[i] for i in idx]
        i = range(self.n_paths)[k]  # IndexError out of range, negative indices from the end
        return self.sample(i, i + 1)[0]

    def __iter__(self) -> Iterator[ChainPath]:
        """All paths, sampled in blocks of 1000 (not all held at once by the iterator)."""
        for b in range(0, self.n_paths, 1000):
            yield from self.sample(b, b + 1000)


def communication_grid(path: ChainPath, step: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Communication points and the joint mode on each interval.

    Returns ``(t, true, fdi)``: ``t`` holds ``0 = t_0 < t_1 < ... < t_N = horizon``, the
    union of the multiples of ``step`` and the jump times; ``true[k], fdi[k]`` hold on
    ``[t_k, t_{k+1})`` (length ``N``). Grid points closer than
    :func:`~ftc_verify.simulation.spec.grid_snap_tolerance` to a jump time are merged
    into it, so no interval is degenerate.
    """
    if not (math.isfinite(step) and step > 0):
        raise ValidationError(f"step: must be a positive finite number, got {step!r}")
    count = math.floor(path.horizon / step + 1e-9)
    regular = np.arange(count + 1) * step
    if regular[-1] < path.horizon * (1 - 1e-12):
        regular = np.append(regular, path.horizon)
    else:
        regular[-1] = path.horizon
    jumps = path.times[1:]
    tol = grid_snap_tolerance(step)
    if jumps.size:  # distance to the nearest jump, O((N + J) log J) memory-light
        idx = np.searchsorted(jumps, regular)
        left = jumps[np.clip(idx - 1, 0, jumps.size - 1)]
        right = jumps[np.clip(idx, 0, jumps.size - 1)]
        near = np.minimum(np.abs(regular - left), np.abs(regular - right)) <= tol
        near[0] = near[-1] = False
        regular = regular[~near]
    t = np.concatenate((regular, jumps))  # np.union1d's sort and de-duplication, without its
    t.sort()  # np.ma.is_masked test (numpy.ma's import, a tenth of a second, in every plant process)
    t = t[np.append(True, t[1:] != t[:-1])]
    k = np.searchsorted(path.times, t[:-1], side="right") - 1
    return t, path.true[k], path.fdi[k]


def sample_points(path: ChainPath, step: float, t: np.ndarray) -> np.ndarray:
    """Which points of the grid ``t`` (:func:`communication_grid` of ``path``) are control
    samples: where the controller reads ``x`` (or ``y_m``) and the FDI report and computes a
    new held ``u`` (and takes ``w``). Boolean, ``(N+1,)``.

    The samples are the multiples ``k step`` (with ``t_0 = 0``) and the last point ``t_N``;
    a multiple replaced by a jump within
    :func:`~ftc_verify.simulation.spec.grid_snap_tolerance` (the first such jump) is a
    sample at that jump time. Every other jump time is a grid point *inside* a period: the
    plant's mode (and ``Delta``) changes there, the controller's output, entry and the
    disturbance value it holds do not -- the purely periodic loop of
    :mod:`ftc_verify.analysis.moments.sampled`.
    """
    count = math.floor(path.horizon / step + 1e-9)
    regular = np.arange(count + 1) * step
    sample = _isin_sorted(t, regular)
    sample[0] = sample[-1] = True
    jumps = path.times[1:]
    inner = regular[1:-1] if regular[-1] >= path.horizon * (1 - 1e-12) else regular[1:]
    if jumps.size and inner.size:
        tol = grid_snap_tolerance(step)
        first = np.searchsorted(jumps, inner - tol, side="left")
        ok = first < jumps.size
        cand = jumps[np.minimum(first, jumps.size - 1)]
        ok &= np.abs(cand - inner) <= tol
        sample |= _isin_sorted(t, cand[ok])
    return sample


def _isin_sorted(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.isin(a, b)`` for ``b`` sorted ascending (by bisection: ``np.isin`` calls
    ``np.unique``, which imports ``numpy.ma``, a tenth of a second in every plant process)."""
    if not b.size:
        return np.zeros(a.shape, dtype=bool)
    return b[np.minimum(np.searchsorted(b, a), b.size - 1)] == a


Disturbance = Callable[[np.ndarray], np.ndarray]


def _paper(t: np.ndarray) -> np.ndarray:
    return np.exp(-0.1 * t) * np.sin(t)


#: Scalar disturbance shapes, applied to every disturbance channel.
DISTURBANCES: dict[str, Disturbance] = {
    "paper": _paper,  # w = exp(-0.1 t) sin t, the paper's Section VI
    "zero": lambda t: np.zeros_like(t),
    "step": lambda t: np.ones_like(t),
    "pulse": lambda t: (t < 1.0).astype(float),
    "sine": np.sin,
}


def disturbance(kind: str, nw: int) -> Callable[[np.ndarray], np.ndarray]:
    """``w(t)`` as an array ``(len(t), nw)``: the named shape on every channel."""
    if kind not in DISTURBANCES:
        raise ValidationError(f"disturbance: unknown kind {kind!r}; choose from {sorted(DISTURBANCES)}")
    shape = DISTURBANCES[kind]

    def w(t: np.ndarray) -> np.ndarray:
        return np.repeat(shape(np.asarray(t, dtype=float))[:, None], nw, axis=1)

    return w


def snap_to_grid(path: ChainPath, step: float) -> tuple[ChainPath, float]:
    """The path with every jump time moved to the nearest multiple of ``step`` (for FMUs
    that cannot vary their communication step), and the largest time shift.

    Jumps that land on the same grid point merge: the modes after the last of them hold
    from that point (a segment shorter than half a step can vanish).
    """
    k = np.rint(path.times / step)
    snapped = np.minimum(k * step, path.horizon)
    snapped[0] = 0.0
    shift = float(np.max(np.abs(snapped - path.times))) if path.times.size else 0.0
    keep = np.append(snapped[1:] != snapped[:-1], True)  # the last segment starting at each time
    times, true, fdi = snapped[keep], path.true[keep], path.fdi[keep]
    if times.size and times[-1] >= path.horizon and times.size > 1:  # a jump moved onto the horizon
        times, true, fdi = times[:-1], true[:-1], fdi[:-1]
    merge = np.append(True, (true[1:] != true[:-1]) | (fdi[1:] != fdi[:-1]))
    return ChainPath(times[merge], true[merge], fdi[merge], path.beta, path.horizon, path.stream), shift
