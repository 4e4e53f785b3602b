r"""State-feedback synthesis with gains that use the FDI mode only (``u = K[l_t] x``).

Methods (all return a :class:`~ftc_verify.synthesis.results.SynthesisResult` verified by the core analysis,
:func:`ftc_verify.analysis.analyze`, never by the synthesis LMI alone):

``two-step``
    The paper's Theorem 4.1. Step 1 solves the projected inequality of
    :func:`ftc_verify.analysis.lmi.xy_block` (eq. (17) corrected: coupling written as
    :math:`X(\sum_{s'} q_{ss'}P_{s'})X`, indicator cases as in READING-NOTES) in
    :math:`X_{ij} > 0, \varepsilon_{ij}, \delta_{ij}` at both ends of every rate, with the
    margin maximised so that step 2 has room. Step 2 fixes :math:`P_{ij} = X_{ij}^{-1}`,
    :math:`\lambda = (\varepsilon^{-1}, \delta^{-1})` and solves eq. (18) -- Lemma 4.1's block
    with the :math:`B_2 K_j` channel in Schur form -- for each :math:`K_j`, over all true
    modes :math:`i` and rate ends; it decouples over ``j``. Step 1 is only necessary:
    when step 2 fails (at a given gamma: at every halved level too, :func:`two_step`), the FDI
    mode ``j`` that failed is reported and no gains are returned.
``full-info``
    The Markov-jump lower bound: gains :math:`K_{ij}` that may use the true mode, convex in
    :math:`X_{ij}, Y_{ij} = K_{ij} X_{ij}` (the unprojected block). Gains files hold
    ``m * m`` tables in the order ``s = (true - 1) * m + fdi``.
``common``
    One gain for every mode, from a common :math:`X` and :math:`Y = K X` (the coupling
    cancels), i.e. quadratic stabilisation ignoring the FDI.
``iterative`` (beyond the paper)
    Alternating descent on the bilinear Lemma 4.1: a P-step (the core's certified robust
    gamma with the gains fixed, which returns :math:`P, \lambda`) and a K-step (eq. (18)
    with :math:`P, \lambda` fixed, minimising gamma per ``j``). Each iterate is certified;
    the best certified gains are kept, so the result is never worse than the start. The
    start is the best certified of: two-step (minimised), common, and the classical designs
    of :mod:`ftc_verify.synthesis.starts` (per-mode LQR with textbook and output weights
    and a scale search, the LQR of the averaged plant, the full-information design
    projected onto FDI-mode gains); so it never loses to any of them, in particular not to
    the textbook per-mode LQR. When nothing is certified, ``diagnosis`` says why
    (:func:`~ftc_verify.synthesis.starts.diagnose`). Two-step, the longest start, runs in
    a forked child; meanwhile the descent from the best of the other starts and the
    analysis of its result run here, and are kept when that start is the best of all (the
    same result as in turn).

``common-fdi``
    One :math:`X_j, Y_j` per FDI mode (:math:`X_{(i,j)} = X_j`, :math:`K_j = Y_j X_j^{-1}`):
    the common-Lyapunov-matrix-per-FDI-mode design (:mod:`ftc_verify.synthesis.xy_design`).
``dilated``
    The S-variable LMI with one slack :math:`G_j` per FDI mode and one Lyapunov matrix per
    joint state, :math:`K_j = Y_j G_j^{-1}`, with a line search on its scalar
    (:mod:`ftc_verify.synthesis.convex_designs`).
``best`` (the default)
    Every route that can win: the starts of ``iterative`` and the ``common-fdi`` and
    ``dilated`` designs, each certified, then the descent of ``iterative`` from the best
    of ``iterative``'s own starts and from the best start overall, each followed by the
    polish of its result (:func:`~ftc_verify.synthesis.polish.polish`: a trust-region
    step in the Lyapunov matrices and the gains together, which the alternation cannot
    make; never worse than its start). The smallest certified robust gamma wins; every
    route is a row of ``starts`` (with its seconds). So ``best`` is never worse than
    ``iterative``, ``two-step``, ``common``, ``common-fdi`` or ``dilated`` run alone (the
    same computations, the same certification). Beside the result it reports the reference
    line of :func:`~ftc_verify.synthesis.convex_designs.true_mode_reference` (gains that
    see the true mode; a reference, not a bound).

``full-info`` is a relaxation of every FDI-only design: the Lemma 4.1 certificate
:math:`(P, \lambda, \gamma)` of FDI-mode gains gives a feasible point of the
full-information LMI (:math:`X_{ij} = P_{ij}^{-1}`, :math:`Y_{ij} = K_j X_{ij}`,
:math:`\varepsilon = \lambda_1^{-1}`, :math:`\delta = \lambda_2^{-1}`; checked with numpy by the
property suite). No *numerical* lower bound is claimed from it: Clarabel reported
``optimal`` at values 1.5x to 4x above certified FDI-only designs whenever the feasible
set near the optimum needs badly conditioned ``X`` (measured cond 2.5e5), so only a
dual certificate could make that bound sound.

**The joint chain** (:mod:`ftc_verify.model.chain`: Erlang-``k`` detection delays, false
alarms, missed detections). The index ``ij`` above stands for a joint *state* ``s``: one
:math:`X_s` (:math:`P_s`), :math:`\varepsilon_s, \delta_s` per state, and each block
imposed at every vertex of the rates in its generator row
(:func:`~ftc_verify.analysis.lmi.block_specs`); the gains :math:`K_j` still depend on the
FDI mode only, shared across true modes and phases. With ``delay_phases > 1`` the
``full-info`` design shares :math:`X, Y` among the phases of a pair (the gain of a pair
is one matrix, as the ``m * m`` tables hold), so it is then a design and no longer a
relaxation of every FDI-only design (that argument needs one :math:`X` per state); with
the paper's model nothing changes. At a missed-detection vertex (:math:`\beta_{ji} = 0`)
the blocks of the pair ``(i, j)`` lose their detection coupling, so the designed
:math:`K_j` must make the frozen loop of true mode ``i`` stable (and
:math:`\gamma`-attenuating) on its own (:mod:`ftc_verify.analysis.lmi`).
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..controllers.controller import Controller
from ..analysis.analyze import AnalysisReport
from ..analysis.closedloop import gain_loop, state_feedback_loop
from ..analysis.conic import Rows, affine_bmat, matrix_variable, scalar_variable, unit_rows
from ..claimtext import upper_text
from ..errors import ValidationError
from ..analysis.lmi import block_specs, lyapunov_block
from ..analysis.lmi_analysis import LMIResult, hinf_gamma
from ..model.system import FTCSystem, Matrix
from ..analysis.solvers import ForkedCall, choose_solver
from .starts import candidates, certify_start, diagnose
from .results import SolverCalls, SynthesisResult, check_levels, verify_controller
from .polish import polish
from .convex_designs import convex_gains, reference_alone
from .xy_design import channel_multipliers, gain_bound_block, posed_level, scaled_disturbance, xy_solve, xy_solver

__all__ = ["METHODS", "SynthesisResult", "synthesize", "two_step", "gain_step", "Descent", "descend"]

METHODS = ("best", "two-step", "iterative", "full-info", "common", "common-fdi", "dilated")
#: The starts of ``iterative`` (``best`` adds :data:`EXTRA_STARTS`).
ITERATIVE_STARTS = ("two-step", "common", "lqr", "lqr-C", "averaged", "full-info projected")
#: The convex designs ``best`` adds to the starts of ``iterative``.
EXTRA_STARTS = ("common-fdi", "dilated")
#: Relative width at which the gamma bisection of ``two-step --minimize`` stops.
BISECTION_RTOL = 2e-3
#: How often :func:`two_step` halves a requested gamma at which step 2 failed.
RETRY_HALVINGS = 40


def gain_step(
    system: FTCSystem,
    P: list[Matrix],
    lam: list[list[float]],
    j: int,
    calls: SolverCalls,
    k_max: float | None,
    gamma: float | None = None,
    measurement: list[Matrix] | None = None,
) -> tuple[Matrix | None, float | None, str]:
    r"""Eq. (18): with ``P_s`` and multipliers fixed, the gain ``K_j`` of FDI mode ``j``
    over all true modes and rate ends; returns ``(K, gamma, status)``.

    With ``gamma=None`` gamma is minimised; with ``gamma`` given, the gain of smallest
    spectral norm achieving it is returned (a real actuator prefers small gains).
    ``measurement``: one matrix ``M_i`` per true mode for static output feedback
    ``u = K_j M_i x`` (the controller step of output feedback on the augmented plant of
    :mod:`ftc_verify.synthesis.output_feedback`, with ``M_i = Cbar_i``); the block stays
    linear in ``K_j`` since ``P`` and the multipliers are fixed.

    Variables :math:`(\operatorname{vec} K_j, g[, k])`: the blocks :func:`~ftc_verify.analysis.lmi.lyapunov_block`
    of FDI mode ``j`` (Schur form in :math:`F`) :math:`\preceq 0` on :class:`~ftc_verify.analysis.conic.Affine`
    matrices, solved in conic form (:meth:`~ftc_verify.synthesis.results.SolverCalls.run_conic`; no cvxpy),
    :math:`g \ge 0`, :func:`~ftc_verify.synthesis.xy_design.gain_bound_block` with ``k_max``; with ``gamma``: the
    blocks at :math:`D/\sigma`, :math:`\sigma = \max(\gamma, 1)` (:func:`.xy_design.posed_level`),
    :math:`g \le (\gamma/\sigma)^2 \le 1`, :math:`\|K_j\|_2 \le k`, min :math:`k`.
    """
    m, (n, nu, _, _) = system.m, system.dims
    scale, g_top = (1.0, math.inf) if gamma is None else posed_level(gamma)  # g <= g_top at D / scale
    cols = n if measurement is None else measurement[0].shape[0]
    size = nu * cols + (1 if gamma is None else 2)
    every = np.arange(size).astype(int)
    K = matrix_variable(nu, cols, 0, size)
    g = scalar_variable(nu * cols, size)
    gains: list[Any]
    if measurement is None:
        gains = [np.zeros((nu, n))] * m
        gains[j] = K
    else:
        gains = [K @ measurement[i] if jj == j else np.zeros((nu, n)) for i in range(m) for jj in range(m)]
    loop = gain_loop(scaled_disturbance(system, scale), gains, "gain step")
    rows = Rows(size)
    for spec in block_specs(loop):
        if spec.fdi == j:
            rows.lmi(lyapunov_block(loop, spec, P, lam[spec.s], g, affine_bmat, schur_F=True), every)
    if k_max is not None:
        rows.lmi(-gain_bound_block(K, k_max, 1.0, affine_bmat), every)
    c = np.eye(size)[nu * cols if gamma is None else -1]  # min g, or min k
    rows.nonneg(unit_rows(size, range(nu * cols, size)), np.zeros(size - nu * cols))  # g >= 0 (and k >= 0)
    if gamma is not None:
        rows.nonneg(unit_rows(size, [nu * cols], 1.0), [g_top])
        rows.lmi(-gain_bound_block(K, 1.0, scalar_variable(size - 1, size), affine_bmat), every)
    out, x = calls.run_conic(rows.problem(c))
    if not out.solved or x is None:
        return None, None, out.status
    return x[:nu * cols].reshape(nu, cols), scale * math.sqrt(max(float(x[nu * cols]), 0.0)), out.status


def _gains_of(system: FTCSystem, step1: dict[str, Any], gamma: float, calls: SolverCalls,
              k_max: float | None) -> tuple[list[Matrix] | None, float | None, str]:
    """Step 2 (eq. (18)) on step 1's numbers at ``gamma``: ``(gains, synthesis gamma, message)``."""
    P = [np.linalg.inv(0.5 * (X + X.T)) for X in step1["X"]]
    P = [0.5 * (p + p.T) for p in P]
    lam = channel_multipliers(system, step1["eps"], step1["delta"])
    gains, worst = [], 0.0
    for j in range(system.m):
        K, gj, _ = gain_step(system, P, lam, j, calls, k_max, gamma)
        if K is None or gj is None or gj > gamma * (1 + 1e-6):
            detail = calls.unsolved() if K is None else f"best gamma {gj:.6g} > {gamma:.6g}"
            return None, None, f"step 2 (eq. 18) failed for FDI mode {j + 1} at gamma {gamma:.6g} ({detail})"
        gains.append(K)
        worst = max(worst, gj)
    return gains, worst, f"two-step succeeded at gamma {gamma:.6g} (step-1 margin {step1['margin']:.3g})"


