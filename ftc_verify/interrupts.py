"""Signals that arrive while native code calls back into Python are kept, not lost.

A Python signal handler runs at the next bytecode boundary of the main thread. When that
is inside a callback from native code -- Clarabel's Rust code importing SciPy's LAPACK
bindings, a C library calling a Python logger -- the exception the handler raises (Ctrl-C's
``KeyboardInterrupt``, the command line's SIGTERM exception) is caught by that library and
turned into something else: pyo3 makes it a ``PanicException`` (with a Rust backtrace on
stderr) that looks like a solver failure, ctypes prints it and drops it. Either way a
signal that should end the run becomes a wrong answer or nothing.

:func:`deferred_signals` is the cure for such calls: while its block runs, SIGINT and
SIGTERM only record that they arrived; when the block ends the previous handlers are
restored and the first recorded signal is delivered to its handler, in plain Python code,
where it raises as it should. The block's native call is not made any slower to stop: a
handler runs only between bytecodes anyway, so it would not have run before the native
code returned to Python.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

__all__ = ["deferred_signals", "die_with_parent"]

_SIGNALS = (signal.SIGINT, signal.SIGTERM)


@contextmanager
def deferred_signals() -> Iterator[None]:
    """Hold SIGINT and SIGTERM while the block runs; deliver the first one after it (module
    docstring). Outside the main thread (where Python runs no handler) it does nothing."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    arrived: list[tuple[int, Any]] = []

    def hold(signum: int, frame: Any) -> None:
        arrived.append((signum, frame))

    previous = {s: signal.signal(s, hold) for s in _SIGNALS}
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        if arrived:
            signum, frame = arrived[0]
            handler = previous[signal.Signals(signum)]
            if callable(handler):
                handler(signum, frame)
            elif handler == signal.SIG_DFL:
                signal.raise_signal(signum)


def die_with_parent(parent: int | None = None) -> None:
    """Linux: this process gets SIGKILL when its parent dies (``prctl(PR_SET_PDEATHSIG)``),
    so a forked or spawned worker never computes on for a parent killed outright
    (SIGKILL, the kernel's out-of-memory killer); with ``parent`` (the parent's pid, read
    before the fork) a process orphaned before the request took effect ends at once.
    Elsewhere nothing."""
    import ctypes

    if not sys.platform.startswith("linux"):
        return
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGKILL), 0, 0, 0)  # 1 = PR_SET_PDEATHSIG
    if parent is not None and os.getppid() != parent:  # orphaned before the request: no signal will come
        os._exit(1)
