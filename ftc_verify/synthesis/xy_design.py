r"""The :math:`(X, Y)` design LMIs of state-feedback synthesis (:func:`xy_solve`).

Step 1 of the paper's Theorem 4.1 (the projected inequality), the full-information and
the common-``X`` designs: :func:`~ftc_verify.analysis.lmi.xy_block` in
:math:`X_s = P_s^{-1}`, :math:`Y_s = K X_s` at every joint state ``s`` of the chain of
:mod:`ftc_verify.model.chain` and every vertex of the rates in its generator row
(:func:`~ftc_verify.analysis.lmi.block_specs`), so the same blocks as the analysis
cover the whole rate box. Which states share a variable is ``_variable_groups``.
Used by :mod:`ftc_verify.synthesis.state_feedback`, which documents the methods.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from ..analysis.closedloop import gain_loop
from ..analysis.lmi import block_specs, projection, xy_block
from ..analysis.lmi_analysis import GAMMA_LADDER
from ..model.system import FTCSystem

__all__ = ["MARGIN_TOL", "CENTRE_WEIGHT", "gain_bound", "xy_solve", "xy_solver"]

#: An (X, Y) problem counts as strictly feasible when its maximised margin exceeds this
#: (a heuristic only: every result is certified by the core analysis afterwards).
MARGIN_TOL = 1e-10
#: Weight of the size penalty that keeps the capped-margin (X, Y) problems bounded.
CENTRE_WEIGHT = 1e-6


def gain_bound(K: Any, k_max: float, mu: Any = 1.0) -> Any:
    r"""``||K||_2 <= k_max * mu`` as the LMI :math:`[[\mu I, K^T/k], [K/k, \mu I]] \succeq 0`.

    Dividing ``K`` by the bound (rather than writing ``k I`` on the diagonal) keeps the
    problem scaled: a huge bound such as ``1e300`` becomes a vanishing coupling, i.e. no
    bound, instead of a diagonal that swamps every other entry of the LMI.
    """
    nu, n = K.shape
    import cvxpy as cp

    return cp.bmat([[mu * np.eye(n), K.T / k_max], [K / k_max, mu * np.eye(nu)]]) >> 0


def _variable_groups(system: FTCSystem, kind: str) -> list[int]:
    """Which ``X`` (and ``Y``) variable each joint state uses in :func:`xy_solve`: one for
    all (``common``); one per pair ``(true, fdi)``, index ``true * m + fdi``, shared by the
    pair's detection phases (``full-info``: the gain :math:`K = Y X^{-1}` of a pair is then
    one matrix, as a full-information controller needs); one per state (``projected``:
    step 2 takes :math:`P_s = X_s^{-1}` per state); one per FDI mode (``common-fdi``:
    :math:`X_{(i, j)} = X_j`, :math:`Y_j = K_j X_j`, so :math:`K_j = Y_j X_j^{-1}` is an
    FDI-mode gain exactly; the coupling between states of one FDI mode becomes
    :math:`q_{ss'} X_j X_j^{-1} X_j = q_{ss'} X_j`, still written by :func:`xy_block`'s
    Schur column)."""
    chain = system.chain
    if kind == "common":
        return [0] * chain.n_states
    if kind == "common-fdi":
        return [j for _, j in chain.joint_modes]
    if kind == "full-info":
        return [i * system.m + j for i, j in chain.joint_modes]
    return list(range(chain.n_states))


def _xy_variables(system: FTCSystem, kind: str) -> tuple[list[Any], list[Any]]:
    """``X`` and ``Y`` (``None`` for ``projected``) of every joint state, one cvxpy variable
    per group of ``_variable_groups`` (all ``X`` created first, then all ``Y``)."""
    import cvxpy as cp

    n, nu = system.dims[0], system.dims[1]
    group = _variable_groups(system, kind)
    Xg = [cp.Variable((n, n), symmetric=True) for _ in range(max(group) + 1)]
    Yg = [None] * len(Xg) if kind == "projected" else [cp.Variable((nu, n)) for _ in Xg]
    return [Xg[k] for k in group], [Yg[k] for k in group]


def xy_solve(system: FTCSystem, kind: str, gamma: float | None, calls: Any, k_max: float | None) -> dict[str, Any] | None:
    """Solve the (X, Y) inequality of :func:`~ftc_verify.analysis.lmi.xy_block` once:
    ``xy_solver(system, kind, calls, k_max)(gamma)`` (:func:`xy_solver`)."""
    return xy_solver(system, kind, calls, k_max)(gamma)


def _xy_constraints(system: FTCSystem, kind: str, variables: tuple[Any, Any, Any, Any], gval: Any, margin: Any,
                    k_max: float | None) -> list[Any]:
    """The constraints of :func:`xy_solver` at ``g = gval`` with the margin ``margin``."""
    import cvxpy as cp

    Xv, Yv, eps, dlt = variables
    n, nu = system.dims[0], system.dims[1]
    common = kind == "common"
    cons = []
    seen: set[int] = set()
    probe = gain_loop(system, [np.zeros((nu, n))] * system.m, "probe")
    for spec in block_specs(probe):
        if common and spec.true in seen:
            continue
        seen.add(spec.true)
        mode = system.modes[spec.true]
        q_row = None if common else spec.q_row
        M = xy_block(mode, Xv, spec.s, Yv[spec.s], eps[spec.s], dlt[spec.s], gval, q_row, cp.bmat)
        if kind == "projected":
            coupled = sum(1 for k, q in enumerate(spec.q_row) if k != spec.s and q > 0)
            N = projection(mode, coupled)
            if N.shape[1] == 0:
                continue
            M = N.T @ M @ N
        M = 0.5 * (M + M.T)
        cons.append(M << -margin * np.eye(M.shape[0]))
    for X in {id(x): x for x in Xv}.values():
        cons.append(X >> margin * np.eye(n))
    if k_max is not None and kind != "projected":
        mu = cp.Variable(nonneg=True)
        for X, Y in {id(x): (x, y) for x, y in zip(Xv, Yv)}.values():
            cons += [X >> mu * np.eye(n), gain_bound(Y, k_max, mu)]
    return cons


def xy_solver(system: FTCSystem, kind: str, calls: Any,
              k_max: float | None) -> Callable[[float | None], dict[str, Any] | None]:
    """The (X, Y) inequality of :func:`~ftc_verify.analysis.lmi.xy_block`, built once and
    solved at any level: a function ``gamma -> numbers`` (below).

    The centred problem is built on its first use with ``g = gamma**2`` a cvxpy
    parameter, so later levels (the bisection of ``two-step``) re-use its
    canonicalisation: the solver receives the same data as from a problem built anew at
    that level, so the answers are the same; only the building, most of a call's time,
    is saved.

    ``kind``: ``"projected"`` (step 1 of Theorem 4.1, no ``Y``; one ``X`` per joint
    state), ``"full-info"`` (one ``X, Y`` per pair ``(true, fdi)``, shared by its phases:
    ``_variable_groups``), ``"common-fdi"`` (one ``X, Y`` per FDI mode) or ``"common"`` (one ``X, Y``). The blocks are
    one per joint state and vertex of its row's rates (:func:`~ftc_verify.analysis.lmi.block_specs`); ``X``,
    ``Y`` and the multipliers are returned per joint state. With ``gamma``
    given the margin ``t`` is maximised at ``g = gamma**2``; with ``gamma=None`` gamma is
    minimised first and the problem re-centred at ``gamma* (1 + 1e-3)``. Returns the
    numbers, or ``None`` when the solver returned no point or no positive margin.
    """
    import cvxpy as cp

    S = system.chain.n_states
    n = system.dims[0]
    Xv, Yv = _xy_variables(system, kind)
    eps = [cp.Variable(nonneg=True) for _ in range(S)]
    dlt = [cp.Variable(nonneg=True) for _ in range(S)]
    g = cp.Variable(nonneg=True)
    t = cp.Variable()
    g_par = cp.Parameter(nonneg=True)

    def constraints(gval: Any, margin: Any) -> list[Any]:
        return _xy_constraints(system, kind, (Xv, Yv, eps, dlt), gval, margin, k_max)

    # The margin is capped (t <= 1) to keep the problem bounded; once the cap binds, the
    # maximiser is not unique and an interior-point method drifts to huge X, eps, delta
    # (measured: 1e5-4e6 at gamma = 10, after which step 2 failed). A small penalty on
    # trace(X) and the multipliers selects a bounded point without changing which t is reachable.
    # Only step 1 of two-step showed it; the baselines' re-centred margins on degenerate
    # plants are ~1e-7, which the penalty would swamp, so they keep the plain objective.
    objective: Any = t
    if kind == "projected":
        unique_x = list({id(x): x for x in Xv}.values())
        size = sum(cp.trace(x) for x in unique_x) / (len(unique_x) * n) + (sum(eps) + sum(dlt)) / (2 * S)
        objective = t - CENTRE_WEIGHT * size
    built: list[Any] = []

    def num(v: Any) -> float:
        return math.nan if v.value is None else float(v.value)  # unused multipliers (common X)

    def solve_at(gamma: float | None) -> dict[str, Any] | None:
        """The numbers at ``gamma`` (or minimised and re-centred: ``gamma=None``), or ``None``."""
        if gamma is None:
            out = calls.run(cp.Problem(cp.Minimize(g), constraints(g, 0.0)))
            if not out.solved or g.value is None:
                return None
            value = math.sqrt(max(float(g.value), 0.0))
            ladder = [value * (1.0 + rho) + 1e-7 for rho in GAMMA_LADDER]
        else:
            ladder = [gamma]
        if not built:
            built.append(cp.Problem(cp.Maximize(objective), constraints(g_par, t) + [t <= 1.0]))
        for level in ladder:
            g_par.value = level ** 2
            out = calls.run(built[0])
            if out.solved and t.value is not None and float(t.value) > MARGIN_TOL:
                break
        else:
            return None
        return {
            "X": [np.array(X.value) for X in Xv],
            "Y": None if kind == "projected" else [np.array(Y.value) for Y in Yv],
            "eps": [num(e) for e in eps],
            "delta": [num(d) for d in dlt],
            "gamma": level,
            "margin": float(t.value),
        }

    return solve_at
