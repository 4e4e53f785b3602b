"""The prestarted child (ftc_verify.prestart): its job's answer is the function's own, the
job runs here when the child is gone, its exception comes back, and python-control's
cross-check through it equals the check in this process."""

from __future__ import annotations

import math
import os
import signal
from pathlib import Path

import numpy as np
import pytest

from ftc_verify.prestart import Prestarted, cross_check

ROOT = Path(__file__).resolve().parents[1]


def _pid_and_square(x: float) -> tuple[int, float]:
    return os.getpid(), x * x


def _fails(x: float) -> float:
    raise ArithmeticError(f"no answer for {x}")


@pytest.mark.skipif(not hasattr(os, "fork"), reason="POSIX fork")
def test_the_job_runs_in_the_child_and_its_answer_comes_back() -> None:
    child = Prestarted(("math",))
    try:
        child.submit(_pid_and_square, 3.0)
        pid, value = child.result()
    finally:
        child.cancel()
    assert value == 9.0 and pid != os.getpid()
    assert set(child.seconds) == {"import", "run", "wait"}


@pytest.mark.skipif(not hasattr(os, "fork"), reason="POSIX fork")
def test_a_killed_child_means_the_job_runs_here() -> None:
    child = Prestarted(())
    try:
        os.kill(child.pid, signal.SIGKILL)
        child.submit(_pid_and_square, 2.0)
        pid, value = child.result()
    finally:
        child.cancel()
    assert value == 4.0 and pid == os.getpid()


@pytest.mark.skipif(not hasattr(os, "fork"), reason="POSIX fork")
def test_the_jobs_exception_is_raised_again_and_a_failed_import_runs_the_job_here() -> None:
    child = Prestarted(())
    try:
        child.submit(_fails, 1.5)
        with pytest.raises(ArithmeticError, match=r"no answer for 1\.5"):
            child.result()
    finally:
        child.cancel()
    child = Prestarted(("ftc_verify_no_such_module",))
    try:
        child.submit(_pid_and_square, 5.0)
        assert child.result() == (os.getpid(), 25.0)
    finally:
        child.cancel()


def test_cross_check_in_the_child_equals_the_check_here() -> None:
    from ftc_verify.analysis.closedloop import closed_loop
    from ftc_verify.analysis.crossval import cross_validate
    from ftc_verify.cli.common import load

    system, gains = load(str(ROOT / "examples" / "paper.toml"), str(ROOT / "examples" / "paper_gains.toml"))
    loop = closed_loop(system, gains)
    child = cross_check()
    try:
        child.submit(cross_validate, loop)
        theirs = child.result()
    finally:
        child.cancel()
    ours = cross_validate(loop)
    assert len(theirs) == len(ours) == 4 and all(m.agree for m in theirs)
    for a, b in zip(theirs, ours, strict=True):
        assert (a.true_mode, a.fdi_mode) == (b.true_mode, b.fdi_mode)
        np.testing.assert_array_equal(a.poles, b.poles)
        assert a.linf_norm == b.linf_norm and math.isfinite(a.control_linf_norm)
        assert a.control_linf_norm == b.control_linf_norm


def test_cancel_without_a_job_ends_the_child() -> None:
    child = Prestarted(("math",))
    pid = child.pid
    child.cancel()
    assert child.pid == 0
    if pid:
        with pytest.raises(ChildProcessError):
            os.waitpid(pid, 0)