def two_step(system: FTCSystem, gamma: float, calls: SolverCalls, k_max: float | None,
             step1_at: Any = None, halvings: int = RETRY_HALVINGS) -> tuple[list[Matrix] | None, float | None, str]:
    """Theorem 4.1 at a given gamma: ``(gains, synthesis gamma, message)``. ``step1_at``:
    step 1 as built once by :func:`~ftc_verify.synthesis.xy_design.xy_solver` (the
    bisection's levels share it); built here when not given.

    Step 2 can fail at ``gamma`` and succeed at a smaller level: step 1's capped margin is
    not invariant under the scaling of a level (:func:`.xy_design.scaled_disturbance`), so
    its ``X`` at a larger level may admit no common ``K_j`` (``examples/paper.toml`` with
    ``D`` times 1e6: 1e3 succeeded, 3e3 to 1e5 failed). Then the level is halved, at most
    ``halvings`` times, until step 2 succeeds (gains achieving that level, below ``gamma``;
    the message names both) or step 1 fails (eq. (17) is an LMI: no smaller level is feasible)."""
    step1_at = step1_at or xy_solver(system, "projected", calls, None)
    level, first = gamma, ""
    for _ in range(halvings + 1):
        step1 = step1_at(level)
        if step1 is None:
            msg = f"step 1 (eq. 17) {calls.unsolved()} at gamma {level:.6g}"
            between = f"step 2 also failed at the halved levels down to {2 * level:.6g}, " if 2 * level < gamma else ""
            return None, None, f"{first}; {between}{msg}" if first else msg
        gains, worst, msg = _gains_of(system, step1, level, calls, k_max)
        if gains is not None:
            return gains, worst, f"{msg}, below the requested {gamma:.6g} where {first}" if first else msg
        first, level = first or msg, level / 2
    return None, None, f"{first}; step 2 also failed at the halved levels down to {2 * level:.6g}" if halvings else first


