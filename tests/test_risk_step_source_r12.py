"""``risk`` names where its step came from when the horizon is too short for it (found
by an independent check, round 12): a controller file's ``period`` was reported as
``--step``, an option the user had not given."""

from __future__ import annotations

from pathlib import Path

import cli_inprocess

ROOT = Path(__file__).resolve().parents[1]


def test_the_period_of_the_controller_file_is_named(tmp_path: Path) -> None:
    gains = (ROOT / "examples/paper_gains.toml").read_text()
    controller = tmp_path / "gains_period_10.toml"
    controller.write_text("period = 10\n" + gains)
    args = ["risk", str(ROOT / "examples/paper.toml"), "--controller", str(controller), "--horizon", "5", "--limit", "1"]
    proc = cli_inprocess.run_cli(args, cwd=tmp_path)
    assert proc.returncode == 2
    assert "10 steps of 10 (the period of" in proc.stderr and "gains_period_10.toml" in proc.stderr
    assert "--step" not in proc.stderr
    proc = cli_inprocess.run_cli(args + ["--step", "1"], cwd=tmp_path)
    assert proc.returncode == 2 and "10 steps of --step 1 " in proc.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["gains_period_10.toml"]  # nothing written
