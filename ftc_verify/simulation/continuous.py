r"""The continuous-time closed loop on one path (no sample-and-hold).

On the augmented state :math:`\xi = (x, x_c)` the loop of
:func:`ftc_verify.analysis.closedloop.closed_loop` in joint mode :math:`(i, j)` (its state
:math:`s` = ``chain.state_index(i, j)``; every detection phase of :math:`(i, j)` has the
same matrices) with the :math:`\Delta` of the chain segment at :math:`t` is

.. math::

    \dot\xi = \Bigl(A_s + \sum_k E_{s,k} \Delta_k F_{s,k}\Bigr) \xi + B_{w,s}\, w(t),
    \qquad A_s = \begin{bmatrix} A_i + B_i D_{c,e} M_i & B_i C_{c,e} \\
                                 B_{c,e} M_i & A_{c,e} \end{bmatrix},
    \qquad B_{w,s} = \begin{bmatrix} D_i \\ 0 \end{bmatrix},

with channels :math:`\Delta_1` (``"Delta1 (A)"``) and :math:`\Delta_2` (``"Delta2 (B)"``),
:math:`e` the controller entry and :math:`M_i` the measurement; the signals are
:math:`y = C_i x`, :math:`v = M_i x`, :math:`u = C_{c,e} x_c + D_{c,e} v`. For static
state feedback this is :math:`\dot x = (A_i + A1_i\Delta_1 A2_i + (B_i + B1_i\Delta_2
B2_i) K_j) x + D_i w` (paper eqs. (2), (13)).

Integration is exact on each grid interval: the disturbance shapes of
:data:`~ftc_verify.simulation.paths.DISTURBANCES` are outputs ``w = E z`` of linear
exosystems :math:`\dot z = S z` (``paper``: :math:`z = e^{-0.1t}(\sin t, \cos t)`), so
the pair :math:`(\xi, z)` follows :math:`\exp\bigl(\begin{smallmatrix} A_{cl} & B_w E \\
0 & S \end{smallmatrix}\bigr) h` (the ``pulse`` is split at its switch), all intervals in
one batch by :func:`~ftc_verify.simulation.discretise.phi_gamma` (a method independent of
the :func:`scipy.linalg.expm` of the reference). A shape without an exosystem is
integrated per chain segment by :func:`scipy.integrate.solve_ivp` (DOP853,
``rtol=1e-10``, ``atol=1e-12``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from ..analysis.closedloop import ClosedLoop, closed_loop
from ..controllers.controller import Controller
from ..errors import ValidationError
from ..model.system import FTCSystem, Matrix
from ._common import check_controller, delta_key, initial_state, measurements, path_arrays
from .delta import DeltaSchedule, delta_segments
from .discretise import phi_gamma
from .paths import DISTURBANCES, ChainPath, communication_grid, disturbance as disturbance_fn
from .records import PathRecord
from .spec import SimulationSpec, spec_from

__all__ = ["simulate_continuous"]

#: Uncertainty channel names of :func:`closed_loop` and the ``Delta`` each one takes.
_CHANNELS = {"Delta1 (A)": 0, "Delta2 (B)": 1}


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
    against :data:`ftc_verify.simulation.paths.DISTURBANCES` on sample points."""
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


def _loop_matrix(loop: ClosedLoop, s: int, deltas: tuple[Matrix | None, Matrix | None]) -> tuple[Matrix, Matrix]:
    r"""``(A_s + sum_k E_k Delta_k F_k, B_w,s)`` of joint mode ``s`` for one ``Delta`` value."""
    A = loop.A[s]
    for ch in loop.channels[s]:
        d = deltas[_CHANNELS[ch.name]]
        if d is not None:
            A = A + ch.E @ d @ ch.F
    return A, loop.Bw[s]


