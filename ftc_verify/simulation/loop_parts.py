"""The pieces of one supervisor run.

Plain data: the prepared control law (:class:`LoopLaw`), the operating-point offsets
(:class:`Offsets`), one path's plan on its grid (:class:`PathPlan`) and the record built
from the rows read (:func:`record_from_rows`).

The three parts of one path's loop, organised as FMPy's ``simulateCS`` (an ``Input``
applying the inputs, the FMU's ``doStep``, a ``Recorder`` sampling the outputs), with the
controller between them; :meth:`~ftc_verify.simulation.supervisor.Supervisor.run` walks
the grid with them:

* :class:`PathInputs` writes into the FMU: the true fault mode and the ``Delta`` segment
  at the plan's events, and ``u``, ``w(t_k)`` at every control sample (the FMU holds
  them across the jumps inside a period);
* :class:`PathController` chooses the controller entry of the modes at a sample, computes
  ``u_k = Cc[e] xc_k + Dc[e] v_k`` there (held until the next sample) and advances ``xc``
  exactly over a step with ``v_k`` held;
* :class:`PathRecorder` reads the FMU's values at every grid point (before ``u, w`` are
  written and, with feedthrough, after) and keeps the rows of the record.
"""

from __future__ import annotations

import ctypes
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..controllers.controller import Controller
from ..plants.fmu_session import FMUSession
from .paths import ChainPath
from .records import PathRecord

__all__ = ["LoopLaw", "Offsets", "PathPlan", "PathInputs", "PathController", "PathRecorder", "StaticLoop", "full_intervals",
           "record_from_rows"]


def full_intervals(t: np.ndarray, step: float) -> np.ndarray:
    """Which grid intervals are full ``[k step, (k+1) step]`` (both ends the floats
    ``k * step`` exactly, as :func:`~ftc_verify.simulation.paths.communication_grid` makes them)."""
    k = np.rint(t / step)
    is_mult = (k * step == t) & (k >= 0)
    return is_mult[:-1] & is_mult[1:] & (k[1:] == k[:-1] + 1)


@dataclass(frozen=True)
class LoopLaw:
    """The controller prepared for one run: contiguous matrices and the full-step updates."""

    controller: Controller
    full_info: bool
    m: int | None
    measured: bool  # v = y_m read from the FMU (else v = x)
    Cc: tuple[np.ndarray, ...]
    Dc: tuple[np.ndarray, ...]
    full_steps: tuple[tuple[np.ndarray, np.ndarray], ...]  # (Phi_c, Gamma_c) per entry, h = step
    external: Any = None  # a ControllerFMU computing u and xc instead of the matrices (--controller-fmu)

    def entry(self, true: int, fdi: int) -> int:
        return true * self.m + fdi if self.full_info else fdi  # type: ignore[operator]

    def update(self, e: int, full: bool, h: float) -> tuple[np.ndarray, np.ndarray]:
        return self.full_steps[e] if full else self.controller.discretise(e, h)


@dataclass(frozen=True)
class Offsets:
    """The operating point as offsets: of the values read before ``u`` (``x``, ``y_m``,
    maybe ``y``), of ``y`` read after ``u``, and of the written ``u``, ``w``; and ``x_op``."""

    read: np.ndarray
    y: np.ndarray
    u: np.ndarray
    w: np.ndarray
    x: np.ndarray


@dataclass(frozen=True)
class PathPlan:
    """One path on its grid: modes, segments and events, the disturbance and Delta values."""

    path: ChainPath
    t: np.ndarray
    true: np.ndarray
    fdi: np.ndarray
    W: np.ndarray
    events: list[int]
    seg: list[int]
    full: list[bool]
    delta_c: list[Any] | None
    sample: list[bool]  # control samples (:func:`~ftc_verify.simulation.paths.sample_points`)


def record_from_rows(plan: PathPlan, law: LoopLaw, n: int, XR: np.ndarray, U: np.ndarray, Y: np.ndarray | None,
            XC: np.ndarray) -> PathRecord:
    """The :class:`PathRecord` from the rows read before ``u`` (``x``, ``y_m``, ``y``)."""
    nv = law.controller.n_v if law.measured else 0
    X = XR[:, :n]
    YM = XR[:, n:n + nv] if law.measured else X
    if Y is None:  # y was read with x
        Y = XR[:, n + nv:]
    return PathRecord(path=plan.path, t=plan.t, true=plan.true, fdi=plan.fdi, x=np.ascontiguousarray(X), u=U,
                      w=plan.W, y=np.ascontiguousarray(Y), xc=XC, ym=np.ascontiguousarray(YM))


