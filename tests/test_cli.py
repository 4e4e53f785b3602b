"""The ``analyze`` command: exit codes, JSON schema, one-line errors without traceback."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import cli_inprocess
import pytest

from ftc_verify.cli.main import main

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "examples" / "paper.toml"
PAPER_GAINS = ROOT / "examples" / "paper_gains.toml"


def run_cli(*args: str) -> subprocess.CompletedProcess[str]:
    """``ftc-verify ARGS`` in this process (``tests/cli_inprocess.py``: exit code, stdout and
    stderr as a subprocess gives them)."""
    return cli_inprocess.run_cli(args)


def test_analyze_paper_json_schema_and_exit_0() -> None:
    proc = run_cli("analyze", str(PAPER), "--gains", str(PAPER_GAINS), "--json")
    assert proc.returncode == 0, proc.stderr
    d = json.loads(proc.stdout)
    assert isinstance(d["mss"]["spectral_abscissa"], float) and d["mss"]["spectral_abscissa"] < 0
    assert d["mss"]["stable"] is True
    assert d["mes_lmi"]["feasible"] is True
    assert 0 < d["hinf"]["nominal_gamma"] <= d["hinf"]["robust_gamma"] < 0.8  # the paper designed for 0.8
    assert d["certificate"]["ok"] is True
    assert len(d["per_mode"]) == 4
    for m in d["per_mode"]:
        assert {"true_mode", "fdi_mode", "poles", "hinf_norm"} <= set(m)
        assert m["agree"] is True and m["hinf_norm"] > 0
    assert {(m["true_mode"], m["fdi_mode"]) for m in d["per_mode"]} == {(1, 1), (1, 2), (2, 1), (2, 2)}


def test_analyze_table_in_process(capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["analyze", str(PAPER), "--gains", str(PAPER_GAINS), "--solver", "clarabel"])
    out = capsys.readouterr().out
    assert code == 0
    assert "verdict: certified stable" in out and "(2, 1)" in out


def test_analyze_unstable_exit_1(tmp_path: Path) -> None:
    gains = tmp_path / "zero.toml"
    gains.write_text("[[gain]]\nK = [[0.0, 0.0], [0.0, 0.0]]\n[[gain]]\nK = [[0.0, 0.0], [0.0, 0.0]]\n")
    proc = run_cli("analyze", str(PAPER), "--gains", str(gains), "--json")
    assert proc.returncode == 1, proc.stderr
    d = json.loads(proc.stdout)
    assert d["mss"]["stable"] is False and d["mss"]["spectral_abscissa"] > 0
    assert d["mes_lmi"]["feasible"] is False
    assert d["hinf"]["nominal_gamma"] is None
    assert d["certificate"]["ok"] is False


@pytest.mark.parametrize(
    ("gains_text", "needle"),
    [
        ("[[gain]]\nK = [[1.0, 2.0]]\n[[gain]]\nK = [[1.0, 2.0]]\n", "gain[1].K: 1 rows, but the system has 2 inputs"),
        ("[[gain]]\nK = [[0.0, 0.0], [0.0, 0.0]]\n", "1 entries given, the system has 2 modes"),
        ("[[gain]]\nK = [[nan, 0.0], [0.0, 0.0]]\n[[gain]]\nK = [[0.0, 0.0], [0.0, 0.0]]\n", "non-finite"),
        ("[[gain]]\nK = [[0.0, 0.0], [0.0, 0.0]]\nL = 1\n", "unknown key"),
        ("this is not toml [[[", "not valid TOML"),
        ("[[controller]]\nAc = [[1.0]]\nBc = [[1.0, 1.0]]\nCc = [[1.0], [1.0]]\nDc = [[0.0, 0.0], [0.0, 0.0]]\n" * 2,
         "controller[1].Dc: 2 columns, but the system has 1 measured outputs"),
        ("[[gain]]\nK = [[0.0, 0.0], [0.0, 0.0]]\n[[controller]]\nDc = [[0.0], [0.0]]\n", "both [[gain]] and [[controller]]"),
        ("[[controller]]\nAc = [[1.0]]\nBc = [[1.0]]\nCc = [[1.0], [1.0]]\nDc = [[0.0], [0.0]]\n"
         "[[controller]]\nAc = [[1.0, 0.0], [0.0, 1.0]]\nBc = [[1.0], [1.0]]\nCc = [[1.0, 0.0], [1.0, 0.0]]\n"
         "Dc = [[0.0], [0.0]]\n", "controller[2].Ac: expected shape 1 x 1"),
    ],
)
def test_bad_gains_exit_2_one_line(tmp_path: Path, gains_text: str, needle: str) -> None:
    gains = tmp_path / "bad.toml"
    gains.write_text(gains_text)
    proc = run_cli("analyze", str(PAPER), "--gains", str(gains))
    assert proc.returncode == 2
    assert proc.stdout == ""
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and needle in lines[0] and "bad.toml" in lines[0]
    assert "Traceback" not in proc.stderr


def test_bad_system_exit_2_names_file_and_value(tmp_path: Path) -> None:
    text = PAPER.read_text().replace("alpha    = [[-0.5, 0.5], [1.0, -1.0]]", "alpha    = [[-0.5, 0.4], [1.0, -1.0]]")
    bad = tmp_path / "sys.toml"
    bad.write_text(text)
    proc = run_cli("analyze", str(bad), "--gains", str(PAPER_GAINS))
    assert proc.returncode == 2
    assert "sys.toml" in proc.stderr and "chain.alpha row 1" in proc.stderr and "-0.1" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_usage_errors_exit_2() -> None:
    assert run_cli("analyze", str(PAPER)).returncode == 2  # --gains missing
    assert run_cli("frobnicate").returncode == 2
    proc = run_cli("analyze", str(PAPER), "--gains", str(PAPER_GAINS), "--solver", "mosek")
    assert proc.returncode == 2 and "mosek" in proc.stderr


def test_dynamic_controller_analyze_says_why_not() -> None:
    """The observer-based example is mean-square unstable: exit 1, the spectral test says
    so, and the JSON names the augmented loop's kind."""
    observer = ROOT / "examples" / "paper_observer.toml"
    proc = run_cli("analyze", str(PAPER), "--controller", str(observer), "--json")
    assert proc.returncode == 1, proc.stderr
    d = json.loads(proc.stdout)
    assert d["controller"] == "FDI-mode dynamic output feedback (n_c = 2)"
    assert d["mss"]["stable"] is False and d["mss"]["spectral_abscissa"] > 0
    assert len(d["per_mode"]) == 4 and all(len(m["poles"]) == 4 for m in d["per_mode"])
