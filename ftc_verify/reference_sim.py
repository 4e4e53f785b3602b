r"""Exact numpy reference simulator of the sampled-data FTC loop, and the continuous loop.

Sampled-data loop (shared with the FMU backend, see :mod:`ftc_verify.paths`)
------------------------------------------------------------------------------
On a path of the joint (true, FDI) chain the communication grid
:func:`~ftc_verify.paths.communication_grid` gives ``t_0 < t_1 < ... < t_N`` (the multiples
of ``step`` and the jump times) and the joint mode ``(i, j)`` on each interval
``[t_k, t_{k+1})``. On that interval the plant of the true mode ``i`` (paper eq. (1) with
the uncertainty of eq. (13), READING-NOTES) evolves with the control and the disturbance
held at their values at ``t_k``:

.. math::

    u_k = K_j x_k, \qquad w_k = w(t_k), \qquad
    A = A_i + A1_i \Delta_1 A2_i, \qquad B = B_i + B1_i \Delta_2 B2_i,

    x_{k+1} = \Phi(h) x_k + \Gamma(h) (B u_k + D_i w_k), \qquad h = t_{k+1} - t_k,

    \Phi(h) = e^{A h}, \qquad \Gamma(h) = \int_0^h e^{A s}\, ds,

with :math:`(\Delta_1, \Delta_2)` of the chain segment containing ``t_k``
(:func:`~ftc_verify.uncertainty.delta_segments`; ``delta=None`` means zero) and
``K_j`` the gain of the FDI mode (``K[i m + j]`` for ``m * m`` full-information gains).
This is the exact zero-order-hold discretisation: :math:`\Phi, \Gamma B, \Gamma D` are
the blocks of :math:`\exp\bigl(\begin{smallmatrix} A & B & D \\ 0 & 0 & 0 \\ 0 & 0 & 0
\end{smallmatrix}\bigr) h`. The output is :math:`y_k = C_i x_k` with ``C`` of the *true*
mode on the interval that starts at ``t_k`` (at ``t_N``: the last interval's mode);
``u`` and ``w`` are recorded as the values held on the interval that starts there (at
``t_N``: ``K[fdi_last] x_N`` and ``w(t_N)``). Every path starts at ``x0`` (default 0).

Full-length intervals ``[k h, (k+1) h]`` (both ends multiples of ``step``, no jump
inside) use :math:`h = ` ``step`` exactly and a cached discretisation per
``(mode, Delta)``; intervals cut by jumps (and a shorter last interval) get their own
exponential with ``h = t_{k+1} - t_k``.

Three entry points
------------------
* :func:`simulate_reference` -- the reference: a plain loop per path with
  :func:`scipy.linalg.expm`, recording every trajectory (``backend="reference"``);
* :func:`energies_reference` -- the fast path for Monte Carlo: per path
  :math:`\int |y|^2` and :math:`\int |w|^2` by the trapezoidal rule of
  :func:`ftc_verify.simulation.l2_norm` on the same grid, all paths advanced together
  (no trajectories kept; see the function for the vectorisation);
* :func:`simulate_continuous` -- the continuous-time loop
  :math:`\dot x = (A + B K_j) x + D_i w(t)` (no sample-and-hold), integrated exactly per
  grid interval with an exosystem for ``w`` (or ``solve_ivp`` for a shape without one).

:func:`phi_gamma` is the batched exponential behind :func:`energies_reference`:
:math:`\Phi(h), \Gamma(h)` for many ``(A, h)`` pairs at once by a Taylor polynomial with
scaling and squaring, accurate to rounding like :func:`scipy.linalg.expm`.

Randomness only through an explicit :class:`numpy.random.Generator` (``rng``, default
``numpy.random.default_rng(seed)``), used by ``Delta`` kind ``random`` only: the draws
are made per path in path order, so every backend given the same generator state sees
the same :math:`\Delta(t)`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.integrate
import scipy.linalg
from numpy.typing import ArrayLike

from .errors import ValidationError
from .model import FTCSystem, Matrix
from .paths import DISTURBANCES, ChainPath, communication_grid, disturbance as disturbance_fn
from .problem_files import check_gains
from .simulation import PathRecord, SimulationResult
from .uncertainty import DeltaSchedule, delta_segments, delta_shapes

__all__ = [
    "simulate_reference",
    "energies_reference",
    "simulate_continuous",
    "zoh_matrices",
    "phi_gamma",
]

#: Scaling target of :func:`phi_gamma`: the Taylor polynomial is evaluated at
#: ``||A h / 2^s||_1 <= _THETA``.
_THETA = 0.5
#: Truncation bound of the Taylor polynomial, relative (``theta^(q+1) / (q+1)! <= _TAYLOR_TOL``).
_TAYLOR_TOL = 1e-18
#: At most this many distinct matrices are handled group by group (one BLAS product per
#: group); beyond, per item (Horner with batched products).
_GROUP_LIMIT = 64
#: Joint tables up to this size use the "all modes, then select" kernel.
_SELECT_LIMIT = 16
#: Target number of doubles of one chunk of the state history in :func:`energies_reference`.
_CHUNK_DOUBLES = 4_000_000


# ------------------------------------------------------------------------------ validation
def _check_step(step: Any) -> float:
    if isinstance(step, bool) or not isinstance(step, (int, float, np.integer, np.floating)) \
            or not math.isfinite(step) or step <= 0:
        raise ValidationError(f"step: must be a positive finite number, got {step!r}")
    return float(step)


def _schedule(delta: DeltaSchedule | str | None) -> DeltaSchedule:
    if delta is None:
        return DeltaSchedule("zero")
    if isinstance(delta, str):
        return DeltaSchedule(delta)
    if isinstance(delta, DeltaSchedule):
        return delta
    raise ValidationError(f"delta: expected a DeltaSchedule, a kind or None, got {type(delta).__name__}")


def _initial_state(system: FTCSystem, x0: ArrayLike | None) -> np.ndarray:
    n = system.dims[0]
    if x0 is None:
        return np.zeros(n)
    try:
        arr = np.asarray(x0, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ValidationError(f"x0: expected {n} finite numbers, got {x0!r}") from None
    if arr.size != n or not np.all(np.isfinite(arr)):
        raise ValidationError(f"x0: expected {n} finite numbers, got {x0!r}")
    return arr


def _rng(rng: np.random.Generator | None, seed: int | None) -> np.random.Generator:
    if rng is not None:
        if not isinstance(rng, np.random.Generator):
            raise ValidationError(f"rng: expected a numpy.random.Generator, got {type(rng).__name__}")
        return rng
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, (int, np.integer))):
        raise ValidationError(f"seed: expected an integer or None, got {seed!r}")
    return np.random.default_rng(seed)


def _path_list(paths: ChainPath | Sequence[ChainPath]) -> list[ChainPath]:
    if isinstance(paths, ChainPath):
        return [paths]
    try:
        out = list(paths)
    except TypeError:
        raise ValidationError(f"paths: expected a sequence of ChainPath, got {type(paths).__name__}") from None
    if not out:
        raise ValidationError("paths: expected a non-empty sequence of ChainPath, got none")
    for k, p in enumerate(out):
        if not isinstance(p, ChainPath):
            raise ValidationError(f"paths[{k}]: expected a ChainPath, got {type(p).__name__}")
    return out


@dataclass(frozen=True)
class _PathArrays:
    """All paths' segments concatenated (segment ``g`` of path ``p`` is ``off[p] + g``)."""

    times: np.ndarray  # (S,) segment start times
    true: np.ndarray  # (S,)
    fdi: np.ndarray  # (S,)
    count: np.ndarray  # (P,) segments per path
    off: np.ndarray  # (P,) offset of the first segment
    horizon: np.ndarray  # (P,)


