r"""A refinement of the proved ``h_max`` bracket that the user asks for (``analyze
--h-max-work UNITS``, ``verify --h-max-work UNITS``), after the scan and the default
bracket of :func:`~ftc_verify.analysis.moments.sampled_bracket.h_max_bracket`, with its
own budget of work units (never seconds: from the same starting bracket, the same loop
and budget give the same refinement on every machine). The starting bracket is the
default one, whose proofs also have a wall-clock safety valve (60 s in ``analyze``, 30 s
in ``verify``): where that valve stops them on a slow machine, the ladder starts from a
different bracket.

**Why a separate stage.** On loops with many uncertain rates the default bracket stops
short of ``rtol`` (random ``n = 4, m = 3`` loops of ``benchmarks/sampled.py``'s draw:
2 % to 17 %; ``benchmarks/results/h31p.md``, ``h31n.md``): near the worst vertex a few
rates are flat on the scale of the margin while the one-period map depends on them
strongly, so a proof polynomial in the rates needs hundreds of sub-boxes. The stage
proves periods closer to the proved-unstable end by covers of the rate box with cubic
clock-dependent certificates (:mod:`~ftc_verify.analysis.moments.sampled_cover`,
:mod:`~ftc_verify.analysis.moments.sampled_cubic`): their conditions are affine in the
rates, so a few sub-boxes cover the box, and cubic pieces in the clock reach in two or
four pieces what quadratic pieces reached in 16 to 32 (``benchmarks/results/h31r.md``;
the quadratic ladder it replaces: ``h31q.md``, ``h31e.md``).

**Memory.** The cover solves one program at a time, of 2 or 4 cubic pieces
(:data:`~ftc_verify.analysis.moments.sampled_cover.PIECES`; every sub-box's program of a
given number of pieces has the size of the whole box's). The check estimates the largest,
4 pieces (:func:`~ftc_verify.analysis.moments.sampled_cover.cubic_memory`: 0.4 GB on
``n = 4, m = 3``), before anything starts, and
refuses above :data:`REFINE_MEMORY` (the CLI: exit 2 naming ``--h-max-work``), whatever
the budget.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

from .sampled import H_MAX_RTOL, SampledLoop
from .sampled_cover import cover_h_max, cubic_memory

if TYPE_CHECKING:
    from ...controllers.controller import Controller
    from ...model.system import FTCSystem
    from .sampled import SampledResult

__all__ = ["REFINE_MEMORY", "check_refine", "refine_result", "refinement_note", "period_text"]

#: The largest estimated memory (bytes) of a refinement's program (or
#: :func:`~ftc_verify.limits.memory_limit` when that is lower).
REFINE_MEMORY = 4.0e9


#: How the refinement's part of ``h_max_note`` starts (:func:`refinement_note`).
_NOTE_HEAD = "; refinement ("


def check_refine(system: FTCSystem, controller: Controller, period: float | None, work: float, *,
                 loop: SampledLoop | None = None) -> None:
    """Refuse ``--h-max-work work`` before any work (a
    :class:`~ftc_verify.errors.ValidationError`, exit 2, naming the option): without a
    sampling period, or when the refinement's program
    (:func:`~ftc_verify.analysis.moments.sampled_cover.cubic_memory`) is estimated above
    :data:`REFINE_MEMORY` or the memory limit. ``loop``: the sampled loop when the caller
    has it (built from ``system`` and ``controller`` otherwise)."""
    from ...errors import ValidationError

    if period is None:
        raise ValidationError(f"--h-max-work {work:g}: refines the sampled loop's h_max bracket; give --period "
                              "(or a period in the controller file)")
    from ...limits import memory_limit

    limit = min(REFINE_MEMORY, memory_limit())  # FTC_VERIFY_MEMORY_LIMIT or 80 % of the free memory, if lower
    need = cubic_memory(SampledLoop.of(system, controller, loop))
    if need > limit:
        raise ValidationError(f"--h-max-work {work:g}: the refinement's clock program needs about {need / 1e9:.1f} GB, "
                              f"over the {limit / 1e9:.1f} GB limit")


def refine_result(system: FTCSystem, controller: Controller, result: SampledResult, work: float,
                  rtol: float = H_MAX_RTOL, *, loop: SampledLoop | None = None) -> SampledResult:
    """``result`` (of :func:`~ftc_verify.analysis.moments.sampled.sampled_analysis`) with
    its ``h_max`` refined by :func:`~ftc_verify.analysis.moments.sampled_cover.cover_h_max`
    within ``work`` units when its bracket is wider than ``rtol``, or has no stable end
    (then from ``h_max_unstable / 2``: the ladder starts 12.5 % below the unstable end);
    unchanged otherwise. The note says what was done. ``loop``: the sampled loop when the
    caller has it (built from ``system`` and ``controller`` otherwise)."""
    from .sampled_conditioned import conditioned

    hm, hu = result.h_max, result.h_max_unstable
    if hu is None or (hm is not None and (hu - hm) / hu <= rtol) or work <= 0:
        return result
    if hm is None:  # no stable end proved (e.g. the wall-time valve): start from a 50 % bracket
        hm = 0.5 * hu
    base = SampledLoop.of(system, controller, loop)
    ref = cover_h_max(conditioned(dataclasses.replace(base, written=(float(result.period),))), hm, hu, work, rtol)
    how = "one-period map" if ref.attempts == 0 else "one-period map or a cubic clock certificate"
    note = (f"{_NOTE_HEAD}--h-max-work {work:g}): {ref.attempts} cubic clock certificate(s), {ref.maps} sub-box map "
            f"proof(s), {ref.work:.0f} units, " + ("no closer period proved" if ref.h_max is None else
                                                   f"proved stable over the rate box at {period_text(ref.h_max, down=True)} "
                                                   f"by {ref.boxes} sub-box(es), each by its {how} (relative gap "
                                                   f"{(hu - ref.h_max) / hu:.1e})"))
    better = ref.h_max is not None and (result.h_max is None or ref.h_max > result.h_max)
    return dataclasses.replace(result, h_max=ref.h_max if better else result.h_max,
                               h_max_note=result.h_max_note + note)


def refinement_note(result: SampledResult) -> str | None:
    """The part of ``result.h_max_note`` that :func:`refine_result` wrote (what the
    refinement did and cost), ``None`` when it did not run."""
    _, found, after = result.h_max_note.partition(_NOTE_HEAD)
    return (_NOTE_HEAD + after).lstrip("; ") if found else None


def period_text(h: float, *, down: bool) -> str:
    """``h`` to 6 significant digits, rounded down (``down``: a proved-stable period,
    never printed above the one proved) or up (a proved-unstable one), so that the
    printed number keeps the claim (:mod:`ftc_verify.claimtext`)."""
    from ...claimtext import lower_text, upper_text

    return lower_text(h) if down else upper_text(h)
