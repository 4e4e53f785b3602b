"""``verify`` end to end on an FDI model beyond the paper (issue 23): Erlang-4 delays and
false alarms (``examples/paper_phase_type.toml``) with the paper's gains -- certified,
exact energies at every rate vertex, the Monte Carlo on the FMU within gamma^2, the FMU
agreeing with the numpy reference on the same phase-type paths -- and the FDI model named
in the output and the report."""

from __future__ import annotations

import json
from pathlib import Path

import cli_inprocess
import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow(40)  # seconds on 2 busy cores (--durations at load 9, / 4): scheduled first
def test_verify_passes_on_a_phase_type_chain_with_false_alarms(tmp_path: Path) -> None:
    out = cli_inprocess.run_cli(["verify", str(ROOT / "examples" / "paper_phase_type.toml"),
                                 "--gains", str(ROOT / "examples" / "paper_gains.toml"), "--paths", "30", "--horizon",
                                 "6", "--seed", "5", "--out", str(tmp_path / "rep")])
    assert out.returncode == 0, out
    assert "FDI: Erlang-4 detection delays" in out.stdout and "false alarms at rates in [0.02, 0.05]" in out.stdout
    report = json.loads((tmp_path / "rep" / "report.json").read_text())
    assert report["verdict"] == "pass" and report["options"]["fdi_model"].startswith("FDI: Erlang-4")
    checks = {c["name"]: c for c in report["checks"]}
    assert checks["FMU vs reference"]["ok"] and "false_alarm" in checks["exact energy"]["detail"]
    vertices = {json.dumps(e["beta"]) for e in report["exact"]}
    assert len(vertices) == 16  # 2 detection rates x 2 false-alarm rates, each at both ends
    assert "FDI: Erlang-4" in (tmp_path / "rep" / "report.md").read_text()