def _path_arrays(system: FTCSystem, paths: list[ChainPath]) -> _PathArrays:
    """Concatenate and validate (vectorised over paths): times start at 0, increase
    strictly and stay below the horizon; modes are in ``0..m-1``."""
    m = system.m
    times = [np.asarray(p.times, dtype=float).reshape(-1) for p in paths]
    true = [np.asarray(p.true).reshape(-1) for p in paths]
    fdi = [np.asarray(p.fdi).reshape(-1) for p in paths]
    count = np.fromiter((t.size for t in times), dtype=np.int64, count=len(paths))
    for name, arrs in (("true", true), ("fdi", fdi)):
        sizes = np.fromiter((a.size for a in arrs), dtype=np.int64, count=len(paths))
        if np.any(sizes != count):
            k = int(np.argmax(sizes != count))
            raise ValidationError(f"paths[{k}].{name}: {sizes[k]} entries for {count[k]} segment times")
    if np.any(count == 0):
        k = int(np.argmax(count == 0))
        raise ValidationError(f"paths[{k}].times: empty")
    horizon = np.fromiter((float(p.horizon) for p in paths), dtype=float, count=len(paths))
    bad = ~np.isfinite(horizon) | (horizon <= 0)
    if np.any(bad):
        k = int(np.argmax(bad))
        raise ValidationError(f"paths[{k}].horizon: must be a positive finite number, got {horizon[k]!r}")
    T = np.concatenate(times)
    tr = np.concatenate(true)
    fd = np.concatenate(fdi)
    off = np.concatenate(([0], np.cumsum(count)[:-1]))
    for name, arr, per_path in (("true", tr, true), ("fdi", fd, fdi)):
        if arr.dtype.kind in "iu":
            bad = (arr < 0) | (arr >= m)
            k = int(np.searchsorted(off, int(np.argmax(bad)), side="right") - 1) if np.any(bad) else -1
        else:
            k = next(j for j, a in enumerate(per_path) if a.dtype.kind not in "iu")
        if k >= 0:
            raise ValidationError(
                f"paths[{k}].{name}: modes must be integers in 0..{m - 1} (0-based), got {per_path[k].tolist()}"
            )
    if not np.all(np.isfinite(T)):
        raise ValidationError("paths: non-finite jump time")
    first = T[off]
    if np.any(first != 0.0):
        k = int(np.argmax(first != 0.0))
        raise ValidationError(f"paths[{k}].times: must start at 0, got {first[k]!r}")
    step_ok = np.diff(T) > 0
    step_ok[off[1:] - 1] = True  # across path boundaries
    if not np.all(step_ok):
        k = int(np.searchsorted(off, int(np.argmax(~step_ok)), side="right") - 1)
        raise ValidationError(f"paths[{k}].times: must increase strictly, got {times[k].tolist()}")
    last = T[off + count - 1]
    if np.any(last >= horizon):
        k = int(np.argmax(last >= horizon))
        raise ValidationError(f"paths[{k}].times: jump time {last[k]!r} not below the horizon {horizon[k]!r}")
    return _PathArrays(T, tr.astype(np.int64), fd.astype(np.int64), count, off, horizon)


# ------------------------------------------------------------------------------ exponentials
def zoh_matrices(A: ArrayLike, B: ArrayLike, D: ArrayLike, h: float) -> tuple[Matrix, Matrix, Matrix]:
    r"""Exact zero-order-hold matrices :math:`(\Phi, \Gamma B, \Gamma D)` over ``h``.

    They are the top blocks of :math:`\exp(M h)`, :math:`M = \bigl(\begin{smallmatrix}
    A & B & D \\ 0 & 0 & 0 \\ 0 & 0 & 0\end{smallmatrix}\bigr)` (:func:`scipy.linalg.expm`),
    so that :math:`x(h) = \Phi x(0) + \Gamma B u + \Gamma D w` for ``u, w`` held constant.
    """
    A, B, D = (np.asarray(v, dtype=float) for v in (A, B, D))
    n, nu, nw = A.shape[0], B.shape[1], D.shape[1]
    M = np.zeros((n + nu + nw, n + nu + nw))
    M[:n, :n], M[:n, n:n + nu], M[:n, n + nu:] = A, B, D
    E = scipy.linalg.expm(M * float(h))
    return E[:n, :n], E[:n, n:n + nu], E[:n, n + nu:]


def _taylor_degree(theta: float) -> int:
    """Smallest ``q`` with ``theta^(q+1) / (q+1)! <= _TAYLOR_TOL`` (at least 1)."""
    q, term = 0, 1.0
    while True:
        q += 1
        term *= theta / q
        if term * theta / (q + 1) <= _TAYLOR_TOL or q >= 40:
            return q


def _series(A: np.ndarray, h: np.ndarray, norm: float) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
    r"""Taylor data of one matrix for many lengths (see :func:`phi_gamma`).

    Returns ``(s, powers, Rphi, Rgam)`` with ``powers[k] = (A tau)^k``,
    :math:`\tau = \max h / 2^s`, such that :math:`\Phi(h_i / 2^s) = \sum_k Rphi[i, k]\,
    powers[k]` and :math:`\Gamma(h_i / 2^s) = \sum_k Rgam[i, k]\, powers[k]`
    (:math:`Rphi = r^k / k!`, :math:`Rgam = (h/2^s)\, r^k/(k+1)!`, :math:`r = h_i / \max h`).
    """
    n = A.shape[0]
    hmax = float(h.max()) if h.size else 0.0
    theta = norm * hmax
    if hmax == 0.0 or theta == 0.0:
        powers = np.eye(n)[None]
        return 0, powers, np.ones((h.size, 1)), h[:, None].copy()
    s = max(0, math.ceil(math.log2(theta / _THETA)))
    q = _taylor_degree(theta / 2.0 ** s)
    As = A * (hmax / 2.0 ** s)
    powers = np.empty((q + 1, n, n))
    powers[0] = np.eye(n)
    for k in range(1, q + 1):
        powers[k] = powers[k - 1] @ As
    r = h / hmax
    R = np.empty((h.size, q + 1))
    R[:, 0] = 1.0
    for k in range(1, q + 1):
        np.multiply(R[:, k - 1], r, out=R[:, k])
    inv_fact = 1.0 / np.array([math.factorial(k) for k in range(q + 2)], dtype=float)
    return s, powers, R * inv_fact[:q + 1], R * inv_fact[1:q + 2] * (h / 2.0 ** s)[:, None]