def _two_step_min(system: FTCSystem, calls: SolverCalls, k_max: float | None,
                  low: Any = False) -> tuple[list[Matrix] | None, float | None, str]:
    """Smallest gamma at which two-step succeeds: bisection between the full-information
    design level (a heuristic lower bracket: the full-information LMI relaxes every FDI-only
    design) and a doubling upper bracket. ``low``: the full-information solution when
    already solved (``None`` when it gave no point; solved here when not given)."""
    if low is False:
        low = xy_solve(system, "full-info", None, calls, None)
    lo = low["gamma"] / (1 + 1e-3) if low else 1e-3
    hi, best = max(lo, 1e-3) * 1.5, None
    step1_at = xy_solver(system, "projected", calls, None)  # built once, solved at every level
    for _ in range(12):
        gains, gsyn, msg = two_step(system, hi, calls, k_max, step1_at, halvings=0)
        if gains is not None:
            best = (gains, gsyn, hi)
            break
        lo, hi = hi, hi * 2.0
    if best is None:
        return None, None, f"two-step failed for every gamma up to {hi / 2:.6g}: {msg}"
    while hi - lo > BISECTION_RTOL * hi:
        mid = 0.5 * (lo + hi)
        gains, gsyn, _ = two_step(system, mid, calls, k_max, step1_at, halvings=0)
        if gains is not None:
            hi, best = mid, (gains, gsyn, mid)
        else:
            lo = mid
    return best[0], best[1], f"smallest two-step gamma {best[2]:.6g} (bisection to {BISECTION_RTOL:g} relative)"


