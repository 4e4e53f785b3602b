"""``risk`` names where its step came from when the horizon is too short for it (found
by an independent check, round 12): a controller file's ``period`` was reported as
``--step``, an option the user had not given."""

from __future__ import annotations

from pathlib import Path

import cli_inprocess
import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("name", ["gains_period_10.toml", "K{x}.toml"])
def test_the_period_of_the_controller_file_is_named(tmp_path: Path, name: str) -> None:
    """(A brace in the file's name once went through ``str.format``: exit 4.)"""
    gains = (ROOT / "examples/paper_gains.toml").read_text()
    controller = tmp_path / name
    controller.write_text("period = 10\n" + gains)
    args = ["risk", str(ROOT / "examples/paper.toml"), "--controller", str(controller), "--horizon", "5", "--limit", "1"]
    proc = cli_inprocess.run_cli(args, cwd=tmp_path)
    assert proc.returncode == 2
    assert f"10 steps of 10 (the period of {controller})" in proc.stderr
    assert "--step" not in proc.stderr
    proc = cli_inprocess.run_cli(args + ["--step", "1"], cwd=tmp_path)
    assert proc.returncode == 2 and "10 steps of --step 1 " in proc.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == [name]  # nothing written
