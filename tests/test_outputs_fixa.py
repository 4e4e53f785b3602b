"""Outputs and the end of a run (audit13 findings 01, 07 and 09, found by an independent check).

* 01: an output written by temporary file + rename onto an existing FIFO, device or socket
  replaced the node by a regular file (exit 0); a symbolic link was replaced by a file, its
  target left stale. Now such a target is refused before any work (exit 2, naming the
  option, the path and what it is) and a link is written through to its target.
* 07: the folder of an output was checked with an access test that root passes on
  ``/proc`` and ``/sys``; the write then failed after the work. Now the check creates and
  removes a file there. ``FILE/K.toml`` with ``FILE`` a regular file says it is not a folder.
* 09: a SIGTERM after the answer was printed (during the interpreter's 0.25-0.5 s of
  shutdown) killed the process without the documented line. Documented, not changed (a
  first fix ending the process by ``os._exit`` with the signals blocked lost a caller's
  code, threads and C stdio and could hang; reviewer, round 13): the process ends by
  that signal, the answer and the outputs complete; a signal during the command still
  gives 130 / 143 and its line.
* Also: stdout closed (``>&-``) is refused before any work (exit 2, one line; it was an
  internal error after the work); an output name that is a symbolic link loop or too
  long is refused naming the option (exit 2; it was an internal error).

Only nodes the test creates under its own temporary folder are used (never ``/dev``).
"""

from __future__ import annotations

import os
import re
import signal
import socket
import stat
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

from ftc_verify.cli.common import check_output_file
from ftc_verify.cli.main import main
from ftc_verify.errors import ValidationError
from ftc_verify.model.files import write_atomic
from ftc_verify.verification.report import check_out_dir

ROOT = Path(__file__).resolve().parents[1]
PAPER = str(ROOT / "examples" / "paper.toml")
GAINS = str(ROOT / "examples" / "paper_gains.toml")


@pytest.fixture
def fifo(tmp_path: Path) -> Path:
    if not hasattr(os, "mkfifo"):
        pytest.skip("no FIFOs on this platform")
    path = tmp_path / "pipe.toml"
    os.mkfifo(path)
    return path


def is_fifo(path: Path) -> bool:
    return stat.S_ISFIFO(os.lstat(path).st_mode)


