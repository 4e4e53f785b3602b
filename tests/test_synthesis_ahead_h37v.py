"""The iterative synthesis descends from the best of the other starts (and analyses the
result) while two-step still runs in its child; the work done ahead is kept only when that
start is the best of all, so the result is the one of the serial order
(``ftc_verify.synthesis.state_feedback._iterative``)."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from ftc_verify.synthesis import state_feedback as sf
from ftc_verify.synthesis.results import SolverCalls


def _row(name: str, gamma: float | None) -> dict[str, Any]:
    return {"name": name, "gamma_certified": gamma, "gains": [np.full((1, 1), gamma or 0.0)], "lmi": None}


def _run(monkeypatch: pytest.MonkeyPatch, two_step: float | None) -> dict[str, Any]:
    """``_iterative`` with stand-ins: the other starts certify common (0.5) and lqr (0.9);
    two-step certifies ``two_step``. Returns its answer, the starts descended from (in
    order) and the gains analysed ahead."""
    descended: list[str] = []
    analysed: list[str] = []

    def starts(system: Any, gamma: Any, k_max: Any, solver: str, calls: SolverCalls, start: Any,
               extra: bool = False, meanwhile: Any = None) -> list[dict[str, Any]]:
        rows = [_row("common", 0.5), _row("lqr", 0.9)]
        if meanwhile is not None:
            meanwhile(rows)  # two-step still running
        return [_row("two-step", two_step)] + rows

    def descend(loop_of: Any, step: Any, m: int, start: list[Any], calls: SolverCalls, solver: str,
                max_iter: int, tol: float, start_lmi: Any = None) -> sf.Descent:
        gamma = float(start[0][0, 0])
        descended.append(str(gamma))
        calls.outcomes.append(f"descent from {gamma}")  # type: ignore[arg-type]
        return sf.Descent(start, [gamma * 0.9], "stopped", start_lmi)

    def verify(system: Any, gains: list[Any], solver: str) -> str:
        analysed.append(str(float(gains[0][0, 0])))
        return f"report of {float(gains[0][0, 0])}"

    monkeypatch.setattr(sf, "_starts", starts)
    monkeypatch.setattr(sf, "descend", descend)
    monkeypatch.setattr(sf, "_verify", verify)
    calls = SolverCalls("clarabel")
    system = SimpleNamespace(m=2)  # the stand-ins read nothing else
    _, history, _, name, rows, report = sf._iterative(system, None, 30.0, "clarabel", calls, None, 10,  # type: ignore[arg-type]
                                                      1e-3)
    return {"history": history, "name": name, "rows": rows, "report": report, "outcomes": calls.outcomes,
            "descended": descended, "analysed": analysed}


def test_work_done_ahead_is_kept_when_two_step_is_not_certified(monkeypatch: pytest.MonkeyPatch) -> None:
    run = _run(monkeypatch, None)
    assert run["name"] == "common" and run["history"] == [0.45] and run["report"] == "report of 0.5"
    assert run["descended"] == ["0.5"] and run["analysed"] == ["0.5"]  # once, ahead; nothing done twice
    assert run["outcomes"] == ["descent from 0.5"]  # the descent's calls added to the run's


def test_work_done_ahead_is_dropped_when_two_step_wins(monkeypatch: pytest.MonkeyPatch) -> None:
    run = _run(monkeypatch, 0.3)
    assert run["name"] == "two-step" and run["history"] == [pytest.approx(0.27)]
    assert run["report"] is None  # analysed later by synthesize, as before
    assert run["descended"] == ["0.5", "0.3"]
    assert run["outcomes"] == ["descent from 0.3"]  # only the kept descent's calls count


def test_a_tie_goes_to_two_step_as_in_the_serial_order(monkeypatch: pytest.MonkeyPatch) -> None:
    run = _run(monkeypatch, 0.5)
    assert run["name"] == "two-step" and run["report"] is None and run["rows"][0]["name"] == "two-step"
    assert run["descended"] == ["0.5", "0.5"] and run["outcomes"] == ["descent from 0.5"]
