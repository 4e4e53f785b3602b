"""Convex solvers behind the LMIs: choice, settings and a call that never crashes.

* ``clarabel`` (``auto`` picks it at every size): interior point, settings :data:`SETTINGS`;
  one thread: its default of one per core was 1.4x slower on the Lemma 4.1 programs at
  n = 8, 3 modes and n = 12, 4 modes on this 2-core machine (same answers), and the test
  suite runs two processes anyway.
* ``sdpa`` (``sdpa-python``; selectable, and the second opinion that confirms an
  infeasibility claim): a primal-dual interior-point SDP solver. It was meant to be
  chosen automatically above a size threshold, but ``benchmarks/analysis.py`` measured
  it 2.5x faster than Clarabel at n=16, m=2, 1.24x at n=12, m=4, yet 1.5x *slower* at
  n=16, m=3, and its answers changed with what it had solved earlier in the same
  process (sdpa-python 0.2.3 via cvxpy 1.9.3: certified but inflated gammas such as
  24.7 instead of 3.27). A tool whose point is trust does not pick that automatically.
* ``scs`` (selectable only): a first-order method; it returns ``optimal`` for violated
  LMIs at its default accuracy, so its answers too stand only through the certificate.

A solver's status is never a proof: callers always check the certificate
(:mod:`ftc_verify.analysis.lmi`); :func:`solve` only reports what the solver said, how
long it took, and turns any exception a solver raises into a status naming the solver.

Native code never decides the process's fate: SDPA's C++ code calls ``exit(0)`` on some
badly scaled problems (entries of 1e200 took a whole ``ftc-verify analyze`` down with exit
status 0 and no output), so the solvers in :data:`ISOLATED` run in a forked child
process that sends back the status and the variables' values through a pipe; a child
that dies or exits without an answer becomes status ``"error"`` naming the solver and how
the child ended.
"""

from __future__ import annotations

import contextlib
import os
import pickle
import sys
import tempfile
import threading
import time
import warnings
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import ValidationError
from ..interrupts import die_with_parent
from ..model.system import Matrix
from ..interrupts import deferred_signals
from .conic import ConicProblem, solve_clarabel, solve_clarabel_dual, to_cvxpy

__all__ = [
    "SOLVERS",
    "SETTINGS",
    "LEAN_SETTINGS",
    "SolveOutcome",
    "ForkedCall",
    "interruptible",
    "choose_solver",
    "second_solver",
    "solve",
    "solve_conic",
    "solve_conic_dual",
    "ISOLATED",
    "INACCURATE_WARNING",
]

#: Solver names accepted by the API and ``--solver`` (lower case) -> cvxpy names.
SOLVERS = {"clarabel": "CLARABEL", "sdpa": "SDPA", "scs": "SCS"}
#: Settings passed to each solver (cvxpy keyword arguments); quoted in results.
SETTINGS: dict[str, dict[str, Any]] = {
    "clarabel": {"tol_gap_abs": 1e-9, "tol_gap_rel": 1e-9, "tol_feas": 1e-9, "max_iter": 200, "max_threads": 1},
    "sdpa": {},
    "scs": {"eps_abs": 1e-8, "eps_rel": 1e-8, "max_iters": 200_000},
}
#: Clarabel's settings of the one-solve margin programs of
#: :func:`~ftc_verify.analysis.lmi_analysis.hinf_gamma` (issue 37): :data:`SETTINGS`
#: without iterative refinement of the KKT solves and without equilibration. On the
#: Lemma 4.1 programs of random n = 8, 3 modes (9 seeds) and n = 12, 4 modes the same
#: number of iterations or fewer (22 -> 17), 0.50 -> 0.25 s and 6.8 -> 3.6 s of CPU, the
#: certified gammas within 3e-8 relative (``benchmarks/results/h37b9.md``). A margin
#: program's answer stands only by its certificate; when a lean solve gives no point or
#: no certificate, the program is solved again with :data:`SETTINGS`.
LEAN_SETTINGS: dict[str, Any] = SETTINGS["clarabel"] | {"iterative_refinement_enable": False,
                                                        "equilibrate_enable": False}
#: Solvers run in a child process (their native code has ended the process itself).
ISOLATED = frozenset({"sdpa"})


