"""Stage 2b: controllers designed from a system; every result is certified by :mod:`ftc_verify.analysis`.

:mod:`.results` (the result every method returns and the log of its solver calls),
:mod:`.state_feedback` (``u = K_l x``), :mod:`.starts` (the starts of its iterative
method and the diagnosis when nothing is certified), :mod:`.convex_designs` (the dilated
design and the true-mode reference), :mod:`.output_feedback` (dynamic controllers on
``y_m = Cy x``: CCL of Theorem 5.1, observer baseline, V-K iteration), :mod:`.descent`
(the abscissa descent) and :mod:`.hinf_descent` (BFGS on the bounded-real gamma).
"""

from __future__ import annotations

from .output_feedback import OF_METHODS, synthesize_output_feedback
from .results import SolverCalls, SynthesisResult
from .state_feedback import METHODS, gain_step, synthesize, two_step

__all__ = [
    "METHODS",
    "OF_METHODS",
    "SynthesisResult",
    "SolverCalls",
    "synthesize",
    "synthesize_output_feedback",
    "two_step",
    "gain_step",
]
