"""``interrupts.die_with_parent``: a forked worker whose parent died before the Linux
parent-death request took effect ends at once instead of computing on, orphaned."""

from __future__ import annotations

import os
import sys

import pytest

from ftc_verify.interrupts import die_with_parent

pytestmark = pytest.mark.skipif(not (hasattr(os, "fork") and sys.platform.startswith("linux")), reason="Linux fork")


def _child_status(parent: int) -> int:
    pid = os.fork()
    if pid == 0:  # child: 0 when die_with_parent returned, 1 when it ended the process
        try:
            die_with_parent(parent)
        finally:
            os._exit(0)
    _, status = os.waitpid(pid, 0)
    return os.waitstatus_to_exitcode(status)


def test_a_child_of_the_named_parent_goes_on() -> None:
    assert _child_status(os.getpid()) == 0


def test_a_child_whose_named_parent_is_gone_ends_at_once() -> None:
    assert _child_status(os.getpid() + 1_000_000) == 1  # not its parent: as if the parent had died and it was adopted
