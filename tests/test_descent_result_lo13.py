"""The descent hands its certified robust result to the polish
(:class:`ftc_verify.synthesis.state_feedback.Descent`): ``descend`` returns Lemma 4.1's
result for the gains it returns, and the polish that follows starts from it instead of
solving the same program again -- the same gains and gammas, one robust solve fewer.

Solver: Clarabel, whose answer to one program is deterministic, so "the same" is
compared bit for bit.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from ftc_verify.analysis.closedloop import state_feedback_loop
from ftc_verify.analysis.lmi_analysis import hinf_gamma
from ftc_verify.model.files import load_system
from ftc_verify.model.system import FTCSystem
from ftc_verify.synthesis import state_feedback as sf
from ftc_verify.synthesis.polish import polish
from ftc_verify.synthesis.results import SolverCalls
from ftc_verify.synthesis.starts import certify_start

DATA = Path(__file__).resolve().parent / "data"
K_MAX = 30.0


@pytest.fixture(scope="module")
def sf301() -> tuple[FTCSystem, dict[str, Any]]:
    """Issue 34's ``sf301`` (n = 2, m = 2, uncertain) and its certified ``common`` start."""
    system = load_system(DATA / "issue34_sf301.toml")
    gains, _, _ = sf._design(system, "common", None, K_MAX, SolverCalls("clarabel"))
    row = certify_start(system, "common", gains, "clarabel")
    assert row["gamma_certified"] is not None
    return system, row


def _descend(system: FTCSystem, row: dict[str, Any], step: Any, calls: SolverCalls, tol: float = 1e-3) -> sf.Descent:
    return sf.descend(lambda G: state_feedback_loop(system, G), step, system.m, list(row["gains"]), calls,
                      "clarabel", 10, tol, row["lmi"])


def _rejected_second(system: FTCSystem, row: dict[str, Any], calls: SolverCalls) -> Any:
    """Eq. (18)'s K-step in the first round, then the start's gains again: a candidate
    worse than the first iterate, which the descent rejects (run with ``tol = 0``, so that
    the first step, 6e-6 relative on sf301, does not end the descent)."""
    done: list[int] = []

    def step(P: Any, lam: Any, j: int) -> Any:
        done.append(j)
        return sf.gain_step(system, P, lam, j, calls, K_MAX) if len(done) <= system.m else (row["gains"][j], None, "")
    return step


# The three ways a descent ends: an accepted last step below the tolerance (eq. (18)'s
# K-step), a candidate rejected (the iterate before it is returned), a K-step that fails
# (the gains so far are returned).
STEPS = {
    "improvement below tol": lambda system, row, calls: (
        lambda P, lam, j: sf.gain_step(system, P, lam, j, calls, K_MAX)),
    "candidate rejected": _rejected_second,
    "K-step failed": lambda system, row, calls: (lambda P, lam, j: (None, None, "stand-in failure")),
}


@pytest.mark.parametrize("end", list(STEPS))
def test_the_descents_result_is_lemma_4_1_for_the_gains_it_returns(sf301: Any, end: str) -> None:
    """Whatever ends the descent, ``lmi`` is the certified result of the returned gains:
    its gamma is the history's last, and solving the program again for those gains gives
    the same gamma and Lyapunov matrices bit for bit."""
    system, row = sf301
    calls = SolverCalls("clarabel")
    found = _descend(system, row, STEPS[end](system, row, calls), calls, 0.0 if end == "candidate rejected" else 1e-3)
    assert ("K-step failed" in found.message) == (end == "K-step failed")
    assert len(found.history) == (1 if end == "K-step failed" else 2)  # sf301's descent stops after one step
    assert found.lmi.certified and found.lmi.gamma == found.history[-1]
    again = hinf_gamma(state_feedback_loop(system, found.gains), robust=True, solver="clarabel")
    assert again.gamma == found.lmi.gamma
    assert all(np.array_equal(a, b) for a, b in zip(again.P or (), found.lmi.P or (), strict=True))


def test_the_polish_from_the_descents_result_is_the_same_with_one_solve_fewer(sf301: Any) -> None:
    """The polish from the descent's result against the polish that solves it again: the
    same gains, gammas and message; the solver outcomes differ by exactly that solve's
    attempts."""
    system, row = sf301
    calls = SolverCalls("clarabel")
    found = _descend(system, row, STEPS["improvement below tol"](system, row, calls), calls)
    given, solved = SolverCalls("clarabel"), SolverCalls("clarabel")
    gains, history, message = polish(system, found.gains, found.lmi, given, "clarabel", K_MAX)
    gains_again, history_again, message_again = polish(system, found.gains, None, solved, "clarabel", K_MAX)
    assert len(history) > 1  # the polish moved: its steps read the start's P and multipliers
    assert all(np.array_equal(a, b) for a, b in zip(gains, gains_again, strict=True))
    assert history == history_again and message == message_again
    first = len(found.lmi.attempts)
    assert first >= 1 and len(solved.outcomes) == len(given.outcomes) + first
    assert [o.status for o in solved.outcomes[first:]] == [o.status for o in given.outcomes]


class _InProcess:
    """:class:`~ftc_verify.analysis.solvers.ForkedCall` run here, when its result is asked for."""

    def __init__(self, fn: Any, what: str) -> None:
        self.fn = fn

    def result(self) -> Any:
        return self.fn()

    def cancel(self) -> None:
        pass


def test_best_polishes_every_descent_from_its_result(sf301: Any, monkeypatch: pytest.MonkeyPatch) -> None:
    """The ``best`` route (its forked calls run in this process, so every call is seen):
    each polish gets the result of the descent before it, the very object, and starts
    from that descent's gains."""
    system, _ = sf301
    made: list[sf.Descent] = []
    given: list[tuple[list[Any], Any]] = []
    descend, polish_ = sf.descend, sf.polish

    def recorded_descend(*args: Any, **kwargs: Any) -> sf.Descent:
        made.append(descend(*args, **kwargs))
        return made[-1]

    def recorded_polish(system: FTCSystem, start: list[Any], start_lmi: Any, *args: Any) -> Any:
        given.append((start, start_lmi))
        return polish_(system, start, start_lmi, *args)

    monkeypatch.setattr(sf, "ForkedCall", _InProcess)
    monkeypatch.setattr(sf, "descend", recorded_descend)
    monkeypatch.setattr(sf, "polish", recorded_polish)
    rows = sf._best(system, None, K_MAX, "clarabel", SolverCalls("clarabel"), 10, 1e-3)[4]
    assert len(made) == len([r for r in rows if r["name"].startswith("descent from")]) >= 1
    polished = [d for d in made if d.history]
    assert len(given) == len(polished) == len([r for r in rows if r["name"].startswith("polish after descent")])
    for found, (start, start_lmi) in zip(polished, given, strict=True):
        assert start_lmi is found.lmi and start is found.gains