@dataclass(frozen=True)
class SolveOutcome:
    """What one solver call said: cvxpy status (or ``"error"``), time, message."""

    solver: str
    status: str
    seconds: float
    message: str = ""

    @property
    def solved(self) -> bool:
        """The solver returned a point (``optimal`` or ``optimal_inaccurate``)."""
        return self.status in ("optimal", "optimal_inaccurate")

    @property
    def infeasible(self) -> bool:
        """The solver claimed infeasibility (possibly inaccurately)."""
        return self.status in ("infeasible", "infeasible_inaccurate")


#: The Python module each solver needs (the ones other than Clarabel also need cvxpy).
_MODULES = {"clarabel": "clarabel", "sdpa": "sdpap", "scs": "scs"}


def _installed() -> set[str]:
    """Solvers importable here, found without importing them (or cvxpy)."""
    import importlib.util

    def found(module: str) -> bool:
        return importlib.util.find_spec(module) is not None

    return {name for name, module in _MODULES.items()
            if found(module) and (name == "clarabel" or found("cvxpy"))}


def choose_solver(requested: str | None, n_scalar: int) -> str:
    """The solver to use: ``requested`` if given (validated), else Clarabel (module
    docstring: why ``auto`` does not switch to SDPA above a size). ``n_scalar`` is kept
    for the record of the problem size."""
    installed = _installed()
    if requested is not None and requested != "auto":
        name = requested.lower()
        if name not in SOLVERS:
            raise ValidationError(f"solver: unknown solver {requested!r}; choose from {sorted(SOLVERS)} or 'auto'")
        if name not in installed:
            raise ValidationError(f"solver: {requested!r} is not installed (installed: {sorted(installed)})")
        return name
    del n_scalar
    return "clarabel"


def second_solver(first: str) -> str | None:
    """An independent solver to confirm an infeasibility claim of ``first``."""
    installed = _installed()
    for name in ("clarabel", "sdpa", "scs"):
        if name != first and name in installed:
            return name
    return None


@contextlib.contextmanager
def _quiet_stdout() -> Iterator[None]:
    """Send file descriptor 1 to /dev/null: SDPA's C code prints there even when not
    verbose, which would corrupt ``--json`` output."""
    sys.stdout.flush()
    try:
        saved = os.dup(1)
    except OSError:  # no usable fd 1 (e.g. closed): nothing to protect
        yield
        return
    try:
        with open(os.devnull, "w") as devnull:
            os.dup2(devnull.fileno(), 1)
            yield
    finally:
        os.dup2(saved, 1)
        os.close(saved)


#: cvxpy's warning for an ``*_inaccurate`` status, which the returned status already says.
INACCURATE_WARNING = "Solution may be inaccurate"


def _solve_here(problem: Any, solver: str) -> tuple[str, str]:
    """Solve in this process; ``(status, message)``, exceptions turned into ``"error"``.

    cvxpy's :data:`INACCURATE_WARNING` is not passed on: the status it repeats
    (``optimal_inaccurate``, ``infeasible_inaccurate``) is returned and recorded in the
    :class:`SolveOutcome`, and no claim rests on it (certificates are checked in ball
    arithmetic). Every other warning passes.
    """
    import cvxpy as cp

    try:
        with _quiet_stdout(), warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=INACCURATE_WARNING, category=UserWarning)
            problem.solve(solver=SOLVERS[solver], **SETTINGS[solver])
        return str(problem.status), ""
    except cp.error.SolverError as exc:
        return "error", f"{solver} failed: {exc}"
    except Exception as exc:  # any solver crash must be reported, not raised
        return "error", f"{solver} raised {type(exc).__name__}: {exc}"


def _child_ended(solver: str, wait_status: int) -> str:
    if os.WIFSIGNALED(wait_status):
        return f"{solver} process killed by signal {os.WTERMSIG(wait_status)} without an answer"
    return f"{solver} process ended (exit status {os.waitstatus_to_exitcode(wait_status)}) without an answer"


