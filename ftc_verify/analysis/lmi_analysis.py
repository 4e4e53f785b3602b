r"""LMI analysis of a fixed closed loop, with independently checked certificates.

* :func:`mes_lmi` -- Theorem 3.1 over the whole ``beta`` box: find :math:`P_s > 0` with
  :math:`\Pi_s < 0` at both ends of every rate. The conditions are homogeneous in
  :math:`P`, so the solver is asked for :math:`P_s \succeq I`, :math:`\Pi_s \preceq -I`
  (equivalent to strict feasibility) while minimising :math:`\max_s \lambda_{max}(P_s)`
  for conditioning.
* :func:`hinf_gamma` -- the smallest certified :math:`\gamma` of Theorem 3.2 (nominal,
  ``robust=False``) or of Lemma 4.1 with the gains fixed (``robust=True``; the
  S-procedure multipliers are free, so the problem is convex).

The minimal-:math:`\gamma` optimum lies on the boundary of the feasible set (singular
Lyapunov matrices), where no certificate can pass. So :func:`hinf_gamma` first
minimises :math:`g = \gamma^2`, then re-solves at :math:`\gamma_1 = \gamma^*(1+\rho)`
for :math:`\rho` in :data:`GAMMA_LADDER`, maximising a common margin :math:`t` with
:math:`M_s \preceq -t I`, :math:`P_s \succeq t I`, and reports the first
:math:`\gamma_1` whose certificate passes -- after :data:`REFINE_STEPS` geometric
bisections of :math:`\rho` between that step and the one before it when the one before
failed, so that a coarse ladder does not cost up to a factor 10 in :math:`\rho`.

Scaling: before any LMI is built the loop is balanced by one diagonal similarity
:math:`x = D\tilde x` common to every joint mode (:func:`balancing_scale`: LAPACK's
``gebal`` on :math:`\sum_s |A_s| + |B_{w,s}| \mathbf 1 \mathbf 1^T |C_{z,s}| + \sum_k
|E_{s,k}| \mathbf 1 \mathbf 1^T |F_{s,k}|`, the state-to-state gains including the loop that the
:math:`H_\infty` test closes from :math:`z` back to :math:`w`; :math:`D` holds powers of
two). Products with :math:`D` are exact in floating point, so the certificate checked on
the balanced loop is a certificate of the original loop; the returned ``P`` are mapped
back, :math:`P = D^{-1}\tilde P D^{-1}`. Without it a Hurwitz loop with states scaled by
1e3 and 1e-2 got "error"/"infeasible" from both solvers (``tests/test_lmi_analysis.py``).

Outcomes: ``certified`` (the numpy check of :mod:`ftc_verify.analysis.lmi` passed),
``candidate`` (a solver returned numbers that failed the check), ``infeasible`` (the
solver and a second, independent solver both claimed infeasibility) and ``error``.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..limits import check_memory
from ..model.system import Matrix
from .closedloop import ClosedLoop
from .lmi import Certificate, block_specs, check_certificate, lyapunov_block
from .solvers import SETTINGS, SolveOutcome, choose_solver, second_solver, solve

__all__ = ["GAMMA_LADDER", "LMIResult", "mes_lmi", "hinf_gamma", "decision_size", "balancing_scale",
           "lmi_memory_estimate", "check_lmi_memory", "LMI_BYTES_PER_NONZERO"]

#: Peak memory per estimated nonzero of the LMI data, cvxpy compile plus Clarabel solve
#: (measured: n = 30, m = 2 took +580 MB for 3.9e5 estimated nonzeros; n = 20, m = 3
#: +365 MB for 3.6e5).
LMI_BYTES_PER_NONZERO = 1600
#: Relative increases of gamma tried, in order, when re-solving for a certificate.
GAMMA_LADDER = (1e-5, 1e-4, 1e-3, 1e-2, 5e-2, 0.2, 1.0)
#: Geometric bisections between the last failing and the first certifying ladder step.
REFINE_STEPS = 3


@dataclass(frozen=True, eq=False)
class LMIResult:
    """Outcome of one LMI analysis, with the certificate and the matrices found."""

    condition: str
    outcome: str
    gamma: float | None
    solver: str
    solver_status: str
    build_seconds: float
    solve_seconds: float
    certificate: Certificate | None
    P: tuple[Matrix, ...] | None = None
    multipliers: tuple[tuple[float, ...], ...] | None = None
    message: str = ""
    attempts: tuple[SolveOutcome, ...] = field(default=())
    scale: tuple[float, ...] | None = None

    @property
    def certified(self) -> bool:
        """True only when the independent certificate passed."""
        return self.outcome == "certified" and self.certificate is not None and self.certificate.ok

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (matrices omitted)."""
        return {
            "condition": self.condition,
            "outcome": self.outcome,
            "certified": self.certified,
            "gamma": self.gamma,
            "solver": self.solver,
            "solver_settings": SETTINGS.get(self.solver, {}),
            "solver_status": self.solver_status,
            "build_seconds": self.build_seconds,
            "solve_seconds": self.solve_seconds,
            "message": self.message,
            "certificate": None if self.certificate is None else self.certificate.to_dict(),
            "attempts": [{"solver": a.solver, "status": a.status, "seconds": a.seconds, "message": a.message} for a in self.attempts],
            "balancing_scale": None if self.scale is None else list(self.scale),
        }


