r"""Sample paths of the joint (fault, FDI) chain and the communication grid on them.

Both simulators -- the FMU co-simulation supervisor and the numpy reference -- consume
the same :class:`ChainPath` and the same :func:`communication_grid`, so that on equal
paths they integrate exactly the same sampled-data loop:

* the joint chain is sampled exactly: from joint mode ``s`` the holding time is
  exponential with rate :math:`-Q_{ss}` and the next mode is drawn with probabilities
  :math:`Q_{ss'}/(-Q_{ss})` (the generator of :meth:`JointChain.generator`, so the
  paper's model or the named ``fault_during_delay`` variant);
* ``beta`` is fixed by the caller or drawn once per path, uniformly in its box;
* the communication grid is the union of the control instants ``k h`` and the jump
  times; on each interval ``[t_k, t_{k+1})`` the joint mode is constant and the loop holds
  ``u = K[l] x(t_k)``, ``w(t_k)`` and ``Delta(t_k)`` (sample-and-hold, zero-order hold).

Randomness only through an explicit :class:`numpy.random.Generator`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..errors import ValidationError
from ..model.system import JointChain, Matrix

__all__ = [
    "snap_to_grid",
    "ChainPath",
    "sample_path",
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
    """

    times: np.ndarray
    true: np.ndarray
    fdi: np.ndarray
    beta: Matrix
    horizon: float

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


def sample_path(
    chain: JointChain,
    horizon: float,
    rng: np.random.Generator,
    *,
    beta: Matrix | None = None,
    start: tuple[int, int] = (0, 0),
) -> ChainPath:
    """One exact path. ``beta=None`` draws ``beta`` uniformly in its box for this path;
    ``start`` is the initial ``(true, fdi)`` (default: no fault, FDI agrees)."""
    horizon = _check_horizon(horizon)
    m = chain.m
    if not (0 <= start[0] < m and 0 <= start[1] < m):
        raise ValidationError(f"start: joint mode {start} outside 0..{m - 1}")
    if beta is None:
        b = chain.beta_min + rng.random((m, m)) * (chain.beta_max - chain.beta_min)
        np.fill_diagonal(b, 0.0)
    else:
        b = chain.check_beta(beta)
    Q = chain.generator(b)
    # Per joint mode: the holding-time scale and the jump distribution's CDF, computed once
    # per path. The draw ``cdf.searchsorted(rng.random(), side="right")`` is the one
    # ``rng.choice(m * m, p=p)`` makes (same uniform, same normalised cumulative sum), so
    # paths are unchanged for a given seed; it is ~6x faster than calling ``choice``.
    rates = -np.diag(Q)
    scale = [1.0 / r if r > 0.0 else 0.0 for r in rates.tolist()]
    cdfs = []
    for s_row in range(m * m):
        probs = np.clip(Q[s_row], 0.0, None)
        probs[s_row] = 0.0
        total = probs.sum()
        cdf = (probs / total).cumsum() if total > 0 else probs
        cdfs.append(cdf / cdf[-1] if total > 0 else cdf)
    s = start[0] * m + start[1]
    times, states = [0.0], [s]
    t = 0.0
    while True:
        if rates[s] <= 0.0:
            break
        t += rng.exponential(scale[s])
        if t >= horizon:
            break
        s = int(cdfs[s].searchsorted(rng.random(), side="right"))
        times.append(t)
        states.append(s)
    st = np.asarray(states)
    return ChainPath(np.asarray(times), st // m, st % m, b, horizon)


def sample_paths(
    chain: JointChain,
    horizon: float,
    count: int,
    rng: np.random.Generator,
    *,
    beta: Matrix | None = None,
    start: tuple[int, int] = (0, 0),
) -> list[ChainPath]:
    """``count`` independent paths (see :func:`sample_path`)."""
    if not (isinstance(count, int) and count >= 1):
        raise ValidationError(f"paths: must be a positive integer, got {count!r}")
    return [sample_path(chain, horizon, rng, beta=beta, start=start) for _ in range(count)]


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
    return ChainPath(times[merge], true[merge], fdi[merge], path.beta, path.horizon), shift
