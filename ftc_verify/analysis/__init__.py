"""Stage 3: the closed loop built from (system, controller) and everything proved about it:
stability over the whole rate box, LMI blocks and independently checked certificates on the
loop as written, proved lower bounds of every gamma, the LMIs as conic programs, solvers,
python-control cross-check."""

from __future__ import annotations

from .analyze import AnalysisReport, analyze, json_ready
from .conic import ConicProblem
from .closedloop import Channel, ClosedLoop, Barred, barred, closed_loop, state_feedback_loop, gain_loop
from .crossval import NORM_RTOL, NORM_AGREE_RTOL, POLE_RTOL, ModeCheck, linf_norm, cross_validate
from .lmi import BlockSpec, block_specs, lyapunov_block, xy_block, null_basis, projection, BlockCheck, Certificate, check_certificate
from .lmi_analysis import GAMMA_LADDER, LMIResult, mes_lmi, hinf_gamma
from .lmi_size import decision_size
from .solvers import SOLVERS, SETTINGS, SolveOutcome, choose_solver, second_solver, solve, solve_conic
from .box import BoxVerdict, RegionVerdict, box_stability
from .exact import exact_loop
from .lower_bound import GainLowerBound, gain_lower_bound
from .moments.stability import MSSResult, duplication_matrix, second_moment_generator, spectral_abscissa, mean_square_stability, abscissa_below, abscissa_near

__all__ = [
    "AnalysisReport",
    "analyze",
    "json_ready",
    "Channel",
    "ClosedLoop",
    "Barred",
    "barred",
    "closed_loop",
    "state_feedback_loop",
    "gain_loop",
    "NORM_RTOL",
    "NORM_AGREE_RTOL",
    "POLE_RTOL",
    "ModeCheck",
    "linf_norm",
    "cross_validate",
    "BlockSpec",
    "block_specs",
    "lyapunov_block",
    "xy_block",
    "null_basis",
    "projection",
    "BlockCheck",
    "Certificate",
    "check_certificate",
    "GAMMA_LADDER",
    "LMIResult",
    "mes_lmi",
    "hinf_gamma",
    "decision_size",
    "SOLVERS",
    "SETTINGS",
    "SolveOutcome",
    "choose_solver",
    "second_solver",
    "solve",
    "solve_conic",
    "ConicProblem",
    "MSSResult",
    "duplication_matrix",
    "second_moment_generator",
    "spectral_abscissa",
    "mean_square_stability",
    "abscissa_below",
    "abscissa_near",
    "BoxVerdict",
    "RegionVerdict",
    "box_stability",
    "exact_loop",
    "GainLowerBound",
    "gain_lower_bound",
]
