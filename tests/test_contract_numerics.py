"""Numerical defects of the exit-code audit, each reproduced first (issue: never a false
"pass", never a false "not certified").

* a badly scaled but plainly stable loop must be certified (balancing before the LMIs),
  within 1e-4 of SLICOT's ab13dd;
* our L-infinity norm agrees with SLICOT's to 1e-8 and stays finite near the axis;
* SDPA's native ``exit(0)`` must not end the process (it runs in a child);
* a huge gain bound behaves as no bound.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from ftc_verify.analysis import analyze, hinf_gamma, mes_lmi, state_feedback_loop
from ftc_verify.analysis.closedloop import ClosedLoop
from ftc_verify.analysis.crossval import cross_validate, linf_norm
from ftc_verify.analysis.lmi import check_certificate
from ftc_verify.analysis.solvers import _installed, solve
from ftc_verify.model import FTCSystem
from ftc_verify.model.files import load_system
from ftc_verify.synthesis import synthesize

control = pytest.importorskip("control")
pytest.importorskip("slycot")

A0 = np.array([[-0.82, 5.0, 0.0], [0.0, -1.5, 8.0], [0.0, 0.0, -2.2]])
B0 = np.array([[0.0], [0.0], [1.0]])
C0 = np.array([[1.0, 0.0, 0.0]])


def scaled_loop(scales: list[float]) -> tuple[ClosedLoop, float]:
    """Two identical modes of the Hurwitz loop (poles -0.82, -1.5, -2.2) in states scaled
    by ``scales``, and its H-infinity norm by SLICOT's ab13dd."""
    T, Ti = np.diag(scales), np.diag(1.0 / np.asarray(scales))
    A, B, C = T @ A0 @ Ti, T @ B0, C0 @ Ti
    ref = float(control.linfnorm(control.ss(A, B, C, 0), tol=1e-12)[0])
    system = FTCSystem.from_arrays(
        name="scaled", modes=[dict(A=A, B=np.zeros((3, 1)), C=C, D=B)] * 2, alpha=[[-1.0, 1.0], [1.0, -1.0]],
        beta_min=[[0.0, 1.0], [1.0, 0.0]], beta_max=[[0.0, 2.0], [2.0, 0.0]])
    return state_feedback_loop(system, [np.zeros((1, 3))] * 2), ref


@pytest.mark.parametrize("scales", [[1.0, 3e2, 1e-2], [1.0, 1e3, 1e-3], [1e-4, 1.0, 1e4], [1e3, 1e-3, 1.0]])
def test_badly_scaled_stable_loop_is_certified(scales: list[float]) -> None:
    loop, ref = scaled_loop(scales)
    res = hinf_gamma(loop, robust=False)
    assert res.certified, res.message
    # first ladder rung 1e-4 relative (or 1e-5), plus the solver's error on the minimum
    assert ref <= res.gamma <= ref * (1 + 1e-4 + 1e-7)
    assert mes_lmi(loop).certified
    # solved in conditioned coordinates (powers of two first), certified in the original ones
    assert res.similarity is not None and res.similarity.steps[0] == "power-of-two diagonal balancing"
    assert check_certificate(loop.nominal(), "theorem-3.2", res.P_conditioned, None, res.gamma ** 2,
                             similarity=res.similarity).ok
    assert not check_certificate(loop.nominal(), "theorem-3.2", res.P_conditioned, None, (0.99 * ref) ** 2,
                                 similarity=res.similarity).ok


def test_stable_but_uncertified_is_not_called_unstable() -> None:
    """The analysis report separates "stable by the exact test" from a certificate."""
    loop, _ = scaled_loop([1.0, 1e3, 1e-3])
    rep = analyze(loop, cross_validation=False)
    assert rep.mss.stable and rep.certified_stable


def test_linf_norm_matches_slicot() -> None:
    rng = np.random.default_rng(11)
    for _ in range(60):
        n = int(rng.integers(1, 7))
        A = rng.normal(size=(n, n))
        A -= (np.max(np.linalg.eigvals(A).real) + rng.uniform(0.01, 2.0)) * np.eye(n)
        B, C = rng.normal(size=(n, int(rng.integers(1, 3)))), rng.normal(size=(int(rng.integers(1, 3)), n))
        ref = float(control.linfnorm(control.ss(A, B, C, 0), tol=1e-12)[0])
        assert linf_norm(A, B, C) == pytest.approx(ref, rel=1e-8)
    loop, ref = scaled_loop([1.0, 3e2, 1e-2])
    assert linf_norm(loop.A[0], loop.Bw[0], loop.Cz[0]) == pytest.approx(ref, rel=1e-8)


def test_pole_near_the_axis_is_finite_and_cross_checked() -> None:
    A = np.array([[-1e-10, 1.0], [-1.0, -1e-10]])
    value = linf_norm(A, np.eye(2), np.eye(2))
    assert math.isfinite(value) and value > 1e9
    system = FTCSystem.from_arrays(name="axis", modes=[dict(A=A, B=np.zeros((2, 1)), C=np.eye(2), D=np.eye(2))] * 2,
                                   alpha=[[-1.0, 1.0], [1.0, -1.0]], beta_min=[[0.0, 1.0], [1.0, 0.0]],
                                   beta_max=[[0.0, 1.0], [1.0, 0.0]])
    checks = cross_validate(state_feedback_loop(system, [np.zeros((1, 2))] * 2))
    assert len(checks) == 4 and all(math.isfinite(c.linf_norm) for c in checks)


@pytest.mark.skipif("sdpa" not in _installed(), reason="sdpa-python not installed")
def test_sdpa_exit_does_not_end_the_process() -> None:
    """Entries of 1e200 made SDPA's C++ code call exit(0) (the audit's silent pass). The
    model loader now refuses them, so the loop is built directly; the solve must come back
    as an error that names SDPA, and this test process must still be alive to assert it."""
    import cvxpy as cp

    A = np.array([[1e200, 0.0], [0.0, -1.0]])
    P = cp.Variable((2, 2), symmetric=True)
    g = cp.Variable(nonneg=True)
    M = cp.bmat([[A.T @ P + P @ A, P @ np.ones((2, 1))], [np.ones((1, 2)) @ P, -g * np.eye(1)]])
    problem = cp.Problem(cp.Minimize(g), [0.5 * (M + M.T) << 0, P >> 0])
    out = solve(problem, "sdpa")
    assert out.solver == "sdpa" and out.status in ("error", "infeasible", "infeasible_inaccurate")
    if out.status == "error":
        assert "sdpa" in out.message


def test_huge_gain_bound_is_no_bound() -> None:
    system = load_system(__import__("pathlib").Path(__file__).resolve().parents[1] / "examples" / "paper.toml")
    free = synthesize(system, method="common", solver="clarabel")
    huge = synthesize(system, method="common", k_max=1e300, solver="clarabel")
    assert free.certified and huge.certified
    assert huge.gamma_certified == pytest.approx(free.gamma_certified, rel=0.2)
