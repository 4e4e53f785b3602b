"""Clarabel's native path without iterative refinement (issue 37, item 3): the same optimum,
and a solve that does not end ``Solved`` is run again with refinement."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from ftc_verify.analysis.conic import Rows, scalar_variable, solve_clarabel_dual
from ftc_verify.analysis.solvers import CLARABEL_NATIVE, SETTINGS, solve_conic_dual


def _problem() -> Any:
    """min t subject to [[t, 1], [1, t]] >= 0: optimum t = 1."""
    rows = Rows(1)
    t = scalar_variable(0, 1)
    rows.lmi(-(t * np.eye(2) + np.array([[0.0, 1.0], [1.0, 0.0]])), np.array([0]))
    return rows.problem(np.array([1.0]))


def test_the_native_path_runs_without_refinement_and_finds_the_optimum(monkeypatch: pytest.MonkeyPatch) -> None:
    import clarabel

    seen: list[bool] = []
    real = clarabel.DefaultSolver

    def spy(P: Any, q: Any, A: Any, b: Any, cones: Any, opts: Any) -> Any:
        seen.append(bool(opts.iterative_refinement_enable))
        return real(P, q, A, b, cones, opts)

    monkeypatch.setattr(clarabel, "DefaultSolver", spy)
    outcome, x, z = solve_conic_dual(_problem())
    assert outcome.status == "optimal" and x is not None and z is not None
    assert x[0] == pytest.approx(1.0, abs=1e-7) and seen == [False]
    assert CLARABEL_NATIVE == {"iterative_refinement_enable": False}
    assert "iterative_refinement_enable" not in SETTINGS["clarabel"]  # the cvxpy path (synthesis) keeps Clarabel's


def test_a_solve_that_does_not_end_solved_is_run_again_with_refinement(monkeypatch: pytest.MonkeyPatch) -> None:
    import clarabel

    seen: list[bool] = []
    real = clarabel.DefaultSolver

    def spy(P: Any, q: Any, A: Any, b: Any, cones: Any, opts: Any) -> Any:
        seen.append(bool(opts.iterative_refinement_enable))
        return real(P, q, A, b, cones, opts)

    monkeypatch.setattr(clarabel, "DefaultSolver", spy)
    status, _, x, _ = solve_clarabel_dual(_problem(), SETTINGS["clarabel"] | CLARABEL_NATIVE | {"max_iter": 1})
    assert seen == [False, True] and status == "user_limit" and x is None
    seen.clear()
    solve_clarabel_dual(_problem(), SETTINGS["clarabel"] | {"max_iter": 1})  # refinement on from the start: once
    assert seen == [True]
