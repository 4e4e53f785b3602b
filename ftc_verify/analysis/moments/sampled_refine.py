r"""A refinement of the proved ``h_max`` bracket that the user asks for (``analyze
--h-max-work UNITS``), after the scan and the default bracket of
:func:`~ftc_verify.analysis.moments.sampled_bracket.h_max_bracket`, with its own budget
of work units (never seconds: the same loop and budget give the same bracket on every
machine).

**Why a separate stage.** On loops with many uncertain rates the default bracket stops
short of ``rtol`` (random ``n = 4, m = 3`` loops of ``benchmarks/sampled.py``'s draw:
2 % to 17 %; ``benchmarks/results/h31p.md``, ``h31n.md``): near the worst vertex a few
rates are flat on the scale of the margin while the one-period map depends on them
strongly, so a proof polynomial in the rates needs hundreds of sub-boxes. The
clock-dependent certificate of :mod:`~ftc_verify.analysis.moments.sampled_clock` needs
none: its conditions are affine in the rates and are checked at the vertices of each
generator row, so one certificate covers the whole box; what limits it is its number
``N`` of quadratic pieces in the clock. On the seed-1 loop the distance it proves below
the proved-unstable end roughly halves with each doubling of ``N`` (``N f`` about 0.04
for ``N = 4, 8, 16``; 32 pieces ``1.8e-3``; ``benchmarks/results/h31e.md``), at a cost
about ``V^1.3`` for a program of ``V`` variables and a memory about ``V^2.2``.

**The ladder.** Rung ``k`` is the period ``h_u (1 - f_k)`` with ``N_k = 4 \cdot 2^k``
pieces and ``f_k = g / 2^{k+1}``, ``g`` the default bracket's relative width and
``h_u`` its proved-unstable end: each rung doubles the pieces and halves the distance
(the bisection the measured ``N f`` suggests). The rungs are planned before any solve
from the budget alone (:func:`refine_plan`: the rungs whose summed work
:func:`clock_work` fits, and at most to ``f = rtol / 2``), tried in order and stopped at
the first failure; a failed rung ``k`` is followed by one attempt with the same pieces at
the geometric mean of its distance and the last proved one (the work of that attempt is
in the plan). A proved rung is one Clarabel program whose every condition is then proved
positive definite in ball arithmetic for the numbers as written
(:func:`~ftc_verify.analysis.moments.sampled_clock.clock_stable`): stability over the
whole rate box, as every claim of the bracket.

**Memory.** Clarabel's factorisation of the largest planned program is estimated before
anything starts (:func:`refine_memory`: 2.8 GB measured at 32 pieces on the seed-1 loop,
6.9 GB at 48); a plan above :data:`REFINE_MEMORY` is refused (the CLI: exit 2 naming
``--h-max-work``).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

from .sampled import H_MAX_RTOL, SampledLoop
from .sampled_clock import clock_size, clock_stable

if TYPE_CHECKING:
    from ...controllers.controller import Controller
    from ...model.system import FTCSystem
    from .sampled import SampledResult

__all__ = ["REFINE_START", "REFINE_MEMORY", "Refinement", "clock_work", "clock_memory", "refine_plan",
           "refine_memory", "check_refine", "refine_h_max", "refine_result"]

#: Quadratic pieces of the first rung (the default bracket's clock rung has 2).
REFINE_START = 4
#: The largest estimated memory (bytes) of a planned clock program (or
#: :func:`~ftc_verify.limits.memory_limit` when that is lower).
REFINE_MEMORY = 4.0e9


def clock_work(loop: SampledLoop, pieces: int) -> float:
    """The work units one attempt with ``pieces`` quadratic pieces is charged, from the
    program's size ``V`` (:func:`~ftc_verify.analysis.moments.sampled_clock.clock_size`)
    only: ``0.22 V^1.3`` -- about a millisecond of one core each, as
    :func:`~ftc_verify.analysis.moments.sampled_bracket.box_work`'s (seed-1 ``n = 4,
    m = 3`` loop: 4 pieces, ``V = 2961``, 7 CPU s, 7100 units; 8 pieces, ``V = 5733``,
    17 s, 16900 units; 16: 43 s, 40800 units; ``benchmarks/results/h31e.md``)."""
    return 0.22 * float(clock_size(loop, pieces, True)) ** 1.3


def clock_memory(loop: SampledLoop, pieces: int) -> float:
    """Estimated peak memory (bytes) of one attempt: ``2.8e9 (V / 22365)^2.2`` (measured
    2.8 GB at ``V = 22365``, 6.9 GB at ``V = 33453``; ``benchmarks/results/h31e.md``)
    plus 0.2 GB for the rest of the process."""
    return 2.8e9 * (float(clock_size(loop, pieces, True)) / 22365.0) ** 2.2 + 2.0e8


def refine_plan(loop: SampledLoop, gap: float, work: float, rtol: float = H_MAX_RTOL) -> tuple[tuple[int, float], ...]:
    """The rungs ``(pieces, f)`` (module docstring) for a default bracket of relative
    width ``gap`` within ``work`` units: each attempt is budgeted twice (the rung and the
    attempt after its failure); none once ``f`` would be below ``rtol / 2``."""
    plan: list[tuple[int, float]] = []
    spent, n, f = 0.0, REFINE_START, gap / 2.0
    while f >= rtol / 2.0 or not plan:
        cost = 2.0 * clock_work(loop, n)
        if spent + cost > work:
            break
        spent += cost
        plan.append((n, f))
        if f < rtol:
            break
        n, f = 2 * n, f / 2.0
    return tuple(plan)


def refine_memory(loop: SampledLoop, gap: float, work: float) -> float:
    """Estimated peak memory (bytes) of :func:`refine_h_max` with ``work`` units (0 when
    the plan is empty)."""
    plan = refine_plan(loop, gap, work)
    return max((clock_memory(loop, n) for n, _ in plan), default=0.0)


def check_refine(system: FTCSystem, controller: Controller, period: float | None, work: float) -> None:
    """Refuse ``--h-max-work work`` before any work (a
    :class:`~ftc_verify.errors.ValidationError`, exit 2, naming the option): without a
    sampling period, or when the largest program its budget could plan (for any default
    bracket: :func:`refine_memory` at ``gap = 1``) is estimated above
    :data:`REFINE_MEMORY`."""
    from ...errors import ValidationError

    if period is None:
        raise ValidationError(f"--h-max-work {work:g}: refines the sampled loop's h_max bracket; give --period "
                              "(or a period in the controller file)")
    from ...limits import memory_limit

    limit = min(REFINE_MEMORY, memory_limit())  # FTC_VERIFY_MEMORY_LIMIT or 80 % of the free memory, if lower
    loop = SampledLoop.build(system, controller)
    need = refine_memory(loop, 1.0, work)
    if need > limit:
        fit = [n for n, _ in refine_plan(loop, 1.0, work) if clock_memory(loop, n) <= limit]
        most = 2.0 * sum(clock_work(loop, n) for n in fit)
        if not fit:
            raise ValidationError(f"--h-max-work {work:g}: even the first clock program ({REFINE_START} pieces) "
                                  f"needs about {need / 1e9:.1f} GB, over the {limit / 1e9:.1f} GB limit")
        raise ValidationError(f"--h-max-work {work:g}: its largest clock program needs about {need / 1e9:.1f} GB, "
                              f"over the {limit / 1e9:.1f} GB limit; give at most {math.floor(most):d}")


@dataclass(frozen=True)
class Refinement:
    """What :func:`refine_h_max` did: ``h_max`` the closest period proved stable over
    the whole rate box (``None`` when no attempt was), ``pieces`` the certificate's pieces
    there (0: none), ``work`` the units charged, ``tried`` one ``(pieces, period,
    proved)`` per attempt in order."""

    h_max: float | None
    pieces: int
    work: float
    tried: tuple[tuple[int, float, bool], ...]


def refine_h_max(loop: SampledLoop, h_max: float, h_max_unstable: float, work: float) -> Refinement:
    """A period closer to ``h_max_unstable`` than the default bracket's ``h_max``,
    proved mean-square stable over the whole rate box by the ladder of
    :func:`refine_plan` (module docstring); deterministic."""
    gap = (h_max_unstable - h_max) / h_max_unstable
    tried: list[tuple[int, float, bool]] = []
    spent = 0.0

    def proved(n: int, f: float) -> bool:
        nonlocal spent
        spent += clock_work(loop, n)
        cert = clock_stable(loop, h_max_unstable * (1.0 - f), n, quadratic=True)
        tried.append((n, h_max_unstable * (1.0 - f), cert is not None and cert.proved))
        return tried[-1][2]

    best: tuple[float, int] | None = None
    last = gap
    for n, f in refine_plan(loop, gap, work):
        if proved(n, f):
            best, last = (f, n), f
            continue
        mid = math.sqrt(f * last)  # between the failed f and the last proved distance (f halves: f < last)
        if proved(n, mid):
            best = (mid, n)
        break
    if best is None:
        return Refinement(None, 0, spent, tuple(tried))
    return Refinement(h_max_unstable * (1.0 - best[0]), best[1], spent, tuple(tried))


def refine_result(system: FTCSystem, controller: Controller, result: SampledResult, work: float,
                  rtol: float = H_MAX_RTOL) -> SampledResult:
    """``result`` (of :func:`~ftc_verify.analysis.moments.sampled.sampled_analysis`) with
    its ``h_max`` refined by :func:`refine_h_max` within ``work`` units when its bracket
    is wider than ``rtol``, or has no stable end (then from ``h_max_unstable / 2``: the
    ladder starts 25 % below the unstable end); unchanged otherwise. The note says what
    was done."""
    from .sampled_conditioned import conditioned

    hm, hu = result.h_max, result.h_max_unstable
    if hu is None or (hm is not None and (hu - hm) / hu <= rtol) or work <= 0:
        return result
    if hm is None:  # no stable end proved (e.g. the wall-time valve): start from a 50 % bracket
        hm = 0.5 * hu
    loop = conditioned(dataclasses.replace(SampledLoop.build(system, controller), written=(float(result.period),)))
    ref = refine_h_max(loop, hm, hu, work)
    note = (f"; refinement (--h-max-work {work:g}): {len(ref.tried)} clock attempt(s), {ref.work:.0f} units, "
            + ("no closer period proved" if ref.h_max is None else
               f"proved stable over the rate box at {ref.h_max:.6g} with {ref.pieces} pieces "
               f"(relative gap {(hu - ref.h_max) / hu:.1e})"))
    return dataclasses.replace(result, h_max=result.h_max if ref.h_max is None else ref.h_max,
                               h_max_note=result.h_max_note + note)
