"""The second-moment generator's assembly and dense solve (issue 37 item 3, h37u round 8):
the same numbers, to the last bit, as the reference formulas they replace."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg

from ftc_verify.analysis.moments.stability import lyapunov_stack_solution
from ftc_verify.analysis.moments.vech import lyapunov_vech, second_moment_matrix


def _case(rng: np.random.Generator, n: int, S: int) -> tuple[list[np.ndarray], np.ndarray]:
    A = [rng.standard_normal((n, n)) * 10.0 ** rng.uniform(-3, 3) for _ in range(S)]
    Q = rng.uniform(0.0, 3.0, (S, S))
    np.fill_diagonal(Q, 0.0)
    np.fill_diagonal(Q, -Q.sum(axis=1))
    return A, Q


@pytest.mark.parametrize("n,S", [(1, 1), (2, 3), (5, 2), (8, 9)])
def test_generator_is_kron_plus_block_diagonal_bit_for_bit(n: int, S: int) -> None:
    rng = np.random.default_rng(1000 * n + S)
    for _ in range(5):
        A, Q = _case(rng, n, S)
        h = n * (n + 1) // 2
        reference = np.kron(Q.T, np.eye(h))
        for s, a in enumerate(A):
            reference[s * h:(s + 1) * h, s * h:(s + 1) * h] += lyapunov_vech(a)
        assert np.array_equal(second_moment_matrix(A, Q), reference)


def test_dense_solution_is_scipy_solve_bit_for_bit() -> None:
    rng = np.random.default_rng(7)
    n, S = 6, 4
    rows, cols = np.tril_indices(n)
    order = np.lexsort((rows, cols))
    rows, cols = rows[order], cols[order]
    for _ in range(10):
        A, Q = _case(rng, n, S)
        R = [r + r.T for r in (rng.standard_normal((n, n)) for _ in range(S))]
        X = lyapunov_stack_solution(A, Q, R)
        v = scipy.linalg.solve(second_moment_matrix(A, Q), -np.concatenate([r[rows, cols] for r in R]))
        assert X is not None
        assert np.array_equal(X[:, rows, cols].ravel(), v)


def test_singular_generator_gives_none() -> None:
    A = [np.zeros((2, 2))]  # A X + X A' = 0 for every X: the generator is zero
    assert lyapunov_stack_solution(A, np.zeros((1, 1))) is None


@pytest.mark.parametrize("omega", [0.0, 0.7, 3.0])
def test_first_moments_enclose_the_real_form_solution(omega: float) -> None:
    """lower_bound._first_moments solves ``(i omega I - Ac) M = b`` in complex balls; its
    ``[Mr; Mi]`` overlaps FLINT's default solve of the real form of twice the size,
    ``[[-Ac, -omega I], [omega I, -Ac]] [Mr; Mi] = [b; 0]``, and is as tight as float64."""
    import flint

    from ftc_verify.analysis import lower_bound
    from ftc_verify.analysis.rigorous import ball, precision

    rng = np.random.default_rng(int(omega * 10) + 3)
    n, S = 3, 4
    A = [rng.normal(size=(n, n)) / np.sqrt(n) - 1.2 * np.eye(n) for _ in range(S)]
    _, Q = _case(rng, n, S)
    B = [rng.normal(size=(n, 2)) for _ in range(S)]
    e = rng.normal(size=2)
    pi_f = rng.uniform(0.1, 1.0, S)
    with precision(128):
        At, Bw = [ball(a) for a in A], [ball(b) for b in B]
        q = [[ball(np.array([[Q[s, t]]])).value[0, 0] for t in range(S)] for s in range(S)]
        pi = ball(pi_f.reshape(-1, 1)).value
        eb = ball(e.reshape(-1, 1))
        got = lower_bound._first_moments(At, Bw, q, pi, eb, omega)
        K = S * n
        G = flint.arb_mat(2 * K, 2 * K)
        b = flint.arb_mat(2 * K, 1)
        for s in range(S):
            Be = (Bw[s] @ eb).value
            for r in range(n):
                b[s * n + r, 0] = pi[s, 0] * Be[r, 0]
                for h in (0, K):
                    for c in range(n):
                        G[h + s * n + r, h + s * n + c] = -At[s].value[r, c]
                    for t in range(S):
                        G[h + s * n + r, h + t * n + r] -= q[t][s]
                G[s * n + r, K + s * n + r] = -omega
                G[K + s * n + r, s * n + r] = omega
        reference = G.solve(b)
    assert got is not None
    rows = 2 * K if omega != 0.0 else K
    assert got.nrows() == rows
    top = max(float(abs(reference[k, 0].mid())) for k in range(2 * K))
    for k in range(rows):
        assert got[k, 0].overlaps(reference[k, 0])
        assert float(got[k, 0].rad()) <= 2.0 ** -56 * top
    if omega == 0.0:  # Mi = 0
        assert all(reference[K + k, 0].contains(0) for k in range(K))
