"""The second-moment generator's assembly and dense solve (issue 37 item 3, h37u round 8):
the same numbers, to the last bit, as the reference formulas they replace."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg

from ftc_verify.analysis.moments.stability import lyapunov_stack_solution, lyapunov_vech, second_moment_matrix


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
