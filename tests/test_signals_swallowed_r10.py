"""A signal whose exception a library swallows still ends the command with its exit code.

CPython ignores an exception raised inside a gc callback (it prints "Exception ignored"
and goes on): a Ctrl-C that landed in the callback of an in-process Dask scheduler was
lost and ``simulate --workers 2`` ended with exit 0 (found running the suite, round 10).
The CLI's handlers record each signal before they raise, and ``main`` ends with 130 / 143
when one arrived, whatever happened to its exception (swallowed, or turned into another
error). Here the command itself does that, as such a library would."""

from __future__ import annotations

import importlib
import os
import signal
import time
from pathlib import Path
from typing import Any

import pytest

from ftc_verify.cli.common import EXIT_INTERRUPTED, EXIT_OK, EXIT_TERMINATED
from ftc_verify.errors import ValidationError

cli_main = importlib.import_module("ftc_verify.cli.main")  # the module (the package's ``main`` is the function)
ROOT = Path(__file__).resolve().parents[1]
ARGV = ["analyze", str(ROOT / "examples" / "paper.toml"), "--gains", str(ROOT / "examples" / "paper_gains.toml")]


def _swallowing(signum: int | None, convert: type[Exception] | None = None) -> Any:
    def command(args: Any) -> int:
        try:
            if signum is not None:
                os.kill(os.getpid(), signum)
                time.sleep(1.0)  # the handler runs at the next bytecode; the sleep is interrupted
        except BaseException as exc:  # what a gc callback does with it, or a library that converts it
            if convert is not None:
                raise convert("a library's own error") from exc
        print("the command's answer")
        return EXIT_OK
    return command


@pytest.mark.parametrize(("signum", "convert", "code", "line"), [
    (signal.SIGINT, None, EXIT_INTERRUPTED, "interrupted"), (signal.SIGTERM, None, EXIT_TERMINATED, "terminated"),
    (signal.SIGTERM, RuntimeError, EXIT_TERMINATED, "terminated"), (signal.SIGINT, OSError, EXIT_INTERRUPTED, "interrupted"),
    (signal.SIGTERM, ValidationError, EXIT_TERMINATED, "terminated"), (None, None, EXIT_OK, "")])
def test_swallowed_signal_still_sets_the_exit_code(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str],
                                                   signum: int | None, convert: type[Exception] | None, code: int,
                                                   line: str) -> None:
    parser = cli_main.build_parser()

    class Parser:
        def parse_args(self, argv: Any) -> Any:
            args = parser.parse_args(argv)
            args.func = _swallowing(signum, convert)
            return args

    monkeypatch.setattr(cli_main, "build_parser", Parser)
    before = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    assert cli_main.main(ARGV) == code
    err = capsys.readouterr().err
    assert (f"ftc-verify: {line}" in err) if line else err == ""
    assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == before  # restored
