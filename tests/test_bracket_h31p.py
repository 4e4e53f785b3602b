"""The clock-dependent rung of the ``h_max`` bracket
(:func:`ftc_verify.analysis.moments.sampled_bracket.clock_below`): which distances below the
float64 crossing it tries, in which order, and that what it returns is stable."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from ftc_verify.analysis.moments import sampled_bracket
from ftc_verify.analysis.moments.sampled import SampledLoop, spectral_radius
from ftc_verify.analysis.moments.sampled_bracket import CLOCK_FALLBACK, CLOCK_LADDER, clock_below
from ftc_verify.controllers.files import load_controller
from ftc_verify.model.files import load_system
from clock_stand_in import ProvedUpTo

ROOT = Path(__file__).resolve().parents[1]
PAPER_CROSSING = 0.08426  # float64 crossing of the paper loop's worst vertex (h31c)


def _paper() -> SampledLoop:
    return SampledLoop.build(load_system(ROOT / "examples" / "paper.toml"),
                             load_controller(ROOT / "examples" / "paper_gains.toml"))


@pytest.mark.parametrize(("limit_f", "expected_f", "tried"), [
    (0.002, 3e-3, (0.02, 0.01, 3e-3)),        # every rung proved
    (0.015, 0.02, (0.02, 0.01)),              # stops at the first failure
    (0.025, 0.03, (0.02, 0.03)),              # the first fails: the fallback, closest first
    (0.2, 0.3, (0.02, 0.03, 0.1, 0.3, math.sqrt(0.03))),  # ... the first proved (then h31n's split)
    (0.6, None, (0.02, 0.03, 0.1, 0.3, 0.5)),  # none
])
def test_ladder_order_and_fallback(monkeypatch: pytest.MonkeyPatch, limit_f: float, expected_f: float | None,
                                   tried: tuple[float, ...]) -> None:
    """With a certificate that holds up to ``a (1 - limit_f)``, the rungs asked and the
    period returned (the closest proved): the fallback only after the first rung fails,
    nothing after the first failure or the first proved fallback."""
    assert CLOCK_LADDER == (0.02, 0.01, 3e-3) and CLOCK_FALLBACK == (0.03, 0.1, 0.3, 0.5)  # the table assumes them
    a = 1.0
    fake = ProvedUpTo(a * (1 - limit_f))
    monkeypatch.setattr(sampled_bracket, "clock_stable", fake)
    got = clock_below(_paper(), a)
    assert fake.asked == pytest.approx([a * (1 - f) for f in tried])
    assert (got is None) if expected_f is None else got == pytest.approx(a * (1 - expected_f))


def test_fallback_proves_where_the_first_rung_lies_above_the_crossing() -> None:
    """The paper loop with a crossing given 2.5 % too high: 2 % below it is above the true
    crossing (a vertex has radius above 1, nothing is proved), 3 % below it is under the
    true one and the two-piece certificate proves it (ball arithmetic); the float64 radius
    is below 1 there at every vertex and at 40 random rates of the box (a proved claim: a
    radius >= 1 would be a bug, no false-failure probability)."""
    loop = _paper()
    a = 1.025 * PAPER_CROSSING
    assert max(spectral_radius(loop, a * (1 - CLOCK_LADDER[0]), v) for v in loop.chain.vertices()) > 1.0
    got = clock_below(loop, a)
    assert got == a * (1 - CLOCK_FALLBACK[0])
    rng = np.random.default_rng(11)
    lo, hi = loop.chain.rate_min, loop.chain.rate_max
    rates = [lo + rng.uniform(size=lo.shape) * (hi - lo) for _ in range(40)] + list(loop.chain.vertices())
    assert max(spectral_radius(loop, got, r) for r in rates) < 1.0
    assert not math.isnan(got)


class _Box:
    """A stand-in for :func:`box_verdict` that proves every period at most ``limit``."""

    def __init__(self, limit: float) -> None:
        self.limit = limit
        self.asked: list[float] = []

    def __call__(self, loop: SampledLoop, h: float, max_boxes: int, max_seconds: float,
                 stable_only: bool = False) -> object:
        self.asked.append(h)

        class Verdict:
            verdict = "stable" if h <= self.limit else "undecided"

        return Verdict()


@pytest.mark.parametrize(("clock_f", "box_f", "expected_f", "box_tried"), [
    (0.5, 0.3, 0.3, (0.25e-3, 0.75e-3, 0.1, 0.3)),   # a coarse clock period: the closer COARSE one tried
    (0.5, 0.6, 0.5, (0.25e-3, 0.75e-3, 0.1, 0.3)),   # ... and kept when that fails
    (0.3, 0.3, 0.3, (0.25e-3, 0.75e-3, 0.1)),        # nothing of COARSE is closer than 30 %
    (None, 0.3, 0.3, (0.25e-3, 0.75e-3, 0.1, 0.3)),  # no clock period: COARSE as before
])
def test_coarse_sub_box_distances_closer_than_the_clock(monkeypatch: pytest.MonkeyPatch, clock_f: float | None,
                                                        box_f: float, expected_f: float, box_tried: tuple[float, ...]) -> None:
    """:func:`prove_below` after the clock rung returned a coarse period: the sub-box
    ladder stops at its first failure (10 %), then only the :data:`COARSE` distances
    closer than the clock's period are tried; the closest proved period is returned."""
    from ftc_verify.analysis.moments.sampled_bracket import CLOCK_WORK, COARSE, LADDER, prove_below

    assert LADDER[0] == 0.1 and COARSE == (0.3, 0.5)  # the table assumes them
    a = 1.0
    box = _Box(a * (1 - box_f))
    monkeypatch.setattr(sampled_bracket, "box_verdict", box)
    monkeypatch.setattr(sampled_bracket, "clock_below",
                        lambda loop, a, deadline=math.inf: None if clock_f is None else a * (1 - clock_f))
    got = prove_below(_paper(), a, 1e-3, 64, CLOCK_WORK, math.inf)
    assert got == pytest.approx(a * (1 - expected_f))
    assert box.asked == pytest.approx([a * (1 - f) for f in box_tried])


def test_stable_only_stops_when_the_budget_cannot_cover_the_sub_boxes_left() -> None:
    """``box_verdict(stable_only=True)`` (the bracket's attempts): the ``n = 2, m = 2`` loop
    of ``benchmarks/sampled.py --seed 2`` at ``3e-3`` below its worst vertex's crossing
    needs more than 8 sub-boxes; with 8 both searches are undecided, the early one after
    fewer sub-boxes; with 64 both prove it stable after the same sub-boxes (the early stop
    never loses a proof the budget could finish)."""
    from ftc_verify.analysis.moments.sampled_proof import box_verdict
    from ftc_verify.testing.sampled_cases import lqr_case

    system, controller = lqr_case(2, 2, np.random.default_rng(2))
    loop = SampledLoop.build(system, controller)
    h = 1.2393284 * (1 - 3e-3)
    full, early = (box_verdict(loop, h, max_boxes=8, max_seconds=math.inf, stable_only=s) for s in (False, True))
    assert full.verdict == early.verdict == "undecided"
    assert early.boxes < full.boxes == 8
    full, early = (box_verdict(loop, h, max_boxes=64, max_seconds=math.inf, stable_only=s) for s in (False, True))
    assert full.verdict == early.verdict == "stable"
    assert early.boxes == full.boxes
