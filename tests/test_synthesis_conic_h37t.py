"""The synthesis LMIs in conic form (no cvxpy) are the programs they replace.

``gain_step`` (eq. 18), the ``(X, Y)`` designs of ``synthesis.xy_design`` (eq. 17 and the
others), the dilated design, the true-mode reference and the CCL programs of Theorem 5.1
are written from the same blocks of ``analysis.lmi`` evaluated on ``analysis.conic.Affine``
and solved by Clarabel directly. Checked here, against the same blocks built with cvxpy
(``cp.bmat``, the former formulation) and solved by Clarabel: the optimal values of
``gain_step``; of step 1 of Theorem 4.1 (the projected margin, bounded from both sides);
of ``xy_solver``'s first program at ``gamma=None`` (min g at margin 0) for every kind; of
``dilated_problem`` at one tau with and without ``k_max``; of ``true_mode_reference``; of
the CCL first point and of one linearised iteration -- each within a tolerance stated
where it is asserted. Also: the points returned satisfy the blocks when evaluated with
numbers, and the conic helpers (local columns, ``Rows.used``, ``ConicProblem.restrict``,
sparse nonnegative rows) place every variable where its columns say.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from ftc_verify.analysis.closedloop import gain_loop, state_feedback_loop
from ftc_verify.analysis.conic import (Affine, ConicProblem, Rows, evaluate, local_variables, matrix_variable,
                                      solve_clarabel, solve_clarabel_dual, sym_variable, unit_rows)
from ftc_verify.analysis.lmi import block_specs, dilated_block, lyapunov_block, projection, xy_block
from ftc_verify.analysis.lmi_analysis import hinf_gamma
from ftc_verify.controllers.files import load_gains
from ftc_verify.model.files import load_system
from ftc_verify.model.system import FTCSystem
from ftc_verify.synthesis.ccl import ccl, ccl_blocks
from ftc_verify.synthesis.convex_designs import dilated_problem, true_mode_reference
from ftc_verify.synthesis.of_blocks import augmented_system
from ftc_verify.synthesis.results import SolverCalls
from ftc_verify.synthesis.state_feedback import gain_step
from ftc_verify.synthesis.xy_design import CENTRE_WEIGHT, gain_bound_block, xy_solver

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"


def gain_bound(K, k_max, mu=1.0):  # type: ignore[no-untyped-def]
    """``||K||_2 <= k_max * mu`` as a cvxpy constraint (the former ``xy_design.gain_bound``)."""
    import cvxpy as cp

    return gain_bound_block(K, k_max, mu, cp.bmat) >> 0


@pytest.fixture(scope="module")
def paper():  # type: ignore[no-untyped-def]
    system = load_system(EXAMPLES / "paper.toml")
    res = hinf_gamma(state_feedback_loop(system, list(load_gains(EXAMPLES / "paper_gains.toml"))), robust=True,
                     solver="clarabel")
    assert res.certified and res.P is not None
    lam = [list(r) for r in (res.multipliers or [()] * len(res.P))]
    return system, list(res.P), lam, float(res.gamma)


def _cvxpy_gain_step(system, P, lam, j, k_max, gamma):  # type: ignore[no-untyped-def]
    """The former cvxpy formulation of eq. (18): the optimal value (g or k)."""
    import cvxpy as cp

    m, (n, nu, _, _) = system.m, system.dims
    K = cp.Variable((nu, n))
    g = cp.Variable(nonneg=True)
    k = cp.Variable(nonneg=True)
    gains = [np.zeros((nu, n))] * m
    gains[j] = K
    loop = gain_loop(system, gains, "gain step")
    cons = []
    for spec in block_specs(loop):
        if spec.fdi == j:
            M = lyapunov_block(loop, spec, P, lam[spec.s], g, cp.bmat, schur_F=True)
            cons.append(0.5 * (M + M.T) << 0)
    if k_max is not None:
        cons.append(gain_bound(K, k_max))
    if gamma is None:
        prob = cp.Problem(cp.Minimize(g), cons)
    else:
        prob = cp.Problem(cp.Minimize(k), cons + [g <= gamma ** 2, gain_bound(K, 1.0, k)])
    prob.solve(solver="CLARABEL")
    return float(prob.value)


@pytest.mark.parametrize(("k_max", "scale"), [(None, None), (50.0, None), (None, 1.5), (50.0, 1.5)])
def test_gain_step_is_the_cvxpy_program(paper, k_max, scale) -> None:  # type: ignore[no-untyped-def]
    system, P, lam, gamma0 = paper
    gamma = None if scale is None else scale * gamma0
    for j in range(system.m):
        K, g, status = gain_step(system, P, lam, j, SolverCalls("clarabel"), k_max, gamma)
        assert status == "optimal" and K is not None and g is not None
        ref = _cvxpy_gain_step(system, P, lam, j, k_max, gamma)
        if gamma is None:
            assert g ** 2 == pytest.approx(ref, rel=1e-6, abs=1e-9)
        else:  # the optimal gain norm, and gamma met
            assert float(np.linalg.norm(K, 2)) == pytest.approx(ref, rel=1e-5)
            assert g <= gamma * (1 + 1e-7)
        if k_max is not None:
            assert np.linalg.norm(K, 2) <= k_max * (1 + 1e-7)
        # the point satisfies every block of FDI mode j, evaluated with numbers
        gains = [np.zeros_like(K)] * system.m
        gains[j] = K
        loop = gain_loop(system, gains, "check")
        for spec in block_specs(loop):
            if spec.fdi == j:
                M = lyapunov_block(loop, spec, P, lam[spec.s], (g * (1 + 1e-6)) ** 2, np.block, schur_F=True)
                assert np.linalg.eigvalsh(0.5 * (M + M.T)).max() <= 1e-6 * max(1.0, np.abs(M).max())


def _cvxpy_projected_margin(system, gamma):  # type: ignore[no-untyped-def]
    """The former cvxpy step 1 of Theorem 4.1: max t - CENTRE_WEIGHT * size (its value)."""
    import cvxpy as cp

    n = system.dims[0]
    S = system.chain.n_states
    X = [cp.Variable((n, n), symmetric=True) for _ in range(S)]
    eps = [cp.Variable(nonneg=True) for _ in range(S)]
    dlt = [cp.Variable(nonneg=True) for _ in range(S)]
    t = cp.Variable()
    cons = [t <= 1.0] + [x >> t * np.eye(n) for x in X]
    probe = gain_loop(system, [np.zeros((system.dims[1], n))] * system.m, "probe")
    for spec in block_specs(probe):
        mode = system.modes[spec.true]
        M = xy_block(mode, X, spec.s, None, eps[spec.s], dlt[spec.s], gamma ** 2, spec.q_row, cp.bmat)
        N = projection(mode, sum(1 for k, q in enumerate(spec.q_row) if k != spec.s and q > 0))
        if N.shape[1]:
            M = N.T @ M @ N
            cons.append(0.5 * (M + M.T) << -t * np.eye(M.shape[0]))
    size = sum(cp.trace(x) for x in X) / (S * n) + (sum(eps) + sum(dlt)) / (2 * S)
    prob = cp.Problem(cp.Maximize(t - CENTRE_WEIGHT * size), cons)
    prob.solve(solver="CLARABEL")
    return float(prob.value)


@pytest.mark.parametrize("gamma", [0.5, 2.0])
def test_projected_step_one_margin_is_the_cvxpy_margin(paper, gamma) -> None:  # type: ignore[no-untyped-def]
    system = paper[0]
    calls = _Recorded()
    sol = xy_solver(system, "projected", calls, None)(gamma)
    assert sol is not None and [o.status for o in calls.outcomes] == ["optimal"]
    n, S = system.dims[0], system.chain.n_states
    size = sum(np.trace(X) for X in sol["X"]) / (S * n) + (sum(sol["eps"]) + sum(sol["delta"])) / (2 * S)
    value = sol["margin"] - CENTRE_WEIGHT * size
    # the optimal value, bounded from both sides: the conic program's own primal and dual
    # values (Clarabel's dual point: an upper bound on the maximum up to its tolerances)
    # differ by the accuracy Clarabel's stopping rule reaches on this flat objective
    # (1e-8 of its scaled problem; measured 5e-6 and 2.5e-5 here); the cvxpy formulation
    # is the same program solved by Clarabel with the same settings, so its value lies
    # within that accuracy of the optimum too (measured 4e-6 and 3.3e-5 from ours)
    problem, x = calls.programs[0]
    status, _, x_dual, z = solve_clarabel_dual(problem, {})
    assert status == "optimal" and x_dual is not None and z is not None
    primal, dual = -_value(problem, x), float(problem.b @ z)
    assert value == pytest.approx(primal, abs=1e-12)
    accuracy = abs(primal - dual) + 1e-7
    reference = _cvxpy_projected_margin(system, gamma)
    assert reference <= max(primal, dual) + accuracy
    assert abs(reference - primal) <= 2 * accuracy
    assert value >= reference - 1e-7  # and never worse than the cvxpy program (measured +4e-6, +3.3e-5)
    probe = gain_loop(system, [np.zeros((system.dims[1], n))] * system.m, "probe")
    for spec in block_specs(probe):
        mode = system.modes[spec.true]
        M = xy_block(mode, sol["X"], spec.s, None, sol["eps"][spec.s], sol["delta"][spec.s], gamma ** 2, spec.q_row,
                     np.block)
        N = projection(mode, sum(1 for k, q in enumerate(spec.q_row) if k != spec.s and q > 0))
        if N.shape[1]:
            assert np.linalg.eigvalsh(N.T @ M @ N).max() + sol["margin"] <= 1e-6
    for X in sol["X"]:
        assert np.allclose(X, X.T) and np.linalg.eigvalsh(X).min() >= sol["margin"] * (1 - 1e-6)


def test_common_design_leaves_unused_multipliers_out(paper) -> None:  # type: ignore[no-untyped-def]
    system = paper[0]
    sol = xy_solver(system, "common", SolverCalls("clarabel"), 30.0)(None)
    assert sol is not None
    # one block per true mode: the multipliers of the other joint states are in no block
    used = {spec.s for spec in block_specs(gain_loop(system, [np.zeros((2, 2))] * system.m, "p"))
            if spec.s == min(s for s, (i, _) in enumerate(system.chain.joint_modes) if i == spec.true)}
    for s, e in enumerate(sol["eps"]):
        assert math.isnan(e) == (s not in used)
    K = sol["Y"][0] @ np.linalg.inv(sol["X"][0])
    assert np.linalg.norm(K, 2) <= 30.0 * (1 + 1e-6)


def test_local_columns_and_restrict() -> None:
    rng = np.random.default_rng(5)
    (X, Y, a), cols = local_variables([("sym", 7, (3,)), ("mat", 20, (2, 3)), ("scalar", 2, ())])
    assert list(cols) == [7, 8, 9, 10, 11, 12, 20, 21, 22, 23, 24, 25, 2]
    x = rng.normal(size=len(cols))
    Xv = evaluate(X, x)
    assert np.array_equal(Xv, Xv.T) and np.array_equal(np.diag(Xv), x[[0, 2, 5]])  # svec: upper triangle by columns
    assert np.array_equal(evaluate(Y, x), x[6:12].reshape(2, 3))
    assert evaluate(a, x) == x[12]
    M = matrix_variable(2, 2, 1, 5)
    assert np.array_equal(evaluate(M / 2.0, np.arange(5.0)), np.array([[0.5, 1.0], [1.5, 2.0]]))
    rows = Rows(6)
    rows.lmi(sym_variable(2, 0, 3) * -1.0, np.array([4, 1, 3]))
    assert list(np.flatnonzero(rows.used())) == [1, 3, 4]
    problem = rows.problem(np.zeros(6)).restrict(rows.used())
    assert problem.A.shape == (3, 3)
    assert isinstance(-Affine(np.zeros(()), np.ones(2)), Affine)
    # sparse nonnegative rows: the same rows as those of a dense identity
    sparse, dense = Rows(6), Rows(6)
    sparse.nonneg(unit_rows(6, [4, 1]), [0.0, 2.0])
    dense.nonneg(-np.eye(6)[[4, 1]], [0.0, 2.0])
    assert unit_rows(6, [4, 1]).shape == (2, 6) and unit_rows(6, [3], 1.0).toarray()[0, 3] == 1.0
    for a, b in zip(sparse.problem(np.ones(6)).__dict__.values(), dense.problem(np.ones(6)).__dict__.values()):
        assert np.array_equal(a.toarray(), b.toarray()) if hasattr(a, "toarray") else np.array_equal(a, b)


class _Recorded(SolverCalls):
    """Clarabel calls that keep every conic program and its point (to read a program's
    optimal value ``c x`` where the synthesis keeps only its point)."""

    def __init__(self) -> None:
        super().__init__("clarabel")
        self.programs: list[tuple[ConicProblem, np.ndarray | None]] = []

    def run_conic(self, problem):  # type: ignore[no-untyped-def]
        out, x = super().run_conic(problem)
        self.programs.append((problem, x))
        return out, x


def _value(problem: ConicProblem, x: np.ndarray | None) -> float:
    assert x is not None
    return float(problem.c @ x)


def _solve_cvxpy(objective, cons) -> float:  # type: ignore[no-untyped-def]
    import cvxpy as cp

    prob = cp.Problem(cp.Minimize(objective), cons)
    prob.solve(solver="CLARABEL")
    assert prob.status in ("optimal", "optimal_inaccurate")
    return float(prob.value)


def _cvxpy_ccl_values(aug, cbars, gamma, point):  # type: ignore[no-untyped-def]
    """The former cvxpy CCL programs: ``ccl_blocks`` on cvxpy variables (``cp.bmat``),
    ``lambda, eps >= 0``; the optimal values of the first-point cost (``sum tr(P + X) +
    lambda + eps``) and of the cost linearised at ``point = (P_k, X_k, lambda_k, eps_k)``."""
    import cvxpy as cp

    nb, S = aug.dims[0], aug.chain.n_states
    chans = [int(aug.modes[i].A1 is not None) + int(aug.modes[i].B1 is not None) for i, _ in aug.chain.joint_modes]
    P = [cp.Variable((nb, nb), symmetric=True) for _ in range(S)]
    X = [cp.Variable((nb, nb), symmetric=True) for _ in range(S)]
    lam = [[cp.Variable(nonneg=True) for _ in range(k)] for k in chans]
    eps = [[cp.Variable(nonneg=True) for _ in range(k)] for k in chans]
    cons = [0.5 * (M + M.T) >> 0 for M in ccl_blocks(aug, cbars, P, X, lam, eps, gamma ** 2, 1e-7, cp.bmat)]
    flat_l, flat_e = [v for r in lam for v in r], [v for r in eps for v in r]
    size = sum(cp.trace(p) + cp.trace(x) for p, x in zip(P, X)) + sum(flat_l) + sum(flat_e)
    Pk, Xk, lk, ek = point
    lin = (sum(cp.trace(Pk[s] @ X[s]) + cp.trace(Xk[s] @ P[s]) for s in range(S))
           + sum(a * e for a, e in zip(lk, flat_e)) + sum(b * la for b, la in zip(ek, flat_l)))
    return _solve_cvxpy(size, cons), _solve_cvxpy(lin, cons)


@pytest.mark.filterwarnings("ignore:Solution may be inaccurate")
def test_ccl_programs_are_the_cvxpy_programs() -> None:
    """The paper plant at gamma 10 with one iteration (the controller step fails at the
    first point, so both programs run): the first point's and the linearised program's
    optimal values are those of ``ccl_blocks`` written with cvxpy, the second linearised
    at the first program's point."""
    system = load_system(EXAMPLES / "paper.toml")
    aug, cbars = augmented_system(system)
    calls = _Recorded()
    ccl(system, 10.0, calls, None, max_iter=1)
    nb, S = aug.dims[0], aug.chain.n_states
    width = nb * (nb + 1) // 2
    K = 2 * S * width + 2 * sum(int(md.A1 is not None) + int(md.B1 is not None)
                                for md in (aug.modes[i] for i, _ in aug.chain.joint_modes))
    progs = [(p, x) for p, x in calls.programs if p.A.shape[1] == K]
    assert len(progs) == 2
    x0 = progs[0][1]
    assert x0 is not None
    (sym,), _ = local_variables([("sym", 0, (nb,))])
    total = (K - 2 * S * width) // 2
    point = ([evaluate(sym, x0[s * width:(s + 1) * width]) for s in range(S)],
             [evaluate(sym, x0[(S + s) * width:(S + s + 1) * width]) for s in range(S)],
             list(x0[2 * S * width:2 * S * width + total]), list(x0[2 * S * width + total:]))
    size_ref, lin_ref = _cvxpy_ccl_values(aug, cbars, 10.0, point)
    # both formulations end "almost solved" here (the 1e-7 margin): Clarabel's reduced
    # tolerance is a relative duality gap of 5e-5, so each value is within 5e-5 of the
    # optimum (measured apart: 8e-8 and 2e-6)
    assert _value(*progs[0]) == pytest.approx(size_ref, rel=1e-4)
    assert _value(*progs[1]) == pytest.approx(lin_ref, rel=1e-4)