class PathInputs:
    """What the loop writes into the FMU on one path (as FMPy's ``Input``).

    Parameters
    ----------
    session : FMUSession
        The FMU.
    plan : PathPlan
        The path on its grid (modes, segments, events, ``w`` and ``Delta`` values).
    law : LoopLaw
        The control law (its :meth:`LoopLaw.entry` of the modes).
    offsets : Offsets or None
        The operating point, added to ``u`` and ``w`` as written.
    index : int
        The path's index, for the messages.

    Notes
    -----
    ``u`` and ``values`` are views of the buffer written by :meth:`write`
    (``u`` then ``w``); ``next_event`` is the next grid point where a mode or the
    segment changes (-1: none).
    """

    def __init__(self, session: FMUSession, plan: PathPlan, law: LoopLaw, offsets: Offsets | None,
                 index: int) -> None:
        self.session, self.plan, self.law, self.offsets, self.index = session, plan, law, offsets, index
        self.true_mode, self.segment = int(plan.true[0]), plan.seg[0]
        self.entry = law.entry(self.true_mode, int(plan.fdi[0]))
        self.next_event, self._events_done = plan.events[0], 0
        self.group = session.uw
        self.values = np.frombuffer(  # type: ignore[call-overload]  # numpy stub: ctypes arrays are buffers too
            self.group.buf, dtype=np.float64, count=self.group.n)
        self.u, self.w = self.values[:session.nu], self.values[session.nu:]
        self._has_w = session.nw > 0

    def start(self, x0: Any) -> None:
        """Initialise the FMU for the path at ``t = 0`` (:meth:`FMUSession.start_path`)
        from the state ``x0`` in the first true mode and ``Delta`` segment."""
        delta = self.plan.delta_c
        self.session.start_path(x0, self.true_mode, None if delta is None else delta[self.segment])

    def switch(self, k: int) -> int:
        """At the event grid point ``k``: write the new fault mode and ``Delta`` where they
        changed; return the controller entry of the new modes."""
        plan, session = self.plan, self.session
        when = f"at t = {float(plan.t[k])!r} (paths[{self.index}], grid point {k})"
        if plan.true[k] != self.true_mode:
            self.true_mode = int(plan.true[k])
            session.set_fault(self.true_mode, when)
        if plan.seg[k] != self.segment:
            self.segment = plan.seg[k]
            if plan.delta_c is not None:
                session.set_delta(plan.delta_c[self.segment], when)
        self._events_done += 1
        self.next_event = plan.events[self._events_done]
        self.entry = self.law.entry(self.true_mode, int(plan.fdi[k]))
        return self.entry

    def write(self, k: int) -> None:
        """Write ``u`` (already computed) and ``w(t_k)``, plus the operating point."""
        if self._has_w:
            self.w[:] = self.plan.W[k]
        if self.offsets is not None:
            self.u += self.offsets.u
            self.w += self.offsets.w
        self.session.write(self.group, self.group.buf)


