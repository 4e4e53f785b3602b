"""Bounded work on large loops (issue 37, item 6): the candidate margin of the Riccati
route, the SDP fallback refused above ``SDP_FALLBACK_LIMIT`` (an answer, never a hang),
and Theorem 3.1 from the coupled Lyapunov equations over the box without an SDP."""

from __future__ import annotations

import numpy as np
import pytest

from ftc_verify.analysis import bounded_real, lmi_analysis, lmi_size
from ftc_verify.analysis.bounded_real import candidate_margin, lyapunov_candidate
from ftc_verify.analysis.lmi_analysis import _conditioned, hinf_gamma, mes_lmi
from ftc_verify.analysis.lmi_size import SDP_FALLBACK_LIMIT, decision_size, sdp_fallback_refusal


def test_candidate_margin_is_second_order_and_keeps_the_sign() -> None:
    assert candidate_margin(1e-4, 21.0) == pytest.approx(21e-8)
    assert candidate_margin(1e-2, 1.0) == pytest.approx(1e-4)
    assert candidate_margin(-1e-3, 2.0) == pytest.approx(-2e-6)


def test_refusal_only_above_the_limit(paper_loop, monkeypatch: pytest.MonkeyPatch) -> None:
    assert decision_size(paper_loop.nominal(), robust=False) <= SDP_FALLBACK_LIMIT
    assert sdp_fallback_refusal(paper_loop.nominal(), False, "Theorem 3.2") == ""
    monkeypatch.setattr(lmi_size, "SDP_FALLBACK_LIMIT", 0)
    why = sdp_fallback_refusal(paper_loop.nominal(), False, "Theorem 3.2")
    assert "not started" in why and "SDP_FALLBACK_LIMIT = 0" in why


def _no_sdp(*args: object, **kwargs: object) -> None:
    raise AssertionError("an SDP was started")


def test_failed_candidate_above_the_limit_is_reported_without_an_sdp(paper_loop, monkeypatch: pytest.MonkeyPatch) -> None:
    """The candidate forced below the float level (rung -1e-3: no candidate can pass) and
    the fallback limit at 0: ``auto`` answers "no certificate" with both reasons and
    never starts the SDP; with the limit as shipped it falls back and certifies."""
    monkeypatch.setattr(bounded_real, "CANDIDATE_LADDER", (-1e-3,))
    monkeypatch.setattr(lmi_analysis, "RICCATI_FIRST_SIZE", 0)
    monkeypatch.setattr(lmi_analysis, "RICCATI_FIRST_STATES", 0)
    monkeypatch.setattr(lmi_size, "SDP_FALLBACK_LIMIT", 0)
    real = lmi_analysis._hinf_gamma
    monkeypatch.setattr(lmi_analysis, "_hinf_gamma", _no_sdp)
    refused = hinf_gamma(paper_loop, robust=False, route="auto")
    assert not refused.certified and refused.outcome == "error" and refused.solver == "riccati"
    assert "no candidate passed" in refused.message and "SDP fallback was not started" in refused.message
    monkeypatch.setattr(lmi_size, "SDP_FALLBACK_LIMIT", SDP_FALLBACK_LIMIT)
    monkeypatch.setattr(lmi_analysis, "_hinf_gamma", real)
    assert hinf_gamma(paper_loop, robust=False, route="auto").certified


def test_lyapunov_candidate_proves_theorem_31_over_the_box(paper_loop) -> None:
    nominal = paper_loop.nominal()
    target, sim = _conditioned(nominal)
    found = lyapunov_candidate(nominal, target, sim)
    assert found.certificate is not None and found.certificate.ok and found.gamma is None
    assert found.certificate.condition == "theorem-3.1"
    assert all(block.ok for block in found.certificate.blocks)
    assert len(found.certificate.blocks) >= nominal.chain.n_states  # one block per joint state and rate vertex


def test_mes_lmi_above_the_limit_takes_the_lyapunov_route(paper_loop, monkeypatch: pytest.MonkeyPatch) -> None:
    """No certified gamma to reuse and the Theorem 3.1 SDP above the limit: certified by
    the coupled Lyapunov candidate, with no SDP started; a loop whose candidate fails
    (the modes made unstable) is reported as not certified, again without an SDP."""
    monkeypatch.setattr(lmi_analysis, "SDP_FALLBACK_LIMIT", 0)
    monkeypatch.setattr(lmi_size, "SDP_FALLBACK_LIMIT", 0)
    monkeypatch.setattr(lmi_analysis, "_mes_lmi", _no_sdp)
    result = mes_lmi(paper_loop)
    assert result.certified and result.solver == "riccati" and "no SDP" in result.message
    import dataclasses

    unstable = dataclasses.replace(paper_loop, A=tuple(a + 50.0 * np.eye(paper_loop.n) for a in paper_loop.A), source=None)
    bad = mes_lmi(unstable)
    assert not bad.certified and "SDP fallback was not started" in bad.message


