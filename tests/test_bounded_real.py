"""The Riccati certificate route of Theorem 3.2 (ftc_verify.analysis.bounded_real) against the SDP route."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings

from ftc_verify.analysis import bounded_real, lmi_analysis
from ftc_verify.analysis.bounded_real import RateEnvelope, coupled_lyapunov
from ftc_verify.analysis.lmi_analysis import hinf_gamma
from ftc_verify.analysis.moments.stability import lyapunov_stack_solution
from ftc_verify.testing import stable_loops
from ftc_verify.testing.illconditioned import identical_mode_loop


def _stable_stack(rng: np.random.Generator, n: int, S: int) -> tuple[list[np.ndarray], np.ndarray]:
    A = [rng.standard_normal((n, n)) / np.sqrt(n) - 2.0 * np.eye(n) for _ in range(S)]
    Q = rng.uniform(0.2, 1.0, (S, S))
    np.fill_diagonal(Q, 0.0)
    np.fill_diagonal(Q, -Q.sum(axis=1))
    return A, Q


def test_gmres_coupled_lyapunov_matches_the_dense_solve(monkeypatch: pytest.MonkeyPatch) -> None:
    rng = np.random.default_rng(37)
    A, Q = _stable_stack(rng, 7, 4)
    R = [np.eye(7) + 0.1 * (lambda X: X @ X.T)(rng.standard_normal((7, 7))) for _ in range(4)]
    dense = lyapunov_stack_solution([a.T for a in A], Q.T, R)
    monkeypatch.setattr(bounded_real, "DENSE_ROWS", 0)
    iterative = coupled_lyapunov(A, Q, R)
    assert dense is not None and iterative is not None
    for s in range(4):
        residual = A[s].T @ iterative[s] + iterative[s] @ A[s] + sum(Q[s, t] * iterative[t] for t in range(4)) + R[s]
        assert np.abs(residual).max() < 1e-9 * np.abs(R[s]).max()
        assert np.allclose(iterative[s], dense[s], rtol=1e-8, atol=1e-10)


def test_gmres_refuses_a_not_mean_square_stable_stack(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(bounded_real, "DENSE_ROWS", 0)
    rng = np.random.default_rng(3)
    A, Q = _stable_stack(rng, 5, 2)
    A = [a + 5.0 * np.eye(5) for a in A]  # every mode unstable: no positive solution
    P = coupled_lyapunov(A, Q, [np.eye(5)] * 2)
    assert P is None or min(float(np.linalg.eigvalsh(p)[0]) for p in P) < 0


def test_envelope_covers_every_vertex_of_the_paper_box(paper_loop) -> None:
    """Every vertex's generator row is the pinned row plus a combination of the half
    ranges that the correction dominates (the inequality the candidate relies on)."""
    chain = paper_loop.chain
    box = RateEnvelope.of(chain)
    rng = np.random.default_rng(5)
    P = [(lambda X: X @ X.T)(rng.standard_normal((paper_loop.n, paper_loop.n))) for _ in range(chain.n_states)]
    E = box.correction(P)
    for vertex in chain.vertices():
        Qv = chain.generator(vertex)
        for s in range(chain.n_states):
            diff = sum(((Qv[s, t] - box.Q[s, t]) * (P[t] - P[s]) for t in range(chain.n_states) if t != s),
                       np.zeros_like(P[s]))
            assert float(np.linalg.eigvalsh(E[s] - diff)[0]) > -1e-9 * max(1.0, float(np.abs(E[s]).max()))


@settings(max_examples=6, deadline=None)
@given(stable_loops(n=3, m=2, margin=0.1))
def test_riccati_route_against_the_sdp_route(drawn) -> None:
    """Random loops: a Riccati certificate is a proved one (its gamma not below the
    SDP's certified minimum up to the SDP's own margin), and ``auto`` is always
    certified when the SDP is."""
    loop = drawn.loop.nominal()
    sdp = hinf_gamma(loop, robust=False, route="sdp")
    riccati = hinf_gamma(loop, robust=False, route="riccati")
    if riccati.certified:
        assert riccati.certificate is not None and riccati.certificate.ok and riccati.solver == "riccati"
        if sdp.certified:
            assert riccati.gamma >= sdp.gamma * (1 - 1e-3)
    if sdp.certified:
        assert hinf_gamma(loop, robust=False, route="auto").certified


@pytest.mark.parametrize("seed", [11, 12])
def test_riccati_route_on_ill_conditioned_loops_against_slicot(seed: int) -> None:
    """Identical modes in units of condition 1e6 and a non-orthogonal transform of
    condition 1e4: the certified gamma is the SLICOT norm within 1e-3, never below."""
    peer = identical_mode_loop(seed, 4, norm=30.0, diagonal_condition=1e6, transform_condition=1e4)
    reference = peer.reference_norm()
    result = hinf_gamma(peer.loop, robust=False, route="riccati")
    assert result.certified, result.message
    assert reference * (1 - 1e-9) <= result.gamma <= reference * (1 + 1e-3)


@pytest.mark.parametrize("scale", [1e-6, 1e-3, 1e3, 1e6])
def test_riccati_route_on_rescaled_loops(paper_loop, scale: float) -> None:
    """The output scaled by 1e-6..1e6: the certified gamma scales with it (within the
    route's 2e-3 relative slack) and stays proved."""
    base = hinf_gamma(paper_loop, robust=False, route="riccati")
    scaled = dataclasses.replace(paper_loop, Cz=tuple(scale * c for c in paper_loop.Cz), source=None)
    result = hinf_gamma(scaled, robust=False, route="riccati")
    assert base.certified and result.certified, result.message
    assert abs(result.gamma / (scale * base.gamma) - 1.0) < 2e-3


def test_failed_candidate_falls_back_to_the_sdp(paper_loop, monkeypatch: pytest.MonkeyPatch) -> None:
    """A candidate below the float level with a negative margin (ladder step -1e-3:
    the Riccati equations hold with ``+1e-3 |C|^2 I`` on the right, so no block is
    negative definite): the proof rejects it, ``route="riccati"`` says so, ``auto``
    (forced to try it first) certifies by the SDP and reports the rejected candidate.
    (With a margin of 1e-15 the candidate still passes: the proof is exact.)"""
    monkeypatch.setattr(bounded_real, "CANDIDATE_LADDER", (-1e-3,))
    alone = hinf_gamma(paper_loop, robust=False, route="riccati")
    assert not alone.certified and "no candidate passed" in alone.message
    monkeypatch.setattr(lmi_analysis, "RICCATI_FIRST_SIZE", 0)
    monkeypatch.setattr(lmi_analysis, "RICCATI_FIRST_STATES", 0)
    auto = hinf_gamma(paper_loop, robust=False, route="auto")
    assert auto.certified and auto.solver != "riccati"
    assert "Riccati candidate was not used" in auto.message


def test_unknown_route_is_refused(paper_loop) -> None:
    with pytest.raises(ValueError, match="route"):
        hinf_gamma(paper_loop, robust=False, route="fast")


def test_large_stacks_of_the_verdicts_go_through_gmres(monkeypatch: pytest.MonkeyPatch) -> None:
    """verdict.float_stack_solution above the dense limit (forced to 0 here): the same
    stack as the direct solve of stability.lyapunov_stack_solution."""
    from ftc_verify.analysis.moments import stability
    from ftc_verify.analysis.verdict import float_stack_solution

    rng = np.random.default_rng(8)
    A, Q = _stable_stack(rng, 6, 4)
    direct = lyapunov_stack_solution(A, Q)
    monkeypatch.setattr(stability, "DENSE_LIMIT", 0)
    monkeypatch.setattr(bounded_real, "DENSE_ROWS", 0)
    iterative = float_stack_solution(A, Q)
    assert direct is not None and iterative is not None
    assert np.allclose(iterative, direct, rtol=1e-8, atol=1e-11)


def test_shifted_stack_solution_solves_the_shifted_equation(monkeypatch: pytest.MonkeyPatch) -> None:
    from ftc_verify.analysis.moments import stability
    from ftc_verify.analysis.verdict import float_stack_solution

    rng = np.random.default_rng(9)
    A, Q = _stable_stack(rng, 5, 3)
    monkeypatch.setattr(stability, "DENSE_LIMIT", 0)
    monkeypatch.setattr(bounded_real, "DENSE_ROWS", 0)
    X = float_stack_solution(A, Q, shift=-0.7)
    assert X is not None
    for s in range(3):
        residual = A[s] @ X[s] + X[s] @ A[s].T + sum(Q[t, s] * X[t] for t in range(3)) + 0.7 * X[s] + np.eye(5)
        assert np.abs(residual).max() < 1e-9


@pytest.mark.slow(25)  # seconds on 2 busy cores (--durations at load 9, / 4): scheduled first
@settings(max_examples=4, deadline=None)
@given(stable_loops(n=2, m=2, margin=0.1, chains={"false_alarms": True, "delay_phases": 2, "missed_detection": True}))
def test_riccati_route_with_the_fdi_models(drawn) -> None:
    """False alarms, Erlang delays and missed detections (rows with several rates, rates
    of 0): whatever the candidate gives is a proved certificate, never below the SDP's
    certified level (up to the SDP's margin)."""
    loop = drawn.loop.nominal()
    riccati = hinf_gamma(loop, robust=False, route="riccati")
    if riccati.certified:
        sdp = hinf_gamma(loop, robust=False, route="sdp")
        assert riccati.certificate is not None and riccati.certificate.ok
        if sdp.certified:
            assert riccati.gamma >= sdp.gamma * (1 - 1e-3)


def test_one_policy_iteration_serves_the_lower_bounds(paper_loop) -> None:
    """lower_bound.worst_case_feedback is bounded_real_solution at one rate vector (no
    envelope correction) with a dense solver: the same feedback as the default GMRES/dense
    route, a solution of the coupled Riccati equations, and no solution below the gain."""
    from ftc_verify.analysis.lower_bound import float_gain, worst_case_feedback

    loop = paper_loop.nominal()
    Q = loop.chain.generator(loop.chain.midpoint())
    point = RateEnvelope.at(Q)
    assert np.array_equal(point.Q, Q)
    assert all(not np.any(e) for e in point.correction([np.eye(loop.n)] * len(loop.A)))
    found = float_gain(loop.A, loop.Bw, loop.Cz, Q)
    assert found is not None
    gain = found[0]
    gamma = 1.2 * gain
    F = worst_case_feedback(loop.A, loop.Bw, loop.Cz, Q, gamma)
    solved = bounded_real.bounded_real_solution(loop.A, loop.Bw, loop.Cz, point, gamma)
    assert F is not None and solved is not None
    P, F_default = solved
    for s in range(len(loop.A)):
        assert np.allclose(F[s], F_default[s], rtol=1e-7, atol=1e-9)
        residual = (loop.A[s].T @ P[s] + P[s] @ loop.A[s] + sum(Q[s, t] * P[t] for t in range(len(P)))
                    + loop.Cz[s].T @ loop.Cz[s] + P[s] @ loop.Bw[s] @ loop.Bw[s].T @ P[s] / gamma**2)
        assert np.abs(residual).max() < 1e-7 * max(1.0, np.abs(P[s]).max())
    assert worst_case_feedback(loop.A, loop.Bw, loop.Cz, Q, 0.99 * gain) is None


def test_memory_check_estimates_the_route_that_runs(paper_loop, monkeypatch: pytest.MonkeyPatch) -> None:
    """A limit between the Riccati route's estimate and the SDP's: refused while the SDP
    would run, accepted when the Riccati candidate comes first (no uncertainty channels)."""
    from ftc_verify.analysis import lmi_size
    from ftc_verify.errors import MemoryLimitError

    loop = paper_loop.nominal()
    riccati, sdp = lmi_size.riccati_memory_estimate(loop), lmi_size.lmi_memory_estimate(loop, robust=False)
    assert riccati < sdp
    monkeypatch.setenv("FTC_VERIFY_MEMORY_LIMIT", str(int(0.5 * (riccati + sdp))))
    with pytest.raises(MemoryLimitError):
        lmi_size.check_lmi_memory(loop)
    monkeypatch.setattr(lmi_size, "RICCATI_FIRST_SIZE", 0)
    monkeypatch.setattr(lmi_size, "RICCATI_FIRST_STATES", 0)
    lmi_size.check_lmi_memory(loop)
    monkeypatch.setenv("FTC_VERIFY_MEMORY_LIMIT", str(int(0.5 * riccati)))
    with pytest.raises(MemoryLimitError):
        lmi_size.check_lmi_memory(loop)
