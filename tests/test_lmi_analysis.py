"""Unit tests of ftc_verify.analysis.lmi_analysis (and the certificate check of ftc_verify.analysis.lmi)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.optimize

from ftc_verify.analysis.closedloop import state_feedback_loop
from ftc_verify.errors import ValidationError
from ftc_verify.analysis.lmi import check_certificate
from ftc_verify.analysis.lmi_analysis import hinf_gamma, mes_lmi
from ftc_verify.model.system import FTCSystem
from ftc_verify.analysis.solvers import SOLVERS, choose_solver
from ftc_verify.analysis.moments.stability import mean_square_stability


# ============================================================================ paper example
@pytest.fixture(scope="module")
def paper_mes(paper_loop):
    return mes_lmi(paper_loop)


@pytest.fixture(scope="module")
def paper_nominal(paper_loop):
    return hinf_gamma(paper_loop, robust=False)


@pytest.fixture(scope="module")
def paper_robust(paper_loop):
    return hinf_gamma(paper_loop, robust=True)


def is_neg_def(M, margin=0.0):
    M = np.asarray(M, dtype=float)
    return float(np.max(np.linalg.eigvalsh(0.5 * (M + M.T)))) < -margin


def test_paper_mes_lmi_certified(paper_mes):
    r = paper_mes
    assert r.outcome == "certified" and r.certified
    assert r.certificate is not None and r.certificate.ok
    assert r.P is not None and len(r.P) == 4
    for P in r.P:
        assert P.shape == (2, 2)
        assert np.min(np.linalg.eigvalsh(0.5 * (P + P.T))) > 0


def test_paper_mes_certificate_rebuilt_by_hand(paper_mes, paper_loop, ref):
    """Theorem 3.1 at every vertex of the beta box, built here from READING-NOTES."""
    P = [0.5 * (p + p.T) for p in paper_mes.P]
    ch = paper_loop.chain
    for beta in ref.box_vertices(ch.beta_min, ch.beta_max):
        Q = ref.joint_generator(ch.alpha, beta)
        for s, A in enumerate(paper_loop.A):
            pi = A.T @ P[s] + P[s] @ A + sum(Q[s, t] * P[t] for t in range(4))
            assert is_neg_def(pi), (beta, s)


def test_paper_mes_certificate_check_passes_and_fails(paper_mes, paper_loop):
    nominal = paper_loop.nominal()
    assert check_certificate(nominal, "theorem-3.1", paper_mes.P, None, None).ok
    assert not check_certificate(nominal, "theorem-3.1", [-p for p in paper_mes.P], None, None).ok
    # P_s = 0 for one mode breaks positivity
    broken = list(paper_mes.P)
    broken[2] = np.zeros((2, 2))
    assert not check_certificate(nominal, "theorem-3.1", broken, None, None).ok


def test_paper_hinf_certified_robust_not_below_nominal(paper_nominal, paper_robust):
    assert paper_nominal.outcome == "certified" and paper_nominal.certified
    assert paper_robust.outcome == "certified" and paper_robust.certified
    assert paper_nominal.condition == "theorem-3.2" and paper_robust.condition == "lemma-4.1"
    assert 0 < paper_nominal.gamma <= paper_robust.gamma
    assert np.isfinite(paper_robust.gamma)
    # the paper designed these gains for gamma = 0.8 (robust): they must meet it
    assert paper_robust.gamma < 0.8


def test_paper_nominal_certificate_rebuilt(paper_nominal, paper_loop, ref):
    r = paper_nominal
    nominal = paper_loop.nominal()
    g = r.gamma ** 2
    assert check_certificate(nominal, "theorem-3.2", r.P, None, g).ok
    assert not check_certificate(nominal, "theorem-3.2", r.P, None, (r.gamma / 2) ** 2).ok
    assert not check_certificate(nominal, "theorem-3.2", [-p for p in r.P], None, g).ok
    # Independent rebuild of the bounded-real block of Theorem 3.2 at every vertex.
    sysm = paper_loop
    P = [0.5 * (p + p.T) for p in r.P]
    ch = sysm.chain
    for beta in ref.box_vertices(ch.beta_min, ch.beta_max):
        Q = ref.joint_generator(ch.alpha, beta)
        for s, A in enumerate(sysm.A):
            Bw, Cz = sysm.Bw[s], sysm.Cz[s]
            pi = A.T @ P[s] + P[s] @ A + sum(Q[s, t] * P[t] for t in range(4))
            M = np.block([
                [pi, P[s] @ Bw, Cz.T],
                [Bw.T @ P[s], -g * np.eye(Bw.shape[1]), np.zeros((Bw.shape[1], Cz.shape[0]))],
                [Cz, np.zeros((Cz.shape[0], Bw.shape[1])), -np.eye(Cz.shape[0])],
            ])
            assert is_neg_def(M), (beta, s)


def test_paper_robust_certificate_rebuilt(paper_robust, paper_loop, paper_system, paper_gains, ref):
    r = paper_robust
    g = r.gamma ** 2
    assert r.multipliers is not None and len(r.multipliers) == 4
    assert all(len(row) == 2 and all(v > 0 for v in row) for row in r.multipliers)
    assert check_certificate(paper_loop, "lemma-4.1", r.P, r.multipliers, g).ok
    assert not check_certificate(paper_loop, "lemma-4.1", r.P, r.multipliers, (r.gamma / 2) ** 2).ok
    assert not check_certificate(paper_loop, "lemma-4.1", [-p for p in r.P], r.multipliers, g).ok
    # Independent rebuild from the plant data: x' = (A_i + B_i K_j) x with the two
    # channels (A1_i, A2_i) and (B1_i, B2_i K_j), multipliers in that order.
    P = [0.5 * (p + p.T) for p in r.P]
    ch = paper_system.chain
    for beta in ref.box_vertices(ch.beta_min, ch.beta_max):
        Q = ref.joint_generator(ch.alpha, beta)
        for i in range(2):
            for j in range(2):
                s = 2 * i + j
                md, K = paper_system.modes[i], paper_gains[j]
                A = md.A + md.B @ K
                lam_a, lam_b = r.multipliers[s]
                F_a, F_b = md.A2, md.B2 @ K
                pi = (A.T @ P[s] + P[s] @ A + sum(Q[s, t] * P[t] for t in range(4))
                      + lam_a * F_a.T @ F_a + lam_b * F_b.T @ F_b)
                E = np.hstack([md.A1, md.B1, md.D])
                diag = np.diag([-lam_a] * md.A1.shape[1] + [-lam_b] * md.B1.shape[1] + [-g] * md.D.shape[1])
                ne = E.shape[1]
                M = np.block([
                    [pi, P[s] @ E, md.C.T],
                    [E.T @ P[s], diag, np.zeros((ne, 1))],
                    [md.C, np.zeros((1, ne)), -np.eye(1)],
                ])
                assert is_neg_def(M), (beta, s)


# ============================================================================ infeasible
def test_unstable_loop_is_infeasible_confirmed_by_two_solvers(paper_system):
    # A = diag(1, 0.8) is unstable and K = 0 leaves it so in every mode.
    loop = state_feedback_loop(paper_system, [np.zeros((2, 2)), np.zeros((2, 2))])
    assert not mean_square_stability(loop).stable  # independent confirmation
    r = mes_lmi(loop)
    assert r.outcome == "infeasible"
    assert not r.certified and r.certificate is None
    claimed = [a for a in r.attempts if a.infeasible]
    assert len(claimed) >= 2
    assert len({a.solver for a in claimed}) >= 2
    assert all(a.solver in SOLVERS for a in claimed)


# ============================================================================ solver choice
def test_choose_solver_rejects_unknown_name():
    with pytest.raises(ValidationError) as info:
        choose_solver("gurobi", 10)
    assert "gurobi" in str(info.value)


def test_mes_lmi_rejects_unknown_solver(paper_loop):
    with pytest.raises(ValidationError) as info:
        mes_lmi(paper_loop, solver="no-such-solver")
    assert "no-such-solver" in str(info.value)


def test_choose_solver_accepts_known_names():
    assert choose_solver("CLARABEL", 10) == "clarabel"
    assert choose_solver(None, 10) == "clarabel"


# ============================================================================ closed forms
def identical_mode_loop(A, B_w, C, unc=None, alpha=((-1.0, 1.0), (2.0, -2.0))):
    A = np.atleast_2d(np.asarray(A, dtype=float))
    n = A.shape[0]
    md = {"A": A, "B": np.ones((n, 1)), "C": np.atleast_2d(C), "D": np.atleast_2d(B_w).reshape(n, -1)}
    if unc is not None:
        md["A1"], md["A2"] = [[unc[0]]], [[unc[1]]]
    s = FTCSystem.from_arrays(name="same", modes=[md, dict(md)], alpha=[list(r) for r in alpha],
                              beta_min=[[0.0, 1.0], [2.0, 0.0]], beta_max=[[0.0, 3.0], [4.0, 0.0]])
    return state_feedback_loop(s, [np.zeros((1, n)), np.zeros((1, n))])


@pytest.mark.parametrize(
    "a, b, c, alpha",
    [
        (-2.0, 3.0, 0.5, ((-1.0, 1.0), (2.0, -2.0))),
        (-0.5, 1.0, -2.0, ((-10.0, 10.0), (0.1, -0.1))),
    ],
)
def test_scalar_nominal_gamma_closed_form(a, b, c, alpha):
    # All joint modes equal: the chain is irrelevant and ||c/(s-a) b||_inf = |b c| / |a|.
    r = hinf_gamma(identical_mode_loop([[a]], [[b]], [[c]], alpha=alpha), robust=False)
    want = abs(b * c) / abs(a)
    assert r.certified
    assert r.gamma == pytest.approx(want, rel=1e-3)
    assert r.gamma >= want * (1 - 1e-7)  # a certified upper bound cannot undercut the true norm


def test_scalar_robust_gamma_closed_form():
    # x' = (a + e Delta f) x + b w: the S-procedure bound is tight for one scalar block,
    # worst case a + |e f|, so gamma = |b c| / |a + |e f||.
    a, b, c, e, f = -2.0, 3.0, 0.5, 0.5, 1.2
    r = hinf_gamma(identical_mode_loop([[a]], [[b]], [[c]], unc=(e, f)), robust=True)
    want = abs(b * c) / abs(a + abs(e * f))
    assert r.certified
    assert r.gamma == pytest.approx(want, rel=1e-3)
    nominal = hinf_gamma(identical_mode_loop([[a]], [[b]], [[c]], unc=(e, f)), robust=False)
    assert nominal.gamma == pytest.approx(abs(b * c) / abs(a), rel=1e-3)


def hinf_norm_by_frequency_sweep(A, B, C):
    def gain(w):
        G = C @ np.linalg.solve(1j * w * np.eye(A.shape[0]) - A, B)
        return float(np.linalg.svd(G, compute_uv=False)[0])

    grid = np.concatenate([[0.0], np.logspace(-4, 4, 4000)])
    vals = [gain(w) for w in grid]
    k = int(np.argmax(vals))
    lo, hi = grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]
    best = max(vals[k], gain(0.0))
    if hi > lo:
        res = scipy.optimize.minimize_scalar(lambda w: -gain(w), bounds=(lo, hi), method="bounded",
                                             options={"xatol": 1e-10})
        best = max(best, -res.fun)
    return best


def test_two_state_nominal_gamma_matches_frequency_sweep():
    # Lightly damped, non-normal A: peak away from w = 0. All joint modes identical.
    A = np.array([[-0.2, 2.0], [-2.0, -0.2]])
    Bw = np.array([[1.0], [0.5]])
    C = np.array([[1.0, -1.0]])
    want = hinf_norm_by_frequency_sweep(A, Bw, C)
    r = hinf_gamma(identical_mode_loop(A, Bw, C), robust=False)
    assert r.certified
    assert r.gamma == pytest.approx(want, rel=1e-3)
    assert r.gamma >= want * (1 - 1e-6)


# ============================================================================ LMI vs spectral test
def fast_loop(A0, A1, q=20.0):
    md = lambda A: {"A": A, "B": [[1.0], [0.0]], "C": [[1.0, 0.0]], "D": [[1.0], [0.0]]}  # noqa: E731
    s = FTCSystem.from_arrays(name="fast", modes=[md(A0), md(A1)], alpha=[[-q, q], [q, -q]],
                              beta_min=[[0.0, q], [q, 0.0]], beta_max=[[0.0, q], [q, 0.0]])
    return state_feedback_loop(s, [np.zeros((1, 2)), np.zeros((1, 2))])


def test_mes_lmi_agrees_with_spectral_test_on_degenerate_box():
    # With a single beta the Lyapunov condition is exact: LMI feasible <=> abscissa < 0.
    unstable = fast_loop([[-1.0, 10.0], [0.0, -1.0]], [[-1.0, 0.0], [10.0, -1.0]])  # Hurwitz modes
    stable = fast_loop([[0.5, 0.0], [0.0, -5.0]], [[-5.0, 0.0], [0.0, 0.5]])  # unstable modes
    assert not mean_square_stability(unstable).stable and mean_square_stability(stable).stable
    r_u = mes_lmi(unstable)
    assert r_u.outcome == "infeasible"
    r_s = mes_lmi(stable)
    assert r_s.outcome == "certified" and r_s.certified