def _verify(system: FTCSystem, gains: list[Matrix], solver: str) -> AnalysisReport:
    return verify_controller(system, Controller.state_feedback(gains), solver)


@dataclass(frozen=True, eq=False)
class Descent:
    """What :func:`descend` found: the best certified ``gains``, their certified robust gammas (``history``,
    empty when the start is not certified), why it stopped, and Lemma 4.1's result for ``gains`` (``lmi``).
    Compared by identity, as :class:`.SynthesisResult`: ``==`` on its lists of arrays would raise."""

    gains: list[Matrix]
    history: list[float]
    message: str
    lmi: LMIResult


def descend(loop_of: Any, step: Any, m: int, start: list[Matrix], calls: SolverCalls, solver: str,
            max_iter: int, tol: float, start_lmi: LMIResult | None = None) -> Descent:
    """P-step / K-step descent from certified ``start`` gains: the best certified gains, the
    certified robust gammas (one per accepted iterate) and Lemma 4.1's result for those gains.
    ``loop_of(gains)`` is the closed loop, ``step(P, lam, j)`` the K-step of FDI mode ``j``
    returning ``(K, gamma, status)`` (:func:`gain_step`; output feedback passes its own);
    ``start_lmi``: the start's certified robust-gamma result, when already computed."""
    best = start
    res = start_lmi
    if res is None:
        res = hinf_gamma(loop_of(best), robust=True, solver=solver)
        calls.outcomes.extend(res.attempts)
    if not res.certified or res.P is None or res.gamma is None:
        return Descent(best, [], "start gains not certified; no descent", res)
    history = [float(res.gamma)]
    reason = f"iteration limit {max_iter}"
    for _ in range(max_iter):
        lam = [list(r) for r in (res.multipliers or [()] * len(res.P))]
        new = []
        for j in range(m):
            K, _, status = step(list(res.P), lam, j)
            if K is None:
                return Descent(best, history, f"K-step failed for FDI mode {j + 1} ({status})", res)
            new.append(K)
        cand = hinf_gamma(loop_of(new), robust=True, solver=solver)
        calls.outcomes.extend(cand.attempts)
        if not cand.certified or cand.gamma is None or cand.gamma >= history[-1] * (1 - tol):
            reason = f"relative improvement below {tol:g}"
            if cand.certified and cand.gamma is not None and cand.gamma < history[-1]:
                best, res = new, cand
                history.append(float(cand.gamma))
            break
        best, res = new, cand
        history.append(float(cand.gamma))
    return Descent(best, history, f"stopped: {reason}", res)


