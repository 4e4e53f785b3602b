"""A 'working' line in a terminal for commands that have no progress bar of their own.

``simulate`` and ``verify`` show tqdm bars over their paths; every other command (the
LMI solves of ``analyze`` and ``synthesize``, ``linearize``, ``build-fmu``...) runs
:func:`working`: once the command has run for ``delay`` seconds, a line on stderr shows
its name and the elapsed time, refreshed a few times a second, and it is erased as soon as
the command prints its answer or ends. Nothing is shown unless stderr is a terminal, so
pipes, files and the test suite see exactly the command's output.
"""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any, TextIO

__all__ = ["working"]


class _FinishOnWrite:
    """``sys.stdout`` while the line is shown: the first write ends the line, then passes through."""

    def __init__(self, out: TextIO, finish: Callable[[], None]) -> None:
        self._out = out
        self._finish = finish

    def write(self, text: str) -> int:
        self._finish()
        return self._out.write(text)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._out, name)


@contextmanager
def working(command: str, *, stream: TextIO | None = None, delay: float = 1.0,
            period: float = 0.25) -> Iterator[None]:
    """Show ``ftc-verify COMMAND: working (N s)`` on ``stream`` (default stderr) after
    ``delay`` seconds, until the body prints to stdout or ends (module docstring)."""
    stream = sys.stderr if stream is None else stream
    if not stream.isatty():
        yield
        return
    stop = threading.Event()
    lock = threading.Lock()
    shown = False
    start = time.monotonic()

    def tick() -> None:
        nonlocal shown
        if stop.wait(delay):
            return
        while True:
            with lock:
                if stop.is_set():
                    return
                stream.write(f"\rftc-verify {command}: working ({time.monotonic() - start:.0f} s)")
                stream.flush()
                shown = True
            stop.wait(period)

    thread = threading.Thread(target=tick, name="ftc-verify-working", daemon=True)

    def finish() -> None:
        nonlocal shown
        stop.set()
        with lock:
            if shown:
                stream.write("\r\033[K")  # erase the line
                stream.flush()
                shown = False

    out = sys.stdout
    sys.stdout = _FinishOnWrite(out, finish)
    thread.start()
    try:
        yield
    finally:
        finish()
        thread.join()
        sys.stdout = out