class PathController:
    """The controller on one path: ``u_k = Cc[e] xc_k + Dc[e] v_k`` and the exact update of ``xc``.

    Parameters
    ----------
    law : LoopLaw
        The prepared controller.
    plan : PathPlan
        The path's grid (which intervals are full steps, their lengths).
    u : numpy.ndarray
        Where :meth:`output` writes ``u`` (``PathInputs.u``).
    entry : int
        The first controller entry.
    n : int
        The number of states: ``v`` is the ``y_m`` read after them when the controller
        measures the output, else the states.

    Notes
    -----
    ``state`` is ``xc`` (zero at the start, empty for a static controller).
    """

    def __init__(self, law: LoopLaw, plan: PathPlan, u: np.ndarray, entry: int, n: int) -> None:
        self.law, self.u = law, u
        self.dynamic = law.controller.n_c > 0
        self.state = np.zeros(law.controller.n_c)
        self.v = slice(n, n + law.controller.n_v) if law.measured else slice(0, n)
        self._full, self._steps = plan.full, np.diff(plan.t).tolist()
        self._times, self.external = plan.t.tolist(), law.external
        if self.external is not None:
            self.external.reset()  # xc = 0 at the start of every path
        self._v, self._held = np.zeros(law.controller.n_v), np.zeros(u.size)
        self.select(entry)

    def select(self, entry: int) -> None:
        """Use the controller entry ``entry`` from now on."""
        self.entry, self._gain = entry, self.law.Dc[entry]

    def output(self, row: np.ndarray, sample: bool = True) -> np.ndarray:
        """At a sample: ``u_k`` from the row read at ``t_k``
        (:meth:`PathRecorder.sample_before`), written into ``u``, and ``v_k`` kept; at a
        grid point inside a period (a jump): the held ``u`` of the last sample (a copy;
        nothing is written)."""
        if not sample:
            return self._held
        self._v = row[self.v].copy()
        if self.external is not None:  # the exported FMU: v and the FDI mode (1-based) in, u out
            self.u[:] = self.external.output(self.entry + 1, self._v)
        else:
            np.dot(self._gain, self._v, out=self.u)
            if self.dynamic:
                self.u += np.dot(self.law.Cc[self.entry], self.state)
        self._held = self.u.copy()
        return self.u

    def advance(self, k: int, row: np.ndarray) -> np.ndarray:
        """``xc_{k+1} = Phi_c xc_k + Gamma_c v`` over the interval ``k``, ``v`` (and the
        entry) of the last sample held."""
        if self.external is not None:  # doStep over the interval (v, FDI mode held), xc read back
            self.state = self.external.step(self._times[k], self._steps[k])
            return self.state
        phi, gamma = self.law.update(self.entry, self._full[k], self._steps[k])
        self.state = np.dot(phi, self.state) + np.dot(gamma, self._v)
        return self.state


class PathRecorder:
    """The rows one path records (as FMPy's ``Recorder``), read from the FMU at each grid point.

    Parameters
    ----------
    session : FMUSession
        The FMU.
    plan : PathPlan
        The path on its grid.
    law : LoopLaw
        The control law (whether ``y_m`` is read).
    offsets : Offsets or None
        The operating point, subtracted from the values read.

    Notes
    -----
    The rows: ``read_rows`` (``x``, ``y_m`` when measured, ``y`` without
    feedthrough: :meth:`FMUSession.read_groups`), ``U``, ``Y`` (``y`` read after
    ``u, w`` with feedthrough, else None) and ``XC``.
    """

    def __init__(self, session: FMUSession, plan: PathPlan, law: LoopLaw, offsets: Offsets | None) -> None:
        self.session, self.plan, self.law, self.offsets = session, plan, law, offsets
        self.before, self.after = session.read_groups(law.measured)
        self.feedthrough = session.feedthrough
        rows = len(plan.t)
        self._before = np.frombuffer(  # type: ignore[call-overload]  # numpy stub: ctypes arrays are buffers too
            self.before.buf, dtype=np.float64, count=self.before.n)
        self._after = np.frombuffer(  # type: ignore[call-overload]  # numpy stub: ctypes arrays are buffers too
            self.after.buf, dtype=np.float64, count=session.ny) if self.feedthrough else None
        self.read_rows = np.empty((rows, self.before.n))
        self.U = np.empty((rows, session.nu))
        self.Y = np.empty((rows, session.ny)) if self.feedthrough else None
        self.XC = np.zeros((rows, law.controller.n_c))

    def sample_before(self, k: int) -> np.ndarray:
        """Read the values before ``u, w`` at grid point ``k`` into their row, which is returned."""
        self.session.read(self.before)
        row = self.read_rows[k]
        row[:] = self._before
        if self.offsets is not None:
            row -= self.offsets.read
        return row

    def sample_after(self, k: int) -> None:
        """Read ``y`` after ``u, w`` at grid point ``k`` (feedthrough) into its row."""
        self.session.read(self.after)
        self.Y[k] = self._after  # type: ignore[index]
        if self.offsets is not None:
            self.Y[k] -= self.offsets.y  # type: ignore[index]

    def record(self) -> PathRecord:
        """The :class:`PathRecord` of the rows (:func:`record_from_rows`)."""
        return record_from_rows(self.plan, self.law, self.session.n, self.read_rows, self.U, self.Y, self.XC)