def balancing_scale(loop: ClosedLoop) -> Matrix:
    """Powers of two ``d`` such that ``loop.scaled(d)`` is balanced (module docstring)."""
    import scipy.linalg

    M = np.zeros((loop.n, loop.n))
    for A, Bw, Cz, chans in zip(loop.A, loop.Bw, loop.Cz, loop.channels):
        M += np.abs(A) + np.outer(np.abs(Bw).sum(axis=1), np.abs(Cz).sum(axis=0))
        for ch in chans:
            M += np.outer(np.abs(ch.E).sum(axis=1), np.abs(ch.F).sum(axis=0))
    _, (scale, _) = scipy.linalg.matrix_balance(M, permute=False, separate=True)
    return np.asarray(scale, dtype=float)


def _balanced(loop: ClosedLoop) -> tuple[ClosedLoop, Matrix]:
    d = balancing_scale(loop)
    return loop.scaled(d), d


def _unscale(result: LMIResult, d: Matrix) -> LMIResult:
    """Map ``P`` back to the original coordinates and record the scale."""
    P = None if result.P is None else tuple((P / d[:, None]) / d[None, :] for P in result.P)
    return dataclasses.replace(result, P=P, scale=tuple(float(v) for v in d))


def lmi_memory_estimate(loop: ClosedLoop, *, robust: bool) -> float:
    """Bytes the LMI stage of ``loop`` needs: blocks x (block size)^2 x (variables per
    entry) nonzeros times :data:`LMI_BYTES_PER_NONZERO`."""
    n, modes = loop.n, len(loop.A)
    extra = max((sum(ch.E.shape[1] for ch in chans) if robust else 0) + Bw.shape[1] + Cz.shape[0]
                for chans, Bw, Cz in zip(loop.channels, loop.Bw, loop.Cz))
    blocks = sum(len(loop.chain.row_beta_ends(i, j)) for i, j in loop.modes)
    return float(blocks * (n + extra) ** 2 * (2 * n + modes) * LMI_BYTES_PER_NONZERO)


def _check_size(loop: ClosedLoop, robust: bool, condition: str) -> None:
    check_memory(lmi_memory_estimate(loop, robust=robust),
                 f"the {condition} LMIs of a loop with n = {loop.n} and {len(loop.A)} joint modes",
                 hint="reduce the problem, or run the exact spectral test alone (analyze --no-lmi)")


def check_lmi_memory(loop: ClosedLoop) -> None:
    """Raise :class:`~ftc_verify.errors.MemoryLimitError` before any work when the largest
    LMI problem of :func:`~ftc_verify.analysis.analyze.analyze` would not fit in memory."""
    _check_size(loop, loop.uncertain, "Lemma 4.1" if loop.uncertain else "Theorem 3.2")


def decision_size(loop: ClosedLoop, *, robust: bool) -> int:
    """Number of scalar decision variables of the analysis LMIs (for solver choice)."""
    n = loop.n
    count = len(loop.A) * n * (n + 1) // 2 + 1
    if robust:
        count += sum(len(c) for c in loop.channels)
    return count


