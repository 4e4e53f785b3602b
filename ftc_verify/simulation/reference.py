r"""Exact numpy reference simulator of the sampled-data FTC loop, one path at a time.

Sampled-data loop (shared with the FMU backend, see :mod:`ftc_verify.simulation.paths`)
----------------------------------------------------------------------------------------
On a path of the joint (true, FDI) chain the communication grid
:func:`~ftc_verify.simulation.paths.communication_grid` gives ``t_0 < t_1 < ... < t_N``
(the multiples of ``step`` and the jump times) and the joint mode ``(i, j)`` on each
interval ``[t_k, t_{k+1})``. The controller is purely periodic: at the *samples*
(:func:`~ftc_verify.simulation.paths.sample_points`: the multiples of ``step``, a
multiple merged into a jump at that jump, and ``t_N``) it reads the measurement and the
FDI report, takes the disturbance value and computes its output; all three are held until
the next sample, across the jumps inside the period. With :math:`s(k)` the last sample at
or before :math:`t_k` and the controller entry :math:`e` (``controller.index(i, j, m)``
of the modes at :math:`t_{s(k)}`: the FDI mode, or ``i m + j`` for full-information
gains):

.. math::

    v_s = M_{i_s} x_s, \qquad u_s = C_{c,e}\, x_{c,s} + D_{c,e}\, v_s, \qquad w_s = w(t_s),

    A = A_i + A1_i \Delta_1 A2_i, \qquad B = B_i + B1_i \Delta_2 B2_i,
    \qquad h = t_{k+1} - t_k,

    x_{k+1} = \Phi(h) x_k + \Gamma(h) (B u_{s(k)} + D_i w_{s(k)}), \qquad
    x_{c,k+1} = \Phi_c(h)\, x_{c,k} + \Gamma_c(h)\, v_{s(k)},

    \Phi(h) = e^{A h}, \quad \Gamma(h) = \int_0^h e^{A s}\, ds, \quad
    \Phi_c(h) = e^{A_{c,e} h}, \quad \Gamma_c(h) = \int_0^h e^{A_{c,e} s}\, ds\, B_{c,e},

with the plant's true mode :math:`i` and :math:`(\Delta_1, \Delta_2)` of the interval
(of the chain segment containing ``t_k``,
:func:`~ftc_verify.simulation.delta.delta_segments`; ``delta=None`` means zero: they
change at the jumps, they are the plant), :math:`M_i` =
``controller.measurement(mode_i)`` (:math:`I` for state feedback, :math:`C_{y,i}` for
output feedback). The
controller's pieces compose to its exact update over the whole period
(:math:`v_s` and :math:`e` held). This is the loop whose second moments
:mod:`ftc_verify.analysis.moments.sampled` maps over one period and whose exact energy
:mod:`ftc_verify.analysis.moments.sampled_energy` computes. For static state feedback
(:math:`n_c = 0`, :math:`M_i = I`) :math:`u_s = K_{j_s} x_s`. The blocks
:math:`\Phi, \Gamma B, \Gamma D` are those of :math:`\exp\bigl(\begin{smallmatrix}
A & B & D \\ 0 & 0 & 0 \\ 0 & 0 & 0 \end{smallmatrix}\bigr) h`
(:func:`~ftc_verify.simulation.discretise.zoh_matrices`), :math:`\Phi_c, \Gamma_c` of
:meth:`Controller.discretise`. Recorded at every grid point: ``x``, the output
:math:`y_k = C_i x_k` with ``C`` of the *true* mode on the interval that starts at
``t_k`` (at ``t_N``: the last interval's mode), the held ``u``, the measurement
:math:`M_i x_k` read there (``ym``), ``x_c`` and the disturbance's value :math:`w(t_k)`
(for :math:`\|w\|_2`); at ``t_N`` (a sample) :math:`v_N = M_{i} x_N`,
:math:`u_N = C_{c,e} x_{c,N} + D_{c,e} v_N` with the last interval's modes. Every path
starts at ``x0`` (default 0) and :math:`x_c(0) = 0`.

Full-length intervals ``[k h, (k+1) h]`` (both ends multiples of ``step``, no jump
inside) use :math:`h = ` ``step`` exactly and a cached discretisation per
``(mode, Delta)`` (and per controller entry); intervals cut by jumps (and a shorter last
interval) get their own exponentials with ``h = t_{k+1} - t_k``.

The other entry points, re-exported here
----------------------------------------
* :func:`~ftc_verify.simulation.vectorised.energies_reference` -- per path
  :math:`\int |y|^2` and :math:`\int |w|^2` of the same loop, all paths advanced together;
* :func:`~ftc_verify.simulation.continuous.simulate_continuous` -- the continuous-time
  loop (no sample-and-hold);
* :func:`~ftc_verify.simulation.discretise.zoh_matrices`,
  :func:`~ftc_verify.simulation.discretise.phi_gamma` -- the exponentials.

Randomness: ``Delta`` kind ``random`` only, drawn from each path's own stream
(:meth:`~ftc_verify.simulation.paths.ChainPath.delta_generator`), so every backend sees
the same :math:`\Delta(t)` on a path; a hand-built path without a stream draws from
``rng`` (default ``numpy.random.default_rng(seed)``) in path order.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from ..controllers.controller import Controller
from ..model.system import FTCSystem, Matrix
from ._common import (
    check_controller,
    delta_key,
    full_intervals,
    initial_state,
    measurements,
    path_arrays,
    path_list,
    perturbed,
    run_options,
)
from .continuous import simulate_continuous
from .delta import DeltaSchedule, delta_segments
from .discretise import phi_gamma, zoh_matrices
from .vectorised import energies_reference
from .paths import ChainPath, communication_grid, disturbance as disturbance_fn, sample_points
from .records import PathRecord, SimulationResult, diverged
from .spec import SimulationSpec, spec_from

__all__ = [
    "simulate_reference",
    "energies_reference",
    "simulate_continuous",
    "zoh_matrices",
    "phi_gamma",
]

_Cache = dict[Any, tuple[Matrix, ...]]


def _plant_zoh(system: FTCSystem, i: int, seg: tuple[Matrix | None, Matrix | None], key: Any,
               h: float, full: bool, cache: _Cache) -> tuple[Matrix, ...]:
    """``(Phi, Gamma B, Gamma D)`` of true mode ``i`` with the segment's ``Delta``,
    cached under ``(i, key)`` for a full-length interval."""
    if not full:
        A, B = perturbed(system, i, *seg)
        return zoh_matrices(A, B, system.modes[i].D, h)
    mats = cache.get((i, key))
    if mats is None:
        A, B = perturbed(system, i, *seg)
        mats = cache[(i, key)] = zoh_matrices(A, B, system.modes[i].D, h)
    return mats


def _controller_zoh(controller: Controller, e: int, h: float, full: bool, cache: _Cache) -> tuple[Matrix, ...]:
    """``(Phi_c, Gamma_c)`` of entry ``e`` (:meth:`Controller.discretise`), cached for a
    full-length interval."""
    if not full:
        return controller.discretise(e, h)
    mats = cache.get(("controller", e))
    if mats is None:
        mats = cache[("controller", e)] = controller.discretise(e, h)
    return mats


def _simulate_path(system: FTCSystem, controller: Controller, path: ChainPath, segs: list[Any], step: float,
                   wfun: Callable[[np.ndarray], np.ndarray], x0: np.ndarray, cache: _Cache) -> PathRecord:
    """One path of the loop of the module docstring, recorded on its grid."""
    m = system.m
    n, nu, ny, _ = system.dims
    nc, nv = controller.n_c, controller.n_v
    Ms = measurements(system, controller)
    reads_state = controller.measures == "state"
    full_info, static = controller.full_information(m), controller.static
    Cc, Dc = controller.Cc, controller.Dc
    t, true, fdi = communication_grid(path, step)
    sample = sample_points(path, step, t)
    N = t.size - 1
    W = wfun(t)
    seg = np.searchsorted(path.times, t[:-1], side="right") - 1
    full = full_intervals(t, step)
    keys = [delta_key(*d) for d in segs]
    X, U, Y = np.empty((N + 1, n)), np.empty((N + 1, nu)), np.empty((N + 1, ny))
    XC, V = np.empty((N + 1, nc)), np.empty((N + 1, nv))
    x, xc = x0.copy(), np.zeros(nc)
    e, v, u, w = 0, np.zeros(nv), np.zeros(nu), W[0]
    for k in range(N):
        if k and diverged(x, xc):
            return PathRecord(path, t, true, fdi, X, U, W, Y, XC, V).truncated(k)
        i, j, g = int(true[k]), int(fdi[k]), int(seg[k])
        if sample[k]:  # the controller reads x (y_m) and the FDI report, and holds u and w
            e = i * m + j if full_info else j
            v = x if reads_state else Ms[i] @ x
            u = Dc[e] @ v if static else Cc[e] @ xc + Dc[e] @ v
            w = W[k]
        X[k], U[k], Y[k], XC[k], V[k] = x, u, system.modes[i].C @ x, xc, x if reads_state else Ms[i] @ x
        h = step if full[k] else t[k + 1] - t[k]
        Phi, GB, GD = _plant_zoh(system, i, segs[g], keys[g], h, bool(full[k]), cache)
        if not static:
            Phic, Gamc = _controller_zoh(controller, e, h, bool(full[k]), cache)
            xc = Phic @ xc + Gamc @ v
        x = Phi @ x + GB @ u + GD @ w
    if diverged(x, xc):
        return PathRecord(path, t, true, fdi, X, U, W, Y, XC, V).truncated(N)
    i, j = int(true[-1]), int(fdi[-1])
    e = i * m + j if full_info else j
    v = x if reads_state else Ms[i] @ x
    X[N], U[N], Y[N], XC[N], V[N] = x, controller.output(e, xc, v), system.modes[i].C @ x, xc, v
    return PathRecord(path, t, true, fdi, X, U, W, Y, XC, V)


def simulate_reference(
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
    seed: int | None = None,
) -> SimulationResult:
    r"""Simulate the sampled-data loop (module docstring) on every path, exactly.

    Parameters
    ----------
    system : FTCSystem
    controller : Controller
        One entry per FDI mode (or ``m * m`` full-information state-feedback gains),
        validated by :meth:`Controller.check`; static gains are
        ``Controller.state_feedback(gains)``.
    paths : ChainPath or sequence of ChainPath
    spec : SimulationSpec, optional
        The run: ``step`` (the control
        period; the grid is :func:`~ftc_verify.simulation.paths.communication_grid`),
        ``disturbance`` (a kind of :data:`ftc_verify.simulation.paths.DISTURBANCES`, on
        every channel), ``delta`` (:math:`\Delta(t)`, from
        :func:`~ftc_verify.simulation.delta.delta_segments` per path in path order),
        ``x0`` (initial plant state of every path, default 0; the controller starts at
        :math:`x_c = 0`) and ``seed`` (of the generator for ``Delta`` kind ``random`` on
        paths without their own stream; recorded in the result). The kept records are
        checked against the memory limit
        (:meth:`~ftc_verify.simulation.spec.SimulationSpec.check_memory`).
    step, disturbance, delta, x0, seed
        Shorthand for ``spec=SimulationSpec(step=..., ...)``
        (:func:`~ftc_verify.simulation.spec.spec_from`); not together with ``spec``.
    rng
        Generator for ``Delta`` kind ``random`` on paths without their own stream
        (default :meth:`~ftc_verify.simulation.spec.SimulationSpec.generator`; sampled
        paths draw from :meth:`~ftc_verify.simulation.paths.ChainPath.delta_generator`).

    Returns
    -------
    SimulationResult
        ``backend="reference"``, one :class:`~ftc_verify.simulation.PathRecord` per path
        (with ``xc`` and the read signal ``ym = v``). ``horizon`` is the largest path
        horizon.

    Notes
    -----
    One loop per path over the grid intervals: :math:`x_{k+1} = \Phi x_k + \Gamma B u_k
    + \Gamma D w_k` with the blocks of :func:`scipy.linalg.expm` of the augmented matrix
    (:func:`zoh_matrices`), cached per ``(true mode, Delta)`` for the full-length intervals
    (``h = step``) across paths, computed afresh for every interval cut by a jump; the
    same for :math:`(\Phi_c, \Gamma_c)` per controller entry.
    """
    spec = spec_from(spec, {"step": step, "disturbance": disturbance, "delta": delta, "x0": x0, "seed": seed})
    controller = check_controller(system, controller)
    plist = path_list(paths)
    path_arrays(system, plist)
    horizon = float(max(p.horizon for p in plist))
    spec.check_memory(system, controller, len(plist), horizon)
    schedule = spec.schedule
    x0v = initial_state(system, spec.x0)
    wfun = disturbance_fn(spec.disturbance, system.dims[3])
    gen = spec.generator(rng)
    cache: _Cache = {}
    records = []
    for p in plist:
        segs = delta_segments(system, p, schedule, gen)
        records.append(_simulate_path(system, controller, p, segs, spec.step, wfun, x0v, cache))
    return SimulationResult(
        backend="reference",
        seed=spec.seed,
        step=spec.step,
        horizon=horizon,
        disturbance=spec.disturbance,
        records=tuple(records),
        options=run_options(system, schedule, x0v, controller,
                            method="exact zero-order hold (scipy.linalg.expm)"),
    )
