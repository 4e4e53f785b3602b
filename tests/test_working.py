"""The 'working' line of commands without a progress bar (ftc_verify.cli.working): shown
on a terminal after the delay, erased before the answer is printed, never shown on a pipe."""

from __future__ import annotations

import io
import sys
import time

import pytest

from ftc_verify.cli.working import working


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_shown_after_the_delay_and_erased_before_the_answer(capsys: pytest.CaptureFixture[str]) -> None:
    term = _Terminal()
    before = sys.stdout
    with working("analyze", stream=term, delay=0.05, period=0.02):
        time.sleep(0.3)
        shown = term.getvalue()
        print("certified")
        after_print = term.getvalue()
        time.sleep(0.1)
    assert "\rftc-verify analyze: working (0 s)" in shown
    assert after_print.endswith("\r\033[K")  # erased before the answer went out
    assert term.getvalue() == after_print  # and not shown again
    assert sys.stdout is before
    assert capsys.readouterr().out == "certified\n"


def test_quick_commands_and_pipes_show_nothing() -> None:
    term = _Terminal()
    with working("plant", stream=term, delay=0.5):
        pass
    assert term.getvalue() == ""
    pipe = io.StringIO()  # not a terminal
    with working("synthesize", stream=pipe, delay=0.0):
        time.sleep(0.05)
    assert pipe.getvalue() == ""
