r"""The paper's Theorem 5.1 by cone complementarity linearisation (the ``ccl`` method of
:mod:`ftc_verify.synthesis.output_feedback`), in conic form.

The conditions (:func:`ccl_blocks`) are the blocks of :mod:`ftc_verify.analysis.lmi`
(:func:`~ftc_verify.analysis.lmi.lyapunov_block`, :func:`~ftc_verify.analysis.lmi.xy_block`)
evaluated on :class:`~ftc_verify.analysis.conic.Affine` matrices, each on its own
variables, and handed to the solver as one conic program per gamma
(:meth:`~ftc_verify.synthesis.results.SolverCalls.run_conic`): the linearised objective of
every iteration is a new cost vector on the same rows (:math:`\operatorname{tr}(P_k X) =
\operatorname{svec}(P_k)^T \operatorname{svec}(X)`), so nothing is rebuilt per iteration
(the former cvxpy formulation spent most of a call in its canonicalisation).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.linalg

from ..analysis.closedloop import gain_loop
from ..analysis.conic import Columns, Rows, affine_bmat, evaluate, local_variables, svec_index, unit_rows
from ..analysis.lmi import BlockSpec, block_specs, lyapunov_block, projection, xy_block
from ..model.system import FTCSystem, Matrix
from .of_blocks import augmented_system
from .results import SolverCalls
from .state_feedback import gain_step
from .xy_design import posed_level, scaled_disturbance

__all__ = ["CCL_MAX_ITER", "CCL_TOL", "ccl_blocks", "ccl_spec_blocks", "ccl_state_blocks", "ccl"]

#: Iteration limit of the cone complementarity linearisation.
CCL_MAX_ITER = 30
#: CCL stops when ``sum(trace(P X)) - n_total + sum(lam eps - 1)`` is below this times
#: ``n_total`` (and a controller step at those ``P`` is tried after every iteration).
CCL_TOL = 1e-6


def ccl_blocks(aug: FTCSystem, cbars: list[Matrix], P: list[Any], X: list[Any], lam: list[list[Any]],
               eps: list[list[Any]], g: float, margin: float, bmat: Any) -> list[Any]:
    r"""The two conditions of Theorem 5.1, re-derived for the augmented plant, and the
    complementarity cones: the matrices that must be positive semidefinite, built with
    ``bmat`` (``numpy.block`` on numbers, :func:`~ftc_verify.analysis.conic.affine_bmat` on
    :class:`~ftc_verify.analysis.conic.Affine`), per rate vertex (:func:`ccl_spec_blocks`)
    and per joint state (:func:`ccl_state_blocks`).

    The Lemma 4.1 block of the loop (Schur form in the channel outputs,
    :func:`~ftc_verify.analysis.lmi.lyapunov_block` with ``schur_F=True``) is
    :math:`M_0 + U^T \mathcal K_j V + V^T \mathcal K_j^T U` with
    :math:`V = [\bar C_i \; 0 \cdots 0]`: the controller enters through
    :math:`P \bar B_{0i} \mathcal K_j \bar C_i` and the channel output
    :math:`\bar B_{2i} \mathcal K_j \bar C_i`. By the projection lemma a :math:`\mathcal K_j`
    exists for this one block iff

    * eq. (22): :math:`N_V^T M_0 N_V < 0`, :math:`N_V = \operatorname{diag}(W_{3i}, I)`,
      :math:`W_{3i}` a basis of :math:`\ker \bar C_i` (``Cbar`` built with ``Cy``); by a
      Schur complement on the channel rows this is the plain Lemma 4.1 block of the
      open augmented loop (:math:`\lambda_k F_k^T F_k` in the corner, linear in
      :math:`P, \lambda`), projected;
    * eq. (23): the same block after the congruence with :math:`X = P^{-1}` and projected
      onto :math:`\ker [\bar B_{0i}^T \; \bar B_{2i}^T]`: exactly step 1 of the
      state-feedback Theorem 4.1 for the augmented plant (:func:`xy_block` and
      :func:`projection`), linear in :math:`X, \varepsilon`.

    Slips corrected against the printed (21)-(23) (READING-NOTES): the missing ``+``
    before :math:`\bar C_{1i}^T \bar C_{1i}` in (21); the coupling in (23) is
    :math:`X(\sum_{s'} q_{ss'} P_{s'})X`, written with Schur complements in
    :math:`X_{s'}` (the printed :math:`M_{6ij}` keeps only the diagonal rate); the
    measured output is ``Cy`` (the paper uses ``C`` for both). The two conditions are only
    necessary for one :math:`\mathcal K_j` serving every true mode ``i``; the controller
    step decides. Cones: :math:`[[P_s, I], [I, X_s]] \ge 0` and
    :math:`[[\lambda, 1], [1, \varepsilon]] \ge 0` per channel, so that the linearised
    objective's minimum :math:`\operatorname{tr}(P X) = n`, :math:`\lambda\varepsilon = 1`
    means :math:`X = P^{-1}`, :math:`\varepsilon = \lambda^{-1}`.
    """
    loop0 = gain_loop(aug, [np.zeros(aug.modes[0].B.T.shape)] * (aug.m * aug.m), "open augmented loop")
    out: list[Any] = []
    for spec in block_specs(loop0):
        out += ccl_spec_blocks(aug, cbars, loop0, spec, P, X, lam[spec.s], eps[spec.s], g, margin, bmat)
    for s in range(aug.chain.n_states):
        out += ccl_state_blocks(P[s], X[s], lam[s], eps[s], margin, bmat)
    return out


def ccl_spec_blocks(aug: FTCSystem, cbars: list[Matrix], loop0: Any, spec: BlockSpec, P: list[Any], X: list[Any],
                    lam_s: list[Any], eps_s: list[Any], g: float, margin: float, bmat: Any) -> list[Any]:
    """Eq. (22) and eq. (23) of ``spec`` (:func:`ccl_blocks`) as matrices that must be
    positive semidefinite (``- margin I`` included); ``P``, ``X`` need the joint states the
    block couples, ``loop0`` is the open augmented loop."""
    i, s = spec.true, spec.s
    M = lyapunov_block(loop0, spec, P, lam_s, g, bmat)
    W3 = scipy.linalg.null_space(cbars[i])
    N = scipy.linalg.block_diag(W3, np.eye(M.shape[0] - W3.shape[0]))
    out = [-(N.T @ M @ N) - margin * np.eye(N.shape[1])]
    mode = aug.modes[i]
    ch_eps = list(eps_s)
    e_a = ch_eps.pop(0) if mode.A1 is not None else None
    e_b = ch_eps.pop(0) if mode.B1 is not None else None
    Mx = xy_block(mode, X, s, None, e_a, e_b, g, spec.q_row, bmat)
    Nx = projection(mode, sum(1 for k, q in enumerate(spec.q_row) if k != s and q > 0))
    if Nx.shape[1]:
        out.append(-(Nx.T @ Mx @ Nx) - margin * np.eye(Nx.shape[1]))
    return out


def ccl_state_blocks(P_s: Any, X_s: Any, lam_s: list[Any], eps_s: list[Any], margin: float, bmat: Any) -> list[Any]:
    r"""The cones of one joint state (:func:`ccl_blocks`): :math:`[[P_s, I], [I, X_s]]`,
    :math:`X_s - \text{margin} I` and :math:`[[\lambda, 1], [1, \varepsilon]]` per channel,
    each positive semidefinite."""
    nb = P_s.shape[0]
    one = np.ones((1, 1))
    out = [bmat([[P_s, np.eye(nb)], [np.eye(nb), X_s]]), X_s - margin * np.eye(nb)]
    for la, ep in zip(lam_s, eps_s):
        out.append(bmat([[la * one, one], [one, ep * one]]))
    return out


def _channel_count(aug: FTCSystem, i: int) -> int:
    md = aug.modes[i]
    return int(md.A1 is not None) + int(md.B1 is not None)


def _ccl_rows(aug: FTCSystem, cbars: list[Matrix], cols: Columns, chans: list[int], g: float,
              margin: float) -> Rows:
    """The rows of :func:`ccl_blocks` on the columns ``cols`` (``P_s``, ``X_s`` in ``svec``
    per joint state, then every ``lambda``, every ``eps``), each block on its own variables,
    and ``lambda, eps >= 0``."""
    nb = aug.dims[0]
    S = aug.chain.n_states
    first = np.concatenate([[0], np.cumsum(chans)]).astype(int)
    rows = Rows(cols.K)
    loop0 = gain_loop(aug, [np.zeros(aug.modes[0].B.T.shape)] * (aug.m * aug.m), "open augmented loop")
    for spec in block_specs(loop0):
        s = spec.s
        states = [s] + [t for t, q in enumerate(spec.q_row) if t != s and q != 0.0]
        pieces: list[tuple[str, int, tuple[int, ...]]] = [("sym", cols.at("P", t), (nb,)) for t in states]
        pieces += [("sym", cols.at("X", t), (nb,)) for t in states]
        pieces += [("scalar", cols.at("lam", first[s] + k), ()) for k in range(chans[s])]
        pieces += [("scalar", cols.at("eps", first[s] + k), ()) for k in range(chans[s])]
        var, at = local_variables(pieces)
        P: list[Any] = [None] * S
        X: list[Any] = [None] * S
        for pos, t in enumerate(states):
            P[t], X[t] = var[pos], var[len(states) + pos]
        lam_s = var[2 * len(states):2 * len(states) + chans[s]]
        for M in ccl_spec_blocks(aug, cbars, loop0, spec, P, X, lam_s, var[2 * len(states) + chans[s]:], g, margin,
                                 affine_bmat):
            rows.lmi(-M, at)
    for s in range(S):
        pieces = [("sym", cols.at("P", s), (nb,)), ("sym", cols.at("X", s), (nb,))]
        pieces += [("scalar", cols.at(name, first[s] + k), ()) for name in ("lam", "eps") for k in range(chans[s])]
        var, at = local_variables(pieces)
        for M in ccl_state_blocks(var[0], var[1], var[2:2 + chans[s]], var[2 + chans[s]:], margin, affine_bmat):
            rows.lmi(-M, at)
    total = int(first[-1])
    rows.nonneg(unit_rows(cols.K, range(cols.at("lam"), cols.K)), np.zeros(2 * total))
    return rows


def ccl(system: FTCSystem, gamma: float, calls: SolverCalls, k_max: float | None, *, max_iter: int = CCL_MAX_ITER,
        tol: float = CCL_TOL, start: tuple[Any, Any] | None = None,
        ) -> tuple[list[Matrix] | None, list[float], str, float | None]:
    r"""Theorem 5.1 at ``gamma`` by cone complementarity linearisation (module docstring):
    ``(controller blocks or None, residual history, message, the controller step's gamma)``.

    The first linearisation point is the minimum of :math:`\sum \operatorname{tr}(P + X) +
    \sum(\lambda + \varepsilon)` under the constraints, or ``start = (P, lambda)``, the
    certificate of a certified controller (with :math:`X = P^{-1}`,
    :math:`\varepsilon = \lambda^{-1}`: a warm start from a design known to work at a higher
    level). Each iteration minimises :math:`\sum \operatorname{tr}(P_k X + X_k P) +
    \lambda_k \varepsilon + \varepsilon_k \lambda` at the last point. After each point the
    controller step is tried with its ``P`` and multipliers; the first success at ``gamma``
    ends the run. Stopping rule: the residual :math:`\sum_s \operatorname{tr}(P_s X_s) -
    \bar n S + \sum(\lambda \varepsilon - 1) \ge 0` of an iterate below ``tol`` times
    :math:`\bar n S` (the conditions hold with :math:`X = P^{-1}`, yet no controller fits),
    a solver failure, or ``max_iter``."""
    aug, cbars = augmented_system(system)
    nb = aug.dims[0]
    S = aug.chain.n_states  # one P_s, X_s per joint state
    chans = [_channel_count(aug, i) for i, _ in aug.chain.joint_modes]
    total = sum(chans)
    cols = Columns()
    cols.add("P", S, nb * (nb + 1) // 2)
    cols.add("X", S, nb * (nb + 1) // 2)
    cols.add("lam", total, 1)
    cols.add("eps", total, 1)
    scale, g = posed_level(gamma)  # the blocks at D / scale, g <= 1: no entry grows with gamma
    rows = _ccl_rows(scaled_disturbance(aug, scale), cbars, cols, chans, g, 1e-7)
    (sym,), _ = local_variables([("sym", 0, (nb,))])
    r, c, w = svec_index(nb)
    width = nb * (nb + 1) // 2

    def current(x: Matrix) -> tuple[list[Matrix], list[Matrix], list[list[float]], list[float]]:
        def mat(name: str, s: int) -> Matrix:
            return evaluate(sym, x[cols.at(name, s):cols.at(name, s) + width])

        lam_flat = [float(v) for v in x[cols.at("lam"):cols.at("lam") + total]]
        lam = [lam_flat[a:a + k] for a, k in zip(np.cumsum([0] + chans[:-1]), chans)]
        return ([mat("P", s) for s in range(S)], [mat("X", s) for s in range(S)], lam,
                [float(v) for v in x[cols.at("eps"):cols.at("eps") + total]])

    def svec(M: Matrix) -> Matrix:
        return np.asarray(0.5 * (M + M.T))[r, c] * w

    if start is None:
        size = np.zeros(cols.K)  # sum tr(P) + tr(X) + lambda + eps
        for s in range(S):
            for name in ("P", "X"):
                size[cols.at(name, s) + np.flatnonzero(r == c)] = 1.0
        size[cols.at("lam"):] = 1.0
        out, x = calls.run_conic(rows.problem(size))
        if not out.solved or x is None:
            msg = f"Theorem 5.1 conditions {calls.unsolved()} at gamma {gamma:.6g}"
            return None, [], msg, None
        point = current(x)
    else:
        P0 = [0.5 * (np.asarray(p) + np.asarray(p).T) for p in start[0]]
        lam0 = [list(map(float, r_)) for r_ in start[1]]
        X0 = [np.linalg.inv(p) for p in P0]
        point = (P0, [0.5 * (x_ + x_.T) for x_ in X0], lam0, [1.0 / v for r_ in lam0 for v in r_])
    history: list[float] = []
    for k in range(max_iter):
        Pv, Xv, lv, ev = point
        flat_l = [v for r_ in lv for v in r_]
        residual = float(sum(np.trace(p @ x_) for p, x_ in zip(Pv, Xv)) - nb * S
                         + sum(a * b - 1.0 for a, b in zip(flat_l, ev)))
        history.append(residual)
        blocks, reached = _controller_step(aug, cbars, Pv, lv, gamma, calls, k_max)
        if blocks is not None:
            return blocks, history, f"CCL: controller step succeeded after {len(history)} point(s)", reached
        if residual <= tol * nb * S and (start is None or k > 0):
            return None, history, (f"CCL converged (residual {residual:.3g}) but the controller step failed at "
                                   f"gamma {gamma:.6g}: the necessary conditions hold, one controller per FDI mode "
                                   "does not fit every true mode"), None
        # the linearised objective sum tr(P_k X + X_k P) + lambda_k eps + eps_k lambda
        lin = np.zeros(cols.K)
        for s in range(S):
            lin[cols.at("X", s):cols.at("X", s) + width] = svec(Pv[s])
            lin[cols.at("P", s):cols.at("P", s) + width] = svec(Xv[s])
        lin[cols.at("eps"):cols.at("eps") + total] = np.maximum(flat_l, 0.0)
        lin[cols.at("lam"):cols.at("lam") + total] = np.maximum(ev, 0.0)
        out, x = calls.run_conic(rows.problem(lin))
        if not out.solved or x is None:
            return None, history, (f"CCL iteration {len(history)} {calls.unsolved()} (residual "
                                   f"{history[-1]:.3g} before it)"), None
        point = current(x)
    return None, history, f"CCL: iteration limit {max_iter} reached (residual {history[-1]:.3g})", None


def _controller_step(aug: FTCSystem, cbars: list[Matrix], P: list[Matrix], lam: list[list[float]],
                     gamma: float, calls: SolverCalls, k_max: float | None) -> tuple[list[Matrix] | None, float | None]:
    """Controller blocks ``K_j`` with ``P`` and the multipliers fixed, each reaching
    ``gamma`` over every true mode and ``beta`` end, and the largest gamma they reach."""
    blocks, worst = [], 0.0
    for j in range(aug.m):
        K, gj, _ = gain_step(aug, P, lam, j, calls, k_max, measurement=cbars)
        if K is None or gj is None or gj > gamma * (1 + 1e-6):
            return None, None
        blocks.append(K)
        worst = max(worst, gj)
    return blocks, worst
