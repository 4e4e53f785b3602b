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
import time
from typing import Any

import numpy as np

from ..analysis.closedloop import gain_loop
from ..analysis.conic import Columns, ConicProblem, Rows, affine_bmat, evaluate, local_variables, unit_rows
from ..analysis.lmi import block_specs, dilated_block, xy_block
from ..model.system import FTCSystem, Matrix
from .results import SolverCalls
from .starts import certify_start
from .xy_design import gain_bound_block, xy_solve

__all__ = ["TAU_GRID", "GOLDEN_STEPS", "dilated_problem", "dilated_solve", "dilated_design", "convex_gains", "true_mode_reference", "reference_row",
           "reference_alone"]

#: Line-search grid of the dilation scalar, in units of ``1/rho`` (module docstring).
TAU_GRID = (1e-3, 1e-2, 1e-1, 1.0, 10.0)
#: Golden-section steps on ``log tau`` after the grid.
GOLDEN_STEPS = 4


def _dilated_columns(system: FTCSystem, k_max: float | None) -> Columns:
    """Columns of the dilated program: ``X_s`` (``svec``) per joint state, ``G_j`` and
    ``Y_j`` (row by row) per FDI mode, ``g``, ``mu`` (with ``k_max``), ``eps_s``, ``delta_s``."""
    n, nu = system.dims[0], system.dims[1]
    S, m = system.chain.n_states, system.m
    cols = Columns()
    cols.add("X", S, n * (n + 1) // 2)
    cols.add("G", m, n * n)
    cols.add("Y", m, nu * n)
    cols.add("g", 1, 1)
    cols.add("mu", 1 if k_max is not None else 0, 1)
    cols.add("eps", S, 1)
    cols.add("delta", S, 1)
    return cols


def dilated_problem(system: FTCSystem, k_max: float | None, tau: float) -> tuple[ConicProblem, Columns, Matrix]:
    r"""The dilated blocks at one ``tau`` in conic form (:mod:`ftc_verify.analysis.conic`,
    each block on its own variables): minimise ``g`` subject to every
    :func:`~ftc_verify.analysis.lmi.dilated_block` :math:`\preceq 0`, :math:`X_s \succeq 0`,
    ``g, eps, delta >= 0`` and the gain bound of the module docstring. Returns the
    program, its columns and the mask of the columns kept (the multipliers no block
    involves are left out)."""
    n, nu = system.dims[0], system.dims[1]
    S, m = system.chain.n_states, system.m
    cols = _dilated_columns(system, k_max)
    rows = Rows(cols.K)
    for s in range(S):
        (Xs,), at = local_variables([("sym", cols.at("X", s), (n,))])
        rows.lmi(-Xs, at)
    probe = gain_loop(system, [np.zeros((nu, n))] * m, "probe")
    for spec in block_specs(probe):
        s, j = spec.s, spec.fdi
        states = [s] + [t for t, q in enumerate(spec.q_row) if t != s and q > 0]
        pieces: list[tuple[str, int, tuple[int, ...]]] = [("sym", cols.at("X", t), (n,)) for t in states]
        pieces += [("mat", cols.at("G", j), (n, n)), ("mat", cols.at("Y", j), (nu, n))]
        pieces += [("scalar", cols.at(name, k), ()) for name, k in (("eps", s), ("delta", s), ("g", 0))]
        var, at = local_variables(pieces)
        X: list[Any] = [None] * S
        for pos, t in enumerate(states):
            X[t] = var[pos]
        G, Y, eps, dlt, g = var[len(states):]
        rows.lmi(dilated_block(system.modes[spec.true], X, G, s, Y, eps, dlt, g, spec.q_row, tau, affine_bmat), at)
    if k_max is not None:
        for j in range(m):
            (G, Y, mu), at = local_variables([("mat", cols.at("G", j), (n, n)), ("mat", cols.at("Y", j), (nu, n)),
                                              ("scalar", cols.at("mu"), ())])
            rows.lmi(2 * mu * np.eye(n) - (G + G.T), at)
            rows.lmi(-gain_bound_block(Y, k_max, mu, affine_bmat), at)
    return _min_g(rows, cols)


def _min_g(rows: Rows, cols: Columns) -> tuple[ConicProblem, Columns, Matrix]:
    """``min g`` over ``rows`` with the scalars from ``g`` on nonnegative, the columns no
    row involves left out: ``(program, cols, kept mask)``."""
    keep = rows.used()
    scalars = [k for k in range(cols.at("g"), cols.K) if keep[k]]
    rows.nonneg(unit_rows(cols.K, scalars), np.zeros(len(scalars)))
    c = np.zeros(cols.K)
    c[cols.at("g")] = 1.0
    keep[cols.at("g")] = True
    return rows.problem(c).restrict(keep), cols, keep


def _point(x: Matrix | None, keep: Matrix) -> Matrix | None:
    """The solver's point in every column of the program (``nan`` where left out)."""
    if x is None:
        return None
    full = np.full(len(keep), math.nan)
    full[keep] = x
    return full


def _matrix(x: Matrix, first: int, shape: tuple[int, int]) -> Matrix:
    return x[first:first + shape[0] * shape[1]].reshape(shape)


def dilated_solve(system: FTCSystem, k_max: float | None, tau: float, calls: Any) -> dict[str, Any] | None:
    """Minimise gamma over the dilated blocks of :func:`dilated_problem` at one ``tau``;
    ``{"gains", "gamma", "tau"}`` (one :math:`K_j = Y_j G_j^{-1}` per FDI mode) or ``None``
    when the solver gave no point."""
    problem, cols, keep = dilated_problem(system, k_max, tau)
    out, x = calls.run_conic(problem)
    x = _point(x, keep)
    if not out.solved or x is None:
        return None
    n, nu = system.dims[0], system.dims[1]
    gains = []
    for j in range(system.m):
        Gv = _matrix(x, cols.at("G", j), (n, n))
        if not np.all(np.isfinite(Gv)) or np.linalg.cond(Gv) > 1e12:
            return None
        gains.append(np.linalg.solve(Gv.T, _matrix(x, cols.at("Y", j), (nu, n)).T).T)
    return {"gains": gains, "gamma": math.sqrt(max(float(x[cols.at("g")]), 0.0)), "tau": tau}


def dilated_design(system: FTCSystem, calls: Any, k_max: float | None) -> dict[str, Any] | None:
    """The dilated design with the line search on ``tau`` of the module docstring: the
    solution of smallest synthesis gamma (``None`` when no ``tau`` gave one)."""
    rho = max([1.0] + [float(np.linalg.norm(md.A, 2)) for md in system.modes])
    found: dict[float, dict[str, Any] | None] = {}

    def at(log_tau: float) -> float:
        if log_tau not in found:
            found[log_tau] = dilated_solve(system, k_max, 10.0 ** log_tau / rho, calls)
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


def convex_gains(system: FTCSystem, method: str, calls: SolverCalls,
                 k_max: float | None) -> tuple[list[Matrix] | None, float | None, str]:
    """The FDI-mode gains of the ``common-fdi`` or ``dilated`` design: ``(gains, gamma, message)``.
    A failure says ``infeasible`` only when the solver said so (for ``dilated``: at every
    ``tau`` of the line search); otherwise :meth:`.SolverCalls.unsolved` of the last call."""
    if method == "dilated":
        before = len(calls.outcomes)
        sol = dilated_design(system, calls, k_max)
        if sol is None:
            tried = calls.outcomes[before:]
            if tried and all(o.infeasible for o in tried):
                return None, None, "dilated LMI infeasible for every tau of the line search"
            said = sum(o.infeasible for o in tried)
            return None, None, (f"dilated LMI not solved for any tau of the line search ({said} of {len(tried)} "
                                f"calls infeasible; the last {calls.unsolved() if tried else 'not made'})")
        return list(sol["gains"]), float(sol["gamma"]), f"dilated LMI solved at gamma {sol['gamma']:.6g} (tau " \
            f"{sol['tau']:.3g})"
    xy = xy_solve(system, "common-fdi", None, calls, k_max)
    if xy is None:
        return None, None, f"common-fdi LMI {calls.unsolved()}"
    Ks = [Y @ np.linalg.inv(X) for X, Y in zip(xy["X"], xy["Y"])]
    return [Ks[system.chain.state_index(j, j)] for j in range(system.m)], float(xy["gamma"]), \
        f"common-fdi LMI solved at gamma {xy['gamma']:.6g}"


def true_mode_reference(system: FTCSystem, calls: Any) -> dict[str, Any] | None:
    """The true-mode (classical MJLS) design of the module docstring: ``{"gamma", "gains"}``
    with one gain per true mode, or ``None`` when the LMI gave no point."""
    n, nu, m = system.dims[0], system.dims[1], system.m
    cols = Columns()
    cols.add("X", m, n * (n + 1) // 2)
    cols.add("Y", m, nu * n)
    cols.add("g", 1, 1)
    cols.add("eps", m, 1)
    cols.add("delta", m, 1)
    rows = Rows(cols.K)
    alpha = np.asarray(system.chain.alpha, dtype=float)
    for i, md in enumerate(system.modes):
        (Xi,), at = local_variables([("sym", cols.at("X", i), (n,))])
        rows.lmi(-Xi, at)
        states = [i] + [t for t, q in enumerate(alpha[i]) if t != i and q > 0]
        pieces: list[tuple[str, int, tuple[int, ...]]] = [("sym", cols.at("X", t), (n,)) for t in states]
        pieces += [("mat", cols.at("Y", i), (nu, n))]
        pieces += [("scalar", cols.at(name, k), ()) for name, k in (("eps", i), ("delta", i), ("g", 0))]
        var, at = local_variables(pieces)
        X: list[Any] = [None] * m
        for pos, t in enumerate(states):
            X[t] = var[pos]
        Y, eps, dlt, g = var[len(states):]
        rows.lmi(xy_block(md, X, i, Y, eps, dlt, g, alpha[i], affine_bmat), at)
    problem, cols, keep = _min_g(rows, cols)
    out, x = calls.run_conic(problem)
    x = _point(x, keep)
    if not out.solved or x is None:
        return None
    gains: list[Matrix] = []
    for i in range(m):
        (Xi,), _ = local_variables([("sym", 0, (n,))])
        Xv = evaluate(Xi, x[cols.at("X", i):cols.at("X", i) + n * (n + 1) // 2])
        gains.append(_matrix(x, cols.at("Y", i), (nu, n)) @ np.linalg.inv(Xv))
    return {"gamma": math.sqrt(max(float(x[cols.at("g")]), 0.0)), "gains": gains}


def reference_row(system: FTCSystem, solver: str, calls: SolverCalls) -> dict[str, Any]:
    """The reference line of ``best``: :func:`true_mode_reference`
    and the certified robust gamma of its gains (``K_(i,j) = K_i``) on the joint chain."""
    t0 = time.perf_counter()
    ref = true_mode_reference(system, calls)
    out: dict[str, Any] = {"name": "true-mode MJLS design (reference, not a bound)", "lmi_gamma": None,
                           "gamma_certified": None, "reason": "LMI gave no point"}
    if ref is not None:
        table = [ref["gains"][i] for i in range(system.m) for _ in range(system.m)]
        row = certify_start(system, "reference", table, solver)
        calls.outcomes.extend(row.get("attempts", ()))
        out |= {"lmi_gamma": ref["gamma"], "gamma_certified": row["gamma_certified"], "reason": row["reason"],
                "max_gain_norm": max(float(np.linalg.norm(K, 2)) for K in ref["gains"])}
    return out | {"seconds": time.perf_counter() - t0}


def reference_alone(system: FTCSystem, solver: str) -> tuple[dict[str, Any], list[Any]]:
    """:func:`reference_row` with calls of its own: ``(row, solver outcomes)``. ``best`` runs it
    in a forked child beside its routes (:class:`~ftc_verify.analysis.solvers.ForkedCall`:
    the same computation on the second core; its outcomes are added to the run's)."""
    calls = SolverCalls(solver)
    return reference_row(system, solver, calls), calls.outcomes
