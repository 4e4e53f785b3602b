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
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ...errors import SolverError
from ..closedloop import ClosedLoop
from ...model.system import Matrix

__all__ = ["RESIDUAL_RTOL", "MomentOperator", "matrix_free_abscissa", "matrix_free_eigenpair", "ASCENT_STEPS",
           "ARPACK_NCV", "linearised_ascent"]

#: Relative residual an ARPACK eigenpair (and the Lyapunov check) must reach.
RESIDUAL_RTOL = 1e-7
#: ARPACK's Krylov basis: 80 vectors converge in a fifth of the CPU time of 40 at
#: N = 10,584 (n = 48, m = 3: 3,200 products instead of 9,100, 2 s instead of 9 s).
ARPACK_NCV = 80
#: Vertices :func:`linearised_ascent` evaluates at most.
ASCENT_STEPS = 6


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


def _rightmost(op: MomentOperator, start: np.ndarray | None = None) -> tuple[complex, np.ndarray]:
    import scipy.sparse.linalg as spla

    k = min(6, op.size - 2)
    try:
        vals, vecs = spla.eigs(op.linear_operator(), k=k, which="LR", tol=1e-12, v0=start,
                               ncv=min(op.size - 1, max(ARPACK_NCV, 2 * k + 1)), maxiter=20 * op.size)
    except spla.ArpackNoConvergence as exc:
        raise SolverError(f"matrix-free spectral test: ARPACK did not converge ({exc})") from None
    best = int(np.argmax(vals.real))
    return complex(vals[best]), vecs[:, best]


def _stability_checked(op: MomentOperator) -> bool:
    """Solve ``L(Y) = -I`` (:func:`~ftc_verify.analysis.bounded_real.coupled_lyapunov`:
    GMRES preconditioned by one Schur form per joint state) and check the residual and
    ``Y_s > 0`` by Cholesky (module docstring)."""
    from ..bounded_real import coupled_lyapunov

    S, n = op.A.shape[0], op.A.shape[1]
    found = coupled_lyapunov([a.T for a in op.A], op.Q.T, [np.eye(n)] * S, rtol=1e-12)
    if found is None:
        return False
    b = -op.vec(np.broadcast_to(np.eye(n), (S, n, n)).copy())
    y = op.vec(np.array(found))
    residual = float(np.linalg.norm(op.apply(y) - b) / np.linalg.norm(b))
    if residual > RESIDUAL_RTOL:
        return False
    for Y in found:
        try:
            np.linalg.cholesky(Y)
        except np.linalg.LinAlgError:
            return False
    return True


def matrix_free_eigenpair(loop: ClosedLoop, beta: Matrix,
                          start: np.ndarray | None = None) -> tuple[float, np.ndarray | None]:
    """The spectral abscissa of the second-moment generator at ``beta``, matrix-free and
    checked (module docstring; raises :class:`SolverError` when a check fails), and its
    eigenvector as a stack of symmetric matrices scaled to a positive trace (``None``
    for a complex eigenvalue). ``start``: such a stack (e.g. the eigenvector at a
    neighbouring rate vertex) to start ARPACK from; the answer does not depend on it."""
    op = MomentOperator.build(loop.nominal(), beta)
    v0 = None if start is None else op.vec(np.asarray(start, dtype=float))
    if v0 is not None and not (np.all(np.isfinite(v0)) and np.any(v0)):
        v0 = None
    lam, v = _rightmost(op, v0)
    residual = float(np.linalg.norm(op.apply(v.real) - lam.real * v.real) if abs(lam.imag) == 0 else
                     np.linalg.norm(op.linear_operator().matvec(v) - lam * v))
    if residual > RESIDUAL_RTOL * max(1.0, op.scale) * float(np.linalg.norm(v)):
        raise SolverError(f"matrix-free spectral test: eigenpair residual {residual:.3g} too large (N = {op.size})")
    if lam.real < 0 and not _stability_checked(op):
        raise SolverError(
            f"matrix-free spectral test: ARPACK says abscissa {lam.real:.6g} < 0 but the Lyapunov check "
            f"(L(Y) = -I, Y > 0) failed (N = {op.size})"
        )
    if lam.imag != 0:
        return float(lam.real), None
    X = op.unvec(v.real)
    trace = float(np.einsum("sii->", X))
    return float(lam.real), (X / trace if trace != 0 else X)