def _variables(loop: ClosedLoop, robust: bool) -> tuple[list[Any], list[list[Any]] | None]:
    import cvxpy as cp

    P = [cp.Variable((loop.n, loop.n), symmetric=True, name=f"P{s}") for s in range(len(loop.A))]
    lam = [[cp.Variable(nonneg=True) for _ in chans] for chans in loop.channels] if robust else None
    return P, lam


def _blocks_neg(loop: ClosedLoop, P: Sequence[Any], lam: Sequence[Any] | None, g: Any, margin: Any) -> list[Any]:
    import cvxpy as cp

    cons = []
    for spec in block_specs(loop):
        M = lyapunov_block(loop, spec, P, None if lam is None else lam[spec.s], g, cp.bmat)
        M = 0.5 * (M + M.T)
        cons.append(M << -margin * np.eye(M.shape[0]))
    return cons


def _values(P: Sequence[Any], lam: Sequence[Sequence[Any]] | None) -> tuple[tuple[Matrix, ...], tuple[tuple[float, ...], ...] | None]:
    Pv = tuple(np.array(p.value, dtype=float) for p in P)
    lv = None if lam is None else tuple(tuple(float(v.value) for v in row) for row in lam)
    return Pv, lv


def _solver_order(loop: ClosedLoop, solver: str | None, robust: bool) -> list[str]:
    first = choose_solver(solver, decision_size(loop, robust=robust))
    second = second_solver(first)
    return [first] + ([second] if second else [])


def _has_values(P: Sequence[Any]) -> bool:
    return all(p.value is not None and np.all(np.isfinite(p.value)) for p in P)


def _conclude(condition: str, attempts: list[SolveOutcome], best: LMIResult | None, t_build: float) -> LMIResult:
    """Candidate if some solver returned numbers, infeasible if every solver claimed so
    (at least two), error otherwise."""
    if best is not None:
        return best
    seconds = sum(a.seconds for a in attempts)
    last = attempts[-1]
    if len(attempts) >= 2 and all(a.infeasible for a in attempts):
        msg = "infeasible: " + ", ".join(f"{a.solver} says {a.status}" for a in attempts)
        return LMIResult(condition, "infeasible", None, attempts[0].solver, attempts[0].status, t_build, seconds, None, message=msg, attempts=tuple(attempts))
    msg = "; ".join(f"{a.solver}: {a.status}{' (' + a.message + ')' if a.message else ''}" for a in attempts)
    if all(a.infeasible for a in attempts):
        msg = "infeasibility claimed but not confirmed by a second solver: " + msg
    return LMIResult(condition, "error", None, last.solver, last.status, t_build, seconds, None, message=msg, attempts=tuple(attempts))


def mes_lmi(loop: ClosedLoop, *, solver: str | None = None) -> LMIResult:
    """Theorem 3.1 (eq. (4)) on the nominal loop over the ``beta`` box, certified, on
    the balanced loop (module docstring)."""
    _check_size(loop, False, "Theorem 3.1")
    balanced, d = _balanced(loop.nominal())
    return _unscale(_mes_lmi(balanced, solver), d)


def _mes_lmi(nominal: ClosedLoop, solver: str | None) -> LMIResult:
    import cvxpy as cp

    condition = "theorem-3.1"
    t0 = time.perf_counter()
    P, _ = _variables(nominal, robust=False)
    t = cp.Variable()
    eye = np.eye(nominal.n)
    cons = _blocks_neg(nominal, P, None, None, 1.0)
    cons += [p >> eye for p in P] + [p << t * eye for p in P]
    problem = cp.Problem(cp.Minimize(t), cons)
    t_build = time.perf_counter() - t0
    attempts: list[SolveOutcome] = []
    best: LMIResult | None = None
    for name in _solver_order(nominal, solver, robust=False):
        out = solve(problem, name)
        attempts.append(out)
        if not (out.solved and _has_values(P)):
            continue
        Pv, _ = _values(P, None)
        cert = check_certificate(nominal, condition, Pv, None, None)
        outcome = "certified" if cert.ok else "candidate"
        note = "" if out.status == "optimal" else f"solver status {out.status}; "
        res = LMIResult(condition, outcome, None, name, out.status, t_build, sum(a.seconds for a in attempts), cert, Pv,
                        message=note + ("certificate passed" if cert.ok else cert.reason), attempts=tuple(attempts))
        if cert.ok:
            return res
        best = best or res
    return _conclude(condition, attempts, best, t_build)


