"""Where a running ``ftc-verify`` process is, seen from outside (Linux ``/proc``), so that a
signal test sends its signal as soon as the stage it is about is reached instead of after
a fixed sleep (issue 37, item 5).

The long stages of the CLI run in a forked child that leads a process group of its own
(:func:`ftc_verify.analysis.solvers.interruptible`: an analysis, a synthesis, the
ball-arithmetic retries), while the command waits for it; :func:`working_child` finds that
child and :func:`cpu_seconds` says how much work it has done.

Polling is cheap: the child found is remembered (per parent pid) and only its own
``/proc/PID/stat`` is read while it stays that parent's working child; ``/proc`` is scanned
again only when it is gone. (A scan of every process's ``stat`` costs about 4 ms of CPU
here, so scanning at every 20 ms poll spent a fifth of a core in the test process.)
"""

from __future__ import annotations

import os
import subprocess
import time
from collections.abc import Callable
from pathlib import Path

__all__ = ["cpu_seconds", "children", "working_child", "child_has_worked", "wait_for_stage", "stage_cpu"]

_TICK = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100


def _stat(pid: int) -> list[str] | None:
    """The fields of ``/proc/PID/stat`` after the command name (field 3 is the first)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None


def cpu_seconds(pid: int) -> float:
    """User and system CPU seconds process ``pid`` has used (0 once it is gone)."""
    fields = _stat(pid)
    return 0.0 if fields is None else (int(fields[11]) + int(fields[12])) / _TICK


def children(pid: int) -> set[int]:
    """The live (not zombie) child processes of ``pid``."""
    found = set()
    for stat in Path("/proc").glob("[0-9]*/stat"):
        fields = _stat(int(stat.parent.name))
        if fields is not None and int(fields[1]) == pid and fields[0] != "Z":
            found.add(int(stat.parent.name))
    return found


def _is_working_child(pid: int, child: int) -> bool:
    """``child`` is a live child of ``pid`` leading a process group of its own."""
    fields = _stat(child)
    return (fields is not None and fields[0] != "Z" and int(fields[1]) == pid
            and int(fields[2]) == child)  # fields 4 and 5: the parent, the process group


#: The working child found last for each parent pid (checked before /proc is scanned again).
_SEEN: dict[int, int] = {}


def working_child(pid: int) -> int | None:
    """The child of ``pid`` that leads a process group of its own (the forked stage of
    :func:`~ftc_verify.analysis.solvers.interruptible`), or ``None``. The one found last
    for ``pid`` is checked first (its own ``stat`` only), ``/proc`` scanned when it is gone."""
    known = _SEEN.get(pid)
    if known is not None and _is_working_child(pid, known):
        return known
    for child in sorted(children(pid)):
        if _is_working_child(pid, child):
            _SEEN[pid] = child
            return child
    _SEEN.pop(pid, None)
    return None


def child_has_worked(pid: int, seconds: float) -> bool:
    """:func:`working_child` of ``pid`` exists and has used ``seconds`` of CPU."""
    child = working_child(pid)
    return child is not None and cpu_seconds(child) >= seconds


def wait_for_stage(proc: subprocess.Popen[str], reached: Callable[[], bool], what: str,
                   seconds: float = 120.0) -> None:
    """Poll ``reached()`` every 20 ms until it holds; fail if ``proc`` ends first or
    ``seconds`` pass (then ``proc`` is killed)."""
    deadline = time.monotonic() + seconds
    while not reached():
        if proc.poll() is not None:
            raise AssertionError(f"the command ended ({proc.returncode}) before {what}: {proc.communicate()}")
        if time.monotonic() > deadline:
            proc.kill()
            raise AssertionError(f"no {what} within {seconds} s")
        time.sleep(0.02)


def stage_cpu(command: list[str]) -> float:
    """The CPU seconds :func:`working_child` of ``command`` uses in a whole run (the last
    value seen, polled every 20 ms), so that a signal test can aim at fractions of the
    stage on whatever machine runs it instead of at seconds measured on another."""
    proc = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    seen = 0.0
    while proc.poll() is None:
        child = working_child(proc.pid)
        if child is not None:
            seen = max(seen, cpu_seconds(child))
        time.sleep(0.02)
    return seen