#: The second mode of the two small plants (``A``, ``B``, ``D``): of ``small`` and of
#: ``apart``, where an ``X`` per FDI mode gives a lower gamma than one ``X`` (1.1412 against
#: 1.1461), so that ``common-fdi`` and ``common`` differ.
SECOND_MODES = {"small": ([[-1.0, 1.0], [0.0, 0.3]], [[0.0], [0.2]], [[1.0], [0.5]]),
                "apart": ([[0.5, 1.0], [0.0, -1.0]], [[1.0], [0.0]], [[0.0], [1.0]])}


def _small_plant(which: str) -> FTCSystem:
    """The paper's chain and uncertainty on a plant with one input that cannot meet the
    disturbance (``B`` and ``D`` on different states, ``C = I``): its optimal gammas are of
    order 1 (the paper plant's minimal gamma is ~1e-3, at the solvers' absolute
    tolerances), so optimal values can be compared relatively."""
    p = load_system(EXAMPLES / "paper.toml")
    modes = []
    for A, b, d in (([[-1.0, 1.0], [0.0, 0.8]], [[0.0], [1.0]], [[1.0], [0.0]]), SECOND_MODES[which]):
        modes.append(dict(A=A, B=b, C=np.eye(2), D=d, A1=0.1 * np.eye(2), A2=0.1 * np.eye(2), B1=[[0.1], [0.1]],
                          B2=[[0.1]]))
    return FTCSystem.from_arrays(name=which, modes=modes, alpha=p.chain.alpha, beta_min=p.chain.beta_min,
                                 beta_max=p.chain.beta_max)