def hinf_gamma(loop: ClosedLoop, *, robust: bool, solver: str | None = None) -> LMIResult:
    """Smallest certified gamma: Theorem 3.2 (``robust=False``, eq. (12), Delta = 0) or
    Lemma 4.1 with the gains fixed (``robust=True``, eq. (16) in LMI form), on the
    balanced loop (module docstring)."""
    _check_size(loop, robust, "Lemma 4.1" if robust else "Theorem 3.2")
    balanced, d = _balanced(loop if robust else loop.nominal())
    return _unscale(_hinf_gamma(balanced, robust, solver), d)


def _hinf_gamma(target: ClosedLoop, robust: bool, solver: str | None) -> LMIResult:
    import cvxpy as cp

    condition = "lemma-4.1" if robust else "theorem-3.2"
    t0 = time.perf_counter()
    P, lam = _variables(target, robust)
    g = cp.Variable(nonneg=True)
    step1 = cp.Problem(cp.Minimize(g), _blocks_neg(target, P, lam, g, 0.0) + [p >> 0 for p in P])
    g_fixed = cp.Parameter(nonneg=True)
    t = cp.Variable()
    eye = np.eye(target.n)
    step2 = cp.Problem(
        cp.Maximize(t),
        _blocks_neg(target, P, lam, g_fixed, t) + [p >> t * eye for p in P] + [t <= 1.0],
    )
    t_build = time.perf_counter() - t0
    attempts: list[SolveOutcome] = []
    best: LMIResult | None = None
    for name in _solver_order(target, solver, robust):
        out = solve(step1, name)
        attempts.append(out)
        if not out.solved or g.value is None or not math.isfinite(float(g.value)):
            continue
        gamma_star = math.sqrt(max(float(g.value), 0.0))

        def attempt(rho: float) -> tuple[float, SolveOutcome, Any, Any, Any] | None:
            """Step 2 at ``gamma_star (1 + rho)``: ``(gamma1, outcome, P, lambda, numpy check)``."""
            gamma1 = max(gamma_star, 1e-7) * (1.0 + rho)
            g_fixed.value = gamma1 ** 2
            out2 = solve(step2, name)
            attempts.append(out2)
            if not (out2.solved and _has_values(P)):
                return None
            Pv, lv = _values(P, lam)
            return gamma1, out2, Pv, lv, check_certificate(target, condition, Pv, lv, gamma1 ** 2)

        failed = 0.0  # the largest rho tried that gave no certificate
        for rho in GAMMA_LADDER:
            found = attempt(rho)
            if found is not None and found[4].ok:
                for _ in range(REFINE_STEPS if failed > 0 else 0):  # bisect (geometrically) towards gamma_star
                    mid = math.sqrt(failed * rho)
                    closer = attempt(mid)
                    if closer is not None and closer[4].ok:
                        rho, found = mid, closer
                    else:
                        failed = mid
                gamma1, out2, Pv, lv, cert = found
                status = out2.status if out2.status != "optimal" else out.status
                note = f"minimum {gamma_star:.6g} from step 1; certified at {gamma1:.6g} (+{rho:.3g} relative)"
                if status != "optimal":
                    note += f"; solver status {status}, accepted only because the certificate passed"
                return LMIResult(condition, "certified", gamma1, name, status, t_build,
                                 sum(a.seconds for a in attempts), cert, Pv, lv, note, tuple(attempts))
            failed = rho
            if found is not None and best is None:
                gamma1, out2, Pv, lv, cert = found
                status = out2.status if out2.status != "optimal" else out.status
                best = LMIResult(condition, "candidate", gamma_star, name, status, t_build,
                                 sum(a.seconds for a in attempts), cert, Pv, lv,
                                 f"no certificate up to gamma {gamma1:.6g}: {cert.reason}", tuple(attempts))
    if best is not None:
        best = dataclasses.replace(best, solve_seconds=sum(a.seconds for a in attempts), attempts=tuple(attempts))
    return _conclude(condition, attempts, best, t_build)
