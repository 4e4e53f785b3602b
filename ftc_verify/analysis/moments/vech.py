r"""The second-moment generator in ``vech`` coordinates, assembled and solved densely.

For joint-mode matrices :math:`A_s` and the joint generator :math:`Q`,

.. math::

    \mathcal{L} = \operatorname{blockdiag}_s\bigl(L_n (I \otimes A_s + A_s \otimes I) D_n\bigr)
                  + Q^T \otimes I_{n(n+1)/2}

(:mod:`~ftc_verify.analysis.moments.stability`, module docstring: :math:`D_n` the
duplication, :math:`L_n` the elimination matrix). Every entry of a diagonal block of
:math:`L_n (I \otimes A + A \otimes I) D_n` is a sum of at most two entries of :math:`A`
(weights 1, or 2 on the diagonal of :math:`X`), so its assembly by a 0/1/2 matrix
product (:func:`second_moment_matrix`) gives the numbers of the Kronecker formula to the
last bit; :func:`dense_solve` is LAPACK's ``gesv``, the routine behind
``scipy.linalg.solve``, without its condition estimate.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import numpy as np

from ...model.system import Matrix

__all__ = ["duplication_matrix", "second_moment_matrix", "lyapunov_vech", "dense_solve", "unvech_stack",
           "vech_order"]


def duplication_matrix(n: int) -> tuple[Matrix, Matrix]:
    """``(D, L)``: ``vec(X) = D vech(X)`` for symmetric ``X`` and ``vech(X) = L vec(X)``.

    ``vech`` stacks the lower triangle column by column (column-major ``vec``).
    """
    pairs = [(r, c) for c in range(n) for r in range(c, n)]
    D = np.zeros((n * n, len(pairs)))
    L = np.zeros((len(pairs), n * n))
    for k, (r, c) in enumerate(pairs):
        D[c * n + r, k] = 1.0
        D[r * n + c, k] = 1.0
        L[k, c * n + r] = 1.0
    return D, L


def second_moment_matrix(A: Sequence[Matrix], Q: Matrix) -> Matrix:
    """:math:`\\mathcal{L}` of the module docstring for the joint-mode matrices ``A`` and
    the joint generator ``Q``: block :math:`(s, t)` is :math:`q_{ts} I` off the diagonal
    and :math:`q_{ss} I + L_n(I \\otimes A_s + A_s \\otimes I)D_n` on it (:func:`lyapunov_vech`,
    one matrix product for every joint state; the entries are those of
    ``kron(Q.T, I) + blockdiag(lyapunov_vech(A_s))`` to the last bit)."""
    n, S = A[0].shape[0], len(A)
    h = n * (n + 1) // 2
    Qa = np.asarray(Q, dtype=float)
    blocks = _lyapunov_vech_stack(np.asarray(A, dtype=float))
    out: Matrix = np.zeros((S, h, S, h))
    idx = np.arange(h)
    for s in range(S):
        out[s, :, s, :] = blocks[s]
        out[s, idx, :, idx] += Qa[:, s]  # q_ts on the diagonal of block (s, t); q_ss + L_s on block (s, s)
    return out.reshape(S * h, S * h)


@functools.lru_cache(maxsize=64)
def _vech_index(n: int) -> tuple[np.ndarray, ...]:
    """Index arrays of :func:`lyapunov_vech`: row ``(r, c)`` of ``vech(A X + X A')``
    takes ``A[r, p]`` at ``X[p, c]`` and ``A[c, p]`` at ``X[r, p]`` (``X`` symmetric).
    Memoised (a pure function of ``n``; the arrays are read-only)."""
    rows, cols = vech_order(n)
    index = np.zeros((n, n), dtype=int)
    index[rows, cols] = np.arange(rows.size)
    index[cols, rows] = np.arange(rows.size)
    k = np.repeat(np.arange(rows.size), n)
    r = np.repeat(rows, n)
    c = np.repeat(cols, n)
    p = np.tile(np.arange(n), rows.size)
    out = (k, index[p, c], r, p, index[r, p], c)
    for arr in out:
        arr.flags.writeable = False
    return out


def lyapunov_vech(A: Matrix) -> Matrix:
    r"""The matrix of :math:`X \mapsto A X + X A^T` on ``vech`` coordinates
    (:math:`L_n (I \otimes A + A \otimes I) D_n`), assembled from index arrays."""
    n = A.shape[0]
    k, j1, r, p, j2, c = _vech_index(n)
    out = np.zeros((n * (n + 1) // 2,) * 2)
    np.add.at(out, (k, j1), A[r, p])
    np.add.at(out, (k, j2), A[c, p])
    return out


@functools.lru_cache(maxsize=64)
def _vech_operator(n: int) -> np.ndarray:
    """The ``(h^2, n^2)`` 0/1/2 matrix taking ``vec(A)`` (row-major) to the row-major
    :func:`lyapunov_vech` of ``A`` (``h = n (n + 1) / 2``; memoised, read-only)."""
    k, j1, r, p, j2, c = _vech_index(n)
    h = n * (n + 1) // 2
    out = np.zeros((h * h, n * n))
    np.add.at(out, (k * h + j1, r * n + p), 1.0)
    np.add.at(out, (k * h + j2, c * n + p), 1.0)
    out.flags.writeable = False
    return out


def _lyapunov_vech_stack(A: np.ndarray) -> np.ndarray:
    """:func:`lyapunov_vech` of every matrix of the stack ``A`` (shape ``(S, n, n)``) by
    one product with :func:`_vech_operator`: every entry is a sum of at most two entries
    of ``A`` (weights 1, or 2 on the diagonal), so the same numbers to the last bit."""
    S, n = A.shape[0], A.shape[1]
    h = n * (n + 1) // 2
    return (A.reshape(S, n * n) @ _vech_operator(n).T).reshape(S, h, h)


def dense_solve(G: Matrix, rhs: Matrix) -> Matrix:
    """``G^{-1} rhs`` by LAPACK's ``gesv`` (LU with partial pivoting), the routine
    ``scipy.linalg.solve`` calls, without its condition estimate and checks (a third of
    its time at 324 rows; the same numbers); ``LinAlgError`` when ``G`` is singular.
    ``G`` is overwritten by its LU factors (pass a copy to keep it)."""
    from scipy.linalg import lapack

    _, _, x, info = lapack.dgesv(G, rhs, overwrite_a=True, overwrite_b=False)
    if info != 0:
        raise np.linalg.LinAlgError(f"gesv: info {info}")
    return x


def unvech_stack(v: Matrix, modes: int, n: int) -> Matrix:
    """The stack of ``modes`` symmetric ``n x n`` matrices whose ``vech`` (lower triangle
    column by column) are the consecutive pieces of ``v``."""
    rows, cols = vech_order(n)
    X = np.zeros((modes, n, n), dtype=np.asarray(v).dtype)
    X[:, rows, cols] = np.asarray(v).reshape(modes, -1)
    X[:, cols, rows] = X[:, rows, cols]
    return X


@functools.lru_cache(maxsize=64)
def vech_order(n: int) -> tuple[np.ndarray, np.ndarray]:
    """``(rows, cols)`` of ``vech``: the lower triangle column by column (memoised, a pure
    function of ``n``: the arrays are read-only)."""
    rows, cols = np.tril_indices(n)
    order = np.lexsort((rows, cols))
    out = rows[order], cols[order]
    for arr in out:
        arr.flags.writeable = False
    return out
