r"""Certificate candidates of Lemma 4.1 (gains fixed) from coupled Riccati equations, without an SDP.

Lemma 4.1's block of joint state :math:`s` (:func:`~ftc_verify.analysis.lmi.lyapunov_block`
with multipliers :math:`\lambda_{s,k} > 0`, one per uncertainty channel
:math:`(E_{s,k}, F_{s,k})`, and :math:`g = \gamma^2`) is, by the Schur complement on its
:math:`-\lambda_{s,k} I`, :math:`-g I` and :math:`-I` rows, negative definite iff

.. math::

    \Pi_s + \sum_k \lambda_{s,k} F_{s,k}^T F_{s,k} + C_{z,s}^T C_{z,s}
    + \gamma^{-2} P_s B_{w,s} B_{w,s}^T P_s + \sum_k \lambda_{s,k}^{-1} P_s E_{s,k} E_{s,k}^T P_s \prec 0 ,

with :math:`\Pi_s = A_s^T P_s + P_s A_s + \sum_t q_{st} P_t`. For fixed multipliers this
is Theorem 3.2's Riccati inequality (:mod:`~ftc_verify.analysis.bounded_real`, eq. (1)) of
the *augmented* loop with inputs :math:`[w; p_k]` and outputs :math:`[z; q_k]`,

.. math::

    \hat B_{w,s} = [\,B_{w,s},\ \gamma \lambda_{s,1}^{-1/2} E_{s,1},\ \dots\,], \qquad
    \hat C_{z,s} = [\,C_{z,s};\ \lambda_{s,1}^{1/2} F_{s,1};\ \dots\,],

at the same :math:`\gamma` (:math:`\gamma^{-2}\hat B\hat B^T = \gamma^{-2}B_wB_w^T +
\sum_k \lambda_k^{-1} E_kE_k^T`, :math:`\hat C^T\hat C = C_z^TC_z + \sum_k \lambda_k F_k^TF_k`).
Its quadratic term decreases as :math:`\gamma` grows, so for fixed multipliers the
feasible levels are an interval :math:`[\gamma^*(\lambda), \infty)`: bisection finds
:math:`\gamma^*(\lambda)` with :func:`~ftc_verify.analysis.bounded_real.bounded_real_solution`
(the box's rate envelope included, policy iteration warm-started).

**The multipliers.** For one direction :math:`x`, :math:`\lambda \|F x\|^2 + \lambda^{-1}
\|E^T P x\|^2` is least at :math:`\lambda = \|E^T P x\| / \|F x\|`; weighted by a
second-moment stack :math:`X` (the dual variable of the SDP, whose optimality condition
is :math:`\operatorname{tr} X_s (F^T F - \lambda^{-2} P E E^T P) = 0`),
:math:`\lambda_{s,k} = (\operatorname{tr} E^T P_s X_s P_s E / \operatorname{tr} F X_s F^T)^{1/2}`.
First round: :math:`P` and :math:`X` of the nominal loop (:math:`\mathcal L^*(P) = -C_z^TC_z`,
:math:`\mathcal L(X) = -I`), the level to :data:`FIRST_RTOL`; then (:data:`ROUNDS` in
all) :math:`P` of the previous level and :math:`X` of its worst-case loop
:math:`A_s + \hat B_{w,s} F_s`, the level to :data:`LEVEL_RTOL`. A heuristic that only
picks the candidate (measured: 0.06 % above the SDP's level on the paper's loop, 0.4 % on
random n = 8, m = 3, 0.9-2.7 % on n = 12, m = 4, 0.8 % on n = 16, m = 3; used first only from
:data:`~ftc_verify.analysis.lmi_size.RICCATI_FIRST_STATES` states on).

**The proof.** The candidate is the solution at :math:`\gamma(1 + 2\rho)` with margin
:math:`\varepsilon = \rho|\rho| \max_s \|C_{z,s}\|^2`
(:func:`~ftc_verify.analysis.bounded_real.candidate_margin`) for :math:`\rho` in
:data:`~ftc_verify.analysis.bounded_real.CANDIDATE_LADDER`; it and its multipliers are
proved at every vertex of the box by :func:`~ftc_verify.analysis.lmi.check_certificate`
(ball arithmetic, the loop as the user wrote it), exactly as an SDP's answer. Nothing
here is trusted: a rejected candidate sends the caller to the SDP
(:func:`~ftc_verify.analysis.lmi_analysis.hinf_gamma`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ..claimtext import upper_text
from ..model.system import Matrix
from .bounded_real import (CANDIDATE_LADDER, POLICY_GMRES_RESTARTS, SEARCH_RTOL, RateEnvelope, RiccatiCandidate,
                           batched_lyapunov, bounded_real_solution, candidate_margin, coupled_lyapunov)
from .closedloop import ClosedLoop
from .conditioning import Similarity
from .lmi import check_certificate

__all__ = ["ROUNDS", "LEVEL_RTOL", "FIRST_RTOL", "SEARCH_GMRES_RTOL", "CANDIDATE_RTOL", "robust_riccati_candidate"]

#: Rounds of multiplier updates (each a bisection on gamma).
ROUNDS = 2
#: Relative width of the first round's bisection (its solution only picks the multipliers).
FIRST_RTOL = 1e-2
#: GMRES's relative residual in the feasibility tests of the bisection.
SEARCH_GMRES_RTOL = 1e-8
#: Relative change of ``P`` at which the candidate's policy iteration stops (its margin
#: ``epsilon`` covers the rest; at 1e-10 GMRES's own error stalled it on n = 16, m = 3).
CANDIDATE_RTOL = 1e-8
#: Relative width of each round's bisection on gamma.
LEVEL_RTOL = 1e-4

Multipliers = list[list[float]]


def _augmented(loop: ClosedLoop, lam: Multipliers, gamma: float) -> tuple[list[Matrix], list[Matrix]]:
    """``(B_hat, C_hat)`` of the module docstring at ``gamma`` and the multipliers ``lam``."""
    B, C = [], []
    for s, chans in enumerate(loop.channels):
        B.append(np.hstack([loop.Bw[s]] + [gamma / math.sqrt(lam[s][k]) * ch.E for k, ch in enumerate(chans)]))
        C.append(np.vstack([loop.Cz[s]] + [math.sqrt(lam[s][k]) * ch.F for k, ch in enumerate(chans)]))
    return B, C


def _multipliers(loop: ClosedLoop, P: Sequence[Matrix], X: Sequence[Matrix] | None = None) -> Multipliers:
    r""":math:`\lambda_{s,k} = (\operatorname{tr} E^T P_s X_s P_s E / \operatorname{tr} F X_s F^T)^{1/2}`
    (module docstring; :math:`X_s = I` when ``X`` is not given), kept in
    :math:`[10^{-12}, 10^{12}]`."""
    out = []
    for s, chans in enumerate(loop.channels):
        W = np.eye(loop.n) if X is None else X[s]
        row = []
        for ch in chans:
            EP = ch.E.T @ P[s]
            num, den = float(np.trace(EP @ W @ EP.T)), float(np.trace(ch.F @ W @ ch.F.T))
            ratio = math.sqrt(num / den) if den > 0 and num > 0 else 1.0
            row.append(min(max(ratio, 1e-12), 1e12) if math.isfinite(ratio) else 1.0)
        out.append(row)
    return out


def _weights(loop: ClosedLoop, box: RateEnvelope, lam: Multipliers, gamma: float, F: Sequence[Matrix]) -> list[Matrix] | None:
    r"""The second moments :math:`X` of the worst-case loop :math:`A_s + \hat B_{w,s} F_s`
    driven by :math:`I` (the dual weight of the multipliers' optimality condition)."""
    B, _ = _augmented(loop, lam, gamma)
    return _moments([a + b @ f for a, b, f in zip(loop.A, B, F)], box.Q)


def _moments(A: Sequence[Matrix], Q: Matrix) -> list[Matrix] | None:
    r"""The second moments :math:`A_s X_s + X_s A_s^T + \sum_t q_{ts} X_t = -I` (the adjoint
    stack of :func:`~ftc_verify.analysis.bounded_real.batched_lyapunov`; the dense or sparse
    solve of :func:`~ftc_verify.analysis.verdict.float_stack_solution` when GMRES fails)."""
    from .verdict import float_stack_solution

    n = A[0].shape[0]
    X = batched_lyapunov([a.T for a in A], np.asarray(Q).T, [np.eye(n)] * len(A), rtol=SEARCH_GMRES_RTOL)
    if X is None:
        Y = float_stack_solution(A, Q)
        X = None if Y is None else list(Y)
    return None if X is None else [0.5 * (x + x.T) for x in X]


def _solve(loop: ClosedLoop, box: RateEnvelope, lam: Multipliers, gamma: float, epsilon: float = 0.0,
           start: Sequence[Matrix] | None = None, rtol: float = SEARCH_RTOL) -> tuple[list[Matrix], list[Matrix]] | None:
    """:func:`~ftc_verify.analysis.bounded_real.bounded_real_solution` of the augmented loop;
    a feasibility test (``rtol`` = ``SEARCH_RTOL``) takes GMRES to :data:`SEARCH_GMRES_RTOL` only."""
    B, C = _augmented(loop, lam, gamma)
    solve = None if rtol < SEARCH_RTOL else _loose
    return bounded_real_solution(list(loop.A), B, C, box, gamma, epsilon, start=start, rtol=rtol, solve=solve)


def _loose(A: Sequence[Matrix], Q: Matrix, R: Sequence[Matrix], start: Sequence[Matrix] | None) -> list[Matrix] | None:
    return batched_lyapunov(A, Q, R, start, rtol=SEARCH_GMRES_RTOL, maxiter=POLICY_GMRES_RESTARTS)


def _level(loop: ClosedLoop, box: RateEnvelope, lam: Multipliers, lo: float, hi: float,
           start: Sequence[Matrix] | None, rtol: float) -> tuple[float, list[Matrix], list[Matrix]] | None:
    """The smallest feasible level (upper end of a bracket of relative width ``rtol``)
    for the multipliers ``lam``, searched from ``hi`` (doubled until feasible) down to
    ``lo`` (halving from ``hi`` while ``lo`` is 0); with ``(P, F)`` there."""
    found = _solve(loop, box, lam, hi, start=start)
    while found is None:
        lo, hi = hi, 2.0 * hi
        if hi > 1e300:
            return None
        found = _solve(loop, box, lam, hi)
    P, F = found
    while hi - lo > rtol * hi:
        mid = math.sqrt(lo * hi) if lo > 0 else 0.5 * hi
        nxt = _solve(loop, box, lam, mid, start=F)
        if nxt is None:
            lo = mid
        else:
            hi, (P, F) = mid, nxt
    return hi, P, F


def robust_riccati_candidate(original: ClosedLoop, target: ClosedLoop, similarity: Similarity | None) -> RiccatiCandidate:
    r"""A certified Lemma 4.1 level of ``original`` (with uncertainty channels) from the
    augmented Riccati equations of ``target`` (``original`` in the coordinates of
    ``similarity``), proved at every vertex of the box (module docstring). The returned
    :class:`~ftc_verify.analysis.bounded_real.RiccatiCandidate`'s ``multipliers`` are the
    certificate's :math:`\lambda_{s,k}`. The first round's multipliers come from the
    nominal loop's observability and controllability stacks (:math:`F = 0`), its level
    to :data:`FIRST_RTOL`; the envelope is then pinned where that solution prefers
    (:meth:`~ftc_verify.analysis.bounded_real.RateEnvelope.pinned`)."""
    box = RateEnvelope.of(target.chain)
    A, Q = list(target.A), box.Q
    P0 = batched_lyapunov(A, Q, [c.T @ c for c in target.Cz], rtol=SEARCH_GMRES_RTOL) or \
        coupled_lyapunov(A, Q, [c.T @ c for c in target.Cz])
    X0 = _moments(A, Q)
    if P0 is None or X0 is None:
        return RiccatiCandidate(None, None, None, None, 0, "the nominal loop is not mean-square stable in float64")
    lam = _multipliers(target, P0, X0)
    best: tuple[float, Multipliers, list[Matrix], RateEnvelope] | None = None
    lo, hi, F, rtol = 0.0, 1.0, None, FIRST_RTOL
    for _ in range(ROUNDS):
        found = _level(target, box, lam, lo, hi, F, rtol)
        if found is None:
            break
        gamma, P, F = found
        if best is None or gamma < best[0]:
            best = (gamma, lam, F, box)
        lam, lo, hi, rtol = _multipliers(target, P, _weights(target, box, lam, gamma, F)), 0.8 * gamma, gamma, LEVEL_RTOL
        box = box.pinned(P)
    if best is None:
        return RiccatiCandidate(None, None, None, None, 0, "no feasible level of the augmented Riccati equations")
    gamma0, lam, F, box = best
    scale = max(*(float(np.linalg.norm(c, 2)) ** 2 for c in target.Cz), np.finfo(float).tiny)  # as Theorem 3.2
    why, tried = "", 0
    for rho in CANDIDATE_LADDER:
        gamma = gamma0 * (1.0 + 2.0 * rho)
        sol = _solve(target, box, lam, gamma, candidate_margin(rho, scale), start=F, rtol=CANDIDATE_RTOL)
        tried += 1
        if sol is None:
            why = f"no Riccati solution at {gamma:.6g} with margin {rho * abs(rho):.1e} |C_z|^2"
            continue
        candidate = tuple(sol[0])
        multipliers = tuple(tuple(row) for row in lam)
        cert = check_certificate(original, "lemma-4.1", candidate, multipliers, gamma * gamma, similarity=similarity)
        if cert.ok:
            return RiccatiCandidate(gamma0, gamma, cert, candidate, tried,
                                    f"float level {gamma0:.6g} of the augmented Riccati equations (no SDP); certified "
                                    f"at {upper_text(gamma)} (+{2 * rho:.1e} relative), margin {rho * abs(rho):.1e} |C_z|^2", multipliers)
        why = cert.reason
    return RiccatiCandidate(gamma0, None, None, None, tried, f"no candidate passed ({tried} tried): {why}")