@dataclass(frozen=True)
class _Grid:
    """The recording grid of one path and the loop matrix of every interval."""

    t: np.ndarray
    true: np.ndarray
    fdi: np.ndarray
    seg: np.ndarray  # chain segment of each interval
    keys: tuple[Any, ...]  # (joint mode, Delta key) of each interval
    closed: Callable[[int], tuple[Matrix, Matrix]]  # interval -> (A_cl, B_w)


def _exact(grid: _Grid, exo: _Exosystem, z0: np.ndarray) -> np.ndarray:
    """States at the grid points by the exact exponentials of ``[[A_cl, B_w E], [0, S]]``."""
    t, nx = grid.t, z0.size
    N, nz = t.size - 1, exo.z0.size
    mat_id: dict[Any, int] = {}
    mats: list[np.ndarray] = []
    pieces: list[tuple[int, float, np.ndarray | None]] = []  # (matrix, h, exosystem reset after it)
    starts: list[np.ndarray | None] = [None] * N  # exosystem reset at the start of an interval
    breaks = list(exo.breaks)
    for k in range(N):
        key = grid.keys[k]
        if key not in mat_id:
            Acl, Bw = grid.closed(k)
            M = np.zeros((nx + nz, nx + nz))
            M[:nx, :nx], M[:nx, nx:], M[nx:, nx:] = Acl, Bw @ exo.E, exo.S
            mat_id[key] = len(mats)
            mats.append(M)
        while breaks and breaks[0][0] <= t[k]:
            starts[k] = breaks.pop(0)[1]
        tc = t[k]
        while breaks and breaks[0][0] < t[k + 1]:
            tb, reset = breaks.pop(0)
            pieces.append((mat_id[key], tb - tc, reset))
            tc = tb
        pieces.append((mat_id[key], t[k + 1] - tc, None))
    E, _ = phi_gamma(np.stack(mats), np.array([p[1] for p in pieces]), np.array([p[0] for p in pieces]))
    X = np.empty((N + 1, nx))
    X[0] = z0
    v = np.concatenate((z0, exo.z0))
    pi = 0
    for k in range(N):
        if starts[k] is not None:
            v[nx:] = starts[k]
        while True:
            v = E[pi] @ v
            after = pieces[pi][2]
            pi += 1
            if after is None:
                break
            v[nx:] = after
        X[k + 1] = v[:nx]
    return X


def _ivp(grid: _Grid, path: ChainPath, wfun: Callable[[np.ndarray], np.ndarray], z0: np.ndarray) -> np.ndarray:
    """States at the grid points by :func:`scipy.integrate.solve_ivp` per chain segment."""
    import scipy.integrate  # here: importing this module (every importer of ftc_verify.simulation) stays cheap

    t = grid.t
    X = np.empty((t.size, z0.size))
    X[0] = z0
    bounds = np.searchsorted(t, np.append(path.times, path.horizon))
    x = z0.copy()
    for g in range(path.times.size):
        a, b = int(bounds[g]), int(bounds[g + 1])  # grid points a..b of this segment
        Acl, Bw = grid.closed(a)

        def rhs(tt: float, xx: np.ndarray, Acl: Matrix = Acl, Bw: Matrix = Bw) -> np.ndarray:
            return Acl @ xx + Bw @ wfun(np.array([tt]))[0]

        sol = scipy.integrate.solve_ivp(rhs, (t[a], t[b]), x, method="DOP853", t_eval=t[a + 1:b + 1],
                                        rtol=1e-10, atol=1e-12)
        if not sol.success:
            raise ValidationError(f"simulate_continuous: solve_ivp failed on segment {g}: {sol.message}")
        X[a + 1:b + 1] = sol.y.T
        x = X[b].copy()
    return X


