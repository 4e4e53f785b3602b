"""Proved bounds are printed rounded outward (:mod:`ftc_verify.claimtext`): a certified
gamma never printed below the number proved, a proved lower bound never above it."""

from __future__ import annotations

import dataclasses
import importlib
import re
from decimal import Decimal
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from ftc_verify.claimtext import lower_text, upper_text
from ftc_verify.cli.common import EXIT_OK
from ftc_verify.cli.main import main
from ftc_verify.cli.sampled_lines import performance_lines

ROOT = Path(__file__).resolve().parents[1]
PAPER, GAINS = str(ROOT / "examples" / "paper.toml"), str(ROOT / "examples" / "paper_gains.toml")
summary_module = importlib.import_module("ftc_verify.analysis.summary")


def _digits(text: str) -> int:
    mantissa = text.lower().split("e")[0].lstrip("-").replace(".", "").lstrip("0")
    return len(mantissa.rstrip("0")) or 1


@given(st.floats(allow_nan=False, allow_infinity=False).filter(lambda x: x != 0))
def test_outward_rounding_keeps_the_bound_and_six_digits(x: float) -> None:
    up, down = upper_text(x), lower_text(x)
    assert Decimal(up) >= Decimal(x) >= Decimal(down)
    assert float(up) >= x >= float(down)
    assert _digits(up) <= 6 and _digits(down) <= 6
    # the nearest 6-digit decimal is one of the two: outward costs at most one unit in the 6th digit
    assert Decimal(f"{x:.6g}") in (Decimal(up), Decimal(down))


def test_rounding_that_would_cross_the_bound() -> None:
    assert f"{0.4980004:.6g}" == "0.498"  # to nearest: below the certified gamma
    assert upper_text(0.4980004) == "0.498001" and lower_text(0.4980004) == "0.498"
    assert upper_text(0.4980006) == "0.498001" and lower_text(0.4980006) == "0.498"
    assert upper_text(9.9999951) == "10" and lower_text(9.9999951) == "9.99999"
    assert upper_text(float("inf")) == "inf" and upper_text(0.0) == "0"


def test_missing_bound_text() -> None:
    assert upper_text(None) == "-" and lower_text(None, 4) == "-"
    assert upper_text(None, 4, missing="none") == "none" and lower_text(None, missing="n/a") == "n/a"
    assert upper_text(0.4980004, missing="none") == "0.498001"


def _printed_number(line: str, before: str) -> str:
    match = re.search(re.escape(before) + r"\s*([-+0-9.e]+)", line)
    assert match is not None, line
    return match.group(1)


def test_analyze_prints_gammas_up_and_lower_bounds_down(monkeypatch: pytest.MonkeyPatch,
                                                        capsys: pytest.CaptureFixture[str]) -> None:
    seen: list[Any] = []
    original = summary_module.analysis_summary

    def keep(rep: Any, **kw: Any) -> str:
        seen.append(rep)
        return original(rep, **kw)

    monkeypatch.setattr(summary_module, "analysis_summary", keep)
    assert main(["analyze", PAPER, "--gains", GAINS]) == EXIT_OK
    out = capsys.readouterr().out
    rep = seen[0]
    gamma_line = next(line for line in out.splitlines() if "robust gamma (Lem. 4.1)" in line)
    assert float(_printed_number(gamma_line, "(Lem. 4.1)")) >= rep.robust.gamma
    # a certified gamma whose nearest 6-digit decimal is below it
    tricky = dataclasses.replace(rep, robust=dataclasses.replace(rep.robust, gamma=0.4980004))
    text = str(tricky)
    assert "robust gamma (Lem. 4.1)  0.498001" in text
    lows = [line for line in text.splitlines() if "proved lower bound" in line]
    assert lows, text
    low = rep.to_dict()["hinf"]["robust_lower_bound"]["value"]
    assert any(float(_printed_number(line, "proved lower bound")) <= low for line in lows)


def test_sampled_performance_lines_round_outward() -> None:
    cert = SimpleNamespace(gamma=0.4980004, pieces=4, degree=1, note="")
    perf = SimpleNamespace(nominal=cert, nominal_lower=0.4980006, nominal_lower_kind="proved", robust=None)
    (line,) = performance_lines(perf)
    assert "gamma <= 0.498001 (proved" in line and "lower bound 0.498 (proved)" in line
    estimate = SimpleNamespace(nominal=cert, nominal_lower=0.4980006, nominal_lower_kind="float64", robust=None)
    (line,) = performance_lines(estimate)
    assert "lower bound 0.498001 (float64, not proved)" in line  # an estimate: to nearest


def test_report_table_rounds_bounds_outward() -> None:
    report = importlib.import_module("ftc_verify.verification.report")
    assert report._bound(0.4980004, "up") == "0.498001" and report._bound(0.4980006, "down") == "0.498"
    assert report._bound(None, "up") == "-"
