"""Command-line interface: ``ftc-verify COMMAND ...`` (also ``python -m ftc_verify``).

Exit codes are a contract (:doc:`/reference/exit-codes`):

* 0 -- the claim holds (certified / pass / done) and its verdict line was printed;
* 1 -- a negative answer that was shown: instability, a bound exceeded, a failed check;
* 2 -- bad input: one line on stderr naming the field or file and the value, no
  traceback, no output written;
* 3 -- the exact spectral test says mean-square stable but no LMI certificate was found
  (neither a proof of stability nor of instability);
* 4 -- an internal error (a bug): one line on stderr, never a traceback;
* 5 -- undecided: at some rate vertex neither mean-square stability nor instability could
  be proved (float64 nor ball arithmetic), never reported as 0 or 1;
* 130 / 143 -- interrupted by SIGINT / SIGTERM (temporary files removed);
* 141 -- the output pipe closed before the answer was printed (e.g. ``| head -1``).

Every command checks its output paths and options before any work starts.
"""

from __future__ import annotations

import argparse
import errno
import os
import re
import signal
import sys
import threading
import warnings
from collections.abc import Iterator, Sequence
from contextlib import contextmanager, nullcontext
from typing import Any, NoReturn

from .. import __version__
from ..errors import FTCError
from ..jsonable import dumps
from .common import (EXIT_BAD_INPUT, EXIT_INTERNAL, EXIT_INTERRUPTED, EXIT_NEGATIVE, EXIT_OK, EXIT_PIPE,
                     EXIT_TERMINATED, EXIT_UNCERTIFIED, EXIT_UNDECIDED, load, positive)

__all__ = ["main", "build_parser"]


#: OS errors that are the environment's, not a bug (exit 2 with the path and the error,
#: :doc:`/reference/exit-codes`): a full disk, a quota, a permission lost or refused, a
#: read-only file system.
_ENVIRONMENT_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EACCES, errno.EPERM, errno.EROFS, errno.EFBIG})


class _Terminated(BaseException):
    """Raised in the main thread by SIGTERM so that every ``finally`` cleans up."""


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:  # one line, exit 2, no usage dump
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message}\n")


def _cmd_analyze(args: argparse.Namespace) -> int:
    from .common import with_cross_check

    return with_cross_check(args, _analyze_command, "ftc_verify.analysis.analyze")


def _analyze_command(args: argparse.Namespace, watch: Any, check: Any) -> int:
    import dataclasses

    from ..analysis.analyze import analyze
    from ..analysis.closedloop import closed_loop
    from ..analysis.crossval import cross_validate
    from .sampled_lines import print_sampled, sampled_exit

    from ..analysis.solvers import interruptible

    system, controller = load(args.system, args.controller)
    period = args.period if args.period is not None else controller.period
    sampled_loop = None  # built once for the check, the analysis, the refinement and the gains
    if period is not None:
        from ..analysis.moments.sampled import SampledLoop

        sampled_loop = SampledLoop.build(system, controller)
    if args.h_max_work is not None:  # refused before any work (issue 31 item 2)
        from ..analysis.moments.sampled_refine import check_refine

        check_refine(system, controller, period, args.h_max_work, loop=sampled_loop)
    loop = closed_loop(system, controller)
    check.submit(cross_validate, loop)
    watch.mark("imports_and_load")
    rep = interruptible(lambda: analyze(loop, solver=args.solver, name=system.name, lmi=not args.no_lmi,
                                        cross_validation=False, lean=True), "the analysis")
    watch.mark("analysis")
    sampled = None
    if period is not None:  # the loop that runs: sampled every period, output held
        from ..analysis.moments.sampled import sampled_analysis

        sampled = interruptible(lambda: sampled_analysis(system, controller, period, loop=sampled_loop),
                                "the sampled-data analysis")
        if args.h_max_work is not None:
            from ..analysis.moments.sampled_refine import refine_result

            first = sampled
            sampled = interruptible(lambda: refine_result(system, controller, first, args.h_max_work, loop=sampled_loop),
                                    "the h_max refinement")
        if not args.no_lmi:  # its proved gains (issue 31 item 3)
            from ..analysis.moments.sampled_gamma import attach_performance

            found = sampled
            sampled = interruptible(lambda: attach_performance(found, system, controller, loop=sampled_loop),
                                    "the sampled-loop gains")
        watch.mark("sampled")
    per_mode = check.result()
    watch.mark("cross_validation_wait")
    rep = dataclasses.replace(rep, per_mode=per_mode, seconds=rep.seconds | {
        "cross_validation": check.seconds.get("run", 0.0), "cross_validation_wait": check.seconds["wait"]})
    if args.json:
        print(dumps(rep.to_dict() | {"timings": watch.timings | {"total": watch.total()},
                                     "lmi_requested": not args.no_lmi, "fdi_model": system.chain.describe(),
                                     "sampled": None if sampled is None else sampled.to_dict()}))
    else:
        from ..analysis.summary import analysis_summary

        print(analysis_summary(rep, fdi_model=system.chain.describe()))
        if sampled is not None:
            print_sampled(sampled)
    if rep.certified_stable or (args.no_lmi and rep.mss.stable):
        code = EXIT_OK
    elif rep.mss.undecided:
        code = EXIT_UNDECIDED
    else:
        code = EXIT_UNCERTIFIED if rep.mss.stable else EXIT_NEGATIVE
    return sampled_exit(code, sampled)


