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
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ..analysis.closedloop import gain_loop
from ..analysis.conic import ConicProblem, Rows, affine_bmat, evaluate, local_variables, svec_index, unit_rows
from ..analysis.lmi import block_specs, projection, xy_block
from ..analysis.lmi_analysis import GAMMA_LADDER
from ..model.system import FTCSystem, Matrix

__all__ = ["MARGIN_TOL", "CENTRE_WEIGHT", "gain_bound_block", "scaled_disturbance", "posed_level", "channel_multipliers",
           "xy_solve", "xy_solver"]

#: An (X, Y) problem counts as strictly feasible when its maximised margin exceeds this
#: (a heuristic only: every result is certified by the core analysis afterwards).
MARGIN_TOL = 1e-10
#: Weight of the size penalty that keeps the capped-margin (X, Y) problems bounded.
CENTRE_WEIGHT = 1e-6


def gain_bound_block(K: Any, k_max: float, mu: Any, bmat: Any) -> Any:
    r"""The matrix :math:`[[\mu I, K^T/k], [K/k, \mu I]]` whose semidefiniteness is
    :math:`\|K\|_2 \le k \mu`, built with ``bmat`` (``cvxpy.bmat``
    or :func:`~ftc_verify.analysis.conic.affine_bmat`).

    Dividing ``K`` by the bound (rather than writing ``k I`` on the diagonal) keeps the
    problem scaled: a huge bound such as ``1e300`` becomes a vanishing coupling, i.e. no
    bound, instead of a diagonal that swamps every other entry of the LMI."""
    nu, n = K.shape
    return bmat([[mu * np.eye(n), K.T / k_max], [K / k_max, mu * np.eye(nu)]])


def scaled_disturbance(system: FTCSystem, scale: float) -> FTCSystem:
    r"""``system`` with every mode's :math:`D` divided by ``scale`` :math:`= \sigma`.

    A bounded-real block at level :math:`\gamma` (:func:`~ftc_verify.analysis.lmi.xy_block`,
    :func:`~ftc_verify.analysis.lmi.lyapunov_block`: column :math:`D`, diagonal
    :math:`-g I` with :math:`g = \gamma^2`) is congruent by :math:`\operatorname{diag}(I,
    \dots, \sigma^{-1} I, \dots)` on its :math:`w` row to the same block of this system with
    :math:`g = \gamma^2 / \sigma^2`: the same ``X``, ``Y`` (``P``, ``K``) are feasible. Posed
    at :math:`\sigma = \gamma`, ``g = 1``, no entry grows with :math:`\gamma`; with
    :math:`g = \gamma^2` one does (at :math:`\gamma = 10^6` Clarabel called the feasible
    common LMI of ``examples/paper.toml`` infeasible; at :math:`10^{16}` it panicked)."""
    if scale == 1.0:
        return system
    return replace(system, modes=tuple(replace(mode, D=mode.D / scale) for mode in system.modes))


def posed_level(gamma: float) -> tuple[float, float]:
    """How every synthesis LMI poses the level ``gamma``: ``(scale, g)`` with
    ``scale = max(gamma, 1)`` (the blocks on :func:`scaled_disturbance` at ``scale``) and
    ``g = (gamma / scale)**2 <= 1`` in place of :math:`\\gamma^2`; a scale below 1 would
    enlarge :math:`D` (past the model's entry limit at tiny levels)."""
    scale = max(gamma, 1.0)
    return scale, (gamma / scale) ** 2


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