def matrix_free_abscissa(loop: ClosedLoop, beta: Matrix) -> float:
    """The spectral abscissa of the second-moment generator at ``beta``, matrix-free and
    checked (module docstring); raises :class:`SolverError` when a check fails."""
    return matrix_free_eigenpair(loop, beta)[0]


def _left_eigenvector(op: MomentOperator, mu: float, start: np.ndarray | None = None) -> np.ndarray | None:
    """The eigenvector of the adjoint :math:`\\mathcal L^*` (``A_s`` and ``Q`` transposed;
    ``svec`` is orthonormal) at ``mu``, as a stack scaled to a positive trace, ARPACK
    started from the stack ``start`` when given; ``None`` when ARPACK's rightmost
    eigenvalue of the adjoint is not ``mu`` or is complex."""
    adjoint = MomentOperator(np.ascontiguousarray(op.A.transpose(0, 2, 1)), op.Q.T, op.rows, op.cols, op.weight)
    lam, z = _rightmost(adjoint, None if start is None else adjoint.vec(start))
    if lam.imag != 0 or abs(lam.real - mu) > 1e-8 * (1.0 + abs(mu)):
        return None
    Z = adjoint.unvec(z.real)
    return Z / float(np.einsum("sii->", Z))


def linearised_ascent(loop: ClosedLoop, vertex: Callable[[tuple[bool, ...]], Matrix],
                      widths: Sequence[float], *, max_steps: int = ASCENT_STEPS) -> dict[tuple[bool, ...], float] | None:
    r"""The spectral abscissae (:func:`matrix_free_eigenpair`) of the rate vertices a
    first-order vertex ascent evaluated (the largest is its answer), for
    generators too large to evaluate every vertex (each evaluation is an ARPACK run of
    seconds). ``vertex(bits)`` is the rate array at a vertex (``bits[r]``: rate ``r`` at
    its top), ``widths`` the widths of the rates (0: fixed).

    At a vertex with a simple real rightmost eigenvalue :math:`\mu` (right eigenvector
    :math:`X`, left :math:`Z` of the adjoint, both positive semidefinite stacks), the
    derivative along rate :math:`r` (:math:`Q` is affine in it, slope
    :math:`\partial_r Q`) is, by first-order perturbation of a simple eigenvalue,

    .. math::

        \partial_r \mu = \frac{\langle Z, \partial_r\mathcal L(X)\rangle}{\langle Z, X\rangle}
        = \frac{\sum_{s,t} (\partial_r Q)_{ts} \operatorname{tr}(Z_s X_t)}{\sum_s \operatorname{tr}(Z_s X_s)},

    since :math:`(\partial_r \mathcal L(X))_s = \sum_t (\partial_r Q)_{ts} X_t` (the
    :math:`A_s` do not depend on the rates). The next vertex puts every rate at the end
    its derivative points to; the ascent stops when that vertex was already evaluated,
    after ``max_steps`` evaluations, or when it is not higher. A heuristic for the
    reported *estimate* only (the verdict is proved over the whole box by
    :mod:`ftc_verify.analysis.box`); ``None`` when the first vertex's eigenvalue is
    complex or its left eigenvector is not found (the caller then evaluates vertices
    one by one)."""
    bits = tuple(False for _ in widths)
    seen: dict[tuple[bool, ...], float] = {}
    best = -math.inf
    start: np.ndarray | None = None
    left: np.ndarray | None = None
    while bits not in seen and len(seen) < max_steps:
        beta = vertex(bits)
        mu, X = matrix_free_eigenpair(loop, beta, start)
        seen[bits] = mu
        if mu <= best:
            break
        best = mu
        Z = None if X is None else _left_eigenvector(MomentOperator.build(loop.nominal(), beta), mu, left)
        if X is None or Z is None:
            return None if len(seen) == 1 else seen
        M = np.einsum("sij,tji->ts", Z, X)  # M[t, s] = tr(Z_s X_t)
        slopes = []
        for r, width in enumerate(widths):
            up = vertex(tuple(True if k == r else b for k, b in enumerate(bits)))
            down = vertex(tuple(False if k == r else b for k, b in enumerate(bits)))
            dQ = (np.asarray(loop.chain.generator(up)) - np.asarray(loop.chain.generator(down)))
            slopes.append(float(np.sum(dQ * M)) if width > 0 else 0.0)
        bits = tuple(g > 0 for g in slopes)
        start, left = X, Z
    return seen
