"""Exception hierarchy of ftc-verify.

Every error the package raises on purpose derives from :class:`FTCError`, and each
subclass also inherits the built-in exception it refines, so callers may catch either
``FTCError`` or the familiar built-in (``ValueError``, ``RuntimeError``, ``OSError``).
Messages name the offending field, file or solver together with the value seen.
"""

from __future__ import annotations

from typing import Any

__all__ = [
    "FTCError",
    "ValidationError",
    "ProblemFileError",
    "SolverError",
    "FMUError",
    "MemoryLimitError",
    "PlantRunError",
    "OutputError",
]


class FTCError(Exception):
    """Root of every error raised deliberately by ftc-verify."""


class ValidationError(FTCError, ValueError):
    """A model, controller or option has an invalid value (names the field and value)."""


class ProblemFileError(ValidationError):
    """A system or gains file is unreadable, malformed or inconsistent.

    The message starts with the file name and, where it applies, the table index and key.
    """


class SolverError(FTCError, RuntimeError):
    """A convex solver failed or raised; the message names the solver."""


class FMUError(FTCError, RuntimeError):
    """Building, locating, validating or running an FMU failed (names the file and the problem)."""


class MemoryLimitError(FTCError, MemoryError):
    """A problem would need more memory than allowed (names the estimate and the limit).

    ``MemoryLimitError.__new__(MemoryLimitError)`` must work: it is how pickle's
    ``copyreg`` reconstructors (and tblib's, which Dask installs for every exception once
    a cluster is used in the process) rebuild an exception sent back by a forked stage.
    Inherited, it would be ``MemoryError.__new__``, which Python refuses for a class laid
    out as ``Exception`` (``"MemoryError.__new__(MemoryLimitError) is not safe"``), and the
    clear memory-limit error would become an internal error."""

    def __new__(cls, *args: Any) -> MemoryLimitError:
        return Exception.__new__(cls, *args)


class OutputError(FTCError, OSError):
    """The operating system refused to write an output (a full disk, a quota, a lost
    permission, a read-only file system): names the path and the OS error. The command
    line answers it like bad input (exit 2); nothing is left half-written."""


class PlantRunError(FMUError):
    """The plant FMU crashed, or returned ``fmi2Fatal``, while a run was under way.

    A property of the plant, not bad input and not a bug of this tool: the command line
    reports it as a negative result (exit 1) naming the FMU, the path and the time.
    (An ``fmi2Error`` or ``fmi2Discard`` during a path is not raised: that path is
    recorded as failed and the run goes on.)

    Attributes
    ----------
    fmu : str
        The FMU file.
    path : int or None
        The 0-based index of the path that was running (None: not known).
    time : float or None
        The simulated time reached on that path (None: not known).
    detail : str
        What happened (the signal that ended the process, the FMU's last log line...).
    batch : tuple of int or None
        ``(first, stop)``: the 0-based path range of the batch that was running, when the
        path itself is not known (a Dask worker that died).
    """

    def __init__(self, fmu: str, detail: str, *, path: int | None = None, time: float | None = None,
                 batch: tuple[int, int] | None = None) -> None:
        self.fmu, self.detail, self.path, self.time, self.batch = str(fmu), detail, path, time, batch
        where = ""
        if path is not None:
            where = f" on paths[{path}]" + ("" if time is None else f" at t = {time:.6g}")
        elif batch is not None:
            where = f" on paths[{batch[0]}:{batch[1]}]"
        super().__init__(f"{fmu}: the plant FMU failed{where}: {detail}")

    def __reduce__(self) -> tuple[Any, ...]:  # picklable across processes
        return (_plant_run_error, (self.fmu, self.detail, self.path, self.time, self.batch))


def _plant_run_error(fmu: str, detail: str, path: int | None, time: float | None,
                     batch: tuple[int, int] | None) -> PlantRunError:
    return PlantRunError(fmu, detail, path=path, time=time, batch=batch)
