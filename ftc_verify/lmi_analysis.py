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
:math:`\gamma_1` whose certificate passes.

Outcomes: ``certified`` (the numpy check of :mod:`ftc_verify.lmi` passed),
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

from .closedloop import ClosedLoop
from .lmi import Certificate, block_specs, check_certificate, lyapunov_block
from .model import Matrix
from .solvers import SETTINGS, SolveOutcome, choose_solver, second_solver, solve

__all__ = ["GAMMA_LADDER", "LMIResult", "mes_lmi", "hinf_gamma", "decision_size"]

#: Relative increases of gamma tried, in order, when re-solving for a certificate.
GAMMA_LADDER = (1e-4, 1e-3, 1e-2, 5e-2, 0.2, 1.0)


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
        }


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
    """Theorem 3.1 (eq. (4)) on the nominal loop over the ``beta`` box, certified."""
    import cvxpy as cp

    condition = "theorem-3.1"
    nominal = loop.nominal()
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
    Lemma 4.1 with the gains fixed (``robust=True``, eq. (16) in LMI form)."""
    import cvxpy as cp

    condition = "lemma-4.1" if robust else "theorem-3.2"
    target = loop if robust else loop.nominal()
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
        for rho in GAMMA_LADDER:
            gamma1 = gamma_star * (1.0 + rho) + 1e-7
            g_fixed.value = gamma1 ** 2
            out2 = solve(step2, name)
            attempts.append(out2)
            if not (out2.solved and _has_values(P)):
                continue
            Pv, lv = _values(P, lam)
            cert = check_certificate(target, condition, Pv, lv, gamma1 ** 2)
            spent = sum(a.seconds for a in attempts)
            status = out2.status if out2.status != "optimal" else out.status
            if cert.ok:
                note = f"minimum {gamma_star:.6g} from step 1; certified at {gamma1:.6g} (+{rho:g} relative)"
                if status != "optimal":
                    note += f"; solver status {status}, accepted only because the certificate passed"
                return LMIResult(condition, "certified", gamma1, name, status, t_build, spent, cert, Pv, lv, note, tuple(attempts))
            if best is None:
                best = LMIResult(condition, "candidate", gamma_star, name, status, t_build, spent, cert, Pv, lv,
                                 f"no certificate up to gamma {gamma1:.6g}: {cert.reason}", tuple(attempts))
    if best is not None:
        best = dataclasses.replace(best, solve_seconds=sum(a.seconds for a in attempts), attempts=tuple(attempts))
    return _conclude(condition, attempts, best, t_build)
