"""Stage 5: exact moments, worst-case disturbances, Monte Carlo statistics, the ``verify`` main job
and its report."""

from __future__ import annotations

from ..analysis.moments.energy import EXOSYSTEMS, ExactEnergy, exact_energy, WorstCase, worst_case_disturbance
from .montecarlo import MCEstimate, estimate, clopper_pearson, sequential_estimate, monte_carlo
from .report import write_report, render_markdown
from .verify import Check, VerifyReport, run_verify, AGREE_RTOL, MAX_EXACT_VERTICES

__all__ = [
    "EXOSYSTEMS",
    "ExactEnergy",
    "exact_energy",
    "WorstCase",
    "worst_case_disturbance",
    "MCEstimate",
    "estimate",
    "clopper_pearson",
    "sequential_estimate",
    "monte_carlo",
    "write_report",
    "render_markdown",
    "Check",
    "VerifyReport",
    "run_verify",
    "AGREE_RTOL",
    "MAX_EXACT_VERTICES",
]
