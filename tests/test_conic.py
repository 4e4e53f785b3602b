"""The native conic path of the analysis LMIs (ftc_verify.analysis.conic), the Theorem 3.1
certificate taken from a certified H-infinity answer, and the pruned spectral stage."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from box_systems import three_mode_loop

from ftc_verify.analysis.moments import stability
from ftc_verify.analysis.closedloop import state_feedback_loop
from ftc_verify.analysis.conic import Affine, Rows, affine_bmat, scalar_variable, solve_clarabel, svec_index, sym_variable
from ftc_verify.analysis.lmi import block_specs, lyapunov_block
from ftc_verify.analysis.lmi_analysis import hinf_gamma, mes_lmi
from ftc_verify.analysis.solvers import SETTINGS
from ftc_verify.analysis.moments.stability import abscissa_below, abscissa_near, mean_square_stability, spectral_abscissa
from ftc_verify.model.system import FTCSystem


def svec(X):
    r, c, w = svec_index(X.shape[0])
    return X[r, c] * w


def test_svec_is_an_isometry():
    rng = np.random.default_rng(0)
    X, Y = (M + M.T for M in rng.normal(size=(2, 5, 5)))
    assert svec(X) @ svec(Y) == pytest.approx(np.trace(X @ Y), rel=1e-12)


def test_sym_variable_evaluates_to_the_matrix_of_its_svec():
    rng = np.random.default_rng(1)
    X = rng.normal(size=(4, 4))
    X = X + X.T
    P = sym_variable(4, 2, 14)
    x = np.zeros(14)
    x[2:12] = svec(X)
    assert np.allclose(P.const + P.lin @ x, X, atol=1e-14)


def robust_loop(seed: int = 3):
    rng = np.random.default_rng(seed)
    n, m = 3, 2
    modes = []
    for _i in range(m):
        modes.append({"A": rng.normal(size=(n, n)) - 2 * np.eye(n), "B": rng.normal(size=(n, 1)),
                      "C": rng.normal(size=(1, n)), "D": rng.normal(size=(n, 1)),
                      "A1": 0.1 * np.eye(n), "A2": 0.1 * np.eye(n), "B1": 0.1 * np.eye(n), "B2": 0.1 * np.ones((n, 1))})
    alpha = np.array([[-0.5, 0.5], [0.3, -0.3]])
    system = FTCSystem.from_arrays(name="robust", modes=modes, alpha=alpha,
                                   beta_min=np.array([[0, 1.0], [2.0, 0]]), beta_max=np.array([[0, 2.0], [3.0, 0]]))
    return state_feedback_loop(system, [-0.5 * np.ones((1, n)), -0.3 * np.ones((1, n))])


def test_affine_block_equals_the_numeric_block_at_any_point():
    """The one block assembly (lmi.lyapunov_block) on Affine variables, evaluated at a
    random point, equals the same function on the numbers: solver and certificate see
    the same LMI."""
    loop = robust_loop()
    rng = np.random.default_rng(4)
    n, modes, per = loop.n, len(loop.A), loop.n * (loop.n + 1) // 2
    lam_counts = [len(c) for c in loop.channels]
    K = modes * per + sum(lam_counts) + 1
    x = rng.normal(size=K)
    P_aff = [sym_variable(n, s * per, K) for s in range(modes)]
    starts = np.cumsum([modes * per] + lam_counts[:-1])
    lam_aff = [[scalar_variable(a + k, K) for k in range(c)] for a, c in zip(starts, lam_counts)]
    g_aff = scalar_variable(K - 1, K)
    P_num = [p.const + p.lin @ x for p in P_aff]
    for spec in block_specs(loop):
        M = lyapunov_block(loop, spec, P_aff, lam_aff[spec.s], g_aff, affine_bmat)
        expect = lyapunov_block(loop, spec, P_num, [float(v.lin @ x) for v in lam_aff[spec.s]], float(x[-1]), np.block)
        assert isinstance(M, Affine)
        assert np.allclose(M.const + M.lin @ x, expect, atol=1e-12)


def test_clarabel_native_matches_a_known_sdp_optimum():
    """min t subject to [[t, 1], [1, t]] >= 0 has optimum t = 1."""
    rows = Rows(1)
    t = scalar_variable(0, 1)
    rows.lmi(-(t * np.eye(2) + np.array([[0.0, 1.0], [1.0, 0.0]])), np.array([0]))
    status, message, x = solve_clarabel(rows.problem(np.array([1.0])), SETTINGS["clarabel"])
    assert status == "optimal" and message == ""
    assert x[0] == pytest.approx(1.0, abs=1e-7)


class PanicException(BaseException):
    """Named like pyo3's panic, which is a ``BaseException``."""


class Interrupt(BaseException):
    """Like the CLI's SIGTERM exception: a ``BaseException`` that must pass."""


