r"""Exact mean-square stability: the spectral abscissa of the second-moment generator.

With :math:`X_s(t) = E[\xi \xi^T 1\{\theta_t = s\}]` and :math:`w = 0`, Dynkin's formula
gives the linear ODE (derived here, not in the paper)

.. math::

    \dot X_s = A_s X_s + X_s A_s^T + \sum_{s'} Q_{s' s} X_{s'} ,

so in half-vectorised (``vech``) Kronecker form :math:`\dot v = \mathcal{L} v` with

.. math::

    \mathcal{L} = \operatorname{blockdiag}_s\bigl(L_n (I \otimes A_s + A_s \otimes I) D_n\bigr)
                  + Q^T \otimes I_{n(n+1)/2},

:math:`D_n` the duplication and :math:`L_n` the elimination matrix. The nominal loop is
mean-square (equivalently mean-exponentially, paper Remark 1) stable iff the spectral
abscissa :math:`\max \operatorname{Re} \lambda(\mathcal{L}) < 0`. Restricting to
symmetric matrices loses nothing: the operator is resolvent-positive, so its abscissa
is attained at a positive semidefinite eigenvector.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.linalg

from .closedloop import ClosedLoop
from ..model.system import Matrix

__all__ = [
    "MSSResult",
    "duplication_matrix",
    "second_moment_generator",
    "spectral_abscissa",
    "generator_size",
    "DENSE_LIMIT",
    "mean_square_stability",
]


#: Largest generator (rows) handled by dense eigenvalues; larger ones go matrix-free
#: (a dense N x N eigenproblem at N = 1500 takes about a second here, and the dense
#: construction needs n^2 x n^2 Kronecker products per mode).
DENSE_LIMIT = 1500


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


def second_moment_generator(loop: ClosedLoop, beta: Matrix) -> Matrix:
    """The matrix :math:`\\mathcal{L}` of the module docstring for rates ``beta``."""
    n = loop.n
    D, L = duplication_matrix(n)
    eye = np.eye(n)
    blocks = [L @ (np.kron(eye, A) + np.kron(A, eye)) @ D for A in loop.A]
    Q = loop.chain.generator(beta)
    return scipy.linalg.block_diag(*blocks) + np.kron(Q.T, np.eye(D.shape[1]))


def spectral_abscissa(loop: ClosedLoop, beta: Matrix) -> float:
    """Largest real part of the eigenvalues of the second-moment generator at ``beta``.

    Dense eigenvalues up to :data:`DENSE_LIMIT` rows; above, the checked matrix-free
    test of :mod:`ftc_verify.analysis.moment_operator` (whose sign is proved by a
    Lyapunov certificate; its value is ARPACK's).

    A shift-invert Arnoldi variant (shift at a Collatz-Wielandt bound) was tried and
    removed: with a large shift every ``1/(sigma - mu)`` agrees to about 1e-9, and it
    returned a complex pair at -1.15 instead of the real abscissa -1.04 (n=12, m=4,
    ``benchmarks/synthesis.py``) -- wrong in the unsafe direction.
    """
    if generator_size(loop) > DENSE_LIMIT:
        from .moment_operator import matrix_free_abscissa

        return matrix_free_abscissa(loop, beta)
    return float(np.max(scipy.linalg.eigvals(second_moment_generator(loop, beta), check_finite=False).real))


def generator_size(loop: ClosedLoop) -> int:
    """Rows of the second-moment generator: joint modes times ``n (n + 1) / 2``."""
    return len(loop.A) * loop.n * (loop.n + 1) // 2


@dataclass(frozen=True, eq=False)
class MSSResult:
    """Worst spectral abscissa over the ``beta`` vertices evaluated.

    ``exhaustive`` tells whether every vertex was evaluated; otherwise a greedy ascent
    over vertices (single-rate flips from the all-min and all-max vertices) was used
    and the value is a lower bound of the vertex maximum.
    """

    spectral_abscissa: float
    worst_beta: Matrix
    vertices_evaluated: int
    exhaustive: bool

    @property
    def stable(self) -> bool:
        """Mean-square stable at every vertex evaluated."""
        return self.spectral_abscissa < 0.0

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary."""
        return {
            "spectral_abscissa": self.spectral_abscissa,
            "stable": self.stable,
            "worst_beta": self.worst_beta.tolist(),
            "vertices_evaluated": self.vertices_evaluated,
            "exhaustive": self.exhaustive,
        }


def mean_square_stability(loop: ClosedLoop, *, max_vertices: int = 256) -> MSSResult:
    """Worst spectral abscissa over the vertices of the ``beta`` box.

    Every vertex is evaluated when there are at most ``max_vertices``; otherwise a
    greedy vertex ascent is run with the same budget (``exhaustive=False``).
    """
    chain = loop.chain
    nominal = loop.nominal()
    if chain.vertex_count() <= max_vertices:
        best = (-np.inf, chain.midpoint())
        count = 0
        for b in chain.vertices():
            best = max(best, (spectral_abscissa(nominal, b), b), key=lambda t: t[0])
            count += 1
        return MSSResult(float(best[0]), best[1], count, True)
    pairs = chain.beta_pairs
    cache: dict[tuple[bool, ...], float] = {}

    def vertex(bits: tuple[bool, ...]) -> Matrix:
        b = np.zeros((chain.m, chain.m))
        for (j, i), hi in zip(pairs, bits):
            b[j, i] = chain.beta_max[j, i] if hi else chain.beta_min[j, i]
        return b

    def value(bits: tuple[bool, ...]) -> float:
        if bits not in cache:
            cache[bits] = spectral_abscissa(nominal, vertex(bits))
        return cache[bits]

    for start in ((False,) * len(pairs), (True,) * len(pairs)):
        if start not in cache and len(cache) >= max_vertices:
            break
        value(start)
        bits, improved = start, True
        while improved:
            improved = False
            for k in range(len(pairs)):
                cand = bits[:k] + (not bits[k],) + bits[k + 1:]
                if cand not in cache and len(cache) >= max_vertices:
                    break
                if value(cand) > value(bits):
                    bits, improved = cand, True
    worst = max(cache, key=lambda k: cache[k])
    return MSSResult(cache[worst], vertex(worst), len(cache), False)
