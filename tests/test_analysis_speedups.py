"""The one-solve path of ``hinf_gamma`` (issue 24): one Clarabel solve per certified gamma,
with the margin built in, the dual bound, the gamma hint, and the fall-back to the
two-step ladder. Every accepted answer is still a proved certificate."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ftc_verify.analysis import lmi_analysis as la
from ftc_verify.analysis import solvers
from ftc_verify.analysis.analyze import analyze
from ftc_verify.analysis.closedloop import state_feedback_loop
from ftc_verify.analysis.lmi import check_certificate
from ftc_verify.analysis.solvers import SolveOutcome
from ftc_verify.model.system import FTCSystem
from ftc_verify.testing.strategies import lqr_gains


def random_loop(n: int, m: int, seed: int):
    """A random loop as benchmarks/analysis.py's ``make_case`` (LQR gains, uncertainty)."""
    rng = np.random.default_rng(seed)
    nu = max(1, n // 2)
    while True:
        A0, B0 = rng.normal(size=(n, n)) / math.sqrt(n), rng.normal(size=(n, nu))
        C, D = rng.normal(size=(1, n)), rng.normal(size=(n, 1))
        eff = np.concatenate([[1.0], rng.uniform(0.6, 0.9, m - 1)])
        modes = [{"A": A0 if i == 0 else A0 + 0.1 * rng.normal(size=(n, n)) / math.sqrt(n), "B": eff[i] * B0,
                  "C": C, "D": D, "A1": 0.05 * np.eye(n), "A2": 0.05 * np.eye(n), "B1": 0.05 * np.eye(n),
                  "B2": 0.05 * np.eye(n, nu)} for i in range(m)]
        alpha = rng.uniform(0.2, 1.0, (m, m))
        np.fill_diagonal(alpha, 0.0)
        np.fill_diagonal(alpha, -alpha.sum(axis=1))
        bmin = rng.uniform(1.5, 2.5, (m, m))
        np.fill_diagonal(bmin, 0.0)
        bmax = bmin + 1.0
        np.fill_diagonal(bmax, 0.0)
        system = FTCSystem.from_arrays(name=f"speed-{seed}", modes=modes, alpha=alpha, beta_min=bmin, beta_max=bmax)
        gains = lqr_gains(system)
        if gains is not None:
            return state_feedback_loop(system, gains)


@pytest.fixture(scope="module")
def loop():
    return random_loop(4, 2, 11)


def ladder_only(loop, robust: bool, monkeypatch: pytest.MonkeyPatch):
    """``hinf_gamma`` with the one-solve path switched off (the code before issue 24)."""
    with monkeypatch.context() as mp:
        mp.setattr(la, "_margin_gamma", lambda *args, **kw: None)
        return la.hinf_gamma(loop, robust=robust, solver="clarabel")


@pytest.mark.parametrize("robust", [False, True])
def test_one_solve_gives_the_ladder_gamma(loop, robust: bool, monkeypatch: pytest.MonkeyPatch) -> None:
    fast = la.hinf_gamma(loop, robust=robust, solver="clarabel")
    slow = ladder_only(loop, robust, monkeypatch)
    assert fast.certified and slow.certified
    assert "one-solve path" in fast.message and len(fast.attempts) == 1
    assert len(slow.attempts) >= 2
    assert abs(fast.gamma - slow.gamma) <= 1e-4 * slow.gamma, (fast.message, slow.message)
    # the certificate is re-provable from what the result carries
    cert = check_certificate(loop if robust else loop.nominal(), fast.condition, fast.P_conditioned,
                             fast.multipliers, fast.gamma ** 2, similarity=fast.similarity)
    assert cert.ok


@pytest.mark.parametrize("factor", [1e-3, 0.5, 1.0, 30.0])
def test_gamma_hint_changes_speed_not_the_answer(loop, factor: float) -> None:
    """The hint (e.g. the nominal gamma passed to Lemma 4.1: a warm start of the scaling)
    only scales the program; a bad hint costs at most MARGIN_SOLVES solves."""
    ref = la.hinf_gamma(loop, robust=True, solver="clarabel")
    hinted = la.hinf_gamma(loop, robust=True, solver="clarabel", gamma_hint=factor * ref.gamma)
    assert hinted.certified and len(hinted.attempts) <= la.MARGIN_SOLVES
    assert abs(hinted.gamma - ref.gamma) <= 1e-4 * ref.gamma, hinted.message


def test_dual_bound_is_below_the_certified_gamma(loop) -> None:
    res = la.hinf_gamma(loop, robust=False, solver="clarabel")
    bound = float(res.message.split("minimum ")[1].split(" ")[0])
    assert bound <= res.gamma * (1 + 1e-9) and res.gamma <= bound * (1 + la.MARGIN_GAP)


def test_analyze_passes_the_nominal_gamma_as_hint(loop, monkeypatch: pytest.MonkeyPatch) -> None:
    seen = []
    original = la.hinf_gamma

    def spy(*args, **kw):
        seen.append(kw.get("gamma_hint"))
        return original(*args, **kw)

    import importlib

    import os

    monkeypatch.setattr(importlib.import_module("ftc_verify.analysis.analyze"), "hinf_gamma", spy)
    monkeypatch.delattr(os, "fork")  # one program after the other (where the two cannot run at once)
    report = analyze(loop, cross_validation=False)
    assert report.certificate_ok
    assert seen == [None, report.nominal.gamma]
    assert report.robust.gamma >= report.nominal.gamma * (1 - 1e-6)
    assert report.mes_lmi.attempts == ()  # Theorem 3.1 from the certified P, no solve


def test_a_failing_margin_certificate_falls_back_to_the_ladder(loop, monkeypatch: pytest.MonkeyPatch) -> None:
    """A margin too small to prove anything: never accepted, the ladder certifies."""
    monkeypatch.setattr(la, "MARGIN_TAU", 1e-16)
    monkeypatch.setattr(la, "MARGIN_SOLVES", 1)
    res = la.hinf_gamma(loop, robust=False, solver="clarabel")
    assert res.certified and "from step 1" in res.message
    assert len(res.attempts) >= 3  # the failed margin solve, step 1, a step 2


def test_margin_solver_failure_falls_back(loop, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(la, "solve_conic_dual", lambda problem, settings=None: (SolveOutcome("clarabel", "error", 0.0, "boom"), None, None))
    res = la.hinf_gamma(loop, robust=True, solver="clarabel")
    assert res.certified and res.attempts[0].status == "error" and "from step 1" in res.message


def test_inaccurate_status_is_reported_not_hidden(loop, monkeypatch: pytest.MonkeyPatch) -> None:
    real = solvers.solve_conic_dual

    def inaccurate(problem, settings=None):
        out, x, z = real(problem, settings)
        return SolveOutcome("clarabel", "optimal_inaccurate", out.seconds), x, z

    monkeypatch.setattr(la, "solve_conic_dual", inaccurate)
    res = la.hinf_gamma(loop, robust=False, solver="clarabel")
    assert res.certified and res.solver_status == "optimal_inaccurate"
    assert "accepted only because the certificate passed" in res.message


def test_infeasible_needs_two_different_solvers() -> None:
    same = [SolveOutcome("clarabel", "infeasible", 0.1), SolveOutcome("clarabel", "infeasible", 0.1)]
    assert la._conclude("theorem-3.2", same, None, 0.0).outcome == "error"
    two = same + [SolveOutcome("sdpa", "infeasible", 0.1)]
    assert la._conclude("theorem-3.2", two, None, 0.0).outcome == "infeasible"


def test_solve_conic_dual_matches_solve_conic(loop) -> None:
    target, _ = la._conditioned(loop.nominal())
    lay = la._layout(target, robust=False)
    problem = la._margin_problem(target, lay, False, 1.0).fix(lay.t, la.MARGIN_TAU)
    out, x = solvers.solve_conic(problem, "clarabel")
    out2, x2, z = solvers.solve_conic_dual(problem)
    assert out.status == out2.status == "optimal"
    assert np.allclose(x, x2) and z is not None
    assert abs(problem.c @ x2 + problem.b @ z) <= 1e-6 * max(1.0, abs(problem.c @ x2))  # strong duality


# ------------------------------------------------------------------------------------------ two programs at once


def test_forked_call_returns_raises_and_cancels() -> None:
    import os
    import time

    from ftc_verify.analysis.solvers import ForkedCall
    from ftc_verify.errors import SolverError

    assert ForkedCall(lambda: {"gamma": 0.5, "pid": os.getpid()}, "test").result()["gamma"] == 0.5
    with pytest.raises(ValueError, match="from the child"):
        ForkedCall(lambda: (_ for _ in ()).throw(ValueError("from the child")), "test").result()
    with pytest.raises(SolverError, match="test: the forked solve process killed by signal 9"):
        ForkedCall(lambda: os.kill(os.getpid(), 9), "test").result()
    slow = ForkedCall(lambda: time.sleep(60), "test")
    pid = slow.pid
    slow.cancel()
    with pytest.raises(ChildProcessError):
        os.waitpid(pid, os.WNOHANG)  # killed and reaped


def test_the_forked_nominal_program_gives_the_sequential_answer(paper_loop) -> None:
    from ftc_verify.analysis.analyze import analyze
    from ftc_verify.analysis.lmi_analysis import hinf_gamma

    rep = analyze(paper_loop, cross_validation=False)
    assert "gammas_wall" in rep.seconds  # the paper's loop is uncertain: the two ran at once
    alone = hinf_gamma(paper_loop, robust=False)
    assert rep.nominal.certified and rep.nominal.gamma == pytest.approx(alone.gamma, rel=1e-12)
    robust = hinf_gamma(paper_loop, robust=True, gamma_hint=alone.gamma)
    assert rep.robust.certified and rep.robust.gamma == pytest.approx(robust.gamma, rel=1e-5)
