"""``--x0`` takes a list of numbers whose first one is negative, as the docs write it
(``--x0 -1,2``): argparse took ``-1,2`` for an option and refused the command with
"expected one argument" (found by an independent check)."""

from __future__ import annotations

from pathlib import Path

import pytest

import cli_inprocess

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("value", ["-1,2,3", "-1.5e-3,-2,4", "-.5,0,1"])
def test_risk_reads_a_negative_first_entry(value: str) -> None:
    """The value reaches the command: the paper plant has 2 states, so three numbers are
    refused by the command itself (exit 2, the option and the value named), not by the
    parser."""
    run = cli_inprocess.run_cli(["risk", str(ROOT / "examples/paper.toml"), "--controller",
                                 str(ROOT / "examples/paper_gains.toml"), "--horizon", "1", "--limit", "10",
                                 "--x0", value])
    assert run.returncode == 2
    assert "expected one argument" not in run.stderr
    assert "--x0 " in run.stderr and "3 numbers for the 2 plant states" in run.stderr


def test_a_following_option_is_not_taken_as_the_value() -> None:
    """``--x0`` followed by another option is still the parser's error (no value)."""
    run = cli_inprocess.run_cli(["risk", str(ROOT / "examples/paper.toml"), "--controller",
                                 str(ROOT / "examples/paper_gains.toml"), "--x0", "--horizon", "1"])
    assert run.returncode == 2 and "--x0: expected one argument" in run.stderr
