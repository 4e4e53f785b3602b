"""fd 2 held during a Clarabel call (:func:`ftc_verify.analysis.solvers._stderr_held`),
review of fixb: holds overlapping in two threads left fd 2 on a deleted temporary file for
the rest of the process, and with ``TMPDIR`` removed every Clarabel call raised
``FileNotFoundError`` (``synthesize`` exit 4); second review: a child forked while fd 2 was
held wrote its errors into the parent's temporary file, and a non-blocking pipe lost what
did not fit at once. Only the main thread holds fd 2 now."""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from ftc_verify.analysis import solvers
from ftc_verify.analysis.conic import Rows, unit_rows
from ftc_verify.analysis.solvers import solve_conic

# Two threads: A holds over 0.0-0.2 s, B over 0.1-0.4 s (A leaves while B holds), then a
# line written straight to fd 2 must reach the pipe, and what each wrote while held too.
THREADS = """
import os, threading, time
from ftc_verify.analysis.solvers import _stderr_held
def hold(name, start, length):
    time.sleep(start)
    with _stderr_held():
        os.write(2, f"held by {name}\\n".encode())
        time.sleep(length)
ts = [threading.Thread(target=hold, args=a) for a in (("A", 0.0, 0.2), ("B", 0.1, 0.3))]
[t.start() for t in ts]; [t.join() for t in ts]
os.write(2, b"after both holds\\n")
"""


def test_overlapping_holds_in_two_threads_give_fd_2_back():
    proc = subprocess.run([sys.executable, "-c", THREADS], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr.splitlines() == ["held by A", "held by B", "after both holds"]


def test_a_dropped_hold_drops_only_the_held_text(capfd):
    with solvers._stderr_held() as drop:
        os.write(2, b"panic text\n")
        drop[0] = True
    with solvers._stderr_held():
        os.write(2, b"kept\n")
    assert capfd.readouterr().err == "kept\n"
    assert solvers._StderrHold.depth == 0


def test_a_removed_tmpdir_runs_clarabel_without_the_hold(tmp_path, capfd):
    rows = Rows(1)
    rows.nonneg(unit_rows(1, [0]), [0.0])  # x >= 0, min x
    saved, tempfile.tempdir = tempfile.tempdir, str(tmp_path / "removed")
    try:  # restored before pytest's own capture makes its next temporary file
        outcome, x = solve_conic(rows.problem(np.ones(1)), "clarabel")
        with solvers._stderr_held():
            os.write(2, b"not held\n")
            assert capfd.readouterr().err == "not held\n"  # straight through: nothing held
    finally:
        tempfile.tempdir = saved
    assert outcome.solved and x is not None and abs(x[0]) < 1e-6
    assert solvers._StderrHold.depth == 0


def test_synthesize_with_a_removed_tmpdir_exits_0(tmp_path):
    paper = Path(__file__).resolve().parents[1] / "examples" / "paper.toml"
    code = ("import sys, tempfile; from ftc_verify.cli import main; "
            f"tempfile.tempdir = {str(tmp_path / 'removed')!r}; "
            f"sys.exit(main(['synthesize', {str(paper)!r}, '--method', 'common', '-o', {str(tmp_path / 'K.toml')!r}]))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "K.toml").exists()


# The main thread holds fd 2 while another thread forks: the child's error line must reach
# the pipe (its fd 2 given back), and the parent's held text after the hold.
FORK = """
import os, threading
from ftc_verify.analysis.solvers import _stderr_held
def fork():
    pid = os.fork()
    if pid == 0:
        os.write(2, b"child line\\n")
        os._exit(0)
    os.waitpid(pid, 0)
with _stderr_held():
    os.write(2, b"parent line\\n")
    t = threading.Thread(target=fork); t.start(); t.join()
"""

# A parent that set O_NONBLOCK on the pipe and reads it only later: all the held text arrives.
NONBLOCKING = """
import os
from ftc_verify.analysis.solvers import _stderr_held
os.set_blocking(2, False)
with _stderr_held():
    os.write(2, b"x" * 100_000 + b"\\nLAST LINE\\n")
"""


def test_a_child_forked_while_fd_2_is_held_writes_to_the_real_fd_2():
    proc = subprocess.run([sys.executable, "-c", FORK], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert sorted(proc.stderr.splitlines()) == ["child line", "parent line"]


def test_held_text_reaches_a_non_blocking_pipe_read_late():
    proc = subprocess.Popen([sys.executable, "-c", NONBLOCKING], stderr=subprocess.PIPE)
    import time

    time.sleep(2)
    err = proc.stderr.read() if proc.stderr else b""
    assert proc.wait(timeout=60) == 0
    assert err.endswith(b"LAST LINE\n") and len(err) == 100_000 + len(b"\nLAST LINE\n")