def test_a_fifo_is_refused_before_any_work_and_kept(fifo: Path, capsys: pytest.CaptureFixture[str],
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    from ftc_verify.model import files

    def no_work(*args: object, **kwargs: object) -> None:
        raise AssertionError("the system was loaded: the output was not checked first")

    monkeypatch.setattr(files, "load_system", no_work)
    rc = main(["synthesize", PAPER, "--method", "common", "-o", str(fifo)])
    err = capsys.readouterr().err
    assert rc == 2, err
    assert f"-o/--output {fifo}: is a FIFO" in err and len(err.strip().splitlines()) == 1
    assert is_fifo(fifo)


def test_a_socket_and_a_link_to_a_fifo_are_refused(tmp_path: Path, fifo: Path) -> None:
    sock_path = tmp_path / "s.png"
    with socket.socket(socket.AF_UNIX) as sock:
        sock.bind(str(sock_path))
        with pytest.raises(ValidationError, match=r"--plot .*s\.png: is a socket"):
            check_output_file(str(sock_path), "--plot", (".png",))
    link = tmp_path / "link.toml"
    link.symlink_to(fifo.name)
    with pytest.raises(ValidationError, match=rf"-o {link}: is a FIFO \(the link points to .*pipe\.toml\)"):
        check_output_file(str(link), "-o")
    assert link.is_symlink() and is_fifo(fifo)


def test_the_writers_refuse_a_fifo_too(fifo: Path) -> None:
    """The atomic writers themselves never rename over a node (a caller that skipped the check)."""
    from matplotlib.figure import Figure

    from ftc_verify.verification.plots import save_figure

    with pytest.raises(ValidationError, match="is a FIFO"):
        write_atomic(fifo, "x = 1\n")
    png = fifo.with_suffix(".png")
    os.mkfifo(png)
    with pytest.raises(ValidationError, match="is a FIFO"):
        save_figure(Figure(), png, "png", f"--plot {png}: cannot write")
    assert is_fifo(fifo) and is_fifo(png)
    assert sorted(p.name for p in fifo.parent.iterdir()) == ["pipe.png", "pipe.toml"]  # no temporary file left


def test_a_symlink_is_written_through_to_its_target(tmp_path: Path) -> None:
    from matplotlib.figure import Figure

    from ftc_verify.verification.plots import save_figure

    target = tmp_path / "real" / "K.toml"
    target.parent.mkdir()
    target.write_text("old\n")
    link = tmp_path / "K.toml"
    link.symlink_to(target)
    check_output_file(str(link), "-o")
    write_atomic(link, "new = 1\n")
    assert link.is_symlink() and target.read_text() == "new = 1\n"
    dangling = tmp_path / "fig.png"
    dangling.symlink_to(tmp_path / "real" / "fig.png")  # a link to a file not yet there: it is created
    save_figure(Figure(), dangling, "png", "fig: cannot write")
    assert dangling.is_symlink() and (tmp_path / "real" / "fig.png").read_bytes()[:4] == b"\x89PNG"


def test_the_folder_check_is_a_real_write(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A folder that passes an access test but refuses a new file (root on /proc, /sys) is
    refused up front, for ``-o`` and ``--out``."""
    def refuse(*args: object, **kwargs: object) -> tuple[int, str]:
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(os, "access", lambda *args, **kwargs: True)
    monkeypatch.setattr(tempfile, "mkstemp", refuse)
    with pytest.raises(ValidationError, match=rf"--plot {tmp_path}/p\.png: folder {tmp_path} is not writable "
                                              r"\(Permission denied\)"):
        check_output_file(str(tmp_path / "p.png"), "--plot", (".png",))
    with pytest.raises(ValidationError, match=r"--out .*/r: folder .* is not writable \(Permission denied\)"):
        check_out_dir(tmp_path / "r")


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="no /proc")
def test_proc_is_refused_up_front() -> None:
    with pytest.raises(ValidationError, match=r"-o /proc/K\.toml: folder /proc is not writable"):
        check_output_file("/proc/K.toml", "-o")


def test_a_file_in_the_path_is_not_a_folder(tmp_path: Path) -> None:
    (tmp_path / "afile").write_text("")
    with pytest.raises(ValidationError, match=r"afile is a regular file, not a folder"):
        check_output_file(str(tmp_path / "afile" / "K.toml"), "-o")


def test_out_through_a_link_replaces_the_folder_it_points_to(tmp_path: Path) -> None:
    """``verify --out LINK`` (LINK -> a report folder): the report replaces the folder the
    link points to, the link is kept (before: the link was replaced by the new folder)."""
    from ftc_verify.cli.common import load
    from ftc_verify.verification.report import write_report
    from ftc_verify.verification.verify import Check, VerifyReport

    system, _ = load(PAPER, str(ROOT / "examples" / "paper_gains.toml"))
    rep = VerifyReport(system, None, None, None, None, (), (), None, (), (Check("synthesis", False, "none"),),
                       seed=1, options={"fdi_model": "FDI: test"})
    real = tmp_path / "reports" / "run"
    real.mkdir(parents=True)
    (real / "report.md").write_text("previous run\n")
    link = tmp_path / "out"
    link.symlink_to(real)
    check_out_dir(link)
    write_report(rep, link)
    assert link.is_symlink() and link.resolve() == real.resolve()
    assert (real / "report.json").is_file() and (real / "report.md").read_text() != "previous run\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out", "reports"]  # no staging folder left
    assert sorted(p.name for p in real.parent.iterdir()) == ["run"]


SIGNAL_AT_THE_END = """
import atexit, os, signal, sys
from ftc_verify.cli import main
atexit.register(lambda: os.kill(os.getpid(), signal.SIGTERM))  # after the answer, at the process's very end
sys.argv = ["ftc-verify", "synthesize", {system!r}, "--method", "common", "-o", {out!r}]
sys.exit(main())
"""


def run_python(code: str, stdout: int | None = subprocess.PIPE) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-c", code], stdout=stdout, stderr=subprocess.PIPE, text=True,
                          timeout=300, env=os.environ | {"OPENBLAS_NUM_THREADS": "1"}, start_new_session=True)


def test_a_sigterm_after_the_answer_ends_the_process_by_the_signal(tmp_path: Path) -> None:
    """As exit-codes.md says: the handlers are restored when the command ends, so a SIGTERM
    during the interpreter's shutdown kills the process (the shell sees 143) without the
    line; the answer was printed and the output written whole."""
    proc = run_python(SIGNAL_AT_THE_END.format(system=PAPER, out=str(tmp_path / "K.toml")))
    assert proc.returncode == -signal.SIGTERM, (proc.returncode, proc.stderr)
    assert "ftc-verify: terminated" not in proc.stderr and "Traceback" not in proc.stderr, proc.stderr
    from ftc_verify.controllers.files import load_controller

    assert "verdict: certified" in proc.stdout and load_controller(str(tmp_path / "K.toml")) is not None
    assert sorted(p.name for p in tmp_path.iterdir()) == ["K.toml"]  # no temporary file left


@pytest.mark.parametrize("sig, code, line", [(signal.SIGTERM, 143, "ftc-verify: terminated"),
                                             (signal.SIGINT, 130, "ftc-verify: interrupted")])
def test_a_signal_during_the_command_gives_its_code_and_line(sig: int, code: int, line: str,
                                                              capsys: pytest.CaptureFixture[str],
                                                              monkeypatch: pytest.MonkeyPatch) -> None:
    from ftc_verify.model import files

    def signalled(*args: object, **kwargs: object) -> None:
        os.kill(os.getpid(), sig)
        raise AssertionError("the signal did not stop the command")

    monkeypatch.setattr(files, "load_system", signalled)
    before = signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGINT)
    assert main(["analyze", PAPER, "--controller", GAINS]) == code
    assert capsys.readouterr().err.strip().splitlines() == [line]
    assert (signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGINT)) == before


def test_in_process_main_returns_and_keeps_the_handlers(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``main(argv)`` (a caller's process) returns its code, the handlers restored."""
    before = signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGINT)
    assert main(["synthesize", PAPER, "--method", "common", "-o", str(tmp_path / "K.toml")]) == 0
    assert (signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGINT)) == before