_PUBLIC_START_KEYS = ("name", "gamma_certified", "spectral_abscissa", "note", "reason", "seconds")


def _starts(system: FTCSystem, gamma: float | None, k_max: float | None, solver: str, calls: SolverCalls,
            start: list[Matrix] | None, extra: bool = False,
            meanwhile: Callable[[list[dict[str, Any]]], Any] | None = None) -> list[dict[str, Any]]:
    """Every start of the iterative method with its certification (module docstring);
    ``extra``: also the designs of :data:`EXTRA_STARTS` (the ``best`` method). Each row
    records its wall ``seconds`` (design and certification). The full-information LMI is
    solved once (two-step's lower bracket and a start of its own); two-step, the longest
    start, runs in a forked child (:class:`~ftc_verify.analysis.solvers.ForkedCall`) beside
    the others, its row first as before. ``meanwhile(rows)``: called with the other
    starts' rows while two-step still runs in its child (``iterative`` descends from the
    best of them there)."""
    if start is not None:
        rows = [certify_start(system, "given", start, solver)]
    else:
        fi = xy_solve(system, "full-info", None, calls, None)  # two-step's bracket and a start of its own
        full_info = None if fi is None else [Y @ np.linalg.inv(X) for X, Y in zip(fi["X"], fi["Y"])]

        def seed(method: str, own: SolverCalls) -> dict[str, Any]:
            t = time.perf_counter()
            gains, _, msg = _design(system, method, gamma, k_max, own, fi)
            row: dict[str, Any] = ({"name": method, "gamma_certified": None, "spectral_abscissa": None, "note": "",
                                    "reason": msg} if gains is None else certify_start(system, method, gains, solver))
            return row | {"seconds": time.perf_counter() - t}

        def two_step_alone() -> tuple[dict[str, Any], list[Any]]:
            own = SolverCalls(solver)
            return seed("two-step", own), own.outcomes

        # two-step's bisection (the longest start) in a forked child beside the other starts
        forked = ForkedCall(two_step_alone, "the two-step design") if hasattr(os, "fork") else None
        try:
            rows = _other_starts(system, k_max, solver, calls, full_info, extra, [seed("common", calls)])
            if meanwhile is not None and forked is not None:
                meanwhile(rows)
            two, outcomes = forked.result() if forked is not None else two_step_alone()
        finally:
            if forked is not None:
                forked.cancel()
        calls.outcomes.extend(outcomes)
        rows.insert(0, two)
    for row in rows:
        calls.outcomes.extend(row.get("attempts", ()))
    return rows