def _solve_isolated(problem: Any, solver: str) -> tuple[str, str]:
    """:func:`_solve_here` in a forked child; the variables' values come back by pipe."""
    variables = problem.variables()
    read_fd, write_fd = os.pipe()
    sys.stdout.flush()
    sys.stderr.flush()
    pid = os.fork()
    if pid == 0:  # child: answer through the pipe, never return into the caller's code
        try:
            os.close(read_fd)
            status, message = _solve_here(problem, solver)
            values = [None if v.value is None else v.value for v in variables]
            with os.fdopen(write_fd, "wb") as out:
                pickle.dump((status, message, values), out)
        finally:
            os._exit(0)
    os.close(write_fd)
    with os.fdopen(read_fd, "rb") as src:
        data = src.read()
    _, wait_status = os.waitpid(pid, 0)
    try:
        status, message, values = pickle.loads(data)
    except Exception:  # no (or a torn) answer: the child died in native code
        return "error", _child_ended(solver, wait_status)
    for var, val in zip(variables, values):
        var.save_value(val)
    return status, message


class _StderrHold:
    """The state of :func:`_stderr_held`, kept by the main thread only: the holds open
    (``depth``), fd 2 as it was before the first (``saved``), the temporary file
    (``held``) and whether a hold asked to drop the text (``drop``)."""

    depth = 0
    saved = -1
    held: Any = None
    drop = False

    @classmethod
    def enter(cls) -> bool:
        """Open a hold; the first redirects fd 2. ``False``: nothing is held (not the main
        thread, no usable fd 2, or no temporary file: ``TMPDIR`` removed, disk full), the
        call runs as is."""
        if threading.current_thread() is not threading.main_thread():
            return False
        if cls.depth == 0:
            with contextlib.suppress(AttributeError, OSError, ValueError):  # sys.stderr None or closed
                sys.stderr.flush()
            try:
                held = tempfile.TemporaryFile()
            except OSError:
                return False
            try:
                cls.saved = os.dup(2)
                os.dup2(held.fileno(), 2)
            except OSError:
                held.close()
                return False
            cls.held, cls.drop = held, False
        cls.depth += 1
        return True

    @classmethod
    def leave(cls, drop: bool) -> None:
        """Close a hold; the last restores fd 2 and writes the text back unless a hold
        dropped it (every byte: a pipe may take it in parts)."""
        cls.depth -= 1
        cls.drop |= drop
        if cls.depth:
            return
        held = cls._restore()
        with held:
            if not cls.drop and held.seek(0, os.SEEK_END):
                held.seek(0)
                _write_all(held.read())

    @classmethod
    def _restore(cls) -> Any:
        """fd 2 back to what it was; the temporary file (the caller closes it)."""
        os.dup2(cls.saved, 2)
        os.close(cls.saved)
        held, cls.held, cls.depth = cls.held, None, 0
        return held

    @classmethod
    def after_fork(cls) -> None:
        """A child forked (by another thread) while the main thread held fd 2: its own fd 2
        back to the terminal's, the held text left to the parent."""
        if cls.depth:
            cls._restore().close()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_StderrHold.after_fork)


def _write_all(text: bytes, patience: float = 10.0) -> None:
    """Every byte of ``text`` to fd 2: a pipe may take it in parts, and a non-blocking one
    (``O_NONBLOCK`` set by the parent) refuses while full -- then wait until it is writable,
    at most ``patience`` seconds in all; an fd 2 that fails otherwise gets nothing more."""
    import select

    deadline = time.monotonic() + patience
    while text:
        try:
            text = text[os.write(2, text):]
        except BlockingIOError:
            left = deadline - time.monotonic()
            if left <= 0:
                return
            select.select([], [2], [], left)
        except OSError:
            return


@contextlib.contextmanager
def _stderr_held() -> Iterator[list[bool]]:
    """File descriptor 2 sent to a temporary file while the block runs, its text written
    back afterwards unless the block set the yielded flag: a Rust panic in Clarabel prints
    its message and, with ``RUST_BACKTRACE=1``, ~70 lines of backtrace there before pyo3
    raises it (``synthesize --gamma 1e16`` printed them on the user's terminal); the
    exception's message names the panic, and the outcome reports it.

    fd 2 belongs to the process, so only the main thread holds it (:class:`_StderrHold`;
    a solve in another thread runs without a hold, and a child forked while it is held gets
    its fd 2 back). Without a temporary file (``TMPDIR`` removed) or a usable fd 2 the block
    runs without a hold. The caller holds SIGINT and SIGTERM around it
    (:func:`_clarabel_guarded`), so a signal cannot leave fd 2 redirected."""
    drop = [False]
    if not _StderrHold.enter():
        yield drop
        return
    try:
        yield drop
    finally:
        _StderrHold.leave(drop[0])