def phi_gamma(A: ArrayLike, h: ArrayLike, groups: ArrayLike | None = None) -> tuple[np.ndarray, np.ndarray]:
    r"""Batched :math:`\Phi(h) = e^{A h}` and :math:`\Gamma(h) = \int_0^h e^{A s} ds`.

    Parameters
    ----------
    A : (G, n, n) array
        Distinct state matrices.
    h : (N,) array
        Non-negative interval lengths.
    groups : (N,) int array, optional
        Which matrix each interval uses (default ``arange(N)``, then ``G == N``).

    Returns
    -------
    Phi, Gamma : (N, n, n) arrays

    Notes
    -----
    Scaling and squaring with a Taylor polynomial: with ``s`` such that
    :math:`\theta = \|A h\|_1 / 2^s \le 1/2` and :math:`\tau = h / 2^s`,

    .. math::

        \Phi(\tau) = \sum_{k=0}^{q} \frac{(A\tau)^k}{k!}, \qquad
        \Gamma(\tau) = \tau \sum_{k=0}^{q} \frac{(A\tau)^k}{(k+1)!},

    ``q`` the smallest degree with :math:`\theta^{q+1}/(q+1)! \le 10^{-18}` (no
    cancellation at :math:`\theta \le 1/2`), then ``s`` times
    :math:`\Gamma(2\tau) = \Gamma(\tau) + \Phi(\tau)\Gamma(\tau)`,
    :math:`\Phi(2\tau) = \Phi(\tau)^2`. For few distinct matrices the powers
    :math:`A^k` are formed once per matrix and the polynomials of all its intervals are
    one matrix product (``(N_g, q+1) @ (q+1, n^2)``); otherwise the polynomial is
    evaluated per interval by Horner's rule with batched products.
    """
    A = np.asarray(A, dtype=float)
    h = np.asarray(h, dtype=float).reshape(-1)
    if A.ndim != 3 or A.shape[1] != A.shape[2]:
        raise ValidationError(f"phi_gamma: A must have shape (G, n, n), got {A.shape}")
    if np.any(~np.isfinite(h)) or np.any(h < 0):
        raise ValidationError(f"phi_gamma: h must be finite and >= 0, got {h[~(np.isfinite(h) & (h >= 0))][:5]}")
    G, n = A.shape[0], A.shape[1]
    N = h.size
    gid = np.arange(N) if groups is None else np.asarray(groups, dtype=np.int64).reshape(-1)
    if gid.size != N or (N and (gid.min() < 0 or gid.max() >= G)):
        raise ValidationError(f"phi_gamma: groups must be {N} indices into {G} matrices")
    Phi = np.empty((N, n, n))
    Gam = np.empty((N, n, n))
    if N == 0:
        return Phi, Gam
    norms = np.abs(A).sum(axis=1).max(axis=1)  # induced 1-norm (max column sum)
    eye = np.eye(n)
    used = np.unique(gid)
    if used.size <= _GROUP_LIMIT:
        for g in used:
            idx = np.flatnonzero(gid == g) if used.size > 1 else slice(None)
            s, powers, Rphi, Rgam = _series(A[g], h[idx], float(norms[g]))
            P = (Rphi @ powers.reshape(powers.shape[0], n * n)).reshape(-1, n, n)
            Gm = (Rgam @ powers.reshape(powers.shape[0], n * n)).reshape(-1, n, n)
            for _ in range(s):
                Gm = Gm + P @ Gm
                P = P @ P
            Phi[idx] = P
            Gam[idx] = Gm
        return Phi, Gam
    # per item: Horner with batched products, squarings per item
    theta = norms[gid] * h
    s = np.zeros(N, dtype=np.int64)
    pos = theta > _THETA
    s[pos] = np.ceil(np.log2(theta[pos] / _THETA)).astype(np.int64)
    tau = h / 2.0 ** s
    As = A[gid] * tau[:, None, None]
    q = _taylor_degree(float(np.max(theta / 2.0 ** s)) if N else 0.0)
    T = np.broadcast_to(eye / math.factorial(q + 1), (N, n, n)).copy()
    for k in range(q - 1, -1, -1):
        T = As @ T
        T += eye / math.factorial(k + 1)
    P = eye + As @ T
    Gm = T * tau[:, None, None]
    for level in range(int(s.max())):
        sel = np.flatnonzero(s > level)
        Gm[sel] = Gm[sel] + P[sel] @ Gm[sel]
        P[sel] = P[sel] @ P[sel]
    return P, Gm


# ------------------------------------------------------------------------------ per-mode matrices
def _gain(Ks: Sequence[Matrix], m: int, i: int, j: int) -> Matrix:
    return Ks[i * m + j] if len(Ks) == m * m else Ks[j]


def _perturbed(system: FTCSystem, i: int, d1: Matrix | None, d2: Matrix | None) -> tuple[Matrix, Matrix]:
    """``(A_i + A1_i Delta1 A2_i, B_i + B1_i Delta2 B2_i)`` (paper eq. (13))."""
    md = system.modes[i]
    A, B = md.A, md.B
    if md.A1 is not None and md.A2 is not None and d1 is not None:
        A = A + md.A1 @ d1 @ md.A2
    if md.B1 is not None and md.B2 is not None and d2 is not None:
        B = B + md.B1 @ d2 @ md.B2
    return A, B


def _delta_key(d1: Matrix | None, d2: Matrix | None) -> tuple[bytes, bytes]:
    return (b"" if d1 is None else np.ascontiguousarray(d1).tobytes(),
            b"" if d2 is None else np.ascontiguousarray(d2).tobytes())


def _full_intervals(t: np.ndarray, step: float) -> np.ndarray:
    """Which grid intervals are full-length ``[k step, (k+1) step]``: both ends are the
    floats ``k * step`` and ``(k+1) * step`` exactly (as :func:`communication_grid` makes
    them with ``arange(...) * step``)."""
    k = np.rint(t / step)
    is_mult = (k * step == t) & (k >= 0)
    return is_mult[:-1] & is_mult[1:] & (k[1:] == k[:-1] + 1)


def _options(system: FTCSystem, schedule: DeltaSchedule, x0: np.ndarray, Ks: Sequence[Matrix],
             **extra: Any) -> dict[str, Any]:
    opts: dict[str, Any] = {
        "delta": schedule.kind,
        "x0": x0.tolist(),
        "gains": "full-information" if len(Ks) == system.m ** 2 else "fdi",
        "fault_during_delay": bool(system.chain.fault_during_delay),
    }
    for name in ("Delta1", "Delta2"):
        val = getattr(schedule, name)
        if val is not None:
            opts[name] = np.asarray(val).tolist()
    opts.update(extra)
    return opts


# ------------------------------------------------------------------------------ reference
def _simulate_path(system: FTCSystem, Ks: Sequence[Matrix], path: ChainPath, segs: list, step: float,
                   wfun: Callable[[np.ndarray], np.ndarray], x0: np.ndarray,
                   cache: dict[Any, tuple[Matrix, Matrix, Matrix]]) -> PathRecord:
    m = system.m
    n, nu, ny, nw = system.dims
    t, true, fdi = communication_grid(path, step)
    N = t.size - 1
    W = wfun(t)
    seg = np.searchsorted(path.times, t[:-1], side="right") - 1
    full = _full_intervals(t, step)
    keys = [_delta_key(*d) for d in segs]
    X = np.empty((N + 1, n))
    U = np.empty((N + 1, nu))
    Y = np.empty((N + 1, ny))
    x = x0.copy()
    for k in range(N):
        i, j, g = int(true[k]), int(fdi[k]), int(seg[k])
        K = _gain(Ks, m, i, j)
        u = K @ x
        X[k], U[k], Y[k] = x, u, system.modes[i].C @ x
        if full[k]:
            key = (i, keys[g])
            mats = cache.get(key)
            if mats is None:
                A, B = _perturbed(system, i, *segs[g])
                mats = cache[key] = zoh_matrices(A, B, system.modes[i].D, step)
        else:
            A, B = _perturbed(system, i, *segs[g])
            mats = zoh_matrices(A, B, system.modes[i].D, t[k + 1] - t[k])
        Phi, GB, GD = mats
        x = Phi @ x + GB @ u + GD @ W[k]
    i, j = int(true[-1]), int(fdi[-1])
    X[N], U[N], Y[N] = x, _gain(Ks, m, i, j) @ x, system.modes[i].C @ x
    return PathRecord(path, t, true, fdi, X, U, W, Y)