def _cmd_build_fmus(args: argparse.Namespace) -> int:
    from ..plants.linear_jump import FMUError, build_binary, build_fmu, validate
    from ..model.files import load_system

    lib = build_binary(force=args.force)
    print(f"binary: {lib}")
    systems = args.systems or []
    for path in systems:
        fmu = build_fmu(load_system(path))
        problems = validate(fmu)
        if problems:
            raise FMUError(f"{fmu}: validation found problems: {'; '.join(problems)}")
        print(f"{path}: {fmu} (validated, no problems)")
    print(f"verdict: built ({len(systems)} FMU{'s' if len(systems) != 1 else ''} validated)")
    return EXIT_OK


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``ftc-verify``."""
    p = _Parser(prog="ftc-verify", description=__doc__.splitlines()[0])
    p.add_argument("--version", action="version", version=f"ftc-verify {__version__}")
    sub = p.add_subparsers(dest="command", required=True, parser_class=_Parser)
    a = sub.add_parser("analyze", help="analyse a closed loop: exact MSS, certified LMIs, cross-validation")
    a.add_argument("system", help="system TOML file")
    a.add_argument("--controller", "--gains", dest="controller", required=True,
                   help="controller TOML file: [[gain]] K (state feedback) or [[controller]] Ac, Bc, Cc, Dc "
                        "(dynamic output feedback), one table per FDI mode; --gains is an alias")
    a.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    a.add_argument("--solver", default="auto", choices=["auto", "clarabel", "sdpa", "scs"],
                   help="LMI solver (default: auto = clarabel at every size; sdpa and scs on request)")
    a.add_argument("--no-lmi", action="store_true",
                   help="only the exact spectral test and the per-mode cross-check (no LMI certificates): "
                        "for loops whose LMIs would not fit in memory or time")
    a.add_argument("--period", type=positive, default=None,
                   help="sampling period H of the digital controller (default: the controller file's period, "
                        "else continuous time): proves the sampled loop's mean-square stability and h_max")
    from .sampled_lines import add_h_max_work_option

    add_h_max_work_option(a)
    a.set_defaults(func=_cmd_analyze)

    from .run_commands import add_run_commands

    add_run_commands(sub)
    b = sub.add_parser("build-fmus", help="compile the plant FMU binary (and FMUs for given systems), validate")
    b.add_argument("systems", nargs="*", help="system TOML files to build FMUs for")
    b.add_argument("--force", action="store_true", help="recompile even when the cached binary is up to date")
    b.set_defaults(func=_cmd_build_fmus)
    from .plant_commands import add_plant_commands
    from .synthesis_commands import add_synthesis_command

    add_synthesis_command(sub)
    add_plant_commands(sub)
    from .export_commands import add_export_commands

    add_export_commands(sub)
    from .risk_command import add_risk_command

    add_risk_command(sub)
    _no_abbreviations(p)
    return p


def _no_abbreviations(parser: argparse.ArgumentParser) -> None:
    """No abbreviated options on ``parser`` and every subcommand's parser: ``--path 10`` is
    an error, not ``--paths`` (a prefix that matches one option today could match another
    tomorrow, and a typo should not silently become a different option)."""
    parser.allow_abbrev = False
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                _no_abbreviations(sub)


@contextmanager
def _signals_raise(arrived: list[int]) -> Iterator[None]:
    """While the command runs, SIGTERM raises :class:`_Terminated` in the main thread so
    that cleanup runs as for Ctrl-C, and SIGINT raises ``KeyboardInterrupt`` (unless it is
    ignored); each records its arrival in ``arrived`` first, so that an exception a library
    swallowed (CPython ignores those raised in a gc callback or a ``__del__``) cannot make
    the command end as if it had not been signalled. The previous handlers are restored
    afterwards."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def terminated(signum: int, frame: Any) -> None:
        arrived.append(signum)
        raise _Terminated()

    def interrupted(signum: int, frame: Any) -> None:
        arrived.append(signum)
        raise KeyboardInterrupt

    previous = {signal.SIGTERM: signal.signal(signal.SIGTERM, terminated)}
    if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        previous[signal.SIGINT] = signal.signal(signal.SIGINT, interrupted)
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


