"""What every command of the CLI shares: the exit codes, argument types, input loading and
output checks (:mod:`ftc_verify.cli.main` and the subcommand modules import them from here).

Exit codes are a contract (:mod:`ftc_verify.cli.main`). Nothing here imports numpy: building
the parser (``ftc-verify --help``) stays free of the numerical libraries.
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ..errors import FTCError
from ..jsonable import jsonable

__all__ = [
    "EXIT_OK",
    "EXIT_NEGATIVE",
    "EXIT_BAD_INPUT",
    "EXIT_UNCERTIFIED",
    "EXIT_INTERNAL",
    "EXIT_UNDECIDED",
    "EXIT_INTERRUPTED",
    "EXIT_PIPE",
    "EXIT_TERMINATED",
    "PLOT_SUFFIXES",
    "with_cross_check",
    "bad",
    "check_output_file",
    "fmt",
    "load",
    "strict",
    "positive",
    "nonneg_int",
    "positive_int",
    "seed_int",
    "Stopwatch",
    "add_connect_timeout",
    "connect_timeout",
]

EXIT_OK, EXIT_NEGATIVE, EXIT_BAD_INPUT, EXIT_UNCERTIFIED, EXIT_INTERNAL, EXIT_UNDECIDED = 0, 1, 2, 3, 4, 5
EXIT_INTERRUPTED, EXIT_PIPE, EXIT_TERMINATED = 130, 141, 143
#: Image formats ``--plot`` accepts (what matplotlib's Agg canvas writes).
PLOT_SUFFIXES = (".png", ".pdf", ".svg")


def bad(message: str) -> FTCError:
    """The error of a bad input (a :class:`~ftc_verify.errors.ValidationError`: exit 2)."""
    from ..errors import ValidationError

    return ValidationError(message)


def check_output_file(path: str, option: str, suffixes: tuple[str, ...] | None = None,
                      inputs: tuple[str, ...] = ()) -> None:
    """A file the command will write, checked before any work: not a folder, not one of
    the command's ``inputs``, right suffix, not an existing node that is not a regular file
    (a FIFO, a device: refused; a symbolic link: its target is checked, and written,
    :func:`~ftc_verify.model.output_paths.output_target`), in a folder that accepts a new file
    (an actual write, :func:`~ftc_verify.model.output_paths.probe_folder`)."""
    from ..model.output_paths import check_name, output_target, probe_folder

    if not str(path).strip():
        raise bad(f"{option} {path!r}: empty file name; give a file name")
    check_name(path, f"{option} {path}")  # a link loop, a name too long: before any other look at it
    p = Path(path)
    for given in inputs:
        if p.resolve() == Path(given).resolve():
            raise bad(f"{option} {path}: is the input file {given}; writing it would replace the input "
                      "(choose another output file)")
    if p.is_dir():
        raise bad(f"{option} {path}: is a folder; give a file name")
    if suffixes is not None and p.suffix.lower() not in suffixes:
        raise bad(f"{option} {path}: unsupported file type {p.suffix or '(none)'!r}; use one of {', '.join(suffixes)}")
    target = output_target(path, f"{option} {path}")
    probe_folder(target.parent if p.is_symlink() else p.parent, f"{option} {path}")


def fmt(x: float | None, digits: int = 6) -> str:
    """``x`` with ``digits`` significant digits, ``-`` for ``None``."""
    return "-" if x is None else f"{x:.{digits}g}"


def load(system_path: str, controller_path: str | None) -> tuple[Any, Any]:
    """The system and (when a path is given) the controller checked against it."""
    from ..controllers.files import load_controller
    from ..model.files import load_system

    system = load_system(system_path)
    if controller_path is None:
        return system, None
    return system, load_controller(controller_path).check(system, source=str(controller_path))


def strict(value: Any) -> Any:
    """JSON-ready built-ins, every non-finite float replaced by ``None`` (strict JSON)."""
    return jsonable(value)


def positive(text: str) -> float:
    """Argument type: a positive finite number."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not (value > 0 and value < float("inf")):
        raise argparse.ArgumentTypeError(f"must be positive and finite, got {text!r}")
    return value


def gamma_level(text: str) -> float:
    """Argument type of ``--gamma``: a positive number at most
    :data:`~ftc_verify.limits.GAMMA_MAX` (the syntheses form its square)."""
    from ..limits import GAMMA_MAX

    value = positive(text)
    if value > GAMMA_MAX:
        raise argparse.ArgumentTypeError(f"must be at most {GAMMA_MAX:g} (its square must stay a finite "
                                         f"float64 number), got {text!r}")
    return value


