"""Ctrl-C while a local cluster's fork server imports its preload: one line, exit 130
(review of the fork server, :func:`ftc_verify.simulation.cluster.start_fork_server`).

The server is a new interpreter; before the fix it took SIGINT's default disposition and
printed a ``KeyboardInterrupt`` traceback from the middle of its 1-2 s of imports. The
signal is sent to the whole process group (as a terminal's Ctrl-C) once the server has
used a fifth of a second of CPU, i.e. inside those imports."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

psutil = pytest.importorskip("psutil")
pytest.importorskip("distributed")
ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.skipif(not hasattr(os, "fork"), reason="POSIX process groups and the fork server")


#: CPU seconds of the server's own before the signal: past the interpreter's start (a few
#: hundredths), well inside the preload's imports (about 1 s of CPU: Dask, numpy, this package).
IMPORTING = 0.2


def _fork_server_importing(pid: int) -> bool:
    """The command's fork server exists and has used :data:`IMPORTING` CPU seconds."""
    try:
        kids = psutil.Process(pid).children(recursive=True)
    except psutil.NoSuchProcess:
        return False
    for kid in kids:
        try:
            if "forkserver" in " ".join(kid.cmdline()):
                cpu = kid.cpu_times()
                return cpu.user + cpu.system >= IMPORTING
        except psutil.Error:
            continue
    return False


def test_ctrl_c_while_the_fork_server_imports_is_one_line() -> None:
    # a short TMPDIR: under pytest-xdist the test's own is too long for the server's Unix socket
    short = tempfile.mkdtemp(prefix="fs", dir="/tmp")
    try:
        env = dict(os.environ, TMPDIR=short)
        cmd = [sys.executable, "-m", "ftc_verify", "simulate", str(ROOT / "examples" / "paper.toml"), "--gains",
               str(ROOT / "examples" / "paper_gains.toml"), "--backend", "reference", "--paths", "100000",
               "--horizon", "5", "--workers", "2"]
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                                start_new_session=True)
        deadline = time.monotonic() + 60
        while not _fork_server_importing(proc.pid) and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.01)
        assert proc.poll() is None and _fork_server_importing(proc.pid), proc.communicate()
        sent = time.monotonic()
        os.killpg(proc.pid, signal.SIGINT)
        out, err = proc.communicate(timeout=60)
        assert proc.returncode == 130, (out, err)
        assert err.strip() == "ftc-verify: interrupted", err
        assert time.monotonic() - sent < 15.0
    finally:
        shutil.rmtree(short, ignore_errors=True)
