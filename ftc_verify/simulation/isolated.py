"""FMU co-simulation in a watched child process: a plant that crashes never takes this one with it.

A plant FMU is C code loaded into the process that runs it; a segfault there ends that
process with no Python exception to catch. :func:`run_isolated` therefore runs the
batches of an FMU Monte Carlo in child processes (:class:`PlantProcess`, one per core up
to :data:`MAX_PROCESSES`, each a contiguous run of the batches on one
:class:`~ftc_verify.simulation.supervisor.Supervisor`) and watches them:

* the child is a fresh interpreter (``python -m ftc_verify.simulation.isolated``): it
  inherits none of this process's threads, signal handlers or main module; its job comes
  pickled on its standard input, and every finished batch comes back pickled through a
  pipe of its own (with the FMU's log messages, which the parent forwards to ``log``), so
  the result is exactly what the same supervisor returns in this process. What the FMU's
  code prints goes to standard error, never into the command's standard output;
* the child writes the index of the running path and the time it has reached into a
  small memory-mapped file before every ``fmi2DoStep`` (the ``monitor`` of
  :meth:`Supervisor.run <ftc_verify.simulation.supervisor.Supervisor.run>`); when it dies
  the parent raises :class:`~ftc_verify.errors.PlantRunError` naming the FMU, the signal
  that ended it, the path and the time;
* the child extracts the FMU into a folder the parent made and removes, whatever happens;
  the child runs in a session of its own (a terminal's Ctrl-C reaches only this process)
  and dies with its parent (Linux ``PR_SET_PDEATHSIG``); the parent kills it (SIGKILL)
  when it leaves early (Ctrl-C, SIGTERM, an error), so a signal to this process ends the
  run at once and leaves nothing behind.

Errors raised in the child (an invalid map, an FMU that does not initialise) are sent back
and raised again here as themselves. :func:`call_isolated` runs one function in such a child
the same way (the FMU calls of ``plant --check`` and ``linearize``).
"""

from __future__ import annotations

import contextlib
import dataclasses
import mmap
import os
import pickle
import select
import shutil
import signal
import struct
import subprocess
import sys
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from ..controllers.controller import Controller
from ..errors import FMUError, PlantRunError
from ..interrupts import die_with_parent
from ..model.system import FTCSystem
from .paths import ChainPath
from .records import SimulationResult
from .spec import SimulationSpec

__all__ = ["POLL_SECONDS", "MAX_PROCESSES", "PlantProcess", "call_isolated", "default_processes", "plant_processes",
           "run_isolated"]

#: How often the parent looks at the child while no message arrives (seconds).
POLL_SECONDS = 0.1
#: Most children one isolated Monte Carlo runs its batches on.
MAX_PROCESSES = 2
_MONITOR = "monitor.f64"  # (path index in the batch, time reached, first path of the batch)
_HEADER = struct.Struct("<Q")


def _signal_name(returncode: int | None) -> str:
    if returncode is None or returncode >= 0:
        return f"exit code {returncode}"
    try:
        return f"signal {signal.Signals(-returncode).name}"
    except ValueError:
        return f"signal {-returncode}"


def _send(out: BinaryIO, message: tuple[str, Any]) -> None:
    data = pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL)
    out.write(_HEADER.pack(len(data)) + data)
    out.flush()


def _import_ahead() -> None:
    """What a child imports while it waits for its job: the job's generator
    (``numpy.random``) and fmpy's FMU loader (:func:`~ftc_verify.plants.fmi_calls.preload`);
    a caller that starts it early (``verify``) finds them ready when the job comes."""
    import numpy.random  # noqa: F401

    from ..plants.fmi_calls import preload

    preload()


def _child_main(workdir: str, fd: int) -> None:
    """The child: every batch on one supervisor; results, log lines and errors to ``fd``."""
    from .supervisor import Supervisor

    die_with_parent()
    _import_ahead()
    job = pickle.load(sys.stdin.buffer)
    out = os.fdopen(fd, "wb")
    if "call" in job:
        _child_call(job, workdir, out)
        return
    with open(Path(workdir) / _MONITOR, "r+b") as f:
        mm = mmap.mmap(f.fileno(), 3 * 8)
    monitor = np.frombuffer(mm, dtype=np.float64)
    plant, paths, spec, rng = job["plant"], job["paths"], job["spec"], job["rng"]
    batch = int(spec.batch)

    def log(status: str, category: str, message: str) -> None:
        _send(out, ("log", (status, category, message)))

    try:
        with Supervisor(plant.fmu, plant.injection_map(), system=job["system"], tolerance=plant.tolerance,
                        log=log if job["log"] else None, workdir=workdir) as sup:
            for b in range(0, len(paths), batch):
                monitor[2] = b
                _send(out, ("batch", sup.run(paths[b:b + batch], job["controller"], spec=spec, rng=rng,
                                             monitor=monitor)))
        _send(out, ("end", rng.bit_generator.state))
    except Exception as exc:  # sent back and raised again in the parent
        try:
            _send(out, ("error", exc))
        except Exception:  # an exception that does not pickle: its message
            _send(out, ("error", FMUError(f"{plant.fmu}: {type(exc).__name__}: {exc}")))


