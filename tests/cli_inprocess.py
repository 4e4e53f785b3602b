"""Run ``ftc-verify ARGS`` in the test process, as a subprocess would see it: for the tests
whose claim is an exit code, an output, or the files a command writes or leaves behind,
not the process itself (issue 37, item 5: a fresh interpreter costs 0.4-1.4 s of CPU per
command, mostly imports, which one test process pays once).

:func:`run_cli` calls :func:`ftc_verify.cli.main.main` with what ``subprocess.run`` would
have given the child: the working folder (``cwd``), the environment (``os.environ``
updated by ``env``; ``TMPDIR`` takes effect: :mod:`tempfile`'s cached folder is reset
for the call), stdout and stderr captured both as Python streams and at the file
descriptors 1 and 2 (so that what a C library or a child process writes there is
captured too; the fd output follows the stream output), argparse's ``SystemExit``
turned into the exit code. Everything is restored afterwards. The result is a
:class:`subprocess.CompletedProcess`, so the tests' assertions read the same.

python-control (the modules of ``analyze``'s and ``verify``'s cross-check child,
:data:`ftc_verify.prestart.CROSS_CHECK_MODULES`) is imported in this process once, so the
child each command forks finds it imported instead of importing it again (about 1 s of
CPU per command; the child still computes the cross-check).

What stays a real subprocess (and is tested as one): signals (SIGINT, SIGTERM, a closed
pipe), the start-up time and imports of a fresh interpreter, the umask, the console
script, and the tutorials' commands as a user types them.
"""

from __future__ import annotations

import contextlib
import io
import os
import subprocess
import sys
import tempfile
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path

__all__ = ["run_cli", "environment"]


@contextlib.contextmanager
def environment(env: Mapping[str, str] | None) -> Iterator[None]:
    """``os.environ`` updated by ``env`` (and :mod:`tempfile`'s folder re-read) for the block."""
    saved_env, saved_tmp = dict(os.environ), tempfile.tempdir
    try:
        os.environ.update(env or {})
        tempfile.tempdir = None  # gettempdir() reads TMPDIR again
        yield
    finally:
        os.environ.clear()
        os.environ.update(saved_env)
        tempfile.tempdir = saved_tmp


@contextlib.contextmanager
def _fd_captured(fd: int) -> Iterator[io.BufferedRandom]:
    """File descriptor ``fd`` writes into a temporary file for the block."""
    with tempfile.TemporaryFile() as sink:
        saved = os.dup(fd)
        try:
            os.dup2(sink.fileno(), fd)
            yield sink  # type: ignore[misc]
        finally:
            os.dup2(saved, fd)
            os.close(saved)


def run_cli(args: Sequence[str], cwd: Path | str | None = None, env: Mapping[str, str] | None = None,
            timeout: float | None = None) -> subprocess.CompletedProcess[str]:
    """``python -m ftc_verify *args`` in this process (module docstring); ``timeout`` is
    accepted for the signature of the subprocess helpers it replaces and not enforced."""
    import importlib

    from ftc_verify.cli.main import main
    from ftc_verify.prestart import CROSS_CHECK_MODULES

    del timeout
    for name in CROSS_CHECK_MODULES:  # once per test process: the forked cross-check children share them
        importlib.import_module(name)
    out, err = io.StringIO(), io.StringIO()
    here = os.getcwd()
    sys.stdout.flush()
    sys.stderr.flush()
    with _fd_captured(1) as fd_out, _fd_captured(2) as fd_err, environment(env):
        try:
            if cwd is not None:
                os.chdir(cwd)
            with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
                try:
                    code = main(list(args))
                except SystemExit as exc:  # argparse: --help, --version, usage errors
                    code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
                    if isinstance(exc.code, str):
                        print(exc.code, file=sys.stderr)
        finally:
            os.chdir(here)
        fd_out.seek(0)
        fd_err.seek(0)
        stdout = out.getvalue() + fd_out.read().decode(errors="replace")
        stderr = err.getvalue() + fd_err.read().decode(errors="replace")
    return subprocess.CompletedProcess([sys.executable, "-m", "ftc_verify", *args], int(code), stdout, stderr)