@pytest.fixture(scope="module")
def small() -> FTCSystem:
    """:func:`_small_plant` ``"small"``."""
    return _small_plant("small")


def _cvxpy_dilated_value(system, k_max, tau):  # type: ignore[no-untyped-def]
    """The dilated program written with cvxpy: min g s.t. every ``dilated_block`` <= 0,
    ``X_s >= 0``, and with ``k_max``: ``G_j + G_j' >= 2 mu I``, ``||Y_j|| <= k_max mu``."""
    import cvxpy as cp

    n, nu = system.dims[0], system.dims[1]
    S, m = system.chain.n_states, system.m
    X = [cp.Variable((n, n), symmetric=True) for _ in range(S)]
    G = [cp.Variable((n, n)) for _ in range(m)]
    Y = [cp.Variable((nu, n)) for _ in range(m)]
    eps = [cp.Variable(nonneg=True) for _ in range(S)]
    dlt = [cp.Variable(nonneg=True) for _ in range(S)]
    g = cp.Variable(nonneg=True)
    cons = [x >> 0 for x in X]
    for spec in block_specs(gain_loop(system, [np.zeros((nu, n))] * m, "probe")):
        s, j = spec.s, spec.fdi
        M = dilated_block(system.modes[spec.true], X, G[j], s, Y[j], eps[s], dlt[s], g, spec.q_row, tau, cp.bmat)
        cons.append(0.5 * (M + M.T) << 0)
    if k_max is not None:
        mu = cp.Variable(nonneg=True)
        for j in range(m):
            cons += [G[j] + G[j].T >> 2 * mu * np.eye(n), gain_bound(Y[j], k_max, mu)]
    return _solve_cvxpy(g, cons)


