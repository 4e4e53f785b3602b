r"""Co-simulation supervisor: the sampled-data FTC loop around an FMI 2.0 or 3.0 co-simulation FMU.

The FMU is the plant; the supervisor is the rest of the loop of the reference paper with a
:class:`~ftc_verify.controllers.Controller` (static state feedback ``u = K[l] x``, or a
static or dynamic controller on the measured output ``y_m``). On each path of the joint
(fault, FDI) chain it walks the grid :func:`~ftc_verify.simulation.paths.communication_grid`
``t_0 < ... < t_N`` (multiples of ``step`` and the jump times). The controller is
purely periodic: it reads and writes only at the samples
(:func:`~ftc_verify.simulation.paths.sample_points`; the jump times inside a period are
grid points for the plant only). On ``[t_k, t_{k+1})`` with joint mode ``(i, j)`` it

1. writes the fault mode ``i`` (when it changed) and ``Delta1, Delta2`` of the chain
   segment (:func:`~ftc_verify.simulation.delta.delta_segments`, when it changed) into the
   FMU, before reading anything at ``t_k``;
2. reads ``x_k`` and, at a sample, takes the controller input ``v_k``: ``x_k`` for state
   feedback, else the FMU's measured outputs ``y_m(t_k) = C_{y,i} x_k`` (the map's
   ``measured`` role), and the entry ``e = controller.index(i, j, m)``;
3. at a sample writes ``u_k = Cc[e] xc_k + Dc[e] v_k`` and ``w(t_k)`` (the FMU holds them
   until the next sample), then reads ``y_k``;
4. calls ``fmi2DoStep(t_k, t_{k+1} - t_k)`` (inputs, ``Delta`` and mode held) and advances
   ``xc_{k+1} = Phi_c xc_k + Gamma_c v`` exactly with ``v`` and ``e`` of the last sample
   held (:meth:`~ftc_verify.controllers.Controller.discretise`, cached per entry for full
   steps ``[k step, (k+1) step]``), ``xc_0 = 0``.

At ``t_N`` it records ``x_N, y_N, xc_N, v_N``, ``u_N = Cc[e] xc_N + Dc[e] v_N`` with the last
interval's modes and ``w(t_N)``; every :class:`~ftc_verify.simulation.records.PathRecord`
holds ``xc`` (zero columns when static) and ``ym`` = the ``v`` read (``x`` for state
feedback). Paths start at ``x = x0`` (default 0). This is the loop of the numpy reference
(:mod:`ftc_verify.simulation.reference`): on equal paths and ``Delta`` draws the backends
agree to rounding. The supervisor only follows the sampled paths, so the chain variant
``JointChain(..., fault_during_delay=True)`` needs nothing special.

The FMU itself -- checks, extraction, variables, FMI calls and their errors, logging,
cleanup -- is an :class:`~ftc_verify.plants.fmu_session.FMUSession` owned by the
supervisor, loaded and instantiated once; paths reuse the instance through ``fmi2Reset``.
Its :meth:`~ftc_verify.plants.fmu_session.FMUSession.read`,
:meth:`~ftc_verify.plants.fmu_session.FMUSession.write` and
:meth:`~ftc_verify.plants.fmu_session.FMUSession.step` make the calls of the FMU's version
(``fmi3GetFloat64``, ``fmi3SetFloat64``, ``fmi3DoStep``... for FMI 3.0); the steps above and
the handling of failed calls are the same for both versions. One path's loop is organised
as FMPy's ``simulateCS``: :class:`~ftc_verify.simulation.loop_parts.PathInputs` writes the
fault mode, ``Delta``, ``u`` and ``w``,
:class:`~ftc_verify.simulation.loop_parts.PathController` computes ``u`` and advances
``xc``, :class:`~ftc_verify.simulation.loop_parts.PathRecorder` reads and keeps the rows.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..controllers.controller import Controller
from ..errors import FMUError, PlantRunError, ValidationError
from ..model.system import FTCSystem
from .delta import DeltaSchedule, delta_segments, delta_shapes
from ..plants.fault_map import FaultInjectionMap
from ..plants.controller_session import ControllerFMU, ExportedController, check_period
from ..plants.fmu_session import FMICallError, FMUSession
from .paths import ChainPath, communication_grid, disturbance as disturbance_fn, sample_points, snap_to_grid
from .loop_parts import (LoopLaw, Offsets, PathController, PathInputs, PathPlan, PathRecorder, StaticLoop,
                         full_intervals)
from .records import DIVERGENCE_BOUND, PathRecord, SimulationResult
from .spec import SimulationSpec, spec_from

__all__ = ["FMUError", "FaultInjectionMap", "Supervisor", "open_supervisor", "resolve_plant", "simulate_fmu"]

_BOUND_SQ = DIVERGENCE_BOUND ** 2  # records.diverged's test: a path stops when |(x, xc)|^2 is not below it


def _delegate(name: str, doc: str) -> property:
    """A read-only property forwarding to the attribute ``name`` of ``self.session``."""
    return property(lambda self: getattr(self.session, name), doc=doc)


class Supervisor:
    """Sampled-data FTC loop around one FMI 2.0 or 3.0 co-simulation FMU (a context manager).

    Parameters
    ----------
    fmu
        Path of the ``.fmu`` archive.
    mapping
        The :class:`FaultInjectionMap`; default: :meth:`FaultInjectionMap.for_linear_jump_plant`
        of ``system``.
    system
        The :class:`~ftc_verify.model.FTCSystem` the FMU simulates; needed for ``Delta``
        (shapes and draws) and to check the controller; optional for other FMUs.
    instance_name
        ``instanceName`` passed to ``fmi2Instantiate``.
    tolerance, log, workdir
        Passed to the :class:`~ftc_verify.plants.fmu_session.FMUSession` (the
        ``fmi2SetupExperiment`` tolerance; a callback for every message the FMU logs; the
        folder to extract the FMU in).

    Notes
    -----
    With an ``operating_point`` in the :class:`FaultInjectionMap` the loop runs in deviation variables
    (:class:`~ftc_verify.plants.fault_map.OperatingPoint`): paths start at ``x_op + x0``,
    records hold ``x - x_op``, ``u - u_op``, ``w - w_op``, ``y - y_op``, ``y_m - y_m,op``.
    FMUs that cannot vary their communication step get paths whose jump times are moved
    to the grid of ``step`` (:func:`~ftc_verify.simulation.paths.snap_to_grid`); the result
    options give the largest shift (``timing_error``). So do runs with an exported
    controller FMU (:class:`~ftc_verify.plants.controller_session.ExportedController`, whose
    ``fmu`` computes ``u`` and steps ``xc``): its update is exact for its sampling period
    only, which must be ``step``.

    The archive is checked, extracted and loaded, and one instance is created, when the
    supervisor is constructed (:class:`~ftc_verify.plants.fmu_session.FMUSession`);
    :meth:`run` reuses it for every path (``fmi2Reset``). :attr:`stats` counts library
    loads, instantiations, resets, paths and steps.
    """

    def __init__(self, fmu: str | os.PathLike[str], mapping: FaultInjectionMap | None = None, *,
                 system: FTCSystem | None = None, instance_name: str = "ftc-verify-supervisor",
                 tolerance: float | None = None, log: Callable[[str, str, str], None] | None = None,
                 workdir: str | os.PathLike[str] | None = None) -> None:
        if mapping is None:
            if system is None:
                raise ValidationError("Supervisor: give a FaultInjectionMap, or the system of a LinearJumpPlant FMU")
            mapping = FaultInjectionMap.for_linear_jump_plant(system)
        if not isinstance(mapping, FaultInjectionMap):
            raise ValidationError(f"Supervisor: mapping must be a FaultInjectionMap, got {type(mapping).__name__}")
        if system is not None and not isinstance(system, FTCSystem):
            raise ValidationError(f"Supervisor: system must be an FTCSystem, got {type(system).__name__}")
        self.path = Path(fmu)
        self.mapping = mapping
        self.system = system
        self.instance_name = str(instance_name)
        self.session = FMUSession(self.path, mapping, instance_name=self.instance_name, tolerance=tolerance, log=log,
                                  workdir=workdir)
        self._op_outputs: tuple[np.ndarray, np.ndarray] | None = None
        self._controller_fmus: dict[str, ControllerFMU] = {}

    # -------------------------------------------------------------------- context manager
    def __enter__(self) -> Supervisor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Terminate and free the instance, unload the library, remove the extracted files
        (of the plant and of any exported controller FMU)."""
        self.session.close()
        while self._controller_fmus:
            self._controller_fmus.popitem()[1].close()

    # the session's state, read-only (as attributes of the supervisor before the split)
    slave = _delegate("slave", "The loaded FMU of this supervisor's session (``session.slave``; "
                               "None once closed).")
    closed = _delegate("closed", "True once :meth:`close` ran.")
    extraction_dir = _delegate("extraction_dir", "The temporary folder of the extracted FMU (None once closed).")
    stats = _delegate("stats", "Library loads, instantiations, resets, paths and steps so far.")
    messages = _delegate("messages", "The FMU's last log messages ``(status, category, text)``.")
    log_counts = _delegate("log_counts", "Messages logged by the FMU, per status.")
    model_description = _delegate("model_description", "The FMU's model description (``session.model_description``).")
    model_identifier = _delegate("model_identifier", "The FMU's co-simulation model identifier.")
    can_vary_step = _delegate("can_vary_step", "Whether the FMU can handle variable communication steps.")
    feedthrough = _delegate("feedthrough", "Whether an output ``y`` depends directly on ``u`` or ``w``.")

    # -------------------------------------------------------------------- checks
    def _modes(self) -> int | None:
        if self.system is not None:
            return self.system.m
        return len(self.mapping.fault_values) if self.mapping.fault_values is not None else None

    def _law(self, controller: Any, step: float) -> LoopLaw:
        """Check ``controller`` against the system and the map; prepare its matrices."""
        if not isinstance(controller, Controller):
            raise ValidationError(
                f"controller: expected a Controller (e.g. Controller.state_feedback(gains)), "
                f"got {type(controller).__name__}"
            )
        s, m = self.session, self._modes()
        if self.system is not None:
            controller.check(self.system, source="controller")
            n, _, ny, nw = self.system.dims
            for count, want, what in ((s.ny, ny, "outputs (performance y)"), (s.nw, nw, "disturbances w"),
                                      (s.n, n, "states x")):
                if count != want:
                    raise ValidationError(f"{self.path}: the map names {count} {what}, but the system "
                                          f"{self.system.name!r} has {want}; a missing role would read as zero")
        elif m is not None and controller.entries not in ((m, m * m) if controller.is_state_feedback else (m,)):
            raise ValidationError(f"controller: {controller.entries} entries given, the plant has {m} modes")
        measured = controller.measures == "output"
        if measured and not self.mapping.measured:
            raise ValidationError(
                f"controller: {controller.describe()} reads the measured output y_m, but "
                "FaultInjectionMap.measured names no FMU variable"
            )
        nv, what = (s.nym, "measured") if measured else (s.n, "states")
        if controller.nu != s.nu or controller.n_v != nv:
            raise ValidationError(
                f"controller: Dc is {controller.nu} x {controller.n_v}, but the fault-injection map has "
                f"{s.nu} inputs and {nv} {what} variables (expected {s.nu} x {nv})"
            )
        full_steps = tuple(controller.discretise(e, step) for e in range(controller.entries)) if controller.n_c else ()
        return LoopLaw(controller, m is not None and controller.full_information(m), m, measured,
                    tuple(np.ascontiguousarray(c, dtype=np.float64) for c in controller.Cc),
                    tuple(np.ascontiguousarray(d, dtype=np.float64) for d in controller.Dc), full_steps,
                    self._controller_fmu(controller, step))

    def _controller_fmu(self, controller: Controller, step: float) -> ControllerFMU | None:
        """The exported FMU of an :class:`ExportedController` (opened once per supervisor,
        closed with it; its period must be ``step``), else None."""
        if not isinstance(controller, ExportedController):
            return None
        if controller.fmu not in self._controller_fmus:
            self._controller_fmus[controller.fmu] = ControllerFMU(controller.fmu, workdir=self.session.workdir)
        fmu = self._controller_fmus[controller.fmu]
        check_period(fmu, step)
        return fmu

    def _offsets(self, law: LoopLaw) -> Offsets | None:
        """The operating point as offsets of the read and written vectors (None: origin)."""
        op = self.mapping.operating_point
        if op is None or op.is_zero():
            return None
        if self._op_outputs is None:
            self._op_outputs = self._probe(op)
        ym_op, y_op = self._op_outputs
        pre, _ = self.session.read_groups(law.measured)
        parts = [op.states] + ([ym_op] if law.measured else [])
        if pre.n > len(parts[0]) + (len(ym_op) if law.measured else 0):
            parts.append(y_op)  # y read together with x
        return Offsets(np.concatenate(parts), y_op, op.inputs, op.disturbances, op.states)

    def _probe(self, op: Any) -> tuple[np.ndarray, np.ndarray]:
        """``(y_m, y)`` of the FMU initialised at the operating point in the first fault mode."""
        s = self.session
        zero_delta = None
        if self.system is not None and s.delta.n:
            shapes = delta_shapes(self.system)
            zero_delta = s.delta_values(tuple(np.zeros(sh if sh else (0, 0)) for sh in shapes))
        return s.probe_outputs(op.states, np.concatenate([op.inputs, op.disturbances]), zero_delta)

    def _initial_state(self, x0: Any, off: Offsets | None) -> tuple[np.ndarray, np.ndarray]:
        """``(x0, the state the FMU starts at)``: ``x0`` checked (default 0), and plus ``x_op``."""
        init = self.session.init
        if x0 is None:
            arr = np.zeros(init.n)
        else:
            if not init.n:
                raise ValidationError(
                    "x0: the fault-injection map names no initial_states, so the initial state cannot be set"
                )
            arr = np.asarray(x0, dtype=float).reshape(-1)
            if arr.size != init.n or not np.all(np.isfinite(arr)):
                raise ValidationError(f"x0: expected {init.n} finite numbers, got {x0!r}")
        start = arr if off is None else arr + off.x
        return arr, start

    def _schedule(self, schedule: DeltaSchedule) -> DeltaSchedule:
        """``schedule`` checked against the plant map's Delta inputs."""
        if self.system is None:
            if schedule.kind != "zero":
                raise ValidationError(f"delta: kind {schedule.kind!r} needs the system (Supervisor(..., system=...))")
            return schedule
        self.mapping.check_delta(delta_shapes(self.system), schedule.kind)
        return schedule

    def _check_paths(self, paths: Any, law: LoopLaw) -> list[ChainPath]:
        if isinstance(paths, ChainPath):
            paths = [paths]
        paths = list(paths)
        if not paths or not all(isinstance(p, ChainPath) for p in paths):
            raise ValidationError("paths: expected a non-empty sequence of ChainPath")
        entries = law.controller.entries
        for i, p in enumerate(paths):
            top_true, top_fdi = int(np.max(p.true)), int(np.max(p.fdi))
            if law.m is not None and max(top_true, top_fdi) >= law.m:
                raise ValidationError(
                    f"paths[{i}]: mode {max(top_true, top_fdi)} (0-based) but the plant has {law.m} modes"
                )
            if not law.full_info and top_fdi >= entries:
                raise ValidationError(f"paths[{i}]: FDI mode {top_fdi} (0-based) but only {entries} controller entries")
        return paths

    # -------------------------------------------------------------------- running
    def run(
        self,
        paths: ChainPath | Sequence[ChainPath],
        controller: Controller,
        *,
        spec: SimulationSpec | None = None,
        step: float | None = None,
        disturbance: str | None = None,
        delta: DeltaSchedule | str | None = None,
        x0: Any = None,
        rng: np.random.Generator | None = None,
        seed: int | None = None,
        monitor: np.ndarray | None = None,
    ) -> SimulationResult:
        """Co-simulate every path; returns a :class:`~ftc_verify.simulation.records.SimulationResult`
        with ``backend="fmu"``.

        ``controller``: a :class:`~ftc_verify.controllers.Controller` (``m`` entries, one per
        FDI mode, or ``m * m`` full-information state-feedback gains ``K[i m + l]``; build
        static gains with ``Controller.state_feedback(gains)``). ``spec``: the
        :class:`~ftc_verify.simulation.spec.SimulationSpec` of the run -- its ``step``;
        ``disturbance``, a kind of :data:`ftc_verify.simulation.paths.DISTURBANCES`;
        ``delta``, whose values come from
        :func:`~ftc_verify.simulation.delta.delta_segments` (each path's own stream;
        ``rng``, default :meth:`~ftc_verify.simulation.spec.SimulationSpec.generator`, for
        paths without one); ``x0``, the initial plant state (default 0; needs
        :attr:`FaultInjectionMap.initial_states`; the controller state starts at 0);
        ``seed``, recorded. The keywords ``step``, ``disturbance``, ``delta``, ``x0``,
        ``seed`` are its shorthand (:func:`~ftc_verify.simulation.spec.spec_from`). With a
        system, the kept records are checked against the memory limit
        (:meth:`~ftc_verify.simulation.spec.SimulationSpec.check_memory`).
        ``monitor``: a float64 array of at least 2 entries (e.g. in memory shared with a
        watching process) that holds the index of the running path and the time reached.

        An ``fmi2Error`` or ``fmi2Discard`` (FMI 3.0: ``fmi3Error``, ``fmi3Discard``) inside a
        path's loop ends that path as a failed record
        (:meth:`~ftc_verify.simulation.records.PathRecord.failed`) and the next path runs;
        ``fmi2Fatal`` (``fmi3Fatal``) raises :class:`~ftc_verify.errors.PlantRunError`.
        """
        self.session.check_open()
        spec = spec_from(spec, {"step": step, "disturbance": disturbance, "delta": delta, "x0": x0, "seed": seed})
        monitor = np.zeros(3) if monitor is None else monitor
        step = spec.step
        law = self._law(controller, step)
        paths = self._check_paths(paths, law)
        if self.system is not None:
            spec.check_memory(self.system, law.controller, len(paths), max(p.horizon for p in paths))
        wfun = disturbance_fn(spec.disturbance, self.session.nw)
        schedule = self._schedule(spec.schedule)
        off = self._offsets(law)
        x0_arr, x0_c = self._initial_state(spec.x0, off)
        shift = 0.0
        if not self.can_vary_step or law.external is not None:  # an exported controller steps by its period
            snapped = [snap_to_grid(p, step) for p in paths]
            paths, shift = [p for p, _ in snapped], max(sh for _, sh in snapped)
        rng = spec.generator(rng)
        for mode in sorted({int(v) for p in paths for v in p.true.tolist()}):  # (np.unique would import numpy.ma)
            self.session.fault_writes(mode)  # every mode's values checked before any simulation

        warnings_before = self.log_counts.get("Warning", 0)
        records = []
        for i, p in enumerate(paths):
            segs = delta_segments(self.system, p, schedule, rng) if self.system is not None else None
            monitor[:2] = (i, 0.0)
            records.append(self._run_path(i, self._plan(i, p, step, wfun, segs), law, x0_c, off, monitor))
        options: dict[str, Any] = {
            "fmu": str(self.path),
            "delta": schedule.kind,
            "x0": x0_arr.tolist(),
            "gains": "full-information" if law.full_info else "fdi",
            "controller": controller.describe(law.m),
            "fmu_warnings": self.log_counts.get("Warning", 0) - warnings_before,
            "model_identifier": self.model_identifier,
            "timing_error": shift,
            "operating_point": off is not None,
        }
        if law.external is not None:
            options["controller_fmu"] = str(law.external.path)
        if self.system is not None:
            options["fault_during_delay"] = bool(self.system.chain.fault_during_delay)
        return SimulationResult(backend="fmu", seed=spec.seed, step=step,
                                horizon=float(max(p.horizon for p in paths)), disturbance=spec.disturbance,
                                records=tuple(records), options=options)

    def _plan(self, index: int, path: ChainPath, step: float, wfun: Any, segs: Any) -> PathPlan:
        t, true, fdi = communication_grid(path, step)
        N = len(t) - 1
        h = np.diff(t)
        if not self.can_vary_step and N > 1 and np.ptp(h) > 1e-9 * step:
            raise self.session.err(
                "the FMU does not declare canHandleVariableCommunicationStepSize, but the grid of "
                f"paths[{index}] has steps from {h.min():.6g} to {h.max():.6g} (jump times are grid points)"
            )
        seg = np.searchsorted(path.times, t[:-1], side="right") - 1
        delta_c = None
        if segs is not None:
            delta_c = [None] * len(segs)
            for j in set(seg.tolist()):
                delta_c[j] = self.session.delta_values(segs[j])
        # events: grid points (k >= 1) where the true mode, the FDI mode or the segment changes
        change = np.zeros(N, dtype=bool)
        if N > 1:
            change[1:] = (true[1:] != true[:-1]) | (fdi[1:] != fdi[:-1]) | (seg[1:] != seg[:-1])
        events = np.flatnonzero(change).tolist()
        events.append(-1)
        return PathPlan(path, t, true, fdi, wfun(t), events, seg.tolist(), full_intervals(t, step).tolist(), delta_c,
                        sample_points(path, step, t).tolist())

    def _run_path(self, index: int, plan: PathPlan, law: LoopLaw, x0: Any, off: Offsets | None,
                  monitor: np.ndarray | None) -> PathRecord:
        """The path ``index`` on the FMU (module docstring): at every grid point the inputs
        of the events, the values read, the controller's ``u`` and ``w`` written, a step;
        the parts of :mod:`~ftc_verify.simulation.loop_parts` do each."""
        s = self.session
        inputs = PathInputs(s, plan, law, off, index)
        inputs.start(x0)
        recorder = PathRecorder(s, plan, law, off)
        if StaticLoop.applies(s, law, off):  # the same calls and numbers, the FMI calls made directly
            return self._run_static(index, plan, StaticLoop(s, inputs, recorder, law), monitor)
        controller = PathController(law, plan, inputs.u, inputs.entry, s.n)
        times, steps, samples = plan.t.tolist(), np.diff(plan.t).tolist(), plan.sample
        last, n = len(times) - 1, s.n
        k, stage, stop = 0, "", 0
        # the loop's methods bound once: ~10 calls per grid point, 600,000 grid points in verify
        before, output, write, step, dot = recorder.sample_before, controller.output, inputs.write, s.step, np.dot
        U, XC, feedthrough, dynamic = recorder.U, recorder.XC, recorder.feedthrough, controller.dynamic
        try:
            for k in range(last + 1):
                if k == inputs.next_event:
                    inputs.switch(k)
                sample = samples[k]
                if sample and controller.entry != inputs.entry:
                    controller.select(inputs.entry)
                stage = "x"
                row = before(k)
                if k:  # records.diverged(x, xc), inline: the same sum of squares and the same test
                    x, xc = row[:n], controller.state
                    if not float(dot(x, x)) + (float(dot(xc, xc)) if dynamic else 0.0) <= _BOUND_SQ:
                        stop = k
                        break
                U[k] = output(row, sample)
                stage = "uw"
                if sample:
                    write(k)
                if feedthrough:
                    stage = "y"
                    recorder.sample_after(k)
                if k == last:
                    break
                if dynamic:
                    XC[k + 1] = controller.advance(k, row)
                stage = "step"
                monitor[1] = times[k]  # type: ignore[index]
                step(times[k], steps[k])
        except FMICallError as exc:
            error = self._loop_error(exc, stage, index, plan, k, law.measured, inputs.values)
            keep = k + 1 if stage == "step" else k  # the grid points recorded completely
            return self._failed(error, index, times[k], recorder.record(), keep)
        finally:
            s.stats["steps"] += min(k, last)
            s.raise_pending()
        s.stats["paths"] += 1
        if not stop and last:
            s.check_advanced(times[last], f"paths[{index}]")
        record = recorder.record()
        return record.truncated(stop) if stop else record

    def _run_static(self, index: int, plan: PathPlan, loop: StaticLoop, monitor: np.ndarray | None) -> PathRecord:
        """:meth:`_run_path` by :class:`~ftc_verify.simulation.loop_parts.StaticLoop`."""
        s, last = self.session, len(plan.t) - 1
        try:
            loop.run(np.zeros(3) if monitor is None else monitor, _BOUND_SQ)
        except FMICallError as exc:
            error = self._loop_error(exc, loop.stage, index, plan, loop.k, loop.law.measured, loop.inputs.values)
            keep = loop.k + 1 if loop.stage == "step" else loop.k
            return self._failed(error, index, float(plan.t[loop.k]), loop.recorder.record(), keep)
        finally:
            s.stats["steps"] += min(loop.k, last)
            s.raise_pending()
        s.stats["paths"] += 1
        if not loop.stop and last:
            s.check_advanced(float(plan.t[last]), f"paths[{index}]")
        record = loop.recorder.record()
        return record.truncated(loop.stop) if loop.stop else record

    def _failed(self, error: FMUError, index: int, time: float, record: PathRecord, keep: int) -> PathRecord:
        """The path ``index`` after the FMU failed in its loop at ``time``: a failed record,
        or :class:`PlantRunError` after ``fmi2Fatal`` (no further path can run)."""
        if self.session.dead:
            raise PlantRunError(str(self.path), str(error), path=index, time=time) from None
        self.session.stats["paths"] += 1
        return record.failed(keep, time, str(error))

    def _loop_error(self, exc: Any, stage: str, index: int, plan: PathPlan, k: int, measured: bool,
                    np_uw: np.ndarray) -> FMUError:
        """The error for an FMI call that failed at grid point ``k`` in ``stage``."""
        tl, N = plan.t.tolist(), len(plan.t) - 1
        if stage == "step":
            h = tl[k + 1] - tl[k]
            when = (f"at t = {tl[k]!r} with step size {h!r} (paths[{index}], grid point {k} of {N}, "
                    f"true mode {int(plan.true[k])}, FDI mode {int(plan.fdi[k])}, 0-based)")
            names: Sequence[str] = ()
        else:
            when = f"at t = {tl[k]!r} (paths[{index}], grid point {k} of {N})"
            pre, post = self.session.read_groups(measured)
            uw = [f"{name} = {v!r}" for name, v in zip(self.session.uw.names, np_uw.tolist())]
            names = {"x": pre.names, "y": post.names, "uw": uw}[stage]
        return self.session.call_error(exc, when, names)


