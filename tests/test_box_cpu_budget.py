"""The box verdict's budget is counted in CPU seconds, not wall seconds: the same loop
gets the same verdict whatever else the machine runs (round 12)."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from box_systems import interior_loop, shifted
from ftc_verify.analysis.moments.stability import mean_square_stability


def test_wall_time_does_not_spend_the_budget(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A wall clock that jumps 1000 s at every reading (a machine so loaded that the
    process barely runs) leaves the 0.5 CPU s budget unspent: the loop of
    ``test_budget_gives_undecided_with_the_open_sub_box`` ends "undecided" by its CPU
    budget, with the same reason as on a quiet machine, not on the first wall reading."""
    loop = shifted(interior_loop(tmp_path), 0.1052)
    quiet = mean_square_stability(loop, budget_seconds=0.5)
    real = time.perf_counter
    jumps = iter(range(1, 10**9))
    monkeypatch.setattr(time, "perf_counter", lambda: real() + 1000.0 * next(jumps))
    loaded = mean_square_stability(loop, budget_seconds=0.5)
    assert quiet.verdict == loaded.verdict == "undecided"
    assert "CPU s" in loaded.reason and quiet.reason.split(" before")[0] == loaded.reason.split(" before")[0]
    assert len(loaded.vertex_verdicts) > 1  # sub-boxes were proved after the first wall reading


def test_a_spent_cpu_budget_gives_undecided(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A CPU clock that jumps 1000 s at every reading spends the budget at once."""
    import ftc_verify.analysis.box as box

    loop = shifted(interior_loop(tmp_path), 0.1052)
    real = box.cpu_clock
    jumps = iter(range(1, 10**9))
    monkeypatch.setattr(box, "cpu_clock", lambda: real() + 1000.0 * next(jumps))
    result = mean_square_stability(loop, budget_seconds=60.0)
    assert result.verdict == "undecided" and "60 CPU s" in result.reason