@pytest.mark.parametrize("n, S", [(12, 16), (20, 3)])
def test_batched_lyapunov_matches_the_schur_gmres_with_a_true_residual(n: int, S: int) -> None:
    """The batched right-preconditioned solve against coupled_lyapunov (per-state Schur
    forms) on a random mean-square stable stack above the dense limit; its residual is
    the operator's own (not a preconditioned one), within the rtol asked; a start is used."""
    from ftc_verify.analysis.bounded_real import batched_lyapunov, coupled_lyapunov

    rng = np.random.default_rng(n * 100 + S)
    A = [rng.standard_normal((n, n)) / np.sqrt(n) - 1.5 * np.eye(n) for _ in range(S)]
    Q = rng.uniform(0.2, 1.0, (S, S))
    np.fill_diagonal(Q, 0.0)
    np.fill_diagonal(Q, -Q.sum(axis=1))
    R = [np.eye(n) + 0.1 * (lambda X: X @ X.T)(rng.standard_normal((n, n))) for _ in range(S)]
    batched, reference = batched_lyapunov(A, Q, R, rtol=1e-12), coupled_lyapunov(A, Q, R)
    assert batched is not None and reference is not None
    r_norm = np.sqrt(sum(np.sum(r * r) for r in R))
    residual = np.sqrt(sum(np.sum((A[s].T @ batched[s] + batched[s] @ A[s] + sum(Q[s, t] * batched[t] for t in range(S))
                                   + R[s]) ** 2) for s in range(S)))
    assert residual <= 1e-11 * r_norm
    assert max(float(np.abs(a - b).max()) for a, b in zip(batched, reference)) < 1e-9 * max(float(np.abs(b).max()) for b in reference)
    again = batched_lyapunov(A, Q, R, start=reference, rtol=1e-12)
    assert again is not None and max(float(np.abs(a - b).max()) for a, b in zip(again, reference)) < 1e-9 * max(
        float(np.abs(b).max()) for b in reference)


def test_batched_lyapunov_refuses_an_unstable_stack() -> None:
    """Every mode unstable (no positive solution): ``None`` after the bounded restarts, or
    a stack that is not positive semidefinite (which the policy iteration rejects)."""
    from ftc_verify.analysis.bounded_real import batched_lyapunov

    rng = np.random.default_rng(11)
    n, S = 12, 8
    A = [rng.standard_normal((n, n)) / np.sqrt(n) + 3.0 * np.eye(n) for _ in range(S)]
    Q = np.full((S, S), 0.5)
    np.fill_diagonal(Q, -0.5 * (S - 1))
    P = batched_lyapunov(A, Q, [np.eye(n)] * S, maxiter=2)
    assert P is None or min(float(np.linalg.eigvalsh(p)[0]) for p in P) < 0


def test_batched_lyapunov_with_defective_modes_is_the_schur_answer() -> None:
    """Modes with a Jordan block (eigenvectors numerically dependent, the eigen-based
    preconditioner useless): the answer is coupled_lyapunov's (Schur forms), with its
    small residual, not a stalled GMRES's None."""
    from ftc_verify.analysis.bounded_real import batched_lyapunov, coupled_lyapunov

    n, S = 12, 6
    J = -np.eye(n) + 0.5 * np.eye(n, k=1)  # one eigenvalue -1, a single Jordan block
    A = [J + 0.01 * s * np.eye(n) for s in range(S)]
    Q = np.full((S, S), 0.3)
    np.fill_diagonal(Q, -0.3 * (S - 1))
    R = [np.eye(n)] * S
    batched, reference = batched_lyapunov(A, Q, R, maxiter=40), coupled_lyapunov(A, Q, R, maxiter=40)
    assert batched is not None and reference is not None
    assert max(float(np.abs(a - b).max()) for a, b in zip(batched, reference)) <= 1e-8 * max(
        float(np.abs(b).max()) for b in reference)