# ------------------------------------------------------------------------------------------
# Convenience
# ------------------------------------------------------------------------------------------


def resolve_plant(system: FTCSystem, plant: Any = None) -> Any:
    """The plant map ``plant`` (:class:`~ftc_verify.plants.plant_map.PlantMap`) checked
    against ``system`` (:func:`~ftc_verify.plants.plant_map.check_against_system`); default:
    the map :func:`~ftc_verify.plants.build_fmu` writes beside the ``LinearJumpPlant`` of
    ``system`` -- one code path for every FMU."""
    from ..plants.linear_jump import build_fmu
    from ..plants.plant_map import PlantMap, check_against_system, load_plant_map, map_path_for

    if not isinstance(system, FTCSystem):
        raise ValidationError(f"expected an FTCSystem, got {type(system).__name__}")
    if plant is None:
        plant = load_plant_map(map_path_for(build_fmu(system)))
    elif not isinstance(plant, PlantMap):
        raise ValidationError(f"plant: expected a PlantMap, got {type(plant).__name__}")
    check_against_system(plant, system)
    return plant


def open_supervisor(system: FTCSystem, plant: Any = None, *,
                    log: Callable[[str, str, str], None] | None = None) -> Supervisor:
    """A :class:`Supervisor` for ``system`` on the FMU of :func:`resolve_plant`."""
    plant = resolve_plant(system, plant)
    return Supervisor(plant.fmu, plant.injection_map(), system=system, tolerance=plant.tolerance, log=log)


def simulate_fmu(
    system: FTCSystem,
    controller: Controller,
    paths: ChainPath | Sequence[ChainPath],
    *,
    spec: SimulationSpec | None = None,
    step: float | None = None,
    disturbance: str | None = None,
    delta: DeltaSchedule | str | None = None,
    x0: Any = None,
    rng: np.random.Generator | None = None,
    seed: int | None = None,
    plant: Any = None,
    log: Callable[[str, str, str], None] | None = None,
) -> SimulationResult:
    """Co-simulate ``paths`` under ``controller`` on :func:`open_supervisor`'s FMU (default:
    the cached ``LinearJumpPlant`` of ``system``); ``spec`` (or its shorthand keywords) and
    ``rng`` as :meth:`Supervisor.run`, checked before the FMU is opened."""
    spec = spec_from(spec, {"step": step, "disturbance": disturbance, "delta": delta, "x0": x0, "seed": seed})
    with open_supervisor(system, plant, log=log) as sup:
        return sup.run(paths, controller, spec=spec, rng=rng)
