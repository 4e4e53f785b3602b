"""``rigorous.tight_solve`` (interval LU first, FLINT's default when LU's balls grow) and
``bounded_real.least_eigenvalue`` (one batched ``eigvalsh``): the fast paths give
enclosures of the exact answer and the same numbers as the slow ones."""

from __future__ import annotations

import flint
import numpy as np
import pytest

from ftc_verify.analysis.bounded_real import least_eigenvalue
from ftc_verify.analysis.rigorous import LU_RADIUS, precision, tight_solve


def _exact(A: np.ndarray, b: np.ndarray) -> list[flint.fmpq]:
    """The exact rational solution of an integer system."""
    x = flint.fmpq_mat(A.astype(int).tolist()).solve(flint.fmpq_mat(b.astype(int).tolist()))
    return [x[i, 0] for i in range(x.nrows())]


def _contains(ball: flint.arb, q: flint.fmpq) -> bool:
    """``ball`` contains the rational ``q`` (converted at 512 bits: a ball far narrower than ``ball``)."""
    with precision(512):
        return bool(ball.contains(flint.arb(q)))


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_well_conditioned_system_is_enclosed_by_the_lu_path(seed: int) -> None:
    rng = np.random.default_rng(seed)
    A = rng.integers(-9, 10, (40, 40)) + 60 * np.eye(40, dtype=int)
    b = rng.integers(-9, 10, (40, 1))
    with precision(128):
        x = tight_solve(flint.arb_mat(A.tolist()), flint.arb_mat(b.tolist()))
        lu = flint.arb_mat(A.tolist()).solve(flint.arb_mat(b.tolist()), algorithm="lu")
    assert x is not None
    exact = _exact(A, b)
    entries = x.entries()
    assert all(_contains(e, q) for e, q in zip(entries, exact))
    top = max(float(abs(e.mid())) for e in entries)
    assert max(float(e.rad()) for e in entries) <= LU_RADIUS * top
    # the LU path was the one taken: its balls are the LU balls
    assert all(float(e.rad()) == float(f.rad()) for e, f in zip(entries, lu.entries()))


def test_ill_conditioned_system_falls_back_to_the_preconditioned_solve() -> None:
    n = 9  # Hilbert matrix times lcm: integer, condition ~1e11, interval LU's balls grow
    H = np.array([[1.0 / (i + j + 1) for j in range(n)] for i in range(n)])
    scale = 1
    for k in range(1, 2 * n):
        scale = scale * k // np.gcd(scale, k)
    A = np.rint(H * scale).astype(np.int64)
    b = np.ones((n, 1), dtype=np.int64)
    with precision(64):
        G, rhs = flint.arb_mat(A.tolist()), flint.arb_mat(b.tolist())
        x = tight_solve(G, rhs)
        lu = G.solve(rhs, algorithm="lu")
    assert x is not None
    lu_top = max(float(abs(e.mid())) for e in lu.entries())
    assert max(float(e.rad()) for e in lu.entries()) > LU_RADIUS * lu_top  # LU alone was too wide here
    assert all(_contains(e, q) for e, q in zip(x.entries(), _exact(A, b)))
    assert max(float(e.rad()) for e in x.entries()) < max(float(e.rad()) for e in lu.entries())


def test_singular_system_gives_none() -> None:
    with precision(128):
        assert tight_solve(flint.arb_mat([[1, 2], [2, 4]]), flint.arb_mat([[1], [1]])) is None


def test_least_eigenvalue_is_the_per_matrix_minimum() -> None:
    rng = np.random.default_rng(7)
    stack = [(m + m.T) / 2 for m in rng.standard_normal((9, 8, 8))]
    assert least_eigenvalue(stack) == min(float(np.linalg.eigvalsh(p)[0]) for p in stack)