def _child_call(job: dict[str, Any], workdir: str, out: BinaryIO) -> None:
    """The child of :func:`call_isolated`: ``job["call"](*job["args"])`` sent back as the
    one batch, with every temporary folder (the extracted FMU) inside ``workdir``."""
    tempfile.tempdir = workdir
    try:
        _send(out, ("batch", job["call"](*job["args"])))
        _send(out, ("end", None))
    except Exception as exc:  # sent back and raised again in the parent
        try:
            _send(out, ("error", exc))
        except Exception:  # an exception that does not pickle: its message
            _send(out, ("error", FMUError(f"{job['fmu']}: {type(exc).__name__}: {exc}")))


class PlantProcess:
    """One watched child (module docstring), started by the constructor and waiting for
    its job: a caller that knows it will co-simulate starts it early (``verify`` does, before
    the synthesis), so the interpreter's start and its imports overlap that work. Used by
    one :func:`run_isolated` call; :meth:`close` (in a ``finally``) kills it if it is still
    running and removes its folder."""

    def __init__(self) -> None:
        self.workdir = tempfile.mkdtemp(prefix="ftc-verify-plant-")
        self.monitor_file = Path(self.workdir) / _MONITOR
        self.monitor_file.write_bytes(bytes(3 * 8))
        self.read_fd, write_fd = os.pipe()
        self.child: subprocess.Popen[bytes] | None = None
        self.buffer = bytearray()  # grown in place: a batch of several MB arrives in many reads
        self.first = 0  # index of this child's first path among all the paths of the run
        self.task: str | None = None  # what a call_isolated child does (its crash names no path)
        try:
            self.child = subprocess.Popen([sys.executable, "-m", "ftc_verify.simulation.isolated", self.workdir,
                                           str(write_fd)], stdin=subprocess.PIPE, stdout=2, pass_fds=(write_fd,),
                                          start_new_session=True)
        finally:
            os.close(write_fd)

    def send(self, job: bytes) -> None:
        """Hand the pickled job to the child. A child that has already ended (it could not
        start) is reported by the read that follows (:meth:`crashed`: its exit status), not
        as a broken pipe of this process, which the CLI would take for its own output."""
        assert self.child is not None and self.child.stdin is not None
        try:
            self.child.stdin.write(job)
            self.child.stdin.close()
        except BrokenPipeError:
            with contextlib.suppress(OSError):
                self.child.stdin.close()

    def receive(self) -> list[tuple[str, Any]] | None:
        """The messages complete after one read (the pipe is readable); ``None`` when the
        pipe closed (the child ended)."""
        chunk = os.read(self.read_fd, 1 << 20)
        if not chunk:
            return None
        self.buffer += chunk
        out = []
        while len(self.buffer) >= _HEADER.size:
            (size,) = _HEADER.unpack_from(self.buffer)
            if len(self.buffer) < _HEADER.size + size:
                break
            out.append(pickle.loads(self.buffer[_HEADER.size:_HEADER.size + size]))
            del self.buffer[:_HEADER.size + size]
        return out

    def crashed(self, fmu: str) -> PlantRunError:
        """The error of a child that ended without its ``end`` message."""
        assert self.child is not None
        returncode = self.child.wait()
        if self.task is not None:
            return PlantRunError(fmu, f"the process running it ended with {_signal_name(returncode)} "
                                 f"(a crash in the FMU's own code) {self.task}")
        index, time, first = np.frombuffer(self.monitor_file.read_bytes(), dtype=np.float64)
        return PlantRunError(fmu, f"the process running it ended with {_signal_name(returncode)} "
                             "(a crash in the FMU's own code)", path=self.first + int(first + index), time=float(time))

    def close(self) -> None:
        """Kill the child if it still runs, close the pipe, remove the folder."""
        if self.child is not None and self.child.poll() is None:
            self.child.kill()
            self.child.wait()
        if self.child is not None and self.child.stdin is not None and not self.child.stdin.closed:
            with contextlib.suppress(OSError):
                self.child.stdin.close()
        if self.read_fd >= 0:
            os.close(self.read_fd)
            self.read_fd = -1
        shutil.rmtree(self.workdir, ignore_errors=True)


def plant_processes(count: int | None = None) -> list[PlantProcess]:
    """``count`` (default: :func:`default_processes`) :class:`PlantProcess` children started now."""
    procs: list[PlantProcess] = []
    try:
        for _ in range(default_processes() if count is None else count):
            procs.append(PlantProcess())
    except BaseException:
        for p in procs:
            p.close()
        raise
    return procs


def default_processes() -> int:
    """Children of an isolated Monte Carlo: one per core this process may use, at most
    :data:`MAX_PROCESSES`."""
    try:
        cores = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        cores = os.cpu_count() or 1
    return max(1, min(MAX_PROCESSES, cores))


