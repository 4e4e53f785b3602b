"""The descent's eigen-solver (:mod:`ftc_verify.synthesis.rightmost`) gives the numbers of
``scipy.linalg.eig`` bit for bit: the rightmost eigenvalue's real part and its left and
right eigenvectors, for real and complex rightmost eigenvalues (random matrices, skew
ones with ties on the imaginary axis, matrices with zero columns), and the descent's
objective built on it equals the one built on ``scipy.linalg.eig``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import scipy.linalg

from ftc_verify.analysis.moments.stability import duplication_matrix, second_moment_matrix
from ftc_verify.model.files import load_system
from ftc_verify.synthesis.descent import Parametrisation, abscissa, abscissa_gradient
from ftc_verify.synthesis.rightmost import rightmost

ROOT = Path(__file__).resolve().parents[1]


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    """Equal dtype, values and signs of zeros (real and imaginary parts)."""
    return (a.dtype == b.dtype and np.array_equal(a, b)
            and np.array_equal(np.signbit(a.real), np.signbit(b.real))
            and np.array_equal(np.signbit(np.imag(a)), np.signbit(np.imag(b))))


def test_rightmost_is_scipy_eig_bit_for_bit() -> None:
    rng = np.random.default_rng(3)
    complex_seen = 0
    for trial in range(300):
        n = int(rng.integers(2, 45))
        G = rng.standard_normal((n, n))
        if trial % 3 == 0:
            G = G - G.T  # eigenvalues on the imaginary axis: ties of the real parts
        if trial % 5 == 0:
            G[:, : n // 2] = 0.0
        vals, vl, vr = scipy.linalg.eig(G, left=True, right=True, check_finite=False)
        k = int(np.argmax(vals.real))
        found = rightmost(G, True)
        assert found is not None
        mu, u, v = found
        assert u is not None and v is not None
        assert mu == vals[k].real and _same(u, vl[:, k]) and _same(v, vr[:, k]), trial
        only = rightmost(G, False)
        assert only is not None and only[0] == mu and only[1] is None
        complex_seen += vals[k].imag != 0
    assert complex_seen > 50  # the conjugate-pair columns were exercised


def test_not_finite_or_not_float64_is_left_to_scipy() -> None:
    G = np.eye(3)
    G[0, 1] = np.nan
    assert rightmost(G, True) is None and rightmost(G, False) is None
    assert rightmost(np.eye(3, dtype=complex), True) is None and rightmost(np.eye(3, dtype=np.float32), False) is None


def test_descent_objective_equals_the_scipy_one() -> None:
    """``abscissa_gradient`` and ``abscissa`` on the paper plant's loops against the
    formula of the descent's docstring evaluated with ``scipy.linalg.eig``."""
    system = load_system(ROOT / "examples" / "paper.toml")
    par = Parametrisation.build(system, 1)
    rng = np.random.default_rng(7)
    n = par.A0[0].shape[0]
    for _ in range(20):
        A = par.loop_matrices(rng.standard_normal(par.size))
        for beta in system.chain.vertices():
            Q = system.chain.generator(beta)
            G = second_moment_matrix(A, Q)
            vals, vl, vr = scipy.linalg.eig(G, left=True, right=True, check_finite=False)
            k = int(np.argmax(vals.real))
            mu, grads = abscissa_gradient(A, Q)
            assert mu == vals[k].real == abscissa(A, Q)
            u, v = vl[:, k], vr[:, k]
            w = np.vdot(u, v)
            h = n * (n + 1) // 2
            D, L = duplication_matrix(n)
            for s, g in enumerate(grads):
                V = (D @ v[s * h:(s + 1) * h]).reshape(n, n, order="F")
                U = (L.T @ u[s * h:(s + 1) * h]).reshape(n, n, order="F")
                assert np.array_equal(g, np.real((np.conj(U) @ V.T + U.conj().T @ V) / w))
