r"""The second-moment generator without forming it: a checked matrix-free spectral test.

The generator of :mod:`ftc_verify.analysis.moments.stability` acts on one symmetric matrix per
joint mode,

.. math::

    \mathcal L(X)_s = A_s X_s + X_s A_s^T + \sum_{s'} Q_{s's} X_{s'},

and its dense form has :math:`N = m^2 n(n+1)/2` rows (and an :math:`n^2 \times n^2`
Kronecker intermediate per mode): at :math:`n = 50, m = 3`, :math:`N = 11\,475`, a dense
eigenvalue problem of minutes and gigabytes; at :math:`n = 200` the Kronecker products
alone need 13 GB. Here :math:`\mathcal L` is applied in :math:`O(m^2 n^3)` on the
orthonormal half-vectorisation (``svec``: off-diagonal entries times :math:`\sqrt 2`, a
similarity of ``vech``, so the spectrum is the same), and

1. ARPACK (:func:`scipy.sparse.linalg.eigs`, ``which="LR"``) returns the rightmost
   eigenvalues; the best eigenpair's residual must be below :data:`RESIDUAL_RTOL`;
2. the verdict is then *checked*: for an operator that is resolvent-positive (it is:
   :math:`e^{\mathcal L t}` maps PSD matrices to PSD matrices), :math:`\alpha(\mathcal L) < 0`
   iff :math:`Y = -\mathcal L^{-1}(I)` is positive definite. So a claimed-stable answer is
   confirmed by solving :math:`\mathcal L(Y) = -I` (GMRES, matrix-free), a Cholesky
   factorisation of every :math:`Y_s` and a residual check; a claimed-unstable answer by
   the eigenpair itself (a real eigenvalue :math:`\ge 0` with a small residual).

An answer that fails either check raises :class:`~ftc_verify.errors.SolverError`; it is
never reported as a verdict.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ...errors import SolverError
from ..closedloop import ClosedLoop
from ...model.system import Matrix

__all__ = ["RESIDUAL_RTOL", "MomentOperator", "matrix_free_abscissa"]

#: Relative residual an ARPACK eigenpair (and the Lyapunov check) must reach.
RESIDUAL_RTOL = 1e-7


@dataclass(frozen=True, eq=False)
class MomentOperator:
    """:math:`\\mathcal L` at one ``beta`` as a matrix-free operator on ``svec``
    coordinates (module docstring)."""

    A: np.ndarray  # (S, n, n)
    Q: Matrix  # (S, S) generator
    rows: np.ndarray
    cols: np.ndarray
    weight: np.ndarray

    @classmethod
    def build(cls, loop: ClosedLoop, beta: Matrix) -> MomentOperator:
        n = loop.n
        rows, cols = np.triu_indices(n)
        weight = np.where(rows == cols, 1.0, math.sqrt(2.0))
        return cls(np.stack(loop.A), loop.chain.generator(beta), rows, cols, weight)

    @property
    def size(self) -> int:
        """``N``: modes times ``n (n + 1) / 2``."""
        return int(self.A.shape[0] * self.rows.size)

    @property
    def scale(self) -> float:
        """An upper bound of ``||L||`` (for relative residuals)."""
        return float(2.0 * max(np.linalg.norm(a, 2) for a in self.A) + 2.0 * np.max(np.abs(self.Q)))

    def unvec(self, v: np.ndarray) -> np.ndarray:
        """``svec`` coordinates -> stack of symmetric matrices."""
        S, n = self.A.shape[0], self.A.shape[1]
        X = np.zeros((S, n, n), dtype=v.dtype)
        X[:, self.rows, self.cols] = v.reshape(S, -1) / self.weight
        X[:, self.cols, self.rows] = X[:, self.rows, self.cols]
        return X

    def vec(self, X: np.ndarray) -> np.ndarray:
        """Stack of symmetric matrices -> ``svec`` coordinates."""
        return (X[:, self.rows, self.cols] * self.weight).reshape(-1)

    def apply(self, v: np.ndarray) -> np.ndarray:
        """:math:`\\mathcal L` in ``svec`` coordinates."""
        X = self.unvec(v)
        AX = self.A @ X
        Y = AX + np.transpose(AX, (0, 2, 1)) + np.einsum("ts,tij->sij", self.Q, X)
        return self.vec(Y)

    def linear_operator(self) -> Any:
        import scipy.sparse.linalg as spla

        return spla.LinearOperator((self.size, self.size), matvec=self.apply, dtype=float)


def _rightmost(op: MomentOperator) -> tuple[complex, np.ndarray]:
    import scipy.sparse.linalg as spla

    k = min(6, op.size - 2)
    try:
        vals, vecs = spla.eigs(op.linear_operator(), k=k, which="LR", tol=1e-12,
                               ncv=min(op.size - 1, max(40, 2 * k + 1)), maxiter=20 * op.size)
    except spla.ArpackNoConvergence as exc:
        raise SolverError(f"matrix-free spectral test: ARPACK did not converge ({exc})") from None
    best = int(np.argmax(vals.real))
    return complex(vals[best]), vecs[:, best]


def _stability_checked(op: MomentOperator) -> bool:
    """Solve ``L(Y) = -I`` and check ``Y_s > 0`` by Cholesky (module docstring)."""
    import scipy.sparse.linalg as spla

    S, n = op.A.shape[0], op.A.shape[1]
    b = -op.vec(np.broadcast_to(np.eye(n), (S, n, n)).copy())
    y, info = spla.gmres(op.linear_operator(), b, rtol=1e-12, restart=min(op.size, 200), maxiter=50)
    residual = float(np.linalg.norm(op.apply(y) - b) / np.linalg.norm(b))
    if info != 0 or residual > RESIDUAL_RTOL:
        return False
    for Y in op.unvec(y):
        try:
            np.linalg.cholesky(0.5 * (Y + Y.T))
        except np.linalg.LinAlgError:
            return False
    return True


def matrix_free_abscissa(loop: ClosedLoop, beta: Matrix) -> float:
    """The spectral abscissa of the second-moment generator at ``beta``, matrix-free and
    checked (module docstring); raises :class:`SolverError` when a check fails."""
    op = MomentOperator.build(loop.nominal(), beta)
    lam, v = _rightmost(op)
    residual = float(np.linalg.norm(op.apply(v.real) - lam.real * v.real) if abs(lam.imag) == 0 else
                     np.linalg.norm(op.linear_operator().matvec(v) - lam * v))
    if residual > RESIDUAL_RTOL * max(1.0, op.scale) * float(np.linalg.norm(v)):
        raise SolverError(f"matrix-free spectral test: eigenpair residual {residual:.3g} too large (N = {op.size})")
    if lam.real < 0 and not _stability_checked(op):
        raise SolverError(
            f"matrix-free spectral test: ARPACK says abscissa {lam.real:.6g} < 0 but the Lyapunov check "
            f"(L(Y) = -I, Y > 0) failed (N = {op.size})"
        )
    return float(lam.real)