def _other_starts(system: FTCSystem, k_max: float | None, solver: str, calls: SolverCalls,
                  full_info: list[Matrix] | None, extra: bool, rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """``rows`` followed by the classical starts (:func:`~ftc_verify.synthesis.starts.candidates`)
    and, with ``extra``, the :data:`EXTRA_STARTS` designs, each certified, with its seconds."""
    t0 = time.perf_counter()
    for c in candidates(system, k_max, full_info):
        if c.gains is None:
            rows.append({"name": c.name, "gamma_certified": None, "spectral_abscissa": None, "note": "",
                         "reason": c.note})
        else:
            rows.append(certify_start(system, c.name, c.gains, solver, c.note))
        rows[-1]["seconds"], t0 = time.perf_counter() - t0, time.perf_counter()
    for name in EXTRA_STARTS if extra else ():
        gains, _, msg = convex_gains(system, name, calls, k_max)
        made: dict[str, Any] = ({"name": name, "gamma_certified": None, "spectral_abscissa": None, "note": "",
                                 "reason": msg} if gains is None else certify_start(system, name, gains, solver))
        rows.append(made | {"seconds": time.perf_counter() - t0})
        t0 = time.perf_counter()
    return rows


def _best(system: FTCSystem, gamma: float | None, k_max: float | None, solver: str, calls: SolverCalls,
          max_iter: int, tol: float) -> tuple[list[Matrix] | None, list[float], str, str | None, list[dict[str, Any]]]:
    """The ``best`` method: every start (``iterative``'s and :data:`EXTRA_STARTS`), then the
    descent from the best start of ``iterative`` (so the result is never worse than
    ``iterative``) and from the best start overall when that is another one, each
    followed by the polish of its result (the two are independent: the second runs in a
    forked child, :class:`~ftc_verify.analysis.solvers.ForkedCall`); the smallest
    certified gamma of all these routes wins. Every route is a row."""
    rows = _starts(system, gamma, k_max, solver, calls, None, extra=True)
    certified = [r for r in rows if r["gamma_certified"] is not None]
    if not certified:
        return None, [], f"no certified route ({len(rows)} tried)", None, rows
    seeds = [min((r for r in certified if r["name"] not in EXTRA_STARTS), key=lambda r: r["gamma_certified"],
                 default=None), min(certified, key=lambda r: r["gamma_certified"])]
    todo: list[dict[str, Any]] = []
    for seed in seeds:
        if seed is not None and all(seed["name"] != t["name"] for t in todo):
            todo.append(seed)

    def run(seed: dict[str, Any]) -> tuple[list[dict[str, Any]], list[Any]]:
        """One descent, then the polish of its result, with calls of their own: their rows
        (the polish's history continues the descent's) and their solver outcomes."""
        own, t0 = SolverCalls(solver), time.perf_counter()
        found = descend(lambda G: state_feedback_loop(system, G),
                        lambda P, lam, j: gain_step(system, P, lam, j, own, k_max), system.m,
                        list(seed["gains"]), own, solver, max_iter, tol, seed.get("lmi"))
        history = found.history
        out = [{"name": f"descent from {seed['name']}", "gamma_certified": history[-1] if history else None,
                "spectral_abscissa": None, "note": "", "reason": "" if history else found.message,
                "gains": found.gains, "history": history, "seconds": time.perf_counter() - t0}]
        if history:
            t0 = time.perf_counter()
            gains, more, msg = polish(system, found.gains, found.lmi, own, solver, k_max)
            out.append({"name": f"polish after descent from {seed['name']}", "gamma_certified": more[-1] if more
                        else None, "spectral_abscissa": None, "note": msg, "reason": "" if more else msg,
                        "gains": gains, "history": history + more[1:], "seconds": time.perf_counter() - t0})
        return out, own.outcomes

    # the second descent and its polish (independent of the first) in a forked child, on the second core
    forked = ForkedCall(lambda: run(todo[1]), "a descent") if len(todo) > 1 and hasattr(os, "fork") else None
    try:
        done = [run(todo[0])] + ([forked.result()] if forked is not None else [run(t) for t in todo[1:]])
    finally:
        if forked is not None:
            forked.cancel()
    for made, outcomes in done:
        rows.extend(made)
        calls.outcomes.extend(outcomes)
    win = min((r for r in rows if r["gamma_certified"] is not None), key=lambda r: r["gamma_certified"])
    history = list(win.get("history") or [win["gamma_certified"]])
    return list(win["gains"]), history, f"best certified route: {win['name']} (gamma {upper_text(win['gamma_certified'])})", \
        win["name"], rows


def _iterative(system: FTCSystem, gamma: float | None, k_max: float | None, solver: str, calls: SolverCalls,
               start: list[Matrix] | None, max_iter: int, tol: float,
               ) -> tuple[list[Matrix] | None, list[float], str, str | None, list[dict[str, Any]], Any]:
    """The iterative method: certify the starts, descend from the best one; also the
    analysis of the result (:func:`_verify`) when it was computed ahead, else ``None``.

    While two-step, the longest start, runs in its child, the descent from the best of
    the other starts and the analysis of its result run here (``ahead``, with solver
    calls of their own); they are kept only when that start is the best of all (two-step
    not certified, or certified above it: ``min`` keeps the first of equal gammas, which
    is two-step's row), so the result is the one of the serial order, and the calls are
    added in that order."""
    early: dict[str, Any] = {}

    def descent(best: dict[str, Any], own: SolverCalls) -> Descent:
        return descend(lambda G: state_feedback_loop(system, G),
                       lambda P, lam, j: gain_step(system, P, lam, j, own, k_max), system.m,
                       list(best["gains"]), own, solver, max_iter, tol, best.get("lmi"))

    def ahead(rows: list[dict[str, Any]]) -> None:
        certified = [r for r in rows if r["gamma_certified"] is not None]
        if certified:
            best, own = min(certified, key=lambda r: r["gamma_certified"]), SolverCalls(solver)
            found = descent(best, own)
            early.update(row=best, found=found, calls=own, report=_verify(system, found.gains, solver))

    rows = _starts(system, gamma, k_max, solver, calls, start, meanwhile=ahead)
    certified = [r for r in rows if r["gamma_certified"] is not None]
    if not certified:
        return None, [], f"no certified start ({len(rows)} tried)", None, rows, None
    best = min(certified, key=lambda r: r["gamma_certified"])
    report = None
    if early.get("row") is best:
        found, report = early["found"], early["report"]
        calls.outcomes.extend(early["calls"].outcomes)
    else:
        found = descent(best, calls)
    msg = f"start {best['name']} (certified gamma {upper_text(best['gamma_certified'])}); {found.message}"
    return found.gains, found.history, msg, best["name"], rows, report


def _design(system: FTCSystem, method: str, gamma: float | None, k_max: float | None, calls: SolverCalls,
            full_info: Any = False) -> tuple[list[Matrix] | None, float | None, str]:
    """The gains of one convex method (``two-step``, ``full-info``, ``common`` or an
    :data:`EXTRA_STARTS` design), not yet certified: ``(gains, synthesis gamma, message)``.
    ``full_info``: the full-information solution when already solved (two-step's lower
    bracket)."""
    if method == "two-step":
        return (two_step(system, gamma, calls, k_max) if gamma is not None
                else _two_step_min(system, calls, k_max, full_info))
    if method in EXTRA_STARTS:
        return convex_gains(system, method, calls, k_max)
    sol = xy_solve(system, method, gamma, calls, k_max)
    if sol is None:
        return None, None, f"{method} LMI {calls.unsolved()}" + (f" at gamma {gamma:.6g}" if gamma else "")
    Ks = [Y @ np.linalg.inv(X) for X, Y in zip(sol["X"], sol["Y"])]  # per joint state
    pairs = [Ks[system.chain.state_index(i, j)] for i in range(system.m) for j in range(system.m)]
    gains = Ks[:1] * system.m if method == "common" else pairs
    return gains, sol["gamma"], f"{method} LMI solved at gamma {sol['gamma']:.6g}"


def synthesize(
    system: FTCSystem,
    *,
    method: str = "best",
    gamma: float | None = None,
    k_max: float | None = None,
    solver: str | None = None,
    start: list[Matrix] | None = None,
    max_iter: int = 10,
    tol: float = 1e-3,
) -> SynthesisResult:
    """Synthesize gains by ``method`` (see module docstring) and verify them.

    ``gamma=None`` minimises gamma (bisection for ``two-step``, gamma**2 as a variable for ``full-info``/``common``);
    a given gamma (at most :data:`~ftc_verify.limits.GAMMA_MAX`) asks for feasibility at that level. ``iterative``
    starts from ``start`` or else from the best certified of the starts in the module docstring.
    """
    if method not in METHODS:
        raise ValidationError(f"method: unknown method {method!r}; choose from {list(METHODS)}")
    check_levels(gamma, k_max)
    t0 = time.perf_counter()
    n = system.dims[0]
    name = choose_solver(solver, system.chain.n_states * (n * (n + 1) // 2 + n * system.dims[1]) + 1)
    calls = SolverCalls(name)
    history: list[float] = []
    gains: list[Matrix] | None = None
    gsyn: float | None = None
    msg = ""
    if method in ("two-step", "full-info", "common") + EXTRA_STARTS:
        gains, gsyn, msg = _design(system, method, gamma, k_max, calls)
    rows: list[dict[str, Any]] = []
    start_name = None
    reference = None
    report = None  # the analysis of the gains, when computed ahead (iterative)
    if method == "iterative":
        gains, history, msg, start_name, rows, report = _iterative(system, gamma, k_max, name, calls, start,
                                                                   max_iter, tol)
        gsyn = history[-1] if history else None
    elif method == "best":
        forked = ForkedCall(lambda: reference_alone(system, name), "the reference design") if hasattr(os, "fork") \
            else None
        try:
            gains, history, msg, start_name, rows = _best(system, gamma, k_max, name, calls, max_iter, tol)
            reference, outcomes = forked.result() if forked is not None else reference_alone(system, name)
        finally:
            if forked is not None:
                forked.cancel()
        calls.outcomes.extend(outcomes)
        gsyn = history[-1] if history else None
    if report is None and gains is not None:
        report = _verify(system, gains, name)
    certified = report is not None and report.certified_stable and report.robust.certified
    diagnosis = None
    if not certified:
        seen = rows + ([{"spectral_abscissa": report.mss.spectral_abscissa}] if report is not None else [])
        diagnosis = diagnose(system, seen, [o.status for o in calls.outcomes], k_max)
        msg = f"{msg}; {diagnosis['message']}"
    return SynthesisResult(
        method, gains is not None, tuple(gains or ()), gsyn, name, calls.seconds,
        time.perf_counter() - t0, calls.count, report, msg, k_max, tuple(history), start_name,
        tuple({k: r.get(k) for k in _PUBLIC_START_KEYS} for r in rows), diagnosis, reference=reference,
    )
