"""``str(AnalysisReport)`` and ``str(VerifyReport)`` are the summaries the CLI prints.

The command runs in-process; the report it computed is caught on its way (the stage's
function wrapped), and the command's output must be ``str(report)`` plus only the lines
the report cannot know: the FDI model's line of ``analyze`` (the report does not hold
the chain) and the ``report:`` line of ``verify`` (the files written).
"""

from __future__ import annotations

import importlib
from pathlib import Path
from typing import Any

import pytest

from ftc_verify.cli.common import EXIT_NEGATIVE, EXIT_OK
from ftc_verify.cli.main import main

ROOT = Path(__file__).resolve().parents[1]
# by import_module: the packages re-export functions under the same names as these modules
summary_module = importlib.import_module("ftc_verify.analysis.summary")
report_module = importlib.import_module("ftc_verify.verification.report")
PAPER, GAINS = str(ROOT / "examples" / "paper.toml"), str(ROOT / "examples" / "paper_gains.toml")


def _caught(monkeypatch: pytest.MonkeyPatch, module: Any, name: str, index: int) -> list[Any]:
    """Wrap ``module.name`` so that the report it makes or gets (return value when
    ``index`` is -1, else positional argument ``index``) is kept."""
    seen: list[Any] = []
    original = getattr(module, name)

    def wrapper(*args: Any, **kwargs: Any) -> Any:
        out = original(*args, **kwargs)
        seen.append(out if index < 0 else args[index])
        return out

    monkeypatch.setattr(module, name, wrapper)
    return seen


@pytest.mark.parametrize("extra", [[], ["--no-lmi"]])
def test_str_of_an_analysis_is_the_cli_summary(extra: list[str], monkeypatch: pytest.MonkeyPatch,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    # the analysis runs in a child process (interruptible); the CLI prints the report it
    # gets back through analysis_summary, here in this process
    reports = _caught(monkeypatch, summary_module, "analysis_summary", 0)
    assert main(["analyze", PAPER, "--gains", GAINS, *extra]) == EXIT_OK
    printed = capsys.readouterr().out.splitlines()
    assert len(reports) == 1
    text = str(reports[0])
    assert "AnalysisReport(" not in text and len(text.splitlines()) < 20
    assert printed[1].startswith("  FDI: ")  # the one line the report does not hold
    assert printed[:1] + printed[2:] == text.splitlines()
    assert text.splitlines()[-1].startswith("  verdict: ")
    assert ("not requested (--no-lmi)" in text) == bool(extra)


@pytest.mark.slow(12)
def test_str_of_a_verify_report_is_the_cli_summary(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    reports = _caught(monkeypatch, report_module, "write_report", 0)
    code = main(["verify", PAPER, "--gains", GAINS, "--paths", "5", "--horizon", "2", "--seed", "1",
                 "--out", str(tmp_path / "rep")])
    assert code in (EXIT_OK, EXIT_NEGATIVE)  # 5 short paths: the Monte Carlo bound may be too wide to pass
    printed = capsys.readouterr().out.splitlines()
    assert len(reports) == 1
    text = str(reports[0])
    assert "VerifyReport(" not in text
    report_lines = [line for line in printed if line.startswith("  report: ")]
    assert len(report_lines) == 1 and str(tmp_path / "rep" / "report.md") in report_lines[0]
    assert [line for line in printed if not line.startswith("  report: ")] == text.splitlines()
    assert text.splitlines()[0] == "ftc-verify verify: paper-section-vi"
    assert text.splitlines()[-1] == f"  verdict: {reports[0].verdict}"
