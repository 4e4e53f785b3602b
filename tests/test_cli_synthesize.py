"""The ``synthesize`` command: JSON schema, gains file written only when certified, exit codes."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import cli_inprocess
import numpy as np

from ftc_verify.controllers.files import load_gains

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "examples" / "paper.toml"


def run_cli(*args: str) -> subprocess.CompletedProcess[str]:
    """``ftc-verify ARGS`` in this process (``tests/cli_inprocess.py``)."""
    return cli_inprocess.run_cli(args)


def test_two_step_at_paper_gamma_is_certified_and_reanalysable(tmp_path: Path) -> None:
    out = tmp_path / "gains.toml"
    proc = run_cli("synthesize", str(PAPER), "--gamma", "0.8", "--method", "two-step", "-o", str(out), "--json")
    assert proc.returncode == 0, proc.stderr
    d = json.loads(proc.stdout)
    assert d["feasible"] is True and d["method"] == "two-step"
    assert d["gamma_certified"] is not None and d["gamma_certified"] <= 0.8
    assert d["gamma_nominal_certified"] <= d["gamma_certified"] + 1e-9
    assert d["spectral_abscissa"] < 0
    assert isinstance(d["solve_seconds"], float) and d["solve_seconds"] > 0
    gains = load_gains(out)
    assert len(gains) == 2 and all(np.allclose(K, np.array(G)) for K, G in zip(gains, d["gains"]))
    again = run_cli("analyze", str(PAPER), "--gains", str(out), "--json")
    assert again.returncode == 0, again.stderr
    assert json.loads(again.stdout)["hinf"]["robust_gamma"] <= 0.8


def test_gain_bound_is_respected_and_full_info_writes_m_squared_gains(tmp_path: Path) -> None:
    out = tmp_path / "fi.toml"
    proc = run_cli("synthesize", str(PAPER), "--minimize", "--method", "full-info", "--k-max", "30", "-o", str(out), "--json")
    assert proc.returncode == 0, proc.stderr
    d = json.loads(proc.stdout)
    assert d["max_gain_norm"] <= 30 * (1 + 1e-6)
    gains = load_gains(out)
    assert len(gains) == 4  # m * m full-information gains
    assert max(np.linalg.norm(K, 2) for K in gains) <= 30 * (1 + 1e-6)
    again = run_cli("analyze", str(PAPER), "--gains", str(out), "--json")
    assert again.returncode == 0, again.stderr


def test_infeasible_exit_1_and_no_file(tmp_path: Path) -> None:
    out = tmp_path / "never.toml"
    # gains bounded by 0.01 cannot stabilise the open-loop unstable plant (eigenvalue 1)
    proc = run_cli("synthesize", str(PAPER), "--method", "common", "--k-max", "0.01", "-o", str(out), "--json")
    assert proc.returncode == 1, proc.stderr
    d = json.loads(proc.stdout)
    assert d["feasible"] is False and d["gamma_certified"] is None and d["gains"] == []
    assert not out.exists()


def test_bad_input_exit_2(tmp_path: Path) -> None:
    out = tmp_path / "g.toml"
    for args in (["--gamma", "-1"], ["--gamma", "nan"], ["--gamma", "1", "--minimize"], ["--k-max", "0"]):
        proc = run_cli("synthesize", str(PAPER), "--method", "two-step", "-o", str(out), *args)
        assert proc.returncode == 2, args
        assert "Traceback" not in proc.stderr and proc.stderr.count("\n") == 1
    proc = run_cli("synthesize", str(PAPER), "--method", "magic", "-o", str(out))
    assert proc.returncode == 2
    proc = run_cli("synthesize", str(tmp_path / "missing.toml"), "--method", "common", "-o", str(out))
    assert proc.returncode == 2 and "missing.toml" in proc.stderr
    assert not out.exists()