@pytest.mark.parametrize("k_max", [None, 2.0])
def test_dilated_program_is_the_cvxpy_program(small, k_max) -> None:  # type: ignore[no-untyped-def]
    """``dilated_problem`` at tau = 0.1 (``k_max = 2`` binds: g 0.52 -> 11.6): its optimal
    value is the cvxpy program's (measured apart: 8e-7, 2e-7 relative)."""
    problem, _, _ = dilated_problem(small, k_max, 0.1)
    status, _, x = solve_clarabel(problem, {})
    assert status == "optimal"
    assert _value(problem, x) == pytest.approx(_cvxpy_dilated_value(small, k_max, 0.1), rel=1e-5)


def test_true_mode_reference_is_the_cvxpy_program(small) -> None:  # type: ignore[no-untyped-def]
    """min g over ``xy_block`` per true mode with the row alpha_i, ``X_i >= 0``, written with cvxpy."""
    import cvxpy as cp

    system = small
    n, nu, m = system.dims[0], system.dims[1], system.m
    X = [cp.Variable((n, n), symmetric=True) for _ in range(m)]
    Y = [cp.Variable((nu, n)) for _ in range(m)]
    eps = [cp.Variable(nonneg=True) for _ in range(m)]
    dlt = [cp.Variable(nonneg=True) for _ in range(m)]
    g = cp.Variable(nonneg=True)
    alpha = np.asarray(system.chain.alpha, dtype=float)
    cons = [x >> 0 for x in X]
    for i, md in enumerate(system.modes):
        M = xy_block(md, X, i, Y[i], eps[i], dlt[i], g, alpha[i], cp.bmat)
        cons.append(0.5 * (M + M.T) << 0)
    sol = true_mode_reference(system, SolverCalls("clarabel"))
    assert sol is not None
    assert sol["gamma"] ** 2 == pytest.approx(_solve_cvxpy(g, cons), rel=1e-5)