def simulate_reference(
    system: FTCSystem,
    gains: Sequence[Matrix],
    paths: ChainPath | Sequence[ChainPath],
    *,
    step: float,
    disturbance: str = "paper",
    delta: DeltaSchedule | str | None = None,
    x0: ArrayLike | None = None,
    rng: np.random.Generator | None = None,
    seed: int | None = None,
) -> SimulationResult:
    r"""Simulate the sampled-data loop (module docstring) on every path, exactly.

    Parameters
    ----------
    system : FTCSystem
    gains : sequence of (nu, n) arrays
        One per FDI mode (``u = K[l] x``), or ``m * m`` full-information gains
        ``K[r m + l]`` (validated by :func:`ftc_verify.problem_files.check_gains`).
    paths : ChainPath or sequence of ChainPath
    step : float
        Control period; the grid is :func:`~ftc_verify.paths.communication_grid`.
    disturbance : str
        A kind of :data:`ftc_verify.paths.DISTURBANCES` (every channel gets it).
    delta : DeltaSchedule, its kind, or None (zero)
        :math:`\Delta(t)`, from :func:`~ftc_verify.uncertainty.delta_segments` per path in
        path order.
    x0 : array-like of n numbers, optional
        Initial state of every path (default 0).
    rng, seed
        Generator for ``Delta`` kind ``random`` (default ``numpy.random.default_rng(seed)``);
        ``seed`` is recorded in the result.

    Returns
    -------
    SimulationResult
        ``backend="reference"``, one :class:`~ftc_verify.simulation.PathRecord` per path.
        ``horizon`` is the largest path horizon.

    Notes
    -----
    One loop per path over the grid intervals: :math:`x_{k+1} = \Phi x_k + \Gamma B u_k
    + \Gamma D w_k` with the blocks of :func:`scipy.linalg.expm` of the augmented matrix
    (:func:`zoh_matrices`), cached per ``(true mode, Delta)`` for the full-length intervals
    (``h = step``) across paths, computed afresh for every interval cut by a jump.
    """
    step = _check_step(step)
    Ks = check_gains(system, gains)
    plist = _path_list(paths)
    _path_arrays(system, plist)
    schedule = _schedule(delta)
    x0v = _initial_state(system, x0)
    wfun = disturbance_fn(disturbance, system.dims[3])
    gen = _rng(rng, seed)
    cache: dict[Any, tuple[Matrix, Matrix, Matrix]] = {}
    records = []
    for p in plist:
        segs = delta_segments(system, p, schedule, gen)
        records.append(_simulate_path(system, Ks, p, segs, step, wfun, x0v, cache))
    return SimulationResult(
        backend="reference",
        seed=seed,
        step=step,
        horizon=float(max(p.horizon for p in plist)),
        disturbance=disturbance,
        records=tuple(records),
        options=_options(system, schedule, x0v, Ks, method="exact zero-order hold (scipy.linalg.expm)"),
    )


# ------------------------------------------------------------------------------ fast energies
@dataclass(frozen=True)
class _Tables:
    """Per dynamics id ``d`` (a joint mode with one ``Delta`` value) and per state-matrix
    id ``a`` (a true mode with one ``Delta1`` value) the matrices of the loop."""

    A: np.ndarray  # (Ga, n, n) perturbed state matrices
    d_a: np.ndarray  # (Dn,) state-matrix id of each dynamics id
    d_true: np.ndarray  # (Dn,) true mode of each dynamics id
    BK: np.ndarray  # (Dn, n, n) perturbed B times the gain
    Dm: np.ndarray  # (Dn, n, nw)


def _stacked_channels(system: FTCSystem) -> tuple[np.ndarray | None, ...]:
    """Uncertainty weights stacked over modes (zeros where a mode lacks a channel)."""
    s1, s2 = delta_shapes(system)
    n, nu, _, _ = system.dims
    out: list[np.ndarray | None] = []
    for shape, left, right, width in ((s1, "A1", "A2", n), (s2, "B1", "B2", nu)):
        if shape is None:
            out += [None, None]
            continue
        L = np.zeros((system.m, n, shape[0]))
        R = np.zeros((system.m, shape[1], width))
        for i, md in enumerate(system.modes):
            if getattr(md, left) is not None:
                L[i], R[i] = getattr(md, left), getattr(md, right)
        out += [L, R]
    return tuple(out)


def _tables(system: FTCSystem, Ks: Sequence[Matrix], a_true: np.ndarray, a_d1: np.ndarray | None,
            d_true: np.ndarray, d_fdi: np.ndarray, d_d2: np.ndarray | None, d_a: np.ndarray) -> _Tables:
    """Batched perturbed matrices (eq. (13)): ``a`` entries ``(true, Delta1)`` and ``d``
    entries ``(true, fdi, Delta2)``; ``d_a`` maps each ``d`` to its ``a``."""
    m = system.m
    A1, A2, B1, B2 = _stacked_channels(system)
    Am = np.stack([md.A for md in system.modes])
    Bm = np.stack([md.B for md in system.modes])
    Dm = np.stack([md.D for md in system.modes])
    A = Am[a_true].copy()
    if A1 is not None and a_d1 is not None:
        A += A1[a_true] @ a_d1 @ A2[a_true]
    B = Bm[d_true].copy()
    if B1 is not None and d_d2 is not None:
        B += B1[d_true] @ d_d2 @ B2[d_true]
    Kst = np.stack(Ks)
    kidx = d_true * m + d_fdi if len(Ks) == m * m else d_fdi
    BK = B @ Kst[kidx]
    return _Tables(A, d_a, d_true, BK, Dm[d_true])


