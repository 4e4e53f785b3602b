r"""Convex state-feedback designs of the literature: the dilated LMI and the true-mode reference.

``dilated`` (:func:`dilated_design`)
    The S-variable (dilated) form of Lemma 4.1, :func:`~ftc_verify.analysis.lmi.dilated_block`
    (derived there from :func:`~ftc_verify.analysis.lmi.xy_block` by Finsler's lemma, the
    de Oliveira--Skelton / Shaked construction): one Lyapunov matrix :math:`X_s` per joint
    state ``s`` (true mode, FDI mode and phase), one slack :math:`G_j` and one :math:`Y_j` per
    FDI mode ``j``, and the gain :math:`K_j = Y_j G_j^{-1}` -- the detector-based structure
    (Costa, Fragoso, Todorov): the gain uses the FDI mode only, the Lyapunov function the
    whole joint state. For a fixed scalar :math:`\tau > 0` the blocks are linear; gamma is
    minimised by a line search on :math:`\log \tau`: a grid :data:`TAU_GRID` times
    :math:`1/\rho`, :math:`\rho = \max(1, \max_i \|A_i\|_2)` (the time scale of the plant),
    then :data:`GOLDEN_STEPS` golden-section steps around the best grid point. With
    ``G_j = X_{(i,j)}`` the block is :func:`~ftc_verify.analysis.lmi.xy_block`, so every
    common-``X``-per-FDI-mode design is feasible here for a small enough :math:`\tau`.
``gain bound``
    :math:`\|K_j\|_2 \le k_{max}` follows from :math:`G_j + G_j^T \succeq 2\mu I` and
    :math:`\|Y_j\|_2 \le k_{max}\mu`: for a unit :math:`v`,
    :math:`\|G_j v\| \ge v^T G_j v \ge \mu`, so :math:`\|G_j^{-1}\|_2 \le 1/\mu` and
    :math:`\|K_j\| \le \|Y_j\|\,\|G_j^{-1}\| \le k_{max}`.
``reference`` (:func:`true_mode_reference`)
    The classical mode-dependent design of a Markov jump linear system: gains :math:`K_i`
    that see the *true* mode :math:`r_t` at once, the fault chain's generator :math:`\alpha`
    alone (no FDI), :func:`~ftc_verify.analysis.lmi.xy_block` with one :math:`X_i, Y_i` per
    true mode and the row :math:`\alpha_i` (Costa--Fragoso--Todorov's state-feedback
    :math:`H_\infty` LMI, with the uncertainty's scaled multipliers), no gain bound.
    It is a *reference*, not a bound: an FDI-only controller reacts late, but the FDI-only
    loop is a different random system (the paper's faults wait for the detection), so its
    gamma may lie on either side. Its gains (:math:`K_{(i,j)} = K_i`) are also certified
    on the joint chain by the core analysis, reported beside the LMI value.

Nothing here certifies an FDI-only result: the caller hands the gains to the core analysis.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..analysis.closedloop import gain_loop
from ..analysis.lmi import block_specs, dilated_block, xy_block
from ..model.system import FTCSystem, Matrix
from .xy_design import gain_bound

__all__ = ["TAU_GRID", "GOLDEN_STEPS", "dilated_problem", "dilated_solve", "dilated_design", "true_mode_reference"]

#: Line-search grid of the dilation scalar, in units of ``1/rho`` (module docstring).
TAU_GRID = (1e-3, 1e-2, 1e-1, 1.0, 10.0)
#: Golden-section steps on ``log tau`` after the grid.
GOLDEN_STEPS = 4


def dilated_problem(system: FTCSystem, k_max: float | None) -> tuple[Any, Any, dict[str, list[Any]]]:
    """The dilated blocks with ``tau`` a cvxpy parameter (compiled once, solved per ``tau``):
    ``(problem minimising g, tau, variables)``."""
    import cvxpy as cp

    n, nu = system.dims[0], system.dims[1]
    S, m = system.chain.n_states, system.m
    X = [cp.Variable((n, n), symmetric=True) for _ in range(S)]
    G = [cp.Variable((n, n)) for _ in range(m)]
    Y = [cp.Variable((nu, n)) for _ in range(m)]
    eps = [cp.Variable(nonneg=True) for _ in range(S)]
    dlt = [cp.Variable(nonneg=True) for _ in range(S)]
    g = cp.Variable(nonneg=True)
    tau = cp.Parameter(pos=True)
    cons = [x >> 0 for x in X]
    probe = gain_loop(system, [np.zeros((nu, n))] * m, "probe")
    for spec in block_specs(probe):
        M = dilated_block(system.modes[spec.true], X, G[spec.fdi], spec.s, Y[spec.fdi], eps[spec.s], dlt[spec.s], g,
                          spec.q_row, tau, cp.bmat)
        cons.append(0.5 * (M + M.T) << 0)
    if k_max is not None:
        mu = cp.Variable(nonneg=True)
        for Gj, Yj in zip(G, Y):
            cons += [Gj + Gj.T >> 2 * mu * np.eye(n), gain_bound(Yj, k_max, mu)]
    return cp.Problem(cp.Minimize(g), cons), tau, {"G": G, "Y": Y, "g": [g]}


def dilated_solve(problem: tuple[Any, Any, dict[str, list[Any]]], tau: float, calls: Any) -> dict[str, Any] | None:
    """Minimise gamma over the dilated blocks of :func:`dilated_problem` at one ``tau``;
    ``{"gains", "gamma", "tau"}`` (one :math:`K_j = Y_j G_j^{-1}` per FDI mode) or ``None``
    when the solver gave no point."""
    prob, tau_par, var = problem
    tau_par.value = tau
    out = calls.run(prob)
    g = var["g"][0]
    if not out.solved or g.value is None or any(v.value is None for v in var["G"] + var["Y"]):
        return None
    gains = []
    for Gj, Yj in zip(var["G"], var["Y"]):
        Gv = np.array(Gj.value)
        if not np.all(np.isfinite(Gv)) or np.linalg.cond(Gv) > 1e12:
            return None
        gains.append(np.linalg.solve(Gv.T, np.array(Yj.value).T).T)
    return {"gains": gains, "gamma": math.sqrt(max(float(g.value), 0.0)), "tau": tau}


def dilated_design(system: FTCSystem, calls: Any, k_max: float | None) -> dict[str, Any] | None:
    """The dilated design with the line search on ``tau`` of the module docstring: the
    solution of smallest synthesis gamma (``None`` when no ``tau`` gave one)."""
    rho = max([1.0] + [float(np.linalg.norm(md.A, 2)) for md in system.modes])
    problem = dilated_problem(system, k_max)
    found: dict[float, dict[str, Any] | None] = {}

    def at(log_tau: float) -> float:
        if log_tau not in found:
            found[log_tau] = dilated_solve(problem, 10.0 ** log_tau / rho, calls)
        sol = found[log_tau]
        return math.inf if sol is None else float(sol["gamma"])

    grid = [math.log10(t) for t in TAU_GRID]
    values = [at(x) for x in grid]
    k = int(np.argmin(values))
    if math.isfinite(values[k]):
        lo, hi = grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]
        ratio = (math.sqrt(5.0) - 1.0) / 2.0
        a, b = hi - ratio * (hi - lo), lo + ratio * (hi - lo)
        for _ in range(GOLDEN_STEPS):
            if at(a) <= at(b):
                hi, b = b, a
                a = hi - ratio * (hi - lo)
            else:
                lo, a = a, b
                b = lo + ratio * (hi - lo)
    sols = [s for s in found.values() if s is not None]
    return min(sols, key=lambda s: s["gamma"]) if sols else None


def true_mode_reference(system: FTCSystem, calls: Any) -> dict[str, Any] | None:
    """The true-mode (classical MJLS) design of the module docstring: ``{"gamma", "gains"}``
    with one gain per true mode, or ``None`` when the LMI gave no point."""
    import cvxpy as cp

    n, nu, m = system.dims[0], system.dims[1], system.m
    X = [cp.Variable((n, n), symmetric=True) for _ in range(m)]
    Y = [cp.Variable((nu, n)) for _ in range(m)]
    eps = [cp.Variable(nonneg=True) for _ in range(m)]
    dlt = [cp.Variable(nonneg=True) for _ in range(m)]
    g = cp.Variable(nonneg=True)
    cons = [x >> 0 for x in X]
    alpha = np.asarray(system.chain.alpha, dtype=float)
    for i, md in enumerate(system.modes):
        M = xy_block(md, X, i, Y[i], eps[i], dlt[i], g, alpha[i], cp.bmat)
        cons.append(0.5 * (M + M.T) << 0)
    out = calls.run(cp.Problem(cp.Minimize(g), cons))
    if not out.solved or g.value is None or any(v.value is None for v in X + Y):
        return None
    gains: list[Matrix] = [np.array(Yi.value) @ np.linalg.inv(np.array(Xi.value)) for Xi, Yi in zip(X, Y)]
    return {"gamma": math.sqrt(max(float(g.value), 0.0)), "gains": gains}
