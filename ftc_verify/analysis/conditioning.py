r"""One similarity transform that makes a closed loop well-conditioned before any computation.

Plants come in physical units (metres against cubic metres per second) and in
realisations nobody chose for their numerics, so the same loop can reach the float
computations in coordinates where its Lyapunov matrices have condition numbers of
1e12 and more. Every state-space quantity this project computes is invariant under a
similarity :math:`x = T\tilde x` common to all joint states

.. math::

    \tilde A_s = T^{-1} A_s T,\quad \tilde B_{w,s} = T^{-1} B_{w,s},\quad
    \tilde C_{z,s} = C_{z,s} T,\quad \tilde E_{s,k} = T^{-1} E_{s,k},\quad
    \tilde F_{s,k} = F_{s,k} T,

with the second moments :math:`X_s = T \tilde X_s T^T` and the Lyapunov matrices of
the LMIs :math:`P_s = T^{-T} \tilde P_s T^{-1}`; so the spectral test and every LMI
are run on :math:`\tilde{\text{loop}}` and their answers mapped back, and the
certificate is re-checked in the original coordinates in ball arithmetic
(:mod:`ftc_verify.analysis.rigorous`), so that the transform (computed in float) never
has to be exact.

:func:`conditioning_transform` chooses :math:`T = c\,D\,T_b`:

1. :math:`D`: LAPACK's ``gebal`` balancing (powers of two, so exact) of the
   state-to-state gain pattern :math:`\sum_s |A_s| + |B_{w,s}|\mathbf 1\mathbf 1^T
   |C_{z,s}| + \sum_k |E_{s,k}|\mathbf 1\mathbf 1^T|F_{s,k}|` (the loop that the
   :math:`H_\infty` test closes from :math:`z` to :math:`w` included). It removes the
   diagonal part of a change of units exactly.
2. :math:`T_b`: the square-root balanced realisation of the *mode-averaged* loop
   :math:`\bar A = \sum_s \pi_s A_s` (:math:`\pi` the stationary distribution of the
   joint chain at the centre of the rate box), shifted left if needed so that it is
   Hurwitz, with the regularised Gramians

   .. math::

       \bar A W_c + W_c \bar A^T + \hat B\hat B^T + \delta I = 0, \qquad
       \bar A^T W_o + W_o \bar A + \hat C^T\hat C + \delta I = 0,

   :math:`\hat B = [\sqrt{\pi_s} B_{w,s}, E_{s,k}] / \|\cdot\|`, :math:`\hat C` likewise,
   :math:`\delta =` :data:`REGULARISATION`. With :math:`W_c = L_c L_c^T`, :math:`W_o =
   L_o L_o^T`, :math:`L_o^T L_c = U\Sigma V^T`: :math:`T_b = L_c V \Sigma^{-1/2}`,
   :math:`T_b^{-1} = \Sigma^{-1/2} U^T L_o^T`, so both Gramians become :math:`\Sigma`.
   Why this one: a non-orthogonal similarity changes the Gramians by congruence and the
   balanced realisation undoes any such congruence (it is unique up to an orthogonal
   factor); the :math:`\delta I` terms make the Gramians positive definite also for
   uncontrollable or unobservable loops and bound :math:`\operatorname{cond}(T_b)`, and
   they are the Lyapunov solutions of the mean-square test with right-hand side
   :math:`I`, so the second-moment matrices are well-conditioned too. The
   :math:`\delta I` terms are not invariant under the similarity still to be undone, so
   step 2 is repeated in the coordinates it produced (at most :data:`PASSES` times,
   until a pass changes the coordinates by a condition number below 10).

3. A scalar power of two :math:`c` (:math:`T \leftarrow cT`) that gives
   :math:`B_w` and :math:`C_z` equal norms: the balanced realisation above normalises
   them, so without it their ratio (a property of the units, e.g. 6e4 against 6e-5)
   would reach the :math:`H_\infty` blocks and the solver would stall.

When a step fails (a singular or non-finite Gramian), the transform skips it; the
result says which steps were applied.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

from ..jsonable import OMIT, fields_dict
from ..model.system import Matrix
from .closedloop import ClosedLoop

__all__ = ["REGULARISATION", "PASSES", "Similarity", "balancing_scale", "conditioning_transform", "stationary_distribution"]

#: The :math:`\delta` of the regularised Gramians (relative to the normalised inputs).
REGULARISATION = 1e-3
#: Passes of step 2 at most (each in the coordinates the previous one produced).
PASSES = 3


@dataclass(frozen=True, eq=False)
class Similarity:
    """``x = T x~`` with ``T`` and its computed inverse ``T_inv`` (floats; ``T_inv`` need
    not be the exact inverse: certificates are re-checked in the original coordinates)."""

    T: Matrix = field(metadata=OMIT)
    T_inv: Matrix = field(metadata=OMIT)
    steps: tuple[str, ...]

    JSON_PROPERTIES = ("condition",)

    @property
    def condition(self) -> float:
        """2-norm condition number of ``T``."""
        return float(np.linalg.cond(self.T))

    def apply(self, loop: ClosedLoop) -> ClosedLoop:
        """The loop in the coordinates ``x~``."""
        return loop.transformed(self.T, self.T_inv)

    def second_moments_back(self, X: Matrix) -> Matrix:
        """``T X~ T'`` for a stack ``X~`` of conditioned second-moment matrices."""
        return self.T @ X @ self.T.T

    def lyapunov_back(self, P: Matrix) -> Matrix:
        """``T_inv' P~ T_inv`` for a conditioned Lyapunov matrix ``P~``."""
        return self.T_inv.T @ P @ self.T_inv

    def to_dict(self) -> dict[str, object]:
        """JSON-ready summary: ``steps`` and ``condition``."""
        return fields_dict(self)