def nonneg_int(text: str) -> int:
    """Argument type: an integer, 0 or more."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be 0 or more, got {text!r}")
    return value


def positive_int(text: str) -> int:
    """Argument type: an integer, at least 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {text!r}")
    return value


def seed_int(text: str) -> int:
    """Argument type: a seed, a non-negative integer."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer seed: {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"seeds are non-negative, got {text!r}")
    return value


def add_connect_timeout(parser: argparse.ArgumentParser) -> None:
    """``--connect-timeout SECONDS`` (with ``--scheduler``) on a command's parser."""
    from ..limits import CONNECT_TIMEOUT

    parser.add_argument("--connect-timeout", type=positive, default=None, metavar="SECONDS",
                        help="with --scheduler: refuse the address when connecting to it (handshake included) "
                             f"takes longer than about this (default: {CONNECT_TIMEOUT:g})")


def connect_timeout(args: argparse.Namespace) -> float:
    """``--connect-timeout``, refused without ``--scheduler`` (exit 2, naming the option), or
    the default time box of connecting to ``--scheduler``
    (:data:`~ftc_verify.limits.CONNECT_TIMEOUT`)."""
    from ..limits import CONNECT_TIMEOUT

    if args.connect_timeout is not None and not args.scheduler:
        raise bad(f"--connect-timeout {args.connect_timeout:g}: only with --scheduler (the time box of connecting to it)")
    return CONNECT_TIMEOUT if args.connect_timeout is None else float(args.connect_timeout)


def _process_age() -> float:
    """Seconds since this process started (Linux: ``/proc``, to 0.01 s; elsewhere 0):
    the interpreter's start-up before :func:`~ftc_verify.cli.main.main` runs."""
    try:
        with open("/proc/self/stat") as f:
            started = int(f.read().rsplit(")", 1)[1].split()[19])  # field 22: start time in clock ticks
        with open("/proc/uptime") as f:
            uptime = float(f.read().split()[0])
        return max(0.0, uptime - started / os.sysconf("SC_CLK_TCK"))
    except (OSError, ValueError, IndexError):
        return 0.0


class Stopwatch:
    """The wall-time breakdown of one command (``timings`` of its JSON): ``startup`` (the
    interpreter's start and the CLI's imports, up to the command's first line), then each
    stage the command marks (:meth:`mark`), then ``total`` since the process started.

    ``spans`` holds each mark's ``(start, end)`` on the clock of :func:`time.perf_counter`
    and ``origin`` the process's start on that clock, so that stages run beside each other
    (in child processes: on Linux the clock is the same in every process) can be placed
    on one time line (:meth:`timeline`)."""

    def __init__(self) -> None:
        import time

        self._clock = time.perf_counter
        self._t0 = self._last = self._clock()
        self.timings: dict[str, float] = {"startup": _process_age()}
        self.origin = self._t0 - self.timings["startup"]
        self.spans: dict[str, tuple[float, float]] = {"startup": (self.origin, self._t0)}

    def mark(self, stage: str) -> float:
        """Record the time since the last mark (or the start) as ``stage``; return it."""
        now = self._clock()
        self.timings[stage] = self.timings.get(stage, 0.0) + now - self._last
        self.spans[stage] = (self.spans.get(stage, (self._last, now))[0], now)
        self._last = now
        return self.timings[stage]

    def timeline(self, spans: dict[str, tuple[float, float]] | None = None) -> dict[str, list[float]]:
        """``{stage: [start, end]}`` in seconds since the process started, for the marks
        and ``spans`` (more stages on the same clock), ordered by start."""
        every = self.spans | (spans or {})
        return {name: [round(a - self.origin, 4), round(b - self.origin, 4)]
                for name, (a, b) in sorted(every.items(), key=lambda item: item[1][0])}

    def total(self) -> float:
        """Seconds since the process started (``startup`` included)."""
        return self.timings["startup"] + self._clock() - self._t0


def with_cross_check(args: argparse.Namespace, command: Callable[[argparse.Namespace, Stopwatch, Any], int],
                     shared: str) -> int:
    """``command(args, watch, check)``: the body of ``analyze`` and ``verify``, with its
    :class:`Stopwatch` started first and python-control's cross-check child
    (:func:`ftc_verify.prestart.cross_check`) started right after importing ``shared``,
    the module of the command's numerical stages (numpy, scipy, the analysis: imported
    once, the forked child shares them), so that python-control's import runs beside
    everything the command does next (issue 37); the child is cancelled at the end."""
    import importlib

    from ..prestart import cross_check

    watch = Stopwatch()
    importlib.import_module(shared)
    check = cross_check()
    try:
        return command(args, watch, check)
    finally:
        check.cancel()