@dataclass(frozen=True)
class _XYLayout:
    """Columns of the (X, Y) program: the ``svec`` of each group's ``X``, each group's
    ``Y`` (row by row; none for ``projected``), ``g``, the margin ``t``, ``mu`` (with
    ``k_max``), then ``eps`` and ``delta`` of every joint state (last, so that dropping
    the unused ones moves no other column)."""

    n: int
    nu: int
    groups: tuple[int, ...]
    with_y: bool
    with_mu: bool

    @property
    def n_groups(self) -> int:
        return max(self.groups) + 1

    def x(self, k: int) -> int:
        return k * (self.n * (self.n + 1) // 2)

    def y(self, k: int) -> int:
        return self.n_groups * (self.n * (self.n + 1) // 2) + k * self.nu * self.n

    @property
    def g(self) -> int:
        return self.y(self.n_groups) if self.with_y else self.x(self.n_groups)

    @property
    def t(self) -> int:
        return self.g + 1

    @property
    def mu(self) -> int:
        return self.g + 2

    def eps(self, s: int) -> int:
        return self.g + 2 + self.with_mu + s

    def delta(self, s: int) -> int:
        return self.eps(len(self.groups)) + s

    @property
    def K(self) -> int:
        return self.delta(len(self.groups))


def xy_solve(system: FTCSystem, kind: str, gamma: float | None, calls: Any, k_max: float | None) -> dict[str, Any] | None:
    """Solve the (X, Y) inequality of :func:`~ftc_verify.analysis.lmi.xy_block` once:
    ``xy_solver(system, kind, calls, k_max)(gamma)`` (:func:`xy_solver`)."""
    return xy_solver(system, kind, calls, k_max)(gamma)


def _xy_rows(system: FTCSystem, kind: str, lay: _XYLayout, k_max: float | None) -> Rows:
    """The constraints of :func:`xy_solver` with ``g`` and the margin ``t`` variables:
    every block ``+ t I <= 0`` (projected for ``projected``), ``X_k >= t I``, with
    ``k_max`` ``X_k >= mu I`` and :func:`gain_bound_block` of ``Y_k`` with ``mu``. Each
    block is built on its own variables (:func:`~ftc_verify.analysis.conic.local_variables`)."""
    n, nu = lay.n, lay.nu
    common = kind == "common"
    rows = Rows(lay.K)
    seen: set[int] = set()
    probe = gain_loop(system, [np.zeros((nu, n))] * system.m, "probe")
    for spec in block_specs(probe):
        if common and spec.true in seen:
            continue
        seen.add(spec.true)
        mode = system.modes[spec.true]
        q_row = None if common else spec.q_row
        s = spec.s
        states = [s] + ([] if q_row is None else [t for t, q in enumerate(q_row) if t != s and q > 0])
        xs = list(dict.fromkeys(lay.groups[t] for t in states))
        pieces: list[tuple[str, int, tuple[int, ...]]] = [("sym", lay.x(k), (n,)) for k in xs]
        pieces += [("mat", lay.y(lay.groups[s]), (nu, n))] if lay.with_y else []
        pieces += [("scalar", col, ()) for col in (lay.eps(s), lay.delta(s), lay.g, lay.t)]
        var, columns = local_variables(pieces)
        X: list[Any] = [None] * len(lay.groups)
        for t in states:
            X[t] = var[xs.index(lay.groups[t])]
        eps, dlt, g, t_var = var[-4:]
        M = xy_block(mode, X, s, var[len(xs)] if lay.with_y else None, eps, dlt, g, q_row, affine_bmat)
        if kind == "projected":
            coupled = sum(1 for k, q in enumerate(spec.q_row) if k != s and q > 0)
            N = projection(mode, coupled)
            if N.shape[1] == 0:
                continue
            M = N.T @ M @ N
        rows.lmi(M + t_var * np.eye(M.shape[0]), columns)
    eye = np.eye(n)
    for k in range(lay.n_groups):
        (Xk, t_var), columns = local_variables([("sym", lay.x(k), (n,)), ("scalar", lay.t, ())])
        rows.lmi(t_var * eye - Xk, columns)
        if k_max is not None and lay.with_y:
            (Xk, Yk, mu), columns = local_variables([("sym", lay.x(k), (n,)), ("mat", lay.y(k), (nu, n)),
                                                     ("scalar", lay.mu, ())])
            rows.lmi(mu * eye - Xk, columns)
            rows.lmi(-gain_bound_block(Yk, k_max, mu, affine_bmat), columns)
    return rows


def _xy_objective(kind: str, lay: _XYLayout) -> Matrix:
    """The cost (minimised) of the centred problem: ``-t``, for ``projected`` plus
    ``CENTRE_WEIGHT`` times the mean of ``trace(X_k) / n`` and of the multipliers.

    The margin is capped (t <= 1) to keep the problem bounded; once the cap binds, the
    maximiser is not unique and an interior-point method drifts to huge X, eps, delta
    (measured: 1e5-4e6 at gamma = 10, after which step 2 failed). The small penalty
    selects a bounded point without changing which t is reachable. Only step 1 of
    two-step showed it; the baselines' re-centred margins on degenerate plants are
    ~1e-7, which the penalty would swamp, so they keep the plain objective."""
    objective = np.zeros(lay.K)
    objective[lay.t] = -1.0
    if kind == "projected":
        n, S = lay.n, len(lay.groups)
        r, c, _ = svec_index(n)
        diag = np.where(r == c)[0]
        for k in range(lay.n_groups):
            objective[lay.x(k) + diag] += CENTRE_WEIGHT / (lay.n_groups * n)
        for s in range(S):
            objective[[lay.eps(s), lay.delta(s)]] += CENTRE_WEIGHT / (2 * S)
    return objective


def _xy_problems(system: FTCSystem, kind: str, lay: _XYLayout, k_max: float | None, objective: Matrix,
                 scale: float) -> tuple[ConicProblem, ConicProblem, list[int]]:
    """The minimising (``min g``, ``t = 0``) and the capped-margin problem (``objective``,
    ``t <= 1``) of :func:`xy_solver` on :func:`scaled_disturbance` at ``scale``
    (:func:`_xy_rows`), the unused columns dropped; and those columns."""
    rows = _xy_rows(scaled_disturbance(system, scale), kind, lay, k_max)
    used = np.zeros(lay.K, dtype=bool)
    for block in rows.blocks:
        used[block[2].indices] = True
    unused = [col for col in range(lay.eps(0), lay.K) if not used[col] and objective[col] == 0.0]
    scalars = [col for col in range(lay.g, lay.K) if col != lay.t and col not in unused]
    rows.nonneg(unit_rows(lay.K, scalars), np.zeros(len(scalars)))  # g, mu, eps, delta >= 0

    def drop(problem: ConicProblem) -> ConicProblem:
        for col in sorted(unused, reverse=True):
            problem = problem.fix(col, 0.0)
        return problem

    e_g = np.zeros(lay.K)
    e_g[lay.g] = 1.0
    capped = drop(rows.extended(unit_rows(lay.K, [lay.t], 1.0), [1.0]).problem(objective))
    return drop(rows.problem(e_g)).fix(lay.t, 0.0), capped, unused


def channel_multipliers(system: FTCSystem, eps: list[float], delta: list[float]) -> list[list[float]]:
    """Step 2's channel multipliers from step 1's numbers (:func:`xy_solver`), per joint mode
    in the order of the closed loop's channels:
    ``lambda = 1/eps`` for the A channel, ``1/delta`` for the B channel."""
    lam = []
    for s, (i, _) in enumerate(system.chain.joint_modes):
        md, row = system.modes[i], []
        if md.A1 is not None:
            row.append(1.0 / max(eps[s], 1e-300))
        if md.B1 is not None:
            row.append(1.0 / max(delta[s], 1e-300))
        lam.append(row)
    return lam


def xy_solver(system: FTCSystem, kind: str, calls: Any,
              k_max: float | None) -> Callable[[float | None], dict[str, Any] | None]:
    """The (X, Y) inequality of :func:`~ftc_verify.analysis.lmi.xy_block`, built once and
    solved at any level: a function ``gamma -> numbers`` (below).

    The blocks are evaluated on :class:`~ftc_verify.analysis.conic.Affine` matrices with
    ``g = gamma**2`` and the margin ``t`` variables, written in conic form
    (:mod:`ftc_verify.analysis.conic`) and solved by
    :meth:`~ftc_verify.synthesis.results.SolverCalls.run_conic`; a level up to 1 fixes
    ``g`` (:meth:`~ftc_verify.analysis.conic.ConicProblem.fix`) in the construction built
    once, a level above 1 is posed on :func:`scaled_disturbance` at that level with
    ``g = 1`` (built per level, 1-3 ms): with ``g = gamma**2`` the blocks' entries grew with
    gamma, and Clarabel called feasible levels infeasible (finding 02 of the independent
    check: the common LMI of ``examples/paper.toml`` at 1e6) or panicked (1e16).

    ``kind``: ``"projected"`` (step 1 of Theorem 4.1, no ``Y``; one ``X`` per joint
    state), ``"full-info"`` (one ``X, Y`` per pair ``(true, fdi)``, shared by its phases:
    ``_variable_groups``), ``"common-fdi"`` (one ``X, Y`` per FDI mode) or ``"common"`` (one ``X, Y``). The blocks are
    one per joint state and vertex of its row's rates (:func:`~ftc_verify.analysis.lmi.block_specs`); ``X``,
    ``Y`` and the multipliers are returned per joint state (``nan`` for a multiplier no
    block uses: ``common`` writes one block per true mode). With ``gamma``
    given the margin ``t`` is maximised at that level; with ``gamma=None`` gamma is
    minimised first (``t = 0``) and the problem re-centred at ``gamma* (1 + 1e-3)``. Returns the
    numbers, or ``None`` when the solver returned no point or no positive margin.
    """
    S = system.chain.n_states
    n, nu = system.dims[0], system.dims[1]
    lay = _XYLayout(n, nu, tuple(_variable_groups(system, kind)), kind != "projected",
                    k_max is not None and kind != "projected")
    objective = _xy_objective(kind, lay)

    minimise, capped_1, unused = _xy_problems(system, kind, lay, k_max, objective, 1.0)

    def num(x: Matrix, col: int) -> float:
        return math.nan if col in unused else float(x[col])

    def at_level(level: float) -> tuple[Any, Matrix | None]:
        """The capped-margin problem at ``level``, posed by :func:`posed_level`. A build
        costs 1-3 ms (``examples/paper.toml``)."""
        scale, g = posed_level(level)
        capped = capped_1 if scale == 1.0 else _xy_problems(system, kind, lay, k_max, objective, scale)[1]
        return calls.run_conic(capped.fix(lay.g, g))

    def solve_at(gamma: float | None) -> dict[str, Any] | None:
        """The numbers at ``gamma`` (or minimised and re-centred: ``gamma=None``), or ``None``."""
        if gamma is None:
            out, x = calls.run_conic(minimise)
            if not out.solved or x is None:
                return None
            value = math.sqrt(max(float(x[lay.g]), 0.0))
            ladder = [value * (1.0 + rho) + 1e-7 for rho in GAMMA_LADDER]
        else:
            ladder = [gamma]
        for level in ladder:
            out, x = at_level(level)
            if out.solved and x is not None and float(x[lay.t - 1]) > MARGIN_TOL:
                break
        else:
            return None
        x = np.insert(x, lay.g, math.nan)  # g was fixed (at_level); unused below
        for col in sorted(unused):
            x = np.insert(x, col, math.nan)
        var, _ = local_variables([("sym", lay.x(k), (n,)) for k in range(lay.n_groups)]
                                 + [("mat", lay.y(k), (nu, n)) for k in range(lay.n_groups) if lay.with_y])
        values = [evaluate(v, x[:lay.g]) for v in var]
        Xs, Ys = values[:lay.n_groups], values[lay.n_groups:]
        return {
            "X": [Xs[k] for k in lay.groups],
            "Y": None if kind == "projected" else [Ys[k] for k in lay.groups],
            "eps": [num(x, lay.eps(s)) for s in range(S)],
            "delta": [num(x, lay.delta(s)) for s in range(S)],
            "gamma": level,
            "margin": float(x[lay.t]),
        }

    return solve_at