def _clarabel_guarded(call: Any, problem: ConicProblem,
                      settings: dict[str, Any] | None = None) -> tuple[SolveOutcome, tuple[Any, ...]]:
    """Run ``call(problem, settings)`` (``(status, message, *arrays)``; ``None``:
    ``SETTINGS["clarabel"]``);
    anything it raises, a Rust panic (a ``BaseException``) included, becomes status
    ``"error"`` and arrays ``None``; what a panic prints on stderr is dropped
    (:func:`_stderr_held`), the rest of that output passed on. SIGINT and SIGTERM are held
    during the call and
    delivered after it (:func:`~ftc_verify.interrupts.deferred_signals`): raised inside
    Clarabel's callbacks into Python they would come out as such a panic."""
    start = time.perf_counter()
    with deferred_signals(), _stderr_held() as panicked:
        try:
            status, message, *arrays = call(problem, SETTINGS["clarabel"] if settings is None else settings)
        except BaseException as exc:  # pyo3's PanicException is a BaseException
            panicked[0] = type(exc).__name__ == "PanicException"
            if not isinstance(exc, Exception) and not panicked[0]:
                raise  # Ctrl-C, SIGTERM (the CLI's own BaseException), SystemExit: never a solver failure
            status, message, arrays = "error", f"clarabel raised {type(exc).__name__}: {exc}", []
    if settings is not None:  # the attempt names the settings it changed (the report's JSON shows them)
        changed = ", ".join(f"{k}={v}" for k, v in settings.items() if SETTINGS["clarabel"].get(k) != v)
        message = "; ".join(part for part in (message, f"settings {changed}" if changed else "") if part)
    outcome = SolveOutcome("clarabel", status, time.perf_counter() - start, message)
    usable = outcome.solved and arrays and all(a is not None and np.all(np.isfinite(a)) for a in arrays)
    return outcome, tuple(arrays) if usable else (None,) * 2


def solve_conic(problem: ConicProblem, solver: str) -> tuple[SolveOutcome, Matrix | None]:
    """Solve a :class:`~ftc_verify.analysis.conic.ConicProblem`: Clarabel natively, the
    other solvers through cvxpy (:func:`~ftc_verify.analysis.conic.to_cvxpy`, and
    :func:`solve`). Returns the outcome and the point (``None`` unless the solver
    returned a finite one). Nothing a solver raises escapes; a Rust panic in Clarabel
    (a ``BaseException``) included."""
    if solver == "clarabel":
        outcome, arrays = _clarabel_guarded(solve_clarabel, problem)
        return outcome, arrays[0]
    cvx_problem, var = to_cvxpy(problem)
    outcome = solve(cvx_problem, solver)
    x = None if var.value is None else np.asarray(var.value, dtype=float)
    if x is not None and not (outcome.solved and np.all(np.isfinite(x))):
        x = None
    return outcome, x


def solve_conic_dual(problem: ConicProblem,
                     settings: dict[str, Any] | None = None) -> tuple[SolveOutcome, Matrix | None, Matrix | None]:
    """Clarabel on ``problem`` with the dual point: ``(outcome, x, z)``, both ``None``
    unless finite ones were returned (:func:`~ftc_verify.analysis.conic.solve_clarabel_dual`);
    nothing raised escapes, as in :func:`solve_conic`. ``settings``: Clarabel's
    (``None``: ``SETTINGS["clarabel"]``; :data:`LEAN_SETTINGS`)."""
    outcome, (x, z) = _clarabel_guarded(solve_clarabel_dual, problem, settings)
    return outcome, x, z


def solve(problem: Any, solver: str) -> SolveOutcome:
    """Solve a cvxpy problem; any exception becomes status ``"error"`` naming the solver,
    and the solvers in :data:`ISOLATED` run in a child process (module docstring)."""
    start = time.perf_counter()
    run = _solve_isolated if solver in ISOLATED else _solve_here
    status, message = run(problem, solver)
    return SolveOutcome(solver, status, time.perf_counter() - start, message)