def _closed_pipe() -> int:
    """stdout's reader went away: silence the final flush and report exit 141."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):
        pass
    print("ftc-verify: output pipe closed before the answer was printed", file=sys.stderr)
    return EXIT_PIPE


#: Options whose value is a comma-separated list of numbers (``risk --x0``, ``export-loop --x0``).
_NUMBER_LISTS = ("--x0",)


def _numbers_attached(argv: Sequence[str]) -> list[str]:
    """``--x0 -1,2`` as ``--x0=-1,2``: argparse takes a value that starts with ``-`` for an
    option unless it is one plain negative number, so a list starting with a negative
    number was refused ("expected one argument")."""
    out: list[str] = []
    for arg in argv:
        if out and out[-1] in _NUMBER_LISTS and re.fullmatch(r"-\.?[0-9][0-9eE.+\-]*(,[0-9eE.+\-]*)*", arg):
            out[-1] = f"{out[-1]}={arg}"
        else:
            out.append(arg)
    return out


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit code (module docstring).

    Unless set by the caller, BLAS runs single-threaded (``OPENBLAS_NUM_THREADS=1``; set
    before numpy is first imported): these problems are small, and on a busy 2-core
    machine threaded OpenBLAS made small matrix exponentials 1000x slower (measured).
    """
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")
    args = build_parser().parse_args(_numbers_attached(sys.argv[1:] if argv is None else argv))
    if argv is None and args.command == "analyze":  # this process's own command line only:
        from ..prestart import defer_numpy_tools  # it changes the interpreter for good

        defer_numpy_tools()  # numpy.f2py, numpy.testing: imported by scipy, used by nobody here
    if sys.stderr is None:  # started with stderr closed (`2>&-`): the user discards the messages
        sys.stderr = open(os.devnull, "w")  # takes fd 2: no file opened later lands on it
    if sys.stdout is None:  # started with stdout closed (`>&-`): the answer cannot be printed
        print("ftc-verify: error: stdout is closed, the answer could not be printed; nothing was done "
              "(to discard the answer, redirect it to /dev/null)", file=sys.stderr)
        return EXIT_BAD_INPUT
    arrived: list[int] = []  # signals received (_signals_raise)
    try:
        from .working import working

        own_bars = args.command in ("simulate", "verify")  # tqdm bars over their paths
        with _signals_raise(arrived), warnings.catch_warnings(), nullcontext() if own_bars else working(args.command):
            warnings.simplefilter("ignore")  # solver chatter; statuses are reported in the results
            code = int(args.func(args))
            sys.stdout.flush()
        return _signalled(arrived) if arrived else code  # a signal whose exception was swallowed
    except FTCError as exc:
        if arrived:  # the signal's exception became another one on its way here
            return _signalled(arrived)
        print(f"ftc-verify: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except BrokenPipeError:
        return _closed_pipe()
    except KeyboardInterrupt:
        return _signalled([signal.SIGINT])
    except _Terminated:
        return _signalled([signal.SIGTERM])
    except OSError as exc:
        if arrived:
            return _signalled(arrived)
        if exc.errno not in _ENVIRONMENT_ERRNOS:
            return _internal(exc)
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"ftc-verify: error: {where}{exc.strerror or exc} ({errno.errorcode.get(exc.errno, 'OSError')}: "
              "refused by the operating system; nothing was written)", file=sys.stderr)
        return EXIT_BAD_INPUT
    except MemoryError:
        if arrived:
            return _signalled(arrived)
        print(f"ftc-verify: error: out of memory (the problem is too large for this machine; {_limit_text()})",
              file=sys.stderr)
        return EXIT_BAD_INPUT
    except Exception as exc:  # a bug: one line, never a traceback, never exit 0 or 1
        return _signalled(arrived) if arrived else _internal(exc)


def _signalled(arrived: list[int]) -> int:
    """The exit code of the first signal in ``arrived`` (130 / 143), its line printed."""
    if arrived[0] == signal.SIGTERM:
        print("ftc-verify: terminated", file=sys.stderr)
        return EXIT_TERMINATED
    print("ftc-verify: interrupted", file=sys.stderr)
    return EXIT_INTERRUPTED


def _limit_text() -> str:
    """The memory limit the estimates are checked against, for the out-of-memory line."""
    from ..limits import format_bytes, memory_limit

    try:
        return f"the memory limit is {format_bytes(memory_limit())}; FTC_VERIFY_MEMORY_LIMIT sets it"
    except FTCError as exc:
        return str(exc)


def _internal(exc: BaseException) -> int:
    print(f"ftc-verify: internal error: {type(exc).__name__}: {exc} (please report)", file=sys.stderr)
    return EXIT_INTERNAL


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