@pytest.mark.skipif(not hasattr(signal, "pthread_sigmask"), reason="no signal masks on this platform")
def test_main_leaves_no_signal_blocked(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["analyze", "/nonexistent.toml", "--controller", "/nonexistent.toml"]) == 2
    assert not signal.pthread_sigmask(signal.SIG_BLOCK, []) & {signal.SIGTERM, signal.SIGINT}


CALLER = """
import sys, threading, time, pathlib
threading.Thread(target=lambda: (time.sleep(0.3), pathlib.Path({done!r}).write_text("ok"))).start()
sys.argv = ["ftc-verify", "analyze", "/nonexistent.toml", "--controller", "/nonexistent.toml"]
from ftc_verify.cli import main
code = main()
print("caller after main():", code)
"""


def test_main_without_argv_returns_to_its_caller(tmp_path: Path) -> None:
    """A script that calls ``main()`` runs on after it and its threads are joined at the
    end (fixa's ``os._exit`` lost both)."""
    proc = run_python(CALLER.format(done=str(tmp_path / "done")))
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "caller after main(): 2" and (tmp_path / "done").read_text() == "ok"


def test_a_closed_stdout_is_refused_before_any_work(capsys: pytest.CaptureFixture[str],
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    """``>&-``: Python's ``sys.stdout`` is None; before, the work ran and the final flush
    was an internal error (exit 4)."""
    from ftc_verify.model import files

    def no_work(*args: object, **kwargs: object) -> None:
        raise AssertionError("the system was loaded with stdout closed")

    monkeypatch.setattr(files, "load_system", no_work)
    monkeypatch.setattr(sys, "stdout", None)
    assert main(["analyze", PAPER, "--controller", GAINS]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        "ftc-verify: error: stdout is closed, the answer could not be printed; nothing was done "
        "(to discard the answer, redirect it to /dev/null)"]


def test_a_closed_stdout_from_the_shell() -> None:
    """The reviewer's command, ``ftc-verify analyze ... >&-``: exit 2, one line, no traceback."""
    argv = [sys.executable, "-m", "ftc_verify", "analyze", PAPER, "--controller", GAINS]
    proc = run_python(f"import os; os.close(1); os.execv({sys.executable!r}, {argv!r})", stdout=None)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.strip().splitlines() == ["ftc-verify: error: stdout is closed, the answer could not be "
                                                "printed; nothing was done (to discard the answer, redirect it "
                                                "to /dev/null)"]


@pytest.mark.parametrize("name, reason", [("loop.toml", r"Too many levels of symbolic links \(ELOOP\)"),
                                          ("a" * 300 + ".toml", r"File name too long \(ENAMETOOLONG\)"),
                                          ("a" * 300 + "/K.toml", r"File name too long \(ENAMETOOLONG\)")])
def test_an_unusable_name_is_refused_naming_the_option(tmp_path: Path, name: str, reason: str) -> None:
    """A link loop or a name too long (before: RuntimeError / OSError, exit 4)."""
    (tmp_path / "loop.toml").symlink_to("loop.toml")
    path = str(tmp_path / name)
    with pytest.raises(ValidationError, match=rf"^-o {re.escape(path)}: {reason}; give another name$"):
        check_output_file(path, "-o", (".toml",), inputs=(PAPER,))
    with pytest.raises(ValidationError, match=rf"^{re.escape(path)}: {reason}"):
        write_atomic(path, "x = 1\n")
    with pytest.raises(ValidationError, match=rf"^--out {re.escape(path)}: {reason}"):
        check_out_dir(path)


def test_a_link_loop_from_the_command_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    loop = tmp_path / "loop.toml"
    loop.symlink_to("loop.toml")
    assert main(["synthesize", PAPER, "--method", "common", "-o", str(loop)]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        f"ftc-verify: error: -o/--output {loop}: Too many levels of symbolic links (ELOOP); give another name"]


def test_a_closed_stderr_from_the_shell() -> None:
    """``ftc-verify analyze ... 2>&-``: the messages are discarded, the answer printed and
    the exit code that of the answer (before: an ``isatty`` on ``None``, exit 4)."""
    argv = [sys.executable, "-m", "ftc_verify", "analyze", PAPER, "--controller", GAINS]
    proc = subprocess.run([sys.executable, "-c", f"import os; os.close(2); os.execv({sys.executable!r}, {argv!r})"],
                          capture_output=False, stdout=subprocess.PIPE, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout
    assert "internal error" not in proc.stdout and "verdict: certified" in proc.stdout
