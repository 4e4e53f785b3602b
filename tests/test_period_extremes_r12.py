"""Finite periods far from the loop's time scale (found by an independent check, round
12): ``--period 1e308`` passed the parser ("positive and finite") and then overflowed in
the ``h_max`` scan's range (``2 * period``), exit 4 "internal error" on ``analyze``,
``synthesize`` and the exports. The scan now widens to the period only within
``SCAN_WIDEN`` of the loop's time scale; the verdict at the period is still given."""

from __future__ import annotations

import math
from pathlib import Path

import cli_inprocess
import pytest

from ftc_verify.analysis.moments.sampled import SCAN_WIDEN, SampledLoop, scan_range
from ftc_verify.controllers.files import load_controller
from ftc_verify.model.files import load_system

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("period", [1e308, 1e-300])
def test_extreme_periods_are_answered_not_crashed(period: float) -> None:
    """The paper's loop is not proved either way at these periods (the map overflows or
    is the identity to float64): exit 5 with the verdict line, no internal error; the
    ``h_max`` bracket of the default scan is still printed."""
    proc = cli_inprocess.run_cli(["analyze", str(ROOT / "examples/paper.toml"), "--gains",
                                  str(ROOT / "examples/paper_gains.toml"), "--period", repr(period), "--no-lmi"])
    assert "internal error" not in proc.stderr and proc.returncode == 5, proc.stderr
    assert "the sampled loop is UNDECIDED" in proc.stdout and "h_max 0.0842" in proc.stdout


def test_scan_range_widens_only_near_the_time_scale() -> None:
    loop = SampledLoop.build(load_system(ROOT / "examples/paper.toml"), load_controller(ROOT / "examples/paper_gains.toml"))
    c = loop.speed
    base = scan_range(loop)
    assert base == (1e-3 / c, 20.0 / c)
    assert scan_range(loop, 1e308) == base and scan_range(loop, 1e-300) == base
    near = 0.5 * SCAN_WIDEN[1] / c
    lo, hi = scan_range(loop, near)
    assert lo == base[0] and hi == 2 * near and math.isfinite(hi)