def _groups(system, kind):  # type: ignore[no-untyped-def]
    """The Lyapunov variable of each joint state per kind (``xy_solver``'s docstring)."""
    joint = system.chain.joint_modes
    return {"common": [0] * len(joint), "common-fdi": [j for _, j in joint],
            "full-info": [i * system.m + j for i, j in joint], "projected": list(range(len(joint)))}[kind]


def _cvxpy_min_g(system, kind, k_max):  # type: ignore[no-untyped-def]
    """``xy_solver``'s first program at ``gamma=None`` with cvxpy: min g at margin ``t = 0``."""
    import cvxpy as cp

    n, nu, S = system.dims[0], system.dims[1], system.chain.n_states
    groups = _groups(system, kind)
    Xg = [cp.Variable((n, n), symmetric=True) for _ in range(max(groups) + 1)]
    Yg = [cp.Variable((nu, n)) for _ in Xg]
    X = [Xg[k] for k in groups]
    eps = [cp.Variable(nonneg=True) for _ in range(S)]
    dlt = [cp.Variable(nonneg=True) for _ in range(S)]
    g = cp.Variable(nonneg=True)
    cons = [x >> 0 for x in Xg]
    seen = set()
    for spec in block_specs(gain_loop(system, [np.zeros((nu, n))] * system.m, "probe")):
        if kind == "common" and spec.true in seen:
            continue
        seen.add(spec.true)
        mode, s = system.modes[spec.true], spec.s
        q_row = None if kind == "common" else spec.q_row
        M = xy_block(mode, X, s, None if kind == "projected" else Yg[groups[s]], eps[s], dlt[s], g, q_row, cp.bmat)
        if kind == "projected":
            N = projection(mode, sum(1 for k, q in enumerate(spec.q_row) if k != s and q > 0))
            if N.shape[1] == 0:
                continue
            M = N.T @ M @ N
        cons.append(0.5 * (M + M.T) << 0)
    if k_max is not None and kind != "projected":
        mu = cp.Variable(nonneg=True)
        for Xk, Yk in zip(Xg, Yg):
            cons += [Xk >> mu * np.eye(n), gain_bound(Yk, k_max, mu)]
    return _solve_cvxpy(g, cons)


@pytest.mark.parametrize(("plant", "kind", "k_max"), [
    ("small", "projected", None), ("small", "full-info", None), ("small", "common-fdi", None),
    ("small", "common", None), ("small", "common-fdi", 2.0), ("apart", "common-fdi", None), ("apart", "common", None)])
def test_xy_minimal_gamma_is_the_cvxpy_program(plant, kind, k_max) -> None:  # type: ignore[no-untyped-def]
    """``gamma=None``: the first program (min g, ``t = 0``) has the cvxpy program's value,
    and the level returned is its re-centred gamma above it. The optimum has a singular
    ``X`` (``t = 0``), where Clarabel stops further from it than its 1e-8 gap: measured
    apart up to 2e-6 relative (8e-6 with ``k_max = 2``, which binds: g 0.53 -> 112)."""
    system = _small_plant(plant)
    calls = _Recorded()
    sol = xy_solver(system, kind, calls, k_max)(None)
    assert sol is not None
    g_min = _value(*calls.programs[0])
    assert g_min == pytest.approx(_cvxpy_min_g(system, kind, k_max), rel=5e-5)
    assert sol["gamma"] >= math.sqrt(g_min) and sol["margin"] > 0
