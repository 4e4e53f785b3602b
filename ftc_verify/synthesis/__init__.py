"""Stage 2b: controllers designed from a system; every result is certified by :mod:`ftc_verify.analysis`."""

from __future__ import annotations

from .state_feedback import METHODS, SynthesisResult, synthesize, two_step, gain_step

__all__ = [
    "METHODS",
    "SynthesisResult",
    "synthesize",
    "two_step",
    "gain_step",
]