def _record(system: FTCSystem, controller: Controller, path: ChainPath, grid: _Grid, Z: np.ndarray,
            W: np.ndarray) -> PathRecord:
    """The signals at the grid points, with the modes of the interval starting there (at
    the end the last interval's)."""
    n, nu, ny, _ = system.dims
    m = system.m
    Ms = measurements(system, controller)
    N = grid.t.size - 1
    idx = np.minimum(np.arange(N + 1), N - 1)
    X, XC = Z[:, :n], Z[:, n:]
    U = np.empty((N + 1, nu))
    Y = np.empty((N + 1, ny))
    V = np.empty((N + 1, controller.n_v))
    for k in range(N + 1):
        i, j = int(grid.true[idx[k]]), int(grid.fdi[idx[k]])
        V[k] = Ms[i] @ X[k]
        U[k] = controller.output(controller.index(i, j, m), XC[k], V[k])
        Y[k] = system.modes[i].C @ X[k]
    return PathRecord(path, grid.t, grid.true, grid.fdi, np.ascontiguousarray(X), U, W, Y,
                      np.ascontiguousarray(XC), V)


def simulate_continuous(
    system: FTCSystem,
    controller: Controller,
    path: ChainPath,
    *,
    spec: SimulationSpec | None = None,
    disturbance: str | None = None,
    delta: DeltaSchedule | str | None = None,
    x0: ArrayLike | None = None,
    rng: np.random.Generator | None = None,
    points_per_unit: int = 200,
) -> PathRecord:
    r"""The continuous-time closed loop (module docstring) on one path.

    Recorded on the grid ``communication_grid(path, 1 / points_per_unit)`` with the
    conventions of :func:`~ftc_verify.simulation.reference.simulate_reference` (``u, v, y``
    with the modes of the interval starting at the point; at the end the last
    interval's), ``w`` continuous. ``controller`` is validated by
    :meth:`Controller.check`. ``spec``
    (:class:`~ftc_verify.simulation.spec.SimulationSpec`; its ``step`` is not used) gives
    the ``disturbance``, the ``delta`` and ``x0``, the plant initial state
    (:math:`x_c(0) = 0`); the keywords ``disturbance``, ``delta``, ``x0`` are its shorthand
    (:func:`~ftc_verify.simulation.spec.spec_from`). ``rng`` draws ``Delta`` kind
    ``random`` (default :meth:`~ftc_verify.simulation.spec.SimulationSpec.generator`).
    """
    spec = spec_from(spec, {"disturbance": disturbance, "delta": delta, "x0": x0})
    disturbance = spec.disturbance
    controller = check_controller(system, controller)
    if not isinstance(path, ChainPath):
        raise ValidationError(f"path: expected a ChainPath, got {type(path).__name__}")
    path_arrays(system, [path])
    if isinstance(points_per_unit, bool) or not isinstance(points_per_unit, (int, np.integer)) or points_per_unit < 1:
        raise ValidationError(f"points_per_unit: must be a positive integer, got {points_per_unit!r}")
    schedule = spec.schedule
    z0 = np.concatenate((initial_state(system, spec.x0), np.zeros(controller.n_c)))
    nw = system.dims[3]
    wfun = disturbance_fn(disturbance, nw)
    segs = delta_segments(system, path, schedule, spec.generator(rng))
    loop = closed_loop(system, controller)
    t, true, fdi = communication_grid(path, 1.0 / points_per_unit)
    seg = np.searchsorted(path.times, t[:-1], side="right") - 1
    dkeys = [delta_key(*d) for d in segs]
    # the loop's matrices of joint mode (true, fdi): those of its state at phase 0 (all
    # phases of a detection share them)
    state = [loop.chain.state_index(int(true[k]), int(fdi[k])) for k in range(t.size - 1)]
    keys = tuple((state[k], dkeys[int(seg[k])]) for k in range(t.size - 1))

    def closed(k: int) -> tuple[Matrix, Matrix]:
        return _loop_matrix(loop, state[k], segs[int(seg[k])])

    grid = _Grid(t, true, fdi, seg, keys, closed)
    exo = _exosystem(disturbance, nw)
    Z = _exact(grid, exo, z0) if exo is not None else _ivp(grid, path, wfun, z0)
    return _record(system, controller, path, grid, Z, wfun(t))