class ForkedCall:
    """``fn()`` running in a forked child process beside this one (POSIX), its result sent
    back pickled: how :func:`~ftc_verify.analysis.analyze.analyze` solves the nominal and
    the robust gamma programs on two cores at once (each solve is single-threaded,
    :data:`SETTINGS`; FLINT's precision, used by the certificate checks, is per process, so
    the two never share state).

    :meth:`result` waits for the answer (the child's exception is raised again here; a
    child that died without an answer is a :class:`~ftc_verify.errors.SolverError`);
    :meth:`cancel` kills a child still running (call it in a ``finally``). The child
    ignores SIGINT (a terminal sends it to the whole group; this process cancels it) and
    never returns into the caller's code.

    ``group=True``: the child leads a process group of its own, and :meth:`cancel` kills
    the whole group (the children the child forked in turn, such as its own
    ``ForkedCall`` solves, included).
    """

    def __init__(self, fn: Any, what: str, *, group: bool = False) -> None:
        import signal

        self.what = what
        self.group = group
        read_fd, write_fd = os.pipe()
        sys.stdout.flush()
        sys.stderr.flush()
        parent = os.getpid()
        self.pid = os.fork()
        if self.pid == 0:  # child
            try:
                if group:
                    os.setpgid(0, 0)
                    die_with_parent(parent)
                signal.signal(signal.SIGINT, signal.SIG_IGN)
                signal.signal(signal.SIGTERM, signal.SIG_DFL)
                os.close(read_fd)
                try:
                    payload: tuple[str, Any] = ("ok", fn())
                except Exception as exc:
                    payload = ("error", exc)
                try:
                    data = pickle.dumps(payload)
                except Exception as exc:  # an answer that cannot be sent (a bug): say so, never a torn pickle
                    data = pickle.dumps(("error", RuntimeError(f"{what}: its answer could not be sent back from the "
                                                               f"child process ({type(exc).__name__}: {exc})")))
                with os.fdopen(write_fd, "wb") as out:
                    out.write(data)
            finally:
                os._exit(0)
        os.close(write_fd)
        self._read_fd: int | None = read_fd

    def result(self) -> Any:
        """The child's return value (its exception raised again)."""
        from ..errors import SolverError

        assert self._read_fd is not None, "ForkedCall.result called twice"
        with os.fdopen(self._read_fd, "rb") as src:
            self._read_fd = None
            data = src.read()
        _, wait_status = os.waitpid(self.pid, 0)
        self.pid = 0
        if not data:
            raise SolverError(f"{self.what}: {_child_ended('the forked solve', wait_status)}")
        kind, value = pickle.loads(data)
        if kind == "error":
            raise value
        return value

    def cancel(self) -> None:
        """Kill and reap the child if it is still there."""
        import signal

        if self.pid:
            with contextlib.suppress(ProcessLookupError, PermissionError):
                if self.group:
                    os.killpg(self.pid, signal.SIGKILL)
                else:
                    os.kill(self.pid, signal.SIGKILL)
            os.waitpid(self.pid, 0)
            self.pid = 0
        if self._read_fd is not None:
            os.close(self._read_fd)
            self._read_fd = None


def interruptible(fn: Any, what: str, meanwhile: Any = None) -> Any:
    """``fn()`` in a :class:`ForkedCall` child leading its own process group; this process
    only waits for the answer. A solve or a dense eigenproblem holds the interpreter until
    it returns, so a SIGTERM or Ctrl-C arriving meanwhile would wait for it (29-87 s were
    measured with Clarabel, issue 32); here the wait is a ``read`` that the signal
    interrupts at once, and the ``finally`` kills the child's whole group (on Linux the
    child also dies with this process if it is killed outright). Where ``fork`` is
    missing, ``fn()`` runs here. The child's exceptions are raised again here.

    ``meanwhile()``, when given, runs here after the fork and before the wait (``verify``
    imports the modules of its later stages while the synthesis runs); a signal
    interrupts it like the wait."""
    if not hasattr(os, "fork"):
        if meanwhile is not None:
            meanwhile()
        return fn()
    forked = ForkedCall(fn, what, group=True)
    try:
        if meanwhile is not None:
            meanwhile()
        return forked.result()
    finally:
        forked.cancel()
