"""The clock rung's split (:data:`~ftc_verify.analysis.moments.sampled_bracket.CLOCK_SPLIT`):
after a fallback distance is proved, one attempt at the geometric mean of it and the failed
distance tried before it, when they differ by more than ``CLOCK_SPLIT`` times."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from ftc_verify.analysis.moments import sampled_bracket
from ftc_verify.analysis.moments.sampled import SampledLoop, spectral_radius
from ftc_verify.analysis.moments.sampled_bracket import CLOCK_FALLBACK, CLOCK_LADDER, CLOCK_SPLIT, clock_below
from ftc_verify.controllers.files import load_controller
from ftc_verify.model.files import load_system
from clock_stand_in import ProvedUpTo

ROOT = Path(__file__).resolve().parents[1]


def _paper() -> SampledLoop:
    return SampledLoop.build(load_system(ROOT / "examples" / "paper.toml"),
                             load_controller(ROOT / "examples" / "paper_gains.toml"))


@pytest.mark.parametrize(("limit_f", "expected_f", "tried"), [
    # 0.1 proved after 0.03 failed (more than 2x apart): the mean sqrt(0.003) tried, and proved
    (0.05, math.sqrt(0.003), (0.02, 0.03, 0.1, math.sqrt(0.003))),
    # ... tried and not proved: the fallback's 0.1 stays
    (0.07, 0.1, (0.02, 0.03, 0.1, math.sqrt(0.003))),
    # 0.3 after 0.1: the mean sqrt(0.03) = 0.173 proved (30 % -> 17 % on held-out loops)
    (0.15, math.sqrt(0.03), (0.02, 0.03, 0.1, 0.3, math.sqrt(0.03))),
    # 0.03 after 0.02 (1.5x) and 0.5 after 0.3 (1.7x): no split
    (0.025, 0.03, (0.02, 0.03)),
    (0.45, 0.5, (0.02, 0.03, 0.1, 0.3, 0.5)),
    # the ladder proved its first rung: no fallback, no split (0.01 fails: 0.02 kept)
    (0.015, 0.02, (0.02, 0.01)),
])
def test_split_after_the_fallback(monkeypatch: pytest.MonkeyPatch, limit_f: float, expected_f: float,
                                  tried: tuple[float, ...]) -> None:
    """With a certificate that holds up to ``a (1 - limit_f)``: the distances asked, in
    order, and the period returned -- the split's period only when it is proved, one
    attempt, never after the ladder's own rungs."""
    assert CLOCK_LADDER == (0.02, 0.01, 3e-3) and CLOCK_FALLBACK == (0.03, 0.1, 0.3, 0.5) and CLOCK_SPLIT == 2.0
    a = 0.7
    fake = ProvedUpTo(a * (1 - limit_f))
    monkeypatch.setattr(sampled_bracket, "clock_stable", fake)
    got = clock_below(_paper(), a)
    assert fake.asked == pytest.approx([a * (1 - f) for f in tried])
    assert got == pytest.approx(a * (1 - expected_f))
    assert got is not None and got <= fake.limit  # only a proved period is returned


def test_split_not_started_after_the_deadline(monkeypatch: pytest.MonkeyPatch) -> None:
    """A deadline already passed starts no attempt at all (the split included)."""
    fake = ProvedUpTo(0.5)
    monkeypatch.setattr(sampled_bracket, "clock_stable", fake)
    assert clock_below(_paper(), 1.0, deadline=-math.inf) is None
    assert fake.asked == []


PAPER_CROSSING = 0.08426  # float64 crossing of the paper loop's worst vertex (h31c)


@pytest.mark.parametrize(("scale", "expected_f"), [
    (1.15, math.sqrt(0.03)),  # 10 % below fails, 30 % proved: the split, 4.9 % below the crossing, proved
    (1.1, 0.1),               # 10 % proved after 3 %: the split at 5.5 % lies above the crossing
])
def test_split_on_the_paper_loop(scale: float, expected_f: float) -> None:
    """The paper loop with its crossing given ``scale`` times too high, the real
    two-piece certificate (ball arithmetic): the period returned, and the float64 radius
    below 1 there at every vertex and at 40 random rates of the box (a proved claim: a
    radius >= 1 would be a bug, no false-failure probability)."""
    loop = _paper()
    a = scale * PAPER_CROSSING
    got = clock_below(loop, a)
    assert got is not None and got == pytest.approx(a * (1 - expected_f), rel=1e-12)
    rng = np.random.default_rng(5)
    lo, hi = loop.chain.rate_min, loop.chain.rate_max
    rates = [lo + rng.uniform(size=lo.shape) * (hi - lo) for _ in range(40)] + list(loop.chain.vertices())
    assert max(spectral_radius(loop, got, r) for r in rates) < 1.0