def run_isolated(system: FTCSystem, plant: Any, controller: Controller, paths: Sequence[ChainPath], *,
                 spec: SimulationSpec, rng: np.random.Generator, log: Callable[[str, str, str], None] | None = None,
                 done: Callable[[int], Any] | None = None,
                 processes: Sequence[PlantProcess] | None = None) -> list[SimulationResult]:
    """What ``Supervisor(plant.fmu, ...).run(batch_k, controller, spec=spec, ...)``
    returns for each batch of ``spec.batch`` paths (default
    :data:`~ftc_verify.simulation.batches.FMU_TASK_PATHS`), computed in watched child
    processes (module docstring). ``plant``: a resolved and checked
    :class:`~ftc_verify.plants.plant_map.PlantMap`; ``rng`` ends in the state a run in
    this process leaves it in; ``log`` gets the FMU's messages and ``done(k)`` is called
    after each batch of ``k`` paths.

    ``processes``: children started earlier (:func:`plant_processes`; closed here), default
    :func:`default_processes` started now. The batches are cut into as many contiguous
    runs as there are children (at most one per batch), each child starting from the
    generator state a serial run has at its first batch
    (:func:`~ftc_verify.simulation.streaming.batch_generators`), so the records are those
    of one serial run, in order; children left without batches are closed.

    Raises
    ------
    PlantRunError
        A child died (the plant FMU crashed, or something killed the process): names the
        FMU, the signal, the path (0-based index into ``paths``) and the time reached.
    """
    from .batches import FMU_TASK_PATHS
    from .streaming import batch_generators

    plist = list(paths)
    if spec.batch is None:
        spec = dataclasses.replace(spec, batch=FMU_TASK_PATHS)
    batch = int(spec.batch)  # type: ignore[arg-type]
    procs = list(processes) if processes is not None else plant_processes()
    try:
        n_batches = max(1, -(-len(plist) // batch))
        used, spare = procs[:n_batches], procs[n_batches:]
        for p in spare:
            p.close()
        starts = list(batch_generators(system, plist, spec.schedule, rng, batch))
        cuts = [round(k * n_batches / len(used)) for k in range(len(used) + 1)]
        for k, p in enumerate(used):
            p.first = cuts[k] * batch
            part = plist[cuts[k] * batch:cuts[k + 1] * batch]
            gen = starts[cuts[k]] if cuts[k] < len(starts) else rng
            p.send(pickle.dumps({"plant": plant, "system": system, "controller": controller, "paths": part,
                                 "spec": spec, "rng": gen, "log": log is not None},
                                protocol=pickle.HIGHEST_PROTOCOL))
        results = _collect(used, str(plant.fmu), log, done)
        return [r for k in range(len(used)) for r in results[k]]
    finally:
        for p in procs:
            p.close()


def call_isolated(fmu: str, task: str, function: Callable[..., Any], *args: Any) -> Any:
    """``function(*args)`` computed in a watched child (module docstring) that runs the
    plant FMU ``fmu`` (``plant --check``, ``linearize``): a signal to this process ends it
    at once (the child killed, its folder removed), a crash of the FMU's code is a
    :class:`~ftc_verify.errors.PlantRunError`, not the end of this process. ``function``
    and ``args`` must pickle (a module-level function); what it raises is raised here.

    Raises
    ------
    PlantRunError
        The child died: names the FMU, the signal that ended it and ``task`` (what it was
        doing, e.g. "during plant --check").
    """
    proc = PlantProcess()
    try:
        proc.task = task
        proc.send(pickle.dumps({"call": function, "args": args, "fmu": fmu}, protocol=pickle.HIGHEST_PROTOCOL))
        return _collect([proc], fmu, None, None)[0][0]  # the one "batch" message: the call's value
    finally:
        proc.close()


def _collect(procs: list[PlantProcess], fmu: str, log: Callable[[str, str, str], None] | None,
             done: Callable[[int], Any] | None) -> list[list[Any]]:
    """Every child's batches (:class:`SimulationResult`, or the one value of a
    :func:`call_isolated` child), as they arrive from all of them; a child's error raised
    again here, a child that ended without finishing as :meth:`PlantProcess.crashed`."""
    parts: list[list[Any]] = [[] for _ in procs]
    pending = {p.read_fd: k for k, p in enumerate(procs)}
    while pending:
        ready, _, _ = select.select(list(pending), [], [], POLL_SECONDS)
        for fd in ready:
            k = pending[fd]
            messages = procs[k].receive()
            if messages is None:
                raise procs[k].crashed(fmu)
            for kind, value in messages:
                if kind == "log" and log is not None:
                    log(*value)
                elif kind == "batch":
                    parts[k].append(value)
                    if done is not None:
                        done(len(value.records))
                elif kind == "error":
                    raise value
                elif kind == "end":
                    del pending[fd]
    return parts


if __name__ == "__main__":
    _child_main(sys.argv[1], int(sys.argv[2]))
