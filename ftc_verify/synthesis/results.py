"""What every synthesis method returns, the log of its solver calls, and its verification.

:class:`SynthesisResult` is the result of :func:`~ftc_verify.synthesis.state_feedback.synthesize`
and :func:`~ftc_verify.synthesis.output_feedback.synthesize_output_feedback`;
:class:`SolverCalls` counts and times the convex programs a run solves (its own and those of
the nested runs it starts); :func:`verify_controller` is the core analysis that certifies
every designed controller (never the synthesis LMI alone).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..analysis.analyze import AnalysisReport, analyze, json_ready
from ..analysis.closedloop import closed_loop
from ..analysis.conic import ConicProblem
from ..analysis.solvers import SolveOutcome, solve, solve_conic
from ..controllers.controller import Controller
from ..errors import ValidationError
from ..limits import GAMMA_MAX
from ..model.system import FTCSystem, Matrix

__all__ = ["SynthesisResult", "SolverCalls", "check_levels", "verify_controller"]


@dataclass(frozen=True, eq=False)
class SynthesisResult:
    """Gains (or a dynamic controller) from one method and their independent verification.

    Attributes
    ----------
    method : str
        The method that produced the result (the route chosen, for ``auto``).
    feasible : bool
        A controller was found (certified or not: see :attr:`certified`).
    gains : tuple of arrays
        The state-feedback gains, or the blocks ``K_j`` of a dynamic controller.
    synthesis_gamma : float or None
        The gamma the synthesis itself reached (not certified).
    solver, solve_seconds, wall_seconds, solver_calls
        The solver used, the time of its calls and of the whole run, and the number of
        calls (:class:`SolverCalls`).
    report : AnalysisReport or None
        The core analysis of the closed loop (:func:`verify_controller`).
    message : str
        What happened, with the diagnosis when nothing was certified.
    k_max : float or None
        The gain bound the design respected.
    history : tuple of float
        The certified gammas of the accepted iterates (the start's first).
    start, starts, diagnosis
        The start chosen, every start tried (public keys only) and the diagnosis when
        nothing was certified.
    dynamic : Controller or None
        The dynamic controller of output-feedback synthesis.
    ccl_history : tuple of float
        The residuals of the cone complementarity linearisation.
    nominal_accepted : bool
        A certified nominal gamma suffices for :attr:`certified` (the output-feedback descent).
    iterations : int or None
        The iterations of the method when it counts them itself (CCL: its points); ``None``
        counts one per accepted iterate after the start, ``len(history) - 1``.
    reference : dict or None
        The ``best`` method's reference line: the gamma of the classical mode-dependent
        design whose gains see the true mode (``lmi_gamma``, no gain bound) and the core's
        certified robust gamma of those gains on the joint chain (``gamma_certified``);
        a reference, not a bound (:mod:`~ftc_verify.synthesis.convex_designs`).
    """

    method: str
    feasible: bool
    gains: tuple[Matrix, ...]
    synthesis_gamma: float | None
    solver: str
    solve_seconds: float
    wall_seconds: float
    solver_calls: int
    report: AnalysisReport | None
    message: str
    k_max: float | None = None
    history: tuple[float, ...] = ()
    start: str | None = None
    starts: tuple[dict[str, Any], ...] = ()
    diagnosis: dict[str, Any] | None = None
    dynamic: Controller | None = None
    ccl_history: tuple[float, ...] = ()
    nominal_accepted: bool = False
    iterations: int | None = None
    reference: dict[str, Any] | None = None

    @property
    def controller(self) -> Controller | None:
        """The gains as a :class:`~ftc_verify.controllers.Controller` (``None`` when none
        were found; the dynamic controller of output-feedback synthesis); what every later
        stage consumes."""
        if self.dynamic is not None:
            return self.dynamic
        return Controller.state_feedback(self.gains, name=self.method) if self.gains else None

    @property
    def certified(self) -> bool:
        """Gains found, certified stable, and a robust gamma certified by the core (or, with
        ``nominal_accepted`` -- the output-feedback descent -- at least the nominal one)."""
        rep = self.report
        if not (self.feasible and rep is not None and rep.certified_stable):
            return False
        return rep.robust.certified or (self.nominal_accepted and rep.nominal.certified)

    @property
    def gamma_certified(self) -> float | None:
        """Certified robust gamma of the closed loop (Lemma 4.1 with these gains)."""
        ok = self.certified and self.report is not None and self.report.robust.certified
        return self.report.robust.gamma if ok and self.report is not None else None

    @property
    def gamma_nominal_certified(self) -> float | None:
        """Certified nominal gamma (Theorem 3.2) of the closed loop."""
        if self.report is None or not self.report.nominal.certified:
            return None
        return self.report.nominal.gamma

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready result (the schema of :doc:`/reference/report-schema`)."""
        rep = self.report
        return json_ready({
            "feasible": self.feasible,
            "certified": self.certified,
            "certified_gamma_kind": (None if not self.certified or self.report is None else
                                     "robust" if self.report.robust.certified else "nominal"),
            "method": self.method,
            "gamma_certified": self.gamma_certified,
            "gamma_nominal_certified": self.gamma_nominal_certified,
            "spectral_abscissa": None if rep is None else rep.mss.spectral_abscissa,
            "synthesis_gamma": self.synthesis_gamma,
            "gains": [K.tolist() for K in self.gains],
            "max_gain_norm": max((float(np.linalg.norm(K, 2)) for K in self.gains), default=None),
            "k_max": self.k_max,
            "solver": self.solver,
            "solve_seconds": self.solve_seconds,
            "wall_seconds": self.wall_seconds,
            "solver_calls": self.solver_calls,
            "history": list(self.history),
            "iterations": self.iterations if self.iterations is not None else max(len(self.history) - 1, 0),
            "ccl_history": list(self.ccl_history),
            "controller": None if self.dynamic is None else self.dynamic.to_dict(),
            "start": self.start,
            "starts": list(self.starts),
            "diagnosis": self.diagnosis,
            "reference": self.reference,
            "message": self.message,
            "analysis": None if rep is None else rep.to_dict(),
        })


def check_levels(gamma: float | None, k_max: float | None) -> None:
    """Refuse (:class:`~ftc_verify.errors.ValidationError`) a ``gamma`` or ``k_max`` that is
    not a positive finite number, and a ``gamma`` above :data:`~ftc_verify.limits.GAMMA_MAX`
    (the syntheses form its square)."""
    for name, val, top in (("gamma", gamma, GAMMA_MAX), ("k_max", k_max, math.inf)):
        if val is not None and not (math.isfinite(val) and val > 0):
            raise ValidationError(f"{name}: must be a positive finite number, got {val!r}")
        if val is not None and val > top:
            raise ValidationError(f"{name}: must be at most {top:g} (its square must stay a finite float64 number), "
                                  f"got {val!r}")


class SolverCalls:
    """The solver calls of one synthesis run: how many and how long.

    Every convex program of a run goes through :meth:`run` (cvxpy) or :meth:`run_conic`; the attempts of the core's
    certifications are appended to ``outcomes`` by the caller, and the totals of a
    nested run (the seeds of ``iterative``, the state-feedback designs under the
    observers) are added by :meth:`absorb`.

    Parameters
    ----------
    solver : str
        The solver every call uses (:func:`~ftc_verify.analysis.solvers.choose_solver`).

    Attributes
    ----------
    solver : str
        As given.
    outcomes : list of SolveOutcome
        Every call of this run, in order.
    nested_calls, nested_seconds
        The calls and their seconds of the nested runs absorbed.
    """

    def __init__(self, solver: str) -> None:
        self.solver = solver
        self.outcomes: list[SolveOutcome] = []
        self.nested_calls = 0
        self.nested_seconds = 0.0

    def run(self, problem: Any) -> SolveOutcome:
        """Solve the cvxpy ``problem`` by :func:`~ftc_verify.analysis.solvers.solve` and log it."""
        out = solve(problem, self.solver)
        self.outcomes.append(out)
        return out

    def run_conic(self, problem: ConicProblem) -> tuple[SolveOutcome, Matrix | None]:
        """Solve a :class:`~ftc_verify.analysis.conic.ConicProblem` by
        :func:`~ftc_verify.analysis.solvers.solve_conic` (Clarabel natively, the other
        solvers through cvxpy from the same numbers) and log it; ``(outcome, x)``, ``x``
        ``None`` unless the solver returned a finite point."""
        out, x = solve_conic(problem, self.solver)
        self.outcomes.append(out)
        return out, x

    def unsolved(self) -> str:
        """Why the last call gave no usable point, for a message: ``infeasible`` only when
        the solver said so; a failure (an exception, a Rust panic, a numerical status)
        names the solver and what it said; a point without margin says so."""
        out = self.outcomes[-1]
        if out.infeasible:
            return "infeasible"
        if out.solved:
            return "without a strictly feasible point"
        said = out.message if out.solver in out.message else f"{out.solver} status {out.status} {out.message}".strip()
        return f"not solved (solver failure: {said})"

    def absorb(self, other: SynthesisResult) -> None:
        """Count the calls of a nested synthesis."""
        self.nested_calls += other.solver_calls
        self.nested_seconds += other.solve_seconds

    @property
    def count(self) -> int:
        """Calls of this run and of the nested ones."""
        return len(self.outcomes) + self.nested_calls

    @property
    def seconds(self) -> float:
        """Solver seconds of this run and of the nested ones."""
        return sum(o.seconds for o in self.outcomes) + self.nested_seconds


def verify_controller(system: FTCSystem, controller: Controller, solver: str) -> AnalysisReport:
    """The core analysis (spectral test, Theorem 3.1, nominal and robust gamma) of the
    closed loop of ``system`` and ``controller`` (:func:`~ftc_verify.analysis.analyze.analyze`,
    without the cross-validation)."""
    return analyze(closed_loop(system, controller), solver=solver, name=system.name, cross_validation=False)
