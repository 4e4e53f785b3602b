r"""Sample paths of the joint (fault, FDI) chain and the communication grid on them.

Both simulators -- the FMU co-simulation supervisor and the numpy reference -- consume
the same :class:`ChainPath` and the same :func:`communication_grid`, so that on equal
paths they integrate exactly the same sampled-data loop:

* the joint chain is sampled exactly: from joint mode ``s`` the holding time is
  exponential with rate :math:`-Q_{ss}` and the next mode is drawn with probabilities
  :math:`Q_{ss'}/(-Q_{ss})` (the generator of :meth:`JointChain.generator`, so the
  paper's model or the named ``fault_during_delay`` variant);
* ``beta`` is fixed by the caller or drawn once per path, uniformly in its box;
* every path has its own random stream, a child of ``numpy.random.SeedSequence(seed)``
  (:func:`sample_paths`), for its chain and its ``Delta`` draws: a path is the same
  whatever else is drawn or simulated with it, serially or on a cluster;
* the communication grid is the union of the control instants ``k h`` and the jump
  times; on each interval ``[t_k, t_{k+1})`` the joint mode is constant and the loop holds
  ``u = K[l] x(t_k)``, ``w(t_k)`` and ``Delta(t_k)`` (sample-and-hold, zero-order hold).

Randomness only through ``numpy.random.SeedSequence`` streams and the generators made
from them.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..errors import ValidationError
from ..model.system import JointChain, Matrix

#: Exponential and uniform draws a path takes from its stream at a time (another block
#: when it jumps more often).
DRAW_BLOCK = 32

__all__ = [
    "DRAW_BLOCK",
    "snap_to_grid",
    "ChainPath",
    "sample_paths",
    "communication_grid",
    "Disturbance",
    "disturbance",
    "DISTURBANCES",
]


@dataclass(frozen=True, eq=False)
class ChainPath:
    """One path of the joint chain on ``[0, horizon]``.

    ``times[0] = 0``; ``true[k], fdi[k]`` (0-based) hold on ``[times[k], times[k+1])``
    (the last one up to ``horizon``). ``beta`` is the detection-rate matrix used.
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
        :attr:`stream` (independent of the chain's draws), new at every call so that every
        simulator sees the same draws; ``None`` for a path without a stream."""
        if self.stream is None:
            return None
        s = self.stream
        return np.random.default_rng(np.random.SeedSequence(s.entropy, spawn_key=(*s.spawn_key, 0),
                                                            pool_size=s.pool_size))

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


def _check_seed(seed: int | np.random.SeedSequence) -> np.random.SeedSequence:
    if isinstance(seed, np.random.SeedSequence):
        return seed
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValidationError(f"seed: expected a non-negative integer or a numpy SeedSequence, got {seed!r}")
    return np.random.SeedSequence(int(seed))


def _generators(chain: JointChain, betas: np.ndarray) -> np.ndarray:
    r""":meth:`JointChain.generator` of every ``betas[p]`` at once, ``(P, m*m, m*m)``.

    ``Q`` is affine in ``beta``: :math:`Q(b) = Q(b_{min}) + \sum_{(j,i)} (b_{ji} -
    b^{min}_{ji})\,\partial Q/\partial b_{ji}`, each derivative the difference of two
    calls of :meth:`JointChain.generator` at valid points of the box divided by the width.
    """
    lo, hi = chain.beta_min, chain.beta_max
    q_lo = chain.generator(lo)
    out = np.broadcast_to(q_lo, (betas.shape[0], *q_lo.shape)).copy()
    for j, i in chain.beta_pairs:
        width = hi[j, i] - lo[j, i]
        if width > 0.0:
            top = lo.copy()
            top[j, i] = hi[j, i]
            out += (betas[:, j, i] - lo[j, i])[:, None, None] * ((chain.generator(top) - q_lo) / width)
    return out


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
    as :attr:`ChainPath.stream`. A path therefore does not depend on how many paths are
    drawn with it, nor on where or in which batch it is simulated. ``beta=None`` draws
    ``beta`` uniformly in its box per path (the first ``m*m`` uniforms of its stream);
    ``start`` is the initial ``(true, fdi)`` (default: no fault, FDI agrees).

    Exact sampling of the generator :math:`Q(\beta)` (:meth:`JointChain.generator`): from
    joint mode ``s`` the holding time is :math:`E/(-Q_{ss})` with :math:`E` standard
    exponential, and the next mode is the smallest ``s'`` whose cumulative jump
    probability :math:`\sum_{r\le s'} Q_{sr}/(-Q_{ss})` (``r != s``) exceeds a uniform
    :math:`U`. Each path draws :math:`E` and :math:`U` in blocks of :data:`DRAW_BLOCK`
    from its stream; the jump recursion then advances all paths together in numpy.
    """
    horizon = _check_horizon(horizon)
    if isinstance(count, bool) or not (isinstance(count, (int, np.integer)) and count >= 1):
        raise ValidationError(f"paths: must be a positive integer, got {count!r}")
    m = chain.m
    if not (0 <= start[0] < m and 0 <= start[1] < m):
        raise ValidationError(f"start: joint mode {start} outside 0..{m - 1}")
    streams = _check_seed(seed).spawn(int(count))
    gens = [np.random.default_rng(k) for k in streams]
    if beta is None:
        betas = chain.beta_min + np.stack([g.random((m, m)) for g in gens]) * (chain.beta_max - chain.beta_min)
        betas[:, np.arange(m), np.arange(m)] = 0.0
        Q = _generators(chain, betas)
        row = np.arange(count)
    else:
        betas = np.broadcast_to(chain.check_beta(beta), (count, m, m))
        Q = chain.generator(betas[0])[None]
        row = np.zeros(count, dtype=np.int64)
    M = m * m
    rates = -np.diagonal(Q, axis1=1, axis2=2)  # (·, M)
    probs = np.clip(Q, 0.0, None)
    probs[:, np.arange(M), np.arange(M)] = 0.0
    cdf = np.cumsum(probs, axis=2)
    cdf /= np.where(cdf[..., -1:] > 0.0, cdf[..., -1:], 1.0)  # the last entry exactly 1
    E = U = np.empty((count, 0))
    state = np.full(count, start[0] * m + start[1], dtype=np.int64)
    t = np.zeros(count)
    alive = np.arange(count)
    jump_t: list[np.ndarray] = []  # per jump k: the paths that jumped, their times, their new modes
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
        state[alive] = np.count_nonzero(cdf[row[alive], state[alive]] <= U[alive, b, None], axis=1)
        jump_p.append(alive)
        jump_t.append(t_next)
        jump_s.append(state[alive])
        k += 1
    path_of = np.concatenate([np.arange(count), *jump_p])
    order = np.argsort(path_of, kind="stable")  # per path, jumps in time order
    times = np.concatenate([np.zeros(count), *jump_t])[order]
    modes = np.concatenate([np.full(count, start[0] * m + start[1]), *jump_s])[order]
    bounds = np.searchsorted(path_of[order], np.arange(count + 1))
    out = []
    for p in range(count):
        seg = slice(bounds[p], bounds[p + 1])
        out.append(ChainPath(times[seg], modes[seg] // m, modes[seg] % m, np.array(betas[p]), horizon, streams[p]))
    return out


def communication_grid(path: ChainPath, step: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Communication points and the joint mode on each interval.

    Returns ``(t, true, fdi)``: ``t`` holds ``0 = t_0 < t_1 < ... < t_N = horizon``, the
    union of the multiples of ``step`` and the jump times; ``true[k], fdi[k]`` hold on
    ``[t_k, t_{k+1})`` (length ``N``). Grid points closer than ``1e-12 * step`` to a jump
    time are merged into it, so no interval is degenerate.
    """
    if not (math.isfinite(step) and step > 0):
        raise ValidationError(f"step: must be a positive finite number, got {step!r}")
    count = int(math.floor(path.horizon / step + 1e-9))
    regular = np.arange(count + 1) * step
    if regular[-1] < path.horizon * (1 - 1e-12):
        regular = np.append(regular, path.horizon)
    else:
        regular[-1] = path.horizon
    jumps = path.times[1:]
    tol = 1e-12 * step
    if jumps.size:  # distance to the nearest jump, O((N + J) log J) memory-light
        idx = np.searchsorted(jumps, regular)
        left = jumps[np.clip(idx - 1, 0, jumps.size - 1)]
        right = jumps[np.clip(idx, 0, jumps.size - 1)]
        near = np.minimum(np.abs(regular - left), np.abs(regular - right)) <= tol
        near[0] = near[-1] = False
        regular = regular[~near]
    t = np.union1d(regular, jumps)
    k = np.searchsorted(path.times, t[:-1], side="right") - 1
    return t, path.true[k], path.fdi[k]


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
