"""FMU co-simulation in a watched child process: a plant that crashes never takes this one with it.

A plant FMU is C code loaded into the process that runs it; a segfault there ends that
process with no Python exception to catch. :func:`run_isolated` therefore runs the
batches of an FMU Monte Carlo on one
:class:`~ftc_verify.simulation.supervisor.Supervisor` in a child process and watches it:

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
and raised again here as themselves.
"""

from __future__ import annotations

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
from ..model.system import FTCSystem
from .paths import ChainPath
from .records import SimulationResult
from .spec import SimulationSpec

__all__ = ["POLL_SECONDS", "run_isolated"]

#: How often the parent looks at the child while no message arrives (seconds).
POLL_SECONDS = 0.1
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


def _die_with_parent() -> None:
    """Linux: SIGKILL this process when its parent dies (best effort elsewhere)."""
    try:
        import ctypes

        ctypes.CDLL(None).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


def _child_main(workdir: str, fd: int) -> None:
    """The child: every batch on one supervisor; results, log lines and errors to ``fd``."""
    from .supervisor import Supervisor

    _die_with_parent()
    job = pickle.load(sys.stdin.buffer)
    out = os.fdopen(fd, "wb")
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


def _messages(fd: int, child: subprocess.Popen[bytes]) -> Any:
    """The child's messages as they arrive; ends when the pipe closes (the child ended)."""
    buffer = bytearray()  # grown in place: a batch of several MB arrives in many reads
    while True:
        ready, _, _ = select.select([fd], [], [], POLL_SECONDS)
        if not ready:
            continue
        chunk = os.read(fd, 1 << 20)
        if not chunk:
            return
        buffer += chunk
        while len(buffer) >= _HEADER.size:
            (size,) = _HEADER.unpack_from(buffer)
            if len(buffer) < _HEADER.size + size:
                break
            message = pickle.loads(buffer[_HEADER.size:_HEADER.size + size])
            del buffer[:_HEADER.size + size]
            yield message


def run_isolated(system: FTCSystem, plant: Any, controller: Controller, paths: Sequence[ChainPath], *,
                 spec: SimulationSpec, rng: np.random.Generator, log: Callable[[str, str, str], None] | None = None,
                 done: Callable[[int], Any] | None = None) -> list[SimulationResult]:
    """What ``Supervisor(plant.fmu, ...).run(batch_k, controller, spec=spec, ...)``
    returns for each batch of ``spec.batch`` paths (default
    :data:`~ftc_verify.simulation.batches.FMU_TASK_PATHS`), computed in a watched child
    process (module docstring). ``plant``: a resolved and checked
    :class:`~ftc_verify.plants.plant_map.PlantMap`; ``rng`` ends in the state a run in
    this process leaves it in; ``log`` gets the FMU's messages and ``done(k)`` is called
    after each batch of ``k`` paths.

    Raises
    ------
    PlantRunError
        The child died (the plant FMU crashed, or something killed the process): names
        the FMU, the signal, the path (0-based index into ``paths``) and the time reached.
    """
    from .batches import FMU_TASK_PATHS

    plist = list(paths)
    if spec.batch is None:
        spec = dataclasses.replace(spec, batch=FMU_TASK_PATHS)
    job = pickle.dumps({"plant": plant, "system": system, "controller": controller, "paths": plist, "spec": spec,
                        "rng": rng, "log": log is not None}, protocol=pickle.HIGHEST_PROTOCOL)
    workdir = tempfile.mkdtemp(prefix="ftc-verify-plant-")
    monitor_file = Path(workdir) / _MONITOR
    monitor_file.write_bytes(bytes(3 * 8))
    read_fd, write_fd = os.pipe()
    child: subprocess.Popen[bytes] | None = None
    parts: list[SimulationResult] = []
    try:
        child = subprocess.Popen([sys.executable, "-m", "ftc_verify.simulation.isolated", workdir, str(write_fd)],
                                 stdin=subprocess.PIPE, stdout=2, pass_fds=(write_fd,),
                                 start_new_session=True)
        os.close(write_fd)
        write_fd = -1
        assert child.stdin is not None
        child.stdin.write(job)
        child.stdin.close()
        for kind, value in _messages(read_fd, child):
            if kind == "log" and log is not None:
                log(*value)
            elif kind == "batch":
                parts.append(value)
                if done is not None:
                    done(len(value.records))
            elif kind == "error":
                raise value
            elif kind == "end":
                rng.bit_generator.state = value
                return parts
        returncode = child.wait()
        index, time, first = np.frombuffer(monitor_file.read_bytes(), dtype=np.float64)
        raise PlantRunError(str(plant.fmu), f"the process running it ended with {_signal_name(returncode)} "
                            "(a crash in the FMU's own code)", path=int(first + index), time=float(time))
    finally:
        if child is not None and child.poll() is None:
            child.kill()
            child.wait()
        for fd in (read_fd, write_fd):
            if fd >= 0:
                os.close(fd)
        shutil.rmtree(workdir, ignore_errors=True)


if __name__ == "__main__":
    _child_main(sys.argv[1], int(sys.argv[2]))