def _below(n: int, near: float) -> Any:
    """``row -> bool``: whether the first ``n`` entries of ``row`` are surely small
    (:class:`StaticLoop`, Notes): each of them within ``+-near / n`` for ``n <= 3``, else
    the float sum of their absolute values at most ``near``."""
    lim = near / max(n, 1)
    if n == 1:
        return lambda r: -lim <= r[0] <= lim
    if n == 2:
        return lambda r: -lim <= r[0] <= lim and -lim <= r[1] <= lim
    if n == 3:
        return lambda r: -lim <= r[0] <= lim and -lim <= r[1] <= lim and -lim <= r[2] <= lim
    return lambda r: sum(map(abs, r[:n])) <= near


def _unconverted(fn: Any) -> Any:
    """The C function of the ctypes function ``fn`` without its ``argtypes``: called with
    ctypes objects of exactly those types (a ``c_void_p``, ctypes arrays, a ``c_size_t``,
    ``c_double``, ``c_int``), it passes them as they are, with no conversion per call (the
    same call in C, a third cheaper); returns the ``int`` status. A Python callable
    standing in for the C function (a test's) gets the ``c_double`` arguments' values."""
    if isinstance(fn, ctypes._CFuncPtr):  # type: ignore[attr-defined]
        return ctypes.CFUNCTYPE(ctypes.c_int)(ctypes.cast(fn, ctypes.c_void_p).value or 0)

    def call(*args: Any) -> Any:
        return fn(*(a.value if isinstance(a, ctypes.c_double) else a for a in args))

    return call


