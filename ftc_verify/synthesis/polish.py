r"""Polishing certified FDI-mode gains: a trust-region descent on the bilinear Lemma 4.1.

The P-step / K-step alternation of ``iterative``
(:func:`~ftc_verify.synthesis.state_feedback.descend`) moves one block of variables at a
time, so it stops at any point where the gains are optimal for the Lyapunov matrices and
the Lyapunov matrices for the gains -- a partial optimum, not a local one. Measured on
issue 34's system ``sf301``: from the ``common`` design (certified robust gamma
0.190028) the alternation moved 1e-6; along the straight line to a plain common-``X``
design the certified gamma falls monotonically to 0.188058.

:func:`polish` moves both blocks at once. At certified gains :math:`K^0` with the
analysis' Lemma 4.1 answer :math:`(P^0, \lambda^0, g^0)`, the block of every joint state
and rate vertex (:func:`~ftc_verify.analysis.lmi.lyapunov_block`, :math:`F` in Schur
form) is affine in :math:`P` for fixed gains and affine in the gains for fixed :math:`P`;
its first-order expansion in :math:`(\Delta P, \Delta K)` is

.. math::

    M(P^0, K^0 + \Delta K; g) + M(P^0 + \Delta P, K^0; g^0) - M(P^0, K^0; g^0) \preceq 0,

the analysis' own blocks evaluated three times (the dropped term is
:math:`\operatorname{He}(\Delta P\, B\, \Delta K)` and its channel analogues), with
:math:`\lambda = \lambda^0` fixed. The step minimises :math:`g` subject to these
blocks, the trust region :math:`-\rho P^0_s \preceq \Delta P_s \preceq \rho P^0_s`
(so :math:`P^0_s + \Delta P_s \succeq (1 - \rho) P^0_s \succ 0`),
:math:`\|\Delta K_j\|_2 \le \rho \max(1, \|K^0_j\|_2)` (both in the analysis'
coordinates, :func:`linearised_step`), and the gain bound
:math:`\|K^0_j + \Delta K_j\|_2 \le k_{max}` (:func:`~ftc_verify.synthesis.xy_design.gain_bound_block`).
At :math:`\Delta = 0` the program has the analysis' point, so its optimum predicts no
increase. The new gains count only when the core's robust gamma
(:func:`~ftc_verify.analysis.lmi_analysis.hinf_gamma`, certificate proved) is smaller
than the best so far; otherwise :math:`\rho` is divided by 4. So the result is never
worse than the start, and every accepted iterate is certified.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from ..analysis.closedloop import ClosedLoop, gain_loop, state_feedback_loop
from ..analysis.conic import Rows, affine_bmat, matrix_variable, scalar_variable, sym_variable, unit_rows
from ..analysis.lmi import block_specs, lyapunov_block
from ..analysis.lmi_analysis import LMIResult, hinf_gamma
from ..model.system import FTCSystem, Matrix
from .results import SolverCalls
from .of_blocks import bounded_blocks
from .xy_design import gain_bound_block

__all__ = ["POLISH_STEPS", "POLISH_RADIUS", "MIN_RADIUS", "polish", "linearised_step"]

#: Candidate gains (programs and certifications) a polish tries at most.
POLISH_STEPS = 12
#: First relative trust radius :math:`\rho`; it doubles (up to 0.5) after an accepted step
#: and is divided by 4 after a rejected one.
POLISH_RADIUS = 0.1
#: The polish stops when the trust radius falls below this.
MIN_RADIUS = 1e-3


def _factors(P: list[Matrix]) -> list[Any] | None:
    """The float64 Cholesky factors of the (symmetrised) ``P_s``, ``None`` when one fails."""
    try:
        return [np.linalg.cholesky(0.5 * (Ps + Ps.T)) for Ps in P]
    except np.linalg.LinAlgError:
        return None


def linearised_step(system: FTCSystem, gains: list[Matrix], res: LMIResult, rho: float, k_max: float | None,
                    calls: SolverCalls) -> list[Matrix] | None:
    r"""One trust-region step of the module docstring from gains ``K^0`` with the analysis'
    certified answer ``res`` (:class:`~ftc_verify.analysis.lmi_analysis.LMIResult`): the
    new gains (scaled back to ``k_max`` when the solver's tolerance put one outside the
    bound), or ``None`` when the solver returned no point (or a ``P^0_s`` has no float64
    Cholesky factor).

    Scaled as the analysis scales its own program: in the analysis' coordinates
    :math:`x = T \tilde x` (``res.similarity``, where ``res.P_conditioned`` lives), with
    :math:`B_w / \gamma^0` (so :math:`g^0 = 1`), :math:`\Delta P_s = L_s V_s L_s^T`
    (:math:`\tilde P^0_s = L_s L_s^T`, so the trust region is :math:`-\rho I \preceq V_s
    \preceq \rho I`, which also keeps :math:`P^0_s + \Delta P_s \succeq (1 - \rho) P^0_s`)
    and :math:`\Delta K_j T = \sigma_j W_j`, :math:`\sigma_j = \max(1, \|K^0_j T\|_2)`,
    :math:`\|W_j\|_2 \le \rho`. Variables: :math:`\operatorname{vec} W_j`, :math:`\operatorname{svec} V_s`
    per joint state, then :math:`h = g / g^0 \ge 0`."""
    m, (n, nu, _, _) = system.m, system.dims
    S = system.chain.n_states
    T, T_inv = (np.eye(n), np.eye(n)) if res.similarity is None else (res.similarity.T, res.similarity.T_inv)
    P0 = list(res.P_conditioned or res.P or ())
    gamma0 = float(res.gamma)  # type: ignore[arg-type]
    lam = [list(r) for r in (res.multipliers or [()] * S)]
    size_k, size_p = nu * n, n * (n + 1) // 2
    K = m * size_k + S * size_p + 1
    every: Any = np.arange(K)
    sigma = [max(1.0, float(np.linalg.norm(G @ T, 2))) for G in gains]
    W = [matrix_variable(nu, n, j * size_k, K) for j in range(m)]
    dK = [sigma[j] * W[j] @ T_inv for j in range(m)]
    L = _factors(P0)
    if L is None:  # P proved definite in balls, yet not in float64: no step
        return None
    V = [sym_variable(n, m * size_k + s * size_p, K) for s in range(S)]
    h = scalar_variable(K - 1, K)

    def scaled(loop: ClosedLoop) -> ClosedLoop:
        return replace(loop.transformed(T, T_inv), Bw=tuple(T_inv @ B / gamma0 for B in loop.Bw))

    moved = scaled(gain_loop(system, [G + d for G, d in zip(gains, dK)], "polish step"))
    here = scaled(state_feedback_loop(system, gains))
    shifted = [Ps + Ls @ Vs @ Ls.T for Ps, Ls, Vs in zip(P0, L, V)]
    rows = Rows(K)
    for spec in block_specs(here):
        fixed = lyapunov_block(here, spec, P0, lam[spec.s], 1.0, np.block, schur_F=True)
        rows.lmi(lyapunov_block(moved, spec, P0, lam[spec.s], h, affine_bmat, schur_F=True)
                 + lyapunov_block(here, spec, shifted, lam[spec.s], 1.0, affine_bmat, schur_F=True) - fixed, every)
    for s in range(S):
        rows.lmi(V[s] - rho * np.eye(n), every)
        rows.lmi(-(V[s] + rho * np.eye(n)), every)
    for j in range(m):
        rows.lmi(-gain_bound_block(W[j], rho, 1.0, affine_bmat), every)
        if k_max is not None:
            rows.lmi(-gain_bound_block(gains[j] + dK[j], k_max, 1.0, affine_bmat), every)
    rows.nonneg(unit_rows(K, [K - 1]), [0.0])
    out, x = calls.run_conic(rows.problem(np.eye(K)[K - 1]))
    if not out.solved or x is None:
        return None
    new = [G + sigma[j] * x[j * size_k:(j + 1) * size_k].reshape(nu, n) @ T_inv for j, G in enumerate(gains)]
    return bounded_blocks(new, k_max)[0]  # the solver's tolerance: back inside the bound


def polish(system: FTCSystem, start: list[Matrix], start_lmi: LMIResult | None, calls: SolverCalls, solver: str,
           k_max: float | None, steps: int = POLISH_STEPS, tol: float = 1e-4) -> tuple[list[Matrix], list[float], str]:
    """The trust-region descent of the module docstring from certified gains ``start``
    (``start_lmi``: their certified robust-gamma result, computed when ``None``): the best
    certified gains, the certified gammas of the accepted iterates (the start's first) and
    why it stopped. Stops after ``steps`` candidates, when the radius falls below :data:`MIN_RADIUS`,
    or when an accepted step gains less than ``tol`` relative."""
    res = start_lmi if start_lmi is not None else hinf_gamma(state_feedback_loop(system, start), robust=True,
                                                              solver=solver)
    if start_lmi is None:
        calls.outcomes.extend(res.attempts)
    if not res.certified or res.P is None or res.gamma is None:
        return list(start), [], "start gains not certified; no polish"
    best, history, rho = list(start), [float(res.gamma)], POLISH_RADIUS
    reason = f"{steps} candidates tried"
    for _ in range(steps):
        if _factors(list(res.P_conditioned or res.P or ())) is None:
            reason = "a certified P has no float64 Cholesky factor"
            break
        new = linearised_step(system, best, res, rho, k_max, calls)
        cand = None if new is None else hinf_gamma(state_feedback_loop(system, new), robust=True, solver=solver)
        if cand is not None:
            calls.outcomes.extend(cand.attempts)
        if new is None or cand is None or not cand.certified or cand.gamma is None or cand.P is None or cand.gamma >= history[-1]:
            rho /= 4.0
            if rho < MIN_RADIUS:
                reason = f"trust radius below {MIN_RADIUS:g}"
                break
            continue
        gain = 1.0 - cand.gamma / history[-1]
        best, res, rho = new, cand, min(0.5, 2.0 * rho)
        history.append(float(cand.gamma))
        if gain < tol:
            reason = f"relative improvement below {tol:g}"
            break
    return best, history, f"stopped: {reason}"