def _loop_matrices(tab: _Tables, d: np.ndarray, h: np.ndarray, wvals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    r"""Closed-loop ZOH maps ``x -> F x + g`` of intervals with dynamics ids ``d``,
    lengths ``h`` and held disturbances ``wvals`` (N, nw):
    :math:`F = \Phi + \Gamma B K`, :math:`g = \Gamma D w`.

    Per dynamics id (few ids) without squaring, ``F`` and ``g`` come straight from the
    Taylor data of :func:`_series`: :math:`F = R_\Phi P + R_\Gamma (P B K)`,
    :math:`g = (R_\Gamma (P D)) w` with the stacked powers ``P`` (two matrix products);
    otherwise through :func:`phi_gamma`."""
    n = tab.A.shape[1]
    nw = tab.Dm.shape[2]
    N = d.size
    used = np.unique(d)
    if used.size > _GROUP_LIMIT:
        Phi, Gam = phi_gamma(tab.A, h, tab.d_a[d])
        return Phi + Gam @ tab.BK[d], np.einsum("pij,pj->pi", Gam, np.einsum("pij,pj->pi", tab.Dm[d], wvals))
    F = np.empty((N, n, n))
    g = np.empty((N, n))
    norms = np.abs(tab.A).sum(axis=1).max(axis=1)
    for dd in used:
        idx = np.flatnonzero(d == dd) if used.size > 1 else slice(None)
        a = int(tab.d_a[dd])
        hi = h[idx]
        s, powers, Rphi, Rgam = _series(tab.A[a], hi, float(norms[a]))
        q1 = powers.shape[0]
        if s == 0:
            PBK = (powers @ tab.BK[dd]).reshape(q1, n * n)
            F[idx] = (Rphi @ powers.reshape(q1, n * n) + Rgam @ PBK).reshape(-1, n, n)
            GD = (Rgam @ (powers @ tab.Dm[dd]).reshape(q1, n * nw)).reshape(-1, n, nw)
        else:
            Phi = (Rphi @ powers.reshape(q1, n * n)).reshape(-1, n, n)
            Gam = (Rgam @ powers.reshape(q1, n * n)).reshape(-1, n, n)
            for _ in range(s):
                Gam = Gam + Phi @ Gam
                Phi = Phi @ Phi
            F[idx] = Phi + (Gam.reshape(-1, n) @ tab.BK[dd]).reshape(-1, n, n)
            GD = (Gam.reshape(-1, n) @ tab.Dm[dd]).reshape(-1, n, nw)
        g[idx] = GD[:, :, 0] * wvals[idx, 0:1] if nw == 1 else np.einsum("pij,pj->pi", GD, wvals[idx])
    return F, g


def energies_reference(
    system: FTCSystem,
    gains: Sequence[Matrix],
    paths: ChainPath | Sequence[ChainPath],
    *,
    step: float,
    disturbance: str = "paper",
    delta: DeltaSchedule | str | None = None,
    x0: ArrayLike | None = None,
    rng: np.random.Generator | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    r"""Per path :math:`\int_0^T |y|^2 dt` and :math:`\int_0^T |w|^2 dt` of the sampled loop.

    Same loop, grid, ``Delta`` draws (from ``rng``, default ``default_rng()``, per path in
    path order) and trapezoidal rule as :func:`simulate_reference` followed by
    ``record.y_norm ** 2, record.w_norm ** 2`` (:func:`ftc_verify.simulation.l2_norm`),
    without keeping trajectories: the fast path for Monte Carlo. The parameters are those
    of :func:`simulate_reference` (without ``seed``); paths may have different horizons.

    Returns
    -------
    (Ey, Ew) : two (P,) arrays

    Notes
    -----
    With grid points :math:`t_g` of a path and weights
    :math:`\omega_g = (t_{g+1} - t_{g-1})/2` (halved ends), the trapezoidal rule is
    :math:`E_y = \sum_g \omega_g |C_{i_g} x_g|^2`. All paths advance together over the
    regular points ``k step``:

    * an interval ``[k step, (k+1) step]`` without a jump is one map
      :math:`x \mapsto F_d x + G_d w_k` (:math:`F_d = \Phi + \Gamma B K`, :math:`G_d =
      \Gamma D`, ``h = step``), one table entry per dynamics id ``d`` (joint mode and
      ``Delta`` value). With few ids, all paths take one matrix product
      ``[[G_d, F_d], [0, C_d]] @ [w_k; x]`` over all ids and gather their own id's rows
      (next state and present output at once); with many ids (``Delta`` kind ``random``)
      a gathered batched product;
    * an interval cut by jumps (or a shorter last interval) is the composition of the
      maps of its pieces, whose exponentials are made in batches per chunk of steps
      (the Taylor series of :func:`phi_gamma`, one matrix product per id; the full-step
      tables come from :func:`phi_gamma` too, so this path never calls
      :func:`scipy.linalg.expm`, agreeing with it to rounding); the states at
      the jump points, needed for their trapezoid terms, are recomputed from the stored
      state at the interval's start;
    * the trapezoid terms of the grid points whose weight or mode differs from the
      regular ones (next to a cut interval) are taken from stored states, the others
      are summed as the steps go.

    A regular point within ``1e-12 step`` of a jump is replaced by the jump, as in
    :func:`~ftc_verify.paths.communication_grid`.
    """
    step = _check_step(step)
    Ks = check_gains(system, gains)
    plist = _path_list(paths)
    pa = _path_arrays(system, plist)
    schedule = _schedule(delta)
    x0v = _initial_state(system, x0)
    nw = system.dims[3]
    wfun = disturbance_fn(disturbance, nw)
    gen = _rng(rng, None)
    m = system.m
    P = len(plist)
    s1, s2 = delta_shapes(system)
    seg_index = np.arange(pa.times.size) - np.repeat(pa.off, pa.count)  # local segment index
    joint = pa.true * m + pa.fdi

    # Delta per segment -> dynamics ids
    if schedule.kind == "random":
        segs = [delta_segments(system, p, schedule, gen) for p in plist]
        flat = [d for sg in segs for d in sg]
        d1 = None if s1 is None else np.stack([d[0] for d in flat])
        d2 = None if s2 is None else np.stack([d[1] for d in flat])
        seg_d = np.arange(pa.times.size)
        tab = _tables(system, Ks, pa.true, d1, pa.true, pa.fdi, d2, seg_d)
    else:
        # deterministic kinds depend on the segment index only: one call on the longest path
        longest = plist[int(np.argmax(pa.count))]
        segs0 = delta_segments(system, longest, schedule, gen)
        keymap: dict[tuple[bytes, bytes], int] = {}
        key_of = np.array([keymap.setdefault(_delta_key(*d), len(keymap)) for d in segs0], dtype=np.int64)
        first = {v: k for k, v in reversed(list(enumerate(key_of.tolist())))}
        values = [segs0[first[v]] for v in range(len(keymap))]
        nk = len(values)
        a_key, a_true = np.divmod(np.arange(nk * m), m)
        d_key, d_joint = np.divmod(np.arange(nk * m * m), m * m)
        d_true, d_fdi = np.divmod(d_joint, m)
        d1 = None if s1 is None else np.stack([values[k][0] for k in a_key])
        d2 = None if s2 is None else np.stack([values[k][1] for k in d_key])
        tab = _tables(system, Ks, a_true, d1, d_true, d_fdi, d2, d_key * m + d_true)
        seg_d = key_of[seg_index] * m * m + joint

    Ey = np.zeros(P)
    Ew = np.zeros(P)
    for hz in np.unique(pa.horizon):
        sel = np.flatnonzero(pa.horizon == hz)
        if sel.size == P:
            sub_pa, sub_seg_d = pa, seg_d
        else:
            segsel = np.concatenate([np.arange(pa.off[p], pa.off[p] + pa.count[p]) for p in sel])
            cnt = pa.count[sel]
            sub_pa = _PathArrays(pa.times[segsel], pa.true[segsel], pa.fdi[segsel], cnt,
                                 np.concatenate(([0], np.cumsum(cnt)[:-1])), pa.horizon[sel])
            sub_seg_d = seg_d[segsel]
        ey, ew = _energies_same_horizon(system, tab, sub_pa, sub_seg_d, float(hz), step, wfun, x0v)
        Ey[sel] = ey
        Ew[sel] = ew
    return Ey, Ew


def _unique(a: np.ndarray) -> np.ndarray:
    """Sorted unique values (sort based; faster than hashing for large integer arrays)."""
    if a.size == 0:
        return a
    s = np.sort(a)
    keep = np.empty(s.size, dtype=bool)
    keep[0] = True
    np.not_equal(s[1:], s[:-1], out=keep[1:])
    return s[keep]


def _lookup(keys_sorted: np.ndarray, query: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Positions of ``query`` in the sorted ``keys_sorted`` and whether they are there."""
    if keys_sorted.size == 0:
        return np.zeros(query.size, dtype=np.int64), np.zeros(query.size, dtype=bool)
    loc = np.minimum(np.searchsorted(keys_sorted, query), keys_sorted.size - 1)
    return loc, keys_sorted[loc] == query


def _energies_same_horizon(system: FTCSystem, tab: _Tables, pa: _PathArrays, seg_d: np.ndarray, horizon: float,
                           step: float, wfun: Callable[[np.ndarray], np.ndarray],
                           x0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The engine of :func:`energies_reference` for paths sharing one horizon.

    Vocabulary: *regular points* ``reg[k]`` (the jump-free grid), *special intervals*
    ``(p, I)`` (regular interval ``I`` of path ``p`` containing a jump, next to a regular
    point replaced by a jump, or not full-length), their *pieces* (split at the jumps)
    and *special points* (ends of special intervals, whose trapezoid weight or mode may
    differ from the standard one). ``d`` is a dynamics id (joint mode and ``Delta``).
    """
    n, _, ny, nw = system.dims
    m = system.m
    P = pa.count.size
    Dn = tab.d_true.size
    # ---- regular grid (the jump-free communication grid) and standard weights
    dummy = ChainPath(np.zeros(1), np.zeros(1, dtype=np.int64), np.zeros(1, dtype=np.int64), np.zeros((m, m)), horizon)
    reg = communication_grid(dummy, step)[0]
    K = reg.size - 1
    dreg = np.diff(reg)
    wt_std = np.zeros(K + 1)
    wt_std[:-1] += 0.5 * dreg
    wt_std[1:] += 0.5 * dreg
    full = _full_intervals(reg, step)
    Wreg = wfun(reg)
    w2reg = np.sum(Wreg ** 2, axis=1)
    Ew = np.full(P, float(np.sum(wt_std * w2reg)))
    tol = 1e-12 * step

    # ---- jumps (all paths, sorted by path then time)
    is_jump = np.ones(pa.times.size, dtype=bool)
    is_jump[pa.off] = False
    jidx = np.flatnonzero(is_jump)
    jt = pa.times[jidx]
    jp = np.repeat(np.arange(P), pa.count - 1)
    jd_new = seg_d[jidx]
    jd_old = seg_d[jidx - 1]
    kj = np.searchsorted(reg, jt, side="right") - 1  # reg[kj] <= jt < reg[kj + 1]
    near_left = (jt - reg[kj] <= tol) & (kj > 0)
    near_right = (reg[kj + 1] - jt <= tol) & (kj + 1 < K)
    anchor = np.where(near_right, kj + 1, np.where(near_left, kj, -1))  # regular point it replaces
    anchored = anchor >= 0
    akey = anchor * P + jp
    prev_same = np.zeros(jt.size, dtype=bool)
    prev_same[1:] = anchored[1:] & anchored[:-1] & (akey[1:] == akey[:-1])
    endpoint = anchored & ~prev_same  # first jump near a regular point: the grid point there
    interior = ~endpoint
    j_interval = np.where(anchored, anchor, kj)  # special interval of an interior jump
    eo = np.argsort(akey[endpoint])
    ep_key, ep_t, ep_d = akey[endpoint][eo], jt[endpoint][eo], jd_new[endpoint][eo]

    def replaced(p: np.ndarray, k: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For regular points ``k`` of paths ``p``: replaced by a jump?, the grid point's
        time, and the replacing jump's ``d`` (valid where replaced)."""
        loc, found = _lookup(ep_key, k * P + p)
        t = reg[k].copy()
        t[found] = ep_t[loc[found]]
        return found, t, ep_d[loc] if ep_d.size else np.zeros(p.size, dtype=np.int64)

    # ---- special intervals (I, p), sorted by step then path
    ep_p, ep_a = jp[endpoint], anchor[endpoint]
    in_key = j_interval[interior] * P + jp[interior]
    parts = [in_key, (ep_a - 1) * P + ep_p, ep_a * P + ep_p]
    notfull = np.flatnonzero(~full)
    if notfull.size:
        parts.append((notfull[:, None] * P + np.arange(P)[None, :]).ravel())
    item_key = _unique(np.concatenate(parts))
    it_I, it_p = np.divmod(item_key, P)
    nitem = item_key.size
    it_rep, it_t0, it_repd = replaced(it_p, it_I)
    _, it_t1, _ = replaced(it_p, it_I + 1)

    # ---- pieces of the special intervals: the start point, then the interior jumps in
    # time order (interior jumps of one item are consecutive in the jump order)
    in_item, found = _lookup(item_key, in_key)
    if not np.all(found):  # pragma: no cover - a bookkeeping error, not an input error
        raise RuntimeError("energies_reference: interior jump outside every special interval")
    ccount = 1 + np.bincount(in_item, minlength=nitem)
    sub_off = np.concatenate(([0], np.cumsum(ccount)[:-1])).astype(np.int64)
    last_sub = sub_off + ccount - 1
    nsub = int(ccount.sum())
    run_start = np.ones(in_item.size, dtype=bool)
    run_start[1:] = in_item[1:] != in_item[:-1]
    first_of_run = np.maximum.accumulate(np.where(run_start, np.arange(in_item.size), 0)) if in_item.size else in_item
    rank = np.arange(in_item.size) - first_of_run  # 0 for the first interior jump of an item
    in_pos = sub_off[in_item] + 1 + rank
    sub_t0 = np.empty(nsub)
    sub_t0[sub_off] = it_t0
    sub_t0[in_pos] = jt[interior]
    sub_d = np.empty(nsub, dtype=np.int64)  # start pieces filled per chunk
    sub_d[in_pos] = jd_new[interior]
    sub_t1 = np.empty(nsub)
    sub_t1[:-1] = sub_t0[1:]
    sub_t1[last_sub] = it_t1
    sub_dt = sub_t1 - sub_t0
    sub_w = wfun(sub_t0)
    sub_wt = np.zeros(nsub)  # weights of the interior jump points (start of pieces >= 1)
    sub_wt[in_pos] = 0.5 * (sub_dt[in_pos - 1] + sub_dt[in_pos])
    Ew += np.bincount(jp[interior], sub_wt[in_pos] * np.sum(sub_w[in_pos] ** 2, axis=1), minlength=P)

    # ---- special points: ends of the special intervals, sorted by point then path
    spk = _unique(np.concatenate((item_key, item_key + P)))
    spt_k, spt_p = np.divmod(spk, P)
    spt_rep, spt_t, spt_repd = replaced(spt_p, spt_k)
    locL, fL = _lookup(item_key, spk - P)
    locR, fR = _lookup(item_key, spk)
    fL &= spt_k > 0
    fR &= spt_k < K
    dtL = np.where(fL, sub_dt[last_sub[locL]], np.where(spt_k > 0, dreg[np.maximum(spt_k - 1, 0)], 0.0))
    dtR = np.where(fR, sub_dt[sub_off[locR]], np.where(spt_k < K, dreg[np.minimum(spt_k, K - 1)], 0.0))
    spt_w = 0.5 * (dtL + dtR)
    w2sp = np.sum(wfun(spt_t) ** 2, axis=1)
    Ew += np.bincount(spt_p, spt_w * w2sp - wt_std[spt_k] * w2reg[spt_k], minlength=P)
    spt_x = np.empty((spk.size, n))  # x at the special points, filled while stepping
    spt_d = np.empty(spk.size, dtype=np.int64)

    # ---- full-step maps. Kernel "all ids, then select" for few ids: rows of Faug per id
    # d are [G_d | F_d] (the next state) and [0 | C_true(d)] (the output now); the state
    # buffers hold rows [w; x; y].
    Ffull, Gfull = _full_maps(tab, step)
    Cst = np.stack([md.C for md in system.modes])  # (m, ny, n)
    select = Dn <= _SELECT_LIMIT
    rows = n + ny
    if select:
        Faug = np.zeros((Dn, rows, nw + n))
        Faug[:, :n, :nw] = Gfull
        Faug[:, :n, nw:] = Ffull
        Faug[:, n:, nw:] = Cst[tab.d_true]
        Faug = Faug.reshape(Dn * rows, nw + n)
        Y = np.empty((Dn * rows, P))
        Yflat = Y.reshape(-1)
        idx_off = (np.arange(rows) * P)[:, None] + np.arange(P)[None, :]  # (rows, P)

    # ---- time stepping, one chunk of regular steps at a time
    j0 = np.searchsorted(reg, jt, side="left")  # first regular point at or after the jump
    jorder = np.argsort(j0, kind="stable")
    j0s, jps, jdelta = j0[jorder], jp[jorder], (jd_new - jd_old)[jorder]
    d_cur = seg_d[pa.off].astype(np.int64)  # d at the chunk's first point
    L = max(1, min(K, _CHUNK_DOUBLES // max(1, P * rows)))
    Ba = np.empty((nw + n + ny, P))
    Ba[nw:nw + n] = x0[:, None]
    Bb = np.empty_like(Ba)
    Ey = np.zeros(P)
    ysq = np.empty(P)
    dtab = np.empty((L + 1, P), dtype=np.int64)
    idx = np.empty((L, rows, P), dtype=np.int64) if select else None
    it_x = np.empty((nitem, n))  # x at the start point of each special interval
    sp_bounds = np.searchsorted(spt_k, np.arange(K + 2))
    it_bounds = np.searchsorted(it_I, np.arange(K + 1))
    for c0 in range(0, K, L):
        c1 = min(K, c0 + L)
        p1 = c1 + 1 if c1 == K else c1  # points c0 .. p1-1, intervals c0 .. c1-1
        npts = p1 - c0
        # d at the chunk's regular points
        dtab[0] = d_cur
        lo = np.searchsorted(j0s, c0 + 1)
        bnd = np.searchsorted(j0s, np.arange(c0 + 1, c1 + 2), side="right")
        for r in range(1, npts):
            dtab[r] = dtab[r - 1]
            hi = bnd[r - 1]
            if hi > lo:
                np.add.at(dtab[r], jps[lo:hi], jdelta[lo:hi])
                lo = hi
        if p1 == c1:  # d at the next chunk's first point
            d_cur = dtab[npts - 1].copy()
            hi = bnd[npts - 1]
            np.add.at(d_cur, jps[lo:hi], jdelta[lo:hi])
        # d at the special points of the chunk
        a0, a1 = sp_bounds[c0], sp_bounds[p1]
        spt_d[a0:a1] = np.where(spt_rep[a0:a1], spt_repd[a0:a1], dtab[spt_k[a0:a1] - c0, spt_p[a0:a1]])
        # special intervals of the chunk: pieces and composite maps x(e_I) -> x(e_{I+1})
        i0, i1 = it_bounds[c0], it_bounds[c1]
        has_items = i1 > i0
        if has_items:
            sub_d[sub_off[i0:i1]] = np.where(it_rep[i0:i1], it_repd[i0:i1], dtab[it_I[i0:i1] - c0, it_p[i0:i1]])
            s0, s1 = int(sub_off[i0]), int(last_sub[i1 - 1] + 1)
            Fs, gs = _loop_matrices(tab, sub_d[s0:s1], sub_dt[s0:s1], sub_w[s0:s1])
            cnt = ccount[i0:i1]
            Ftot = Fs[sub_off[i0:i1] - s0]
            gtot = gs[sub_off[i0:i1] - s0]
            for r in range(1, int(cnt.max())):
                a = np.flatnonzero(cnt > r)
                si = sub_off[i0 + a] + r - s0
                Ftot[a] = Fs[si] @ Ftot[a]
                gtot[a] = np.einsum("pij,pj->pi", Fs[si], gtot[a]) + gs[si]
        if select:
            np.add(dtab[:c1 - c0, None, :] * (rows * P), idx_off[None], out=idx[:c1 - c0])
        for k in range(c0, c1):
            kk = k - c0
            X = Ba[nw:nw + n]
            Ba[:nw] = Wreg[k][:, None]
            if select:
                np.matmul(Faug, Ba[:nw + n], out=Y)
                np.take(Yflat, idx[kk], out=Bb[nw:])
                yk = Bb[nw + n:]
            else:
                dcol = dtab[kk]
                Bb[nw:nw + n] = ((Ffull[dcol] @ X.T[:, :, None])[:, :, 0] + Gfull[dcol] @ Wreg[k]).T
                yk = np.einsum("pij,jp->ip", Cst[tab.d_true[dcol]], X)
            if ny == 1:
                np.square(yk[0], out=ysq)
            else:
                np.sum(np.square(yk), axis=0, out=ysq)
            b0, b1 = sp_bounds[k], sp_bounds[k + 1]
            if b1 > b0:
                pp = spt_p[b0:b1]
                spt_x[b0:b1] = X[:, pp].T
                ysq[pp] = 0.0
            ysq *= wt_std[k]
            Ey += ysq
            b0, b1 = it_bounds[k], it_bounds[k + 1]
            if b1 > b0:
                pp = it_p[b0:b1]
                xs = X[:, pp]
                it_x[b0:b1] = xs.T
                Bb[nw:nw + n, pp] = (np.einsum("pij,jp->pi", Ftot[b0 - i0:b1 - i0], xs) + gtot[b0 - i0:b1 - i0]).T
            Ba, Bb = Bb, Ba
        # interior jump points of the chunk's special intervals
        if has_items:
            xi = it_x[i0:i1].copy()
            for r in range(1, int(cnt.max())):
                a = np.flatnonzero(cnt > r)
                si = sub_off[i0 + a] + r  # the piece starting at the point
                xi[a] = np.einsum("pij,pj->pi", Fs[si - 1 - s0], xi[a]) + gs[si - 1 - s0]
                Ci = Cst[tab.d_true[sub_d[si]]]
                qi = np.square(np.einsum("pij,pj->pi", Ci, xi[a])).sum(axis=1)
                Ey += np.bincount(it_p[i0 + a], sub_wt[si] * qi, minlength=P)
    # the last point t_N = horizon
    X = Ba[nw:nw + n]
    yK = np.einsum("pij,jp->pi", Cst[tab.d_true[dtab[npts - 1]]], X)
    qK = np.square(yK).sum(axis=1)
    b0, b1 = sp_bounds[K], sp_bounds[K + 1]
    if b1 > b0:
        spt_x[b0:b1] = X[:, spt_p[b0:b1]].T
        qK[spt_p[b0:b1]] = 0.0
    Ey += wt_std[K] * qK
    # special points
    Csp = Cst[tab.d_true[spt_d]]
    Ey += np.bincount(spt_p, spt_w * np.square(np.einsum("pij,pj->pi", Csp, spt_x)).sum(axis=1), minlength=P)
    return Ey, Ew


def _full_maps(tab: _Tables, step: float) -> tuple[np.ndarray, np.ndarray]:
    r"""Full-step maps :math:`F_d = \Phi + \Gamma B K`, :math:`G_d = \Gamma D` per
    dynamics id (``h = step``, :func:`phi_gamma`)."""
    Phi, Gam = phi_gamma(tab.A, np.full(tab.d_a.size, step), tab.d_a)
    return Phi + Gam @ tab.BK, Gam @ tab.Dm


# ------------------------------------------------------------------------------ continuous loop
@dataclass(frozen=True)
class _Exosystem:
    r"""``w(t) = E z(t)``, :math:`\dot z = S z`, ``z(0) = z0``; at each break time the
    state is reset to the given value."""

    S: np.ndarray
    z0: np.ndarray
    E: np.ndarray  # (nw, nz)
    breaks: tuple[tuple[float, np.ndarray], ...] = ()


def _exosystem(kind: str, nw: int) -> _Exosystem | None:
    """Exosystem of a named disturbance shape (None if there is none); it is checked
    against :data:`ftc_verify.paths.DISTURBANCES` on sample points."""
    ones = np.ones((nw, 1))
    rot = np.array([[1.0, 0.0]])
    table = {
        "paper": _Exosystem(np.array([[-0.1, 1.0], [-1.0, -0.1]]), np.array([0.0, 1.0]), ones @ rot),
        "sine": _Exosystem(np.array([[0.0, 1.0], [-1.0, 0.0]]), np.array([0.0, 1.0]), ones @ rot),
        "step": _Exosystem(np.zeros((1, 1)), np.ones(1), ones),
        "zero": _Exosystem(np.zeros((0, 0)), np.zeros(0), np.zeros((nw, 0))),
        "pulse": _Exosystem(np.zeros((1, 1)), np.ones(1), ones, ((1.0, np.zeros(1)),)),
    }
    exo = table.get(kind)
    if exo is None or kind not in DISTURBANCES:
        return None
    ts = np.array([0.0, 0.3, 0.999, 1.0, 1.7, 2.5, 4.0, 7.3])
    if exo.z0.size:
        z0s, t0s = [], []
        for t in ts:
            z, t0 = exo.z0, 0.0
            for tb, reset in exo.breaks:
                if tb <= t:
                    z, t0 = reset, tb
            z0s.append(z)
            t0s.append(t0)
        Phi, _ = phi_gamma(exo.S[None], ts - np.array(t0s), np.zeros(ts.size, dtype=np.int64))
        got = np.einsum("ij,kjl,kl->ki", exo.E, Phi, np.array(z0s))
    else:
        got = np.zeros((ts.size, nw))
    want = disturbance_fn(kind, nw)(ts)
    if not np.allclose(got, want, rtol=1e-12, atol=1e-12):
        return None
    return exo


def simulate_continuous(
    system: FTCSystem,
    gains: Sequence[Matrix],
    path: ChainPath,
    *,
    disturbance: str = "paper",
    delta: DeltaSchedule | str | None = None,
    x0: ArrayLike | None = None,
    rng: np.random.Generator | None = None,
    points_per_unit: int = 200,
) -> PathRecord:
    r"""The continuous-time closed loop on one path (no sample-and-hold).

    .. math::

        \dot x = \bigl(A_i + A1_i\Delta_1 A2_i + (B_i + B1_i\Delta_2 B2_i) K_j\bigr) x
                 + D_i w(t), \qquad y = C_i x, \qquad u = K_j x,

    with ``(i, j)`` the joint mode and :math:`\Delta` of the chain segment at ``t``
    (paper eqs. (2), (13)). Recorded on the grid
    ``communication_grid(path, 1 / points_per_unit)`` with the conventions of
    :func:`simulate_reference` (``u, y`` with the modes of the interval starting at the
    point; at the end the last interval's), ``w`` continuous.

    Integration is exact on each grid interval: the disturbance shapes of
    :data:`~ftc_verify.paths.DISTURBANCES` are outputs ``w = E z`` of linear exosystems
    :math:`\dot z = S z` (``paper``: :math:`z = e^{-0.1t}(\sin t, \cos t)`), so the pair
    :math:`(x, z)` follows :math:`\exp\bigl(\begin{smallmatrix} A_{cl} & D E \\ 0 & S
    \end{smallmatrix}\bigr) h` (the ``pulse`` is split at its switch); the exponentials of
    all intervals are made in one batch by :func:`phi_gamma` (a method independent of the
    :func:`scipy.linalg.expm` used by :func:`simulate_reference`). A shape without an
    exosystem is integrated per chain segment by :func:`scipy.integrate.solve_ivp`
    (DOP853, ``rtol=1e-10``, ``atol=1e-12``).
    """
    Ks = check_gains(system, gains)
    if not isinstance(path, ChainPath):
        raise ValidationError(f"path: expected a ChainPath, got {type(path).__name__}")
    _path_arrays(system, [path])
    if isinstance(points_per_unit, bool) or not isinstance(points_per_unit, (int, np.integer)) or points_per_unit < 1:
        raise ValidationError(f"points_per_unit: must be a positive integer, got {points_per_unit!r}")
    schedule = _schedule(delta)
    x0v = _initial_state(system, x0)
    n, nu, ny, nw = system.dims
    m = system.m
    wfun = disturbance_fn(disturbance, nw)
    gen = _rng(rng, None)
    segs = delta_segments(system, path, schedule, gen)
    t, true, fdi = communication_grid(path, 1.0 / points_per_unit)
    N = t.size - 1
    seg = np.searchsorted(path.times, t[:-1], side="right") - 1
    W = wfun(t)

    def closed(k: int) -> tuple[Matrix, Matrix]:
        i, j, g = int(true[k]), int(fdi[k]), int(seg[k])
        A, B = _perturbed(system, i, *segs[g])
        return A + B @ _gain(Ks, m, i, j), system.modes[i].D

    X = np.empty((N + 1, n))
    X[0] = x0v
    exo = _exosystem(disturbance, nw)
    if exo is not None:
        nz = exo.z0.size
        keys = [_delta_key(*d) for d in segs]
        mat_id: dict[Any, int] = {}
        mats: list[np.ndarray] = []
        pieces: list[tuple[int, float, np.ndarray | None]] = []  # (matrix, h, z reset after the piece)
        starts: list[np.ndarray | None] = [None] * N  # z reset at the start of an interval
        breaks = list(exo.breaks)
        for k in range(N):
            key = (int(true[k]), int(fdi[k]), keys[int(seg[k])])
            if key not in mat_id:
                Acl, D = closed(k)
                M = np.zeros((n + nz, n + nz))
                M[:n, :n] = Acl
                M[:n, n:] = D @ exo.E
                M[n:, n:] = exo.S
                mat_id[key] = len(mats)
                mats.append(M)
            while breaks and breaks[0][0] <= t[k]:
                starts[k] = breaks.pop(0)[1]
            tc = t[k]
            count = 0
            while breaks and breaks[0][0] < t[k + 1]:
                tb, reset = breaks.pop(0)
                pieces.append((mat_id[key], tb - tc, reset))
                tc = tb
                count += 1
            pieces.append((mat_id[key], t[k + 1] - tc, None))
        E, _ = phi_gamma(np.stack(mats), np.array([p[1] for p in pieces]), np.array([p[0] for p in pieces]))
        v = np.concatenate((x0v, exo.z0))
        pi = 0
        for k in range(N):
            if starts[k] is not None:
                v[n:] = starts[k]
            while True:
                v = E[pi] @ v
                reset = pieces[pi][2]
                pi += 1
                if reset is None:
                    break
                v[n:] = reset
            X[k + 1] = v[:n]
    else:
        bounds = np.searchsorted(t, np.append(path.times, path.horizon))
        x = x0v.copy()
        for g in range(path.times.size):
            a, b = int(bounds[g]), int(bounds[g + 1])  # grid points a..b of this segment
            Acl, D = closed(a)

            def rhs(tt: float, xx: np.ndarray, Acl: Matrix = Acl, D: Matrix = D) -> np.ndarray:
                return Acl @ xx + D @ wfun(np.array([tt]))[0]

            sol = scipy.integrate.solve_ivp(rhs, (t[a], t[b]), x, method="DOP853", t_eval=t[a + 1:b + 1],
                                            rtol=1e-10, atol=1e-12)
            if not sol.success:
                raise ValidationError(f"simulate_continuous: solve_ivp failed on segment {g}: {sol.message}")
            X[a + 1:b + 1] = sol.y.T
            x = X[b].copy()
    idx = np.minimum(np.arange(N + 1), N - 1)
    U = np.empty((N + 1, nu))
    Y = np.empty((N + 1, ny))
    for k in range(N + 1):
        i, j = int(true[idx[k]]), int(fdi[idx[k]])
        U[k] = _gain(Ks, m, i, j) @ X[k]
        Y[k] = system.modes[i].C @ X[k]
    return PathRecord(path, t, true, fdi, X, U, W, Y)