class StaticLoop:
    r"""One path's loop (:meth:`~ftc_verify.simulation.supervisor.Supervisor.run`, steps
    1-4) for a static controller on an FMI 2.0 FMU without feedthrough or operating point,
    with the FMI calls made directly (:meth:`FMUSession.raw_calls`: no wrapper per call,
    the status checked inline, every status above Warning raised as the
    :class:`~ftc_verify.plants.fmu_session.FMICallError` of :meth:`FMUSession.failed`) and
    the rows kept as Python lists until the end: the same calls, in the same order, with
    the same values as the parts above, at a third of their cost per step.

    Parameters
    ----------
    session : FMUSession
        The FMU, its path started (:meth:`PathInputs.start`).
    inputs, recorder : PathInputs, PathRecorder
        The path's parts: ``inputs`` switches the modes at the events, ``recorder``
        receives the rows (:meth:`run` fills ``read_rows`` and ``U`` at the end, also when
        it raises).
    law : LoopLaw
        The static controller: ``u_k = Dc[e] v_k`` at each sample (``v`` the states or
        ``y_m``), held in between.

    Notes
    -----
    ``k`` and ``stage`` (``"x"``, ``"uw"``, ``"step"``) say where :meth:`run` stopped, as
    the supervisor's loop does; ``stop`` is the grid point where the path diverged
    (``|x|^2`` not below :data:`~ftc_verify.simulation.records.DIVERGENCE_BOUND` squared,
    the same ``numpy.dot`` as :func:`~ftc_verify.simulation.records.diverged`), else 0.
    That test is skipped when the float sum :math:`S` of the :math:`|x_i|` is at most
    :math:`c = B (1 - 10^{-6})` (:math:`B` the bound): then :math:`\sum x_i^2 \le
    (\sum |x_i|)^2 \le c^2 (1 + n u)^2` (:math:`u = 2^{-53}`), and ``numpy.dot`` of these
    :math:`n` non-negative squares, in any order and with or without fused multiply-adds,
    is at most :math:`(1 + n u)` times larger, so below :math:`B^2` for any
    :math:`n < 10^9`: the test would pass. A NaN or infinite entry makes :math:`S` NaN or
    infinite, and the test runs. So the decision is the test's at every grid point.
    For :math:`n \le 3` the skip asks instead that every :math:`|x_i|` be at most the
    float :math:`L = c / n` (``_below``: chained comparisons, a third of the sum's
    cost): then the exact :math:`\sum |x_i| \le n L \le c (1 + u)` and the same bound
    holds with one more factor :math:`(1 + u)`; a NaN entry fails its comparison, and the
    test runs.
    """

    def __init__(self, session: FMUSession, inputs: PathInputs, recorder: PathRecorder, law: LoopLaw) -> None:
        self.session, self.inputs, self.recorder, self.law = session, inputs, recorder, law
        self.k, self.stage, self.stop = 0, "", 0

    @staticmethod
    def applies(session: FMUSession, law: LoopLaw, offsets: Offsets | None) -> bool:
        """Whether this loop runs the path: a static controller, no operating point, no
        feedthrough, an FMI 2.0 FMU (:meth:`FMUSession.raw_calls`)."""
        return (law.external is None and law.controller.n_c == 0 and offsets is None and not session.feedthrough
                and session.raw_calls() is not None)

    def run(self, monitor: np.ndarray, bound_sq: float) -> None:
        """Walk the grid (``monitor[1]``: the time reached before each step); raises
        :class:`~ftc_verify.plants.fmu_session.FMICallError` where a call failed."""
        s, inputs, plan, rec = self.session, self.inputs, self.inputs.plan, self.recorder
        get, put, do_step, c = s.raw_calls()  # type: ignore[misc]
        get, put, do_step = _unconverted(get), _unconverted(put), _unconverted(do_step)
        before, group, n, nu = rec.before, inputs.group, s.n, s.nu
        vr_x, nx, buf_x, vr_uw, nuw, buf_uw = before.vr, before.n, before.buf, group.vr, group.n, group.buf
        # the arguments as ctypes objects of the C types: passed as they are (_unconverted)
        c, c_nx, c_nuw, c_true = ctypes.c_void_p(c), ctypes.c_size_t(nx), ctypes.c_size_t(nuw), ctypes.c_int(1)
        double, h_last, c_h = ctypes.c_double, math.nan, ctypes.c_double(math.nan)
        near = math.sqrt(bound_sq) * (1 - 1e-6)  # sum |x_i| <= near: |x|^2 <= bound_sq however summed (Notes)
        below = _below(n, near)
        read = np.frombuffer(buf_x, dtype=np.float64, count=nx)  # type: ignore[call-overload]
        x, v = read[:n], read[n:n + self.law.controller.n_v] if self.law.measured else read[:n]
        u, dot, Dc, entry = inputs.u, np.dot, self.law.Dc, inputs.entry
        # u = gain.dot(v): numpy.dot's own product (ndarray.dot and numpy.dot are one C function,
        # PyArray_MatrixProduct2), without numpy.dot's dispatch per call
        gain, held = Dc[entry], [0.0] * nu  # u before the first sample: zero, as in PathController
        W = plan.W.reshape(len(plan.t), -1).tolist() if s.nw else None
        times, steps, samples = plan.t.tolist(), np.diff(plan.t).tolist(), plan.sample
        last, event, rows, U = len(times) - 1, inputs.next_event, [], []
        at: Any = memoryview(monitor) if monitor.flags.c_contiguous and monitor.dtype == np.float64 else monitor  # type: ignore[arg-type]
        k, stage, wanted = 0, "", entry
        try:
            for k in range(last + 1):
                if k == event:
                    wanted = inputs.switch(k)
                    event = inputs.next_event
                sample = samples[k]
                if sample and entry != wanted:
                    entry = wanted
                    gain = Dc[entry]
                stage = "x"
                status = get(c, vr_x, c_nx, buf_x)
                if status > 1:
                    raise s.failed("fmi2GetReal", status, before.names)
                row = buf_x[:nx]
                rows.append(row)
                if k and not (below(row) or float(dot(x, x)) <= bound_sq):
                    self.stop = k
                    break
                if sample:
                    gain.dot(v, out=u)
                    held = buf_uw[:nu]  # type: ignore[assignment]  # c_double slices are floats
                    if W is not None:
                        buf_uw[nu:nuw] = W[k]
                    stage = "uw"
                    status = put(c, vr_uw, c_nuw, buf_uw)
                    if status > 1:
                        raise s.failed("fmi2SetReal", status, group.names)
                U.append(held)
                if k == last:
                    break
                stage = "step"
                t, h = times[k], steps[k]
                at[1] = t
                if h != h_last:
                    c_h, h_last = double(h), h
                status = do_step(c, double(t), c_h, c_true)
                if status > 1:
                    raise s.failed("fmi2DoStep", status, ())
                if s.pending is not None:
                    s.raise_pending()
        finally:
            self.k, self.stage = k, stage
            if rows:
                rec.read_rows[:len(rows)] = rows
            if U:
                rec.U[:len(U)] = U
