"""Synthesis: null-space bases, the projection of Theorem 4.1, step 2 on a hand-solved case,
failures reported (not raised), and every method's gains verified by the core analysis."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from ftc_verify.analysis.closedloop import gain_loop
from ftc_verify.errors import ValidationError
from ftc_verify.analysis.lmi import block_specs, null_basis, projection, xy_block
from ftc_verify.model.system import FTCSystem
from ftc_verify.model.files import load_system
from ftc_verify.synthesis.results import SolverCalls
from ftc_verify.synthesis.state_feedback import gain_step, synthesize

ROOT = Path(__file__).resolve().parents[1]
PAPER = load_system(ROOT / "examples" / "paper.toml")


def scalar_system(a: float = 1.0, b: float = 1.0, c: float = 1.0, d: float = 1.0) -> FTCSystem:
    mode = {"A": [[a]], "B": [[b]], "C": [[c]], "D": [[d]]}
    return FTCSystem.from_arrays(name="scalar", modes=[mode, mode], alpha=[[-1.0, 1.0], [2.0, -2.0]],
                                 beta_min=[[0.0, 3.0], [4.0, 0.0]], beta_max=[[0.0, 3.0], [4.0, 0.0]])


@pytest.mark.parametrize("mode_index", [0, 1])
def test_null_basis_is_orthonormal_kernel(mode_index: int) -> None:
    md = PAPER.modes[mode_index]
    W1, W2 = null_basis(md)
    W = np.vstack([W1, W2])
    M = np.hstack([md.B.T, md.B2.T])
    assert W.shape[1] == M.shape[1] - np.linalg.matrix_rank(M)  # full kernel dimension
    assert np.allclose(M @ W, 0.0, atol=1e-12)
    assert np.allclose(W.T @ W, np.eye(W.shape[1]), atol=1e-12)


def test_projection_eliminates_the_gain() -> None:
    """N' (block with Y) N does not depend on Y: the gain terms lie in the projected-out space."""
    rng = np.random.default_rng(7)
    n, nu = 2, 2
    X = [np.eye(n) * (1 + s) + 0.1 * np.ones((n, n)) for s in range(4)]
    probe = gain_loop(PAPER, [np.zeros((nu, n))] * 2, "probe")
    for spec in block_specs(probe):
        md = PAPER.modes[spec.true]
        coupled = sum(1 for k, q in enumerate(spec.q_row) if k != spec.s and q > 0)
        N = projection(md, coupled)
        base = xy_block(md, X, spec.s, None, 0.3, 0.7, 0.64, spec.q_row, np.block)
        with_y = xy_block(md, X, spec.s, rng.normal(size=(nu, n)), 0.3, 0.7, 0.64, spec.q_row, np.block)
        assert base.shape == with_y.shape == (N.shape[0], N.shape[0])
        assert not np.allclose(base, with_y)  # Y does enter the unprojected block
        assert np.allclose(N.T @ base @ N, N.T @ with_y @ N, atol=1e-12)


def test_gain_step_matches_hand_solution() -> None:
    """Scalar plant, equal P in every joint mode (coupling cancels), |K| <= 3:
    2p(a + bK) + c^2 + p^2 d^2 / g <= 0 is best at K = -3, g = p^2 d^2 / (-2p(a - 3) - c^2) = 1/3."""
    system = scalar_system()
    P = [np.array([[1.0]])] * 4
    lam: list[list[float]] = [[] for _ in range(4)]
    for j in (0, 1):
        K, gamma, status = gain_step(system, P, lam, j, SolverCalls("clarabel"), 3.0)
        assert status == "optimal"
        assert K is not None and gamma is not None
        assert K[0, 0] == pytest.approx(-3.0, abs=1e-5)
        assert gamma == pytest.approx(math.sqrt(1.0 / 3.0), rel=1e-5)


def test_gain_step_with_gamma_returns_smallest_gain() -> None:
    """Same case at gamma^2 = 1/2: need -2(1 + K) - 1 >= 2, i.e. K <= -2.5; smallest |K| is 2.5."""
    system = scalar_system()
    P = [np.array([[1.0]])] * 4
    K, gamma, _ = gain_step(system, P, [[] for _ in range(4)], 0, SolverCalls("clarabel"), None, math.sqrt(0.5))
    assert K is not None and gamma is not None
    assert K[0, 0] == pytest.approx(-2.5, abs=1e-5)
    assert gamma <= math.sqrt(0.5) * (1 + 1e-6)


def test_infeasible_two_step_is_reported_not_raised() -> None:
    res = synthesize(PAPER, method="two-step", gamma=0.8, k_max=30.0, solver="clarabel")
    assert res.feasible is False and res.certified is False
    assert res.gains == () and res.gamma_certified is None
    assert "FDI mode" in res.message and "step 2" in res.message


def test_two_step_at_paper_gamma_certified_by_core() -> None:
    res = synthesize(PAPER, method="two-step", gamma=0.8, solver="clarabel")
    assert res.certified and res.report is not None
    assert res.report.certified_stable and res.report.robust.certificate is not None and res.report.robust.certificate.ok
    assert res.gamma_certified is not None and res.gamma_certified <= 0.8
    assert res.synthesis_gamma is not None and res.synthesis_gamma <= 0.8 * (1 + 1e-6)


@pytest.mark.parametrize("method", ["full-info", "common"])
def test_baselines_respect_gain_bound_and_are_certified(method: str) -> None:
    res = synthesize(PAPER, method=method, k_max=30.0, solver="clarabel")
    assert res.certified
    assert len(res.gains) == (4 if method == "full-info" else 2)
    assert max(np.linalg.norm(K, 2) for K in res.gains) <= 30.0 * (1 + 1e-6)
    if method == "common":
        assert np.array_equal(res.gains[0], res.gains[1])


def test_iterative_never_ends_above_its_start() -> None:
    start = synthesize(PAPER, method="common", k_max=30.0, solver="clarabel")
    assert start.certified and start.gamma_certified is not None
    res = synthesize(PAPER, method="iterative", k_max=30.0, solver="clarabel", start=list(start.gains))
    assert res.certified and res.gamma_certified is not None
    assert res.history and all(b <= a for a, b in zip(res.history, res.history[1:]))
    assert res.gamma_certified <= start.gamma_certified * (1 + 1e-3)  # ladder slack of the re-certification


def test_bad_options_raise_validation_error() -> None:
    with pytest.raises(ValidationError, match="magic"):
        synthesize(PAPER, method="magic")
    with pytest.raises(ValidationError, match="gamma"):
        synthesize(PAPER, method="two-step", gamma=-1.0)
    with pytest.raises(ValidationError, match="k_max"):
        synthesize(PAPER, method="two-step", k_max=float("nan"))