def balancing_scale(loop: ClosedLoop) -> Matrix:
    """Powers of two ``d`` such that ``loop.scaled(d)`` is balanced (step 1 of the module
    docstring)."""
    M = np.zeros((loop.n, loop.n))
    for A, Bw, Cz, chans in zip(loop.A, loop.Bw, loop.Cz, loop.channels):
        M += np.abs(A) + np.outer(np.abs(Bw).sum(axis=1), np.abs(Cz).sum(axis=0))
        for ch in chans:
            M += np.outer(np.abs(ch.E).sum(axis=1), np.abs(ch.F).sum(axis=0))
    if not np.all(np.isfinite(M)):
        return np.ones(loop.n)
    _, (scale, _) = scipy.linalg.matrix_balance(M, permute=False, separate=True)
    return np.asarray(scale, dtype=float)


def stationary_distribution(Q: Matrix) -> Matrix:
    """A stationary distribution ``pi`` of the generator ``Q`` (``pi Q = 0``, ``sum pi = 1``),
    by least squares (any one of them when the chain is reducible)."""
    S = Q.shape[0]
    M = np.vstack([Q.T, np.ones((1, S))])
    rhs = np.zeros(S + 1)
    rhs[-1] = 1.0
    pi = np.linalg.lstsq(M, rhs, rcond=None)[0]
    pi = np.clip(pi, 0.0, None)
    return pi / pi.sum() if pi.sum() > 0 else np.full(S, 1.0 / S)


def _normalised(M: Matrix) -> Matrix:
    norm = np.linalg.norm(M, 2) if M.size else 0.0
    return M / norm if norm > 0 and np.isfinite(norm) else M


def _balanced_realisation(loop: ClosedLoop) -> tuple[Matrix, Matrix] | None:
    """``(T_b, T_b^-1)`` of step 2, or ``None`` when a Gramian is not usable."""
    n = loop.n
    pi = stationary_distribution(loop.chain.generator(loop.chain.midpoint()))
    A = sum(p * a for p, a in zip(pi, loop.A))
    B = np.hstack([np.sqrt(p) * b for p, b in zip(pi, loop.Bw)]
                  + [ch.E for chans in loop.channels for ch in chans])
    C = np.vstack([np.sqrt(p) * c for p, c in zip(pi, loop.Cz)]
                  + [ch.F for chans in loop.channels for ch in chans])
    if not (np.all(np.isfinite(A)) and np.all(np.isfinite(B)) and np.all(np.isfinite(C))):
        return None
    size = max(float(np.linalg.norm(A, 2)), float(np.finfo(float).tiny))
    alpha = float(np.max(np.linalg.eigvals(A).real))
    shift = max(0.0, alpha + 1e-3 * size)
    A = A - shift * np.eye(n)
    B, C = _normalised(B), _normalised(C)
    eye = np.eye(n)
    try:
        Wc = scipy.linalg.solve_continuous_lyapunov(A, -(B @ B.T + REGULARISATION * eye))
        Wo = scipy.linalg.solve_continuous_lyapunov(A.T, -(C.T @ C + REGULARISATION * eye))
        Lc = np.linalg.cholesky(0.5 * (Wc + Wc.T))
        Lo = np.linalg.cholesky(0.5 * (Wo + Wo.T))
        U, sv, Vt = np.linalg.svd(Lo.T @ Lc)
    except (np.linalg.LinAlgError, ValueError, scipy.linalg.LinAlgError):
        return None
    if not (np.all(np.isfinite(sv)) and sv[-1] > 0):
        return None
    root = 1.0 / np.sqrt(sv)
    T = (Lc @ Vt.T) * root[None, :]
    T_inv = root[:, None] * (U.T @ Lo.T)
    if not (np.all(np.isfinite(T)) and np.all(np.isfinite(T_inv))):
        return None
    return T, T_inv


def conditioning_transform(loop: ClosedLoop) -> Similarity:
    """The similarity of the module docstring for ``loop`` (uncertainty channels included)."""
    d = balancing_scale(loop)
    T, T_inv = np.diag(d), np.diag(1.0 / d)
    steps = ["power-of-two diagonal balancing"]
    for _ in range(PASSES):
        bal = _balanced_realisation(loop.transformed(T, T_inv))
        if bal is None:
            break
        Tb, Tb_inv = bal
        T, T_inv = T @ Tb, Tb_inv @ T_inv
        steps.append("balanced realisation of the mode-averaged loop")
        if np.linalg.cond(Tb) < 10.0:  # already balanced: the regularisation no longer moves it
            break
    c = _io_scale(loop.transformed(T, T_inv))
    if c != 1.0:
        T, T_inv = T * c, T_inv / c
        steps.append(f"scalar {c:g} equalising the input and output norms")
    return Similarity(T, T_inv, tuple(steps))


def _io_scale(loop: ClosedLoop) -> float:
    r"""The power of two ``c`` nearest to ``sqrt(||Bw|| / ||Cz||)`` (inputs and outputs
    over all joint modes): ``x = c x~`` gives them equal norms, so that the
    :math:`H_\infty` blocks ``P Bw`` and ``Cz'`` have comparable scales (step 3)."""
    b = max(float(np.linalg.norm(B, 2)) if B.size else 0.0 for B in loop.Bw)
    c = max(float(np.linalg.norm(C, 2)) if C.size else 0.0 for C in loop.Cz)
    if not (b > 0 and c > 0 and np.isfinite(b) and np.isfinite(c)):
        return 1.0
    return float(2.0 ** round(0.5 * np.log2(b / c)))
