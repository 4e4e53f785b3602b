r"""The arithmetic of the sampled lower bound's proof, and two devices that keep it narrow and cheap.

:class:`MomentOps` holds the few operations the moment computation uses, in float64 (the
search) or in Arb balls (the proof); :func:`trace_weights` the row of a trace. Used by :mod:`~ftc_verify.analysis.moments.sampled_lower` (its module docstring has the
formulas: one period's map :math:`T` of the sampled moments, :math:`S = \sum_{j < K - 1}
T^j v_1` by doubling, the Van Loan exponential of :math:`[[0, \ell^T], [0, \mathcal L]]\,h`).

**The output row** (:func:`row_exponent`). The Van Loan matrix's first row is the output
weights :math:`\ell^T h`; on the three-tank example its absolute sum is 128 while every other
row's is below 0.38, so the exponential's norm, its number of squarings (each one widens a
ball by the cancellation in :math:`|X|\,|X|` against :math:`|X^2|`) and Arb's work were set by
one row. With :math:`D = \operatorname{diag}(2^k, I)`,

.. math::

    D^{-1} \begin{bmatrix} 0 & \ell^T \\ 0 & \mathcal L \end{bmatrix} D \, h
    = \begin{bmatrix} 0 & 2^{-k}\ell^T \\ 0 & \mathcal L \end{bmatrix} h, \qquad
    e^{M} = D\, e^{D^{-1} M D}\, D^{-1},

so the exponential of the matrix with the row scaled by :math:`2^{-k}` has the same
:math:`\mathcal F` block and :math:`2^{-k}\ell^T\mathcal G` in the first row: multiplied back
by :math:`2^k` (exact in ball arithmetic: a power of two). Any :math:`k` is exact; it is chosen
so that the row's sum is at most the largest other one.

**Doubling in an eigenbasis** (:func:`eigen_sums`). Ball products widen by :math:`|T|`,
whose spectral radius can exceed :math:`\rho(T)` (cancellation): after :math:`2^p` periods
that wrapping lost the 64-bit enclosure (three-tank example: proved to :math:`K = 4097` of
8193 periods, relative radius 0.05 there) and a 128-bit redo with Arb's exponential was
needed. With :math:`V` the float eigenvectors of the midpoint of :math:`T` (complex, taken
as exact numbers) and :math:`W` Arb's enclosure of :math:`V^{-1}` (``acb_mat.inv``: ``None``
when :math:`V` is not proved invertible), :math:`T' = W T V` contains
:math:`V^{-1} T V` and

.. math::

    g S = (g V) \sum_{j} T'^{\,j} (W v_1), \qquad f S = (f V) \sum_j T'^{\,j} (W v_1)

exactly, with the same doubling :math:`S'_{2m} = S'_m + T'^m S'_m`. :math:`T'` is nearly
diagonal, so its ball powers widen about linearly in the number of periods (three-tank:
relative radius 2e-8 at 8193 periods in 64-bit arithmetic). The products are real; the
real parts of their complex enclosures contain them. Not used (``[]``) when the
eigenvectors are not finite or their condition number is above :data:`EIGEN_CONDITION`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import scipy.linalg

from ...model.system import Matrix
from .stability import vech_order

__all__ = ["EIGEN_CONDITION", "MomentOps", "trace_weights", "row_exponent", "eigen_sums"]


def trace_weights(W: Matrix) -> Matrix:
    """The row ``w`` with ``w . vech(X) = tr(W X)`` for symmetric ``X`` (float64)."""
    rows, cols = vech_order(W.shape[0])
    return np.where(rows == cols, 1.0, 2.0) * W[rows, cols]


class MomentOps:
    """float64 or ball versions of the few operations the moment computation uses."""

    def __init__(self, balls: bool) -> None:
        self.balls = balls

    def mat(self, M: Any) -> Any:
        if not self.balls:
            return np.asarray(M, dtype=float)
        from ..rigorous import ball

        return ball(M)

    def kron(self, A: Any, B: Any) -> Any:
        if not self.balls:
            return np.kron(A, B)
        from .sampled_balls import ball_kron

        return ball_kron(A, B)

    def diag(self, blocks: Sequence[Any]) -> Any:
        if not self.balls:
            return scipy.linalg.block_diag(*blocks)
        from .sampled_balls import ball_block_diag

        return ball_block_diag(blocks)

    def bmat(self, rows: Sequence[Sequence[Any]]) -> Any:
        if not self.balls:
            return np.block([[np.asarray(b, dtype=float) for b in row] for row in rows])
        from ..rigorous import ball_bmat

        return ball_bmat(rows)

    def expm(self, M: Any, h: Any) -> Any:
        if not self.balls:
            return scipy.linalg.expm(M * h)
        from ..rigorous import Ball
        from .fast_balls import arb_expm

        return Ball(arb_expm(M.value * h))

    def weights(self, W: Any) -> Any:
        """The row ``w`` with ``w . vech(X) = tr(W X)`` for symmetric ``X``."""
        if not self.balls:
            return trace_weights(W)[None, :]
        import flint

        from ..rigorous import Ball

        rows, cols = vech_order(W.shape[0])
        out = flint.arb_mat(1, rows.size)
        for k, (i, j) in enumerate(zip(rows, cols)):
            out[0, k] = W.value[int(i), int(j)] * (1 if i == j else 2)
        return Ball(out)

    def block(self, M: Any, r0: int, r1: int, c0: int, c1: int) -> Any:
        if not self.balls:
            return M[r0:r1, c0:c1]
        import flint

        from ..rigorous import Ball

        out = flint.arb_mat(r1 - r0, c1 - c0)
        v = M.value
        for i in range(r1 - r0):
            for j in range(c1 - c0):
                out[i, j] = v[r0 + i, c0 + j]
        return Ball(out)


#: Largest condition number of the float eigenvectors :func:`eigen_sums` uses.
EIGEN_CONDITION = 1e8


def row_exponent(row_sum: float, other_rows: float) -> int:
    """The ``k >= 0`` of the module docstring: the smallest with ``row_sum / 2^k`` at most
    ``max(other_rows, 1/4)`` (the absolute sums of the output row and the largest other
    row, times ``h``; midpoints suffice: ``k`` decides only the work), at most 1000."""
    bound = max(other_rows, 0.25)
    if not (math.isfinite(row_sum) and math.isfinite(bound) and row_sum > bound):
        return 0
    return min(1000, math.ceil(math.log2(row_sum / bound)))


def eigen_sums(T: Any, v1: Any, g: Any, f: Any, doublings: int) -> list[tuple[Any, Any]]:
    r"""``[(g S, f S)]`` (Arb real balls, real parts) for :math:`K = 2^{p'} + 1` periods,
    :math:`p' = 0, \dots,` ``doublings``, computed in the eigenbasis of the midpoint of
    the ``arb_mat`` :math:`T` (module docstring); ``v1`` a column, ``g`` and ``f`` rows
    (``arb_mat``). ``[]`` when the eigenbasis is unusable."""
    import flint

    n = T.nrows()
    mid = np.array([float(x.mid()) for x in T.entries()], dtype=np.float64).reshape(n, n)
    with np.errstate(all="ignore"):
        if not np.all(np.isfinite(mid)):
            return []
        try:
            _, V = np.linalg.eig(mid)
            if not np.all(np.isfinite(V)) or not np.linalg.cond(V) < EIGEN_CONDITION:
                return []
        except np.linalg.LinAlgError:  # no convergence: the plain doublings stand alone
            return []
    Vb = flint.acb_mat(n, n, [complex(x) for x in V.ravel().tolist()])
    try:
        W = Vb.inv()
    except ZeroDivisionError:  # not proved invertible
        return []
    Pw = W * flint.acb_mat(T) * Vb
    Sm = W * flint.acb_mat(v1)
    gp, fp = flint.acb_mat(g) * Vb, flint.acb_mat(f) * Vb
    out = []
    for k in range(doublings + 1):
        if k:
            Sm = Sm + Pw * Sm
            Pw = Pw * Pw if k < doublings else Pw
        out.append(((gp * Sm)[0, 0].real, (fp * Sm)[0, 0].real))
    return out