def test_a_clarabel_panic_is_a_solver_failure_but_an_interrupt_passes(monkeypatch):
    from ftc_verify.analysis import solvers

    rows = Rows(1)
    rows.lmi(-(scalar_variable(0, 1) * np.eye(2)), np.array([0]))
    problem = rows.problem(np.array([1.0]))

    def panic(*_):
        raise PanicException("index out of bounds")

    monkeypatch.setattr(solvers, "solve_clarabel", panic)
    outcome, x = solvers.solve_conic(problem, "clarabel")
    assert outcome.status == "error" and "PanicException" in outcome.message and x is None

    def interrupt(*_):
        raise Interrupt()

    monkeypatch.setattr(solvers, "solve_clarabel", interrupt)
    with pytest.raises(Interrupt):
        solvers.solve_conic(problem, "clarabel")


def test_native_and_cvxpy_paths_give_the_same_gamma(paper_loop):
    """Clarabel directly and SDPA through cvxpy, both built from one ConicProblem."""
    pytest.importorskip("sdpap")
    native = hinf_gamma(paper_loop, robust=True, solver="clarabel")
    via_cvxpy = hinf_gamma(paper_loop, robust=True, solver="sdpa")
    assert native.certified and via_cvxpy.certified
    assert via_cvxpy.gamma == pytest.approx(native.gamma, rel=1e-4)


def test_theorem_3_1_from_a_certified_hinf_answer_needs_no_solve(paper_loop):
    nominal = hinf_gamma(paper_loop, robust=False)
    derived = mes_lmi(paper_loop, known=(nominal,))
    assert derived.certified and derived.attempts == () and "no solve" in derived.message
    assert all(np.array_equal(a, b) for a, b in zip(derived.P, nominal.P))
    # a failed (here: tampered) answer is not used; the LMI is solved instead
    tampered = dataclasses.replace(nominal, outcome="candidate")
    solved = mes_lmi(paper_loop, known=(tampered,))
    assert solved.certified and len(solved.attempts) >= 1


def test_shift_test_brackets_the_abscissa(paper_loop):
    nominal = paper_loop.nominal()
    for beta in nominal.chain.vertices():
        mu = spectral_abscissa(nominal, beta)
        assert abscissa_below(nominal, beta, mu + 1e-6 * (1 + abs(mu)))
        assert not abscissa_below(nominal, beta, mu - 1e-6 * (1 + abs(mu)))


def test_inverse_iteration_abscissa_equals_dense_eigenvalues(paper_loop):
    """abscissa_near from a level 5 % off (either side) returns the dense value."""
    nominal = paper_loop.nominal()
    for beta in nominal.chain.vertices():
        mu = spectral_abscissa(nominal, beta)
        for level in (mu - 0.05 * (1 + abs(mu)), mu + 0.05 * (1 + abs(mu))):
            assert abscissa_near(nominal, beta, level) == pytest.approx(mu, rel=1e-10, abs=1e-10)


def test_pruned_vertex_search_equals_the_exhaustive_one(monkeypatch):
    """Three fault modes, n = 5 (a generator of 135 rows: pruned): same worst vertex and
    value (to rounding) as with the shift test switched off, with fewer eigenvalue
    problems."""
    loop = three_mode_loop()
    pruned = mean_square_stability(loop)
    monkeypatch.setattr(stability, "SHIFT_TEST_MIN", 10**9)
    full = mean_square_stability(loop)
    assert full.exact_evaluations == full.vertices_evaluated == 64
    assert pruned.vertices_evaluated == 64 and pruned.exact_evaluations < 64
    assert pruned.spectral_abscissa == pytest.approx(full.spectral_abscissa, rel=1e-10)
    assert np.array_equal(pruned.worst_beta, full.worst_beta)


def test_keyed_variables_read_their_columns():
    """``KeyedVariables`` (the sampled certificates' constraints): each key once, in order,
    its symmetric matrix read from the program's columns at ``first(*key)``, then the
    extra columns as scalars and as a symmetric block."""
    from ftc_verify.analysis.conic import KeyedVariables, evaluate

    first = {(0, 1): 10, (1, 0): 3}
    v = KeyedVariables(2, lambda *key: first[key], [(0, 1), (1, 0), (0, 1)], [30, 31, 32, 40])
    assert v.keys == [(0, 1), (1, 0)]
    assert list(v.columns) == [10, 11, 12, 3, 4, 5, 30, 31, 32, 40] and v.K == 10
    x = np.random.default_rng(1).normal(size=50)
    local = x[v.columns]
    for key, start in first.items():
        X = evaluate(v.var[key], local)
        assert np.allclose(svec(X), x[start:start + 3], rtol=1e-15, atol=0)
    assert evaluate(v.scalar(3), local) == x[40]
    assert np.allclose(svec(evaluate(v.sym(0, 2), local)), x[30:33], rtol=1e-15, atol=0)
