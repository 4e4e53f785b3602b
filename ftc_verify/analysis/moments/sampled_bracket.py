"""The stable end of the sampled loop's ``h_max`` bracket
(:func:`ftc_verify.analysis.moments.sampled.h_max_bracket`): which periods below the
float64 crossing to prove stable over the rate box, in which order, with which budget.

A proof over the rate box near the crossing has a small margin and needs many sub-boxes
(:func:`~ftc_verify.analysis.moments.sampled_proof.box_verdict`), so a failing attempt
spends its whole budget; the attempts are ordered so that few fail.
"""

from __future__ import annotations

import time

from .sampled import SampledLoop
from .sampled_proof import box_verdict

__all__ = ["prove_below"]


def prove_below(loop: SampledLoop, a: float, rtol: float, max_boxes: int, max_seconds: float,
                 deadline: float) -> float | None:
    """A period ``a (1 - f)`` below the float64 crossing ``a`` proved mean-square stable
    over the whole rate box, the closest to ``a`` of those tried (``None`` if none; no
    attempt starts after ``deadline``, ``time.perf_counter()``): first ``f = rtol / 4`` with a third of the budget (the bracket within
    ``rtol`` at once); if that fails, easy first -- ``f = 0.1`` with the full budget,
    then ``10^{-2}`` and ``3 rtol / 4`` with a third each -- stopping at the first
    failure (a smaller margin is harder: its proof would rarely succeed and would spend
    its whole budget)."""

    def proved(f: float, seconds: float) -> bool:
        return box_verdict(loop, a * (1 - f), max_boxes=max_boxes, max_seconds=seconds).verdict == "stable"

    if time.perf_counter() > deadline:
        return None
    if proved(0.25 * rtol, max_seconds / 3):
        return a * (1 - 0.25 * rtol)
    best = None
    for f, seconds in ((0.1, max_seconds), (1e-2, max_seconds / 3), (0.75 * rtol, max_seconds / 3)):
        if time.perf_counter() > deadline or not proved(f, seconds):
            break
        best = a * (1 - f)
    return best
