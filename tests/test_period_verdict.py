"""The verdict at the controller's period (issue 31, item 2): the whole box in one sub-box
proof, then one clock-dependent certificate of the whole box, then the sub-box proofs
(:func:`ftc_verify.analysis.moments.sampled_clock.period_verdict`)."""

from __future__ import annotations

import dataclasses
import importlib
from typing import Any

import numpy as np
import pytest

from ftc_verify.analysis.moments.sampled import SampledLoop, rate_points, sampled_analysis, spectral_radius, worst_radius
from ftc_verify.analysis.moments.sampled_proof import BoxVerdict
from ftc_verify.controllers.files import load_controller
from ftc_verify.testing.sampled_cases import lqr_case

clock_module = importlib.import_module("ftc_verify.analysis.moments.sampled_clock")


@pytest.fixture(scope="module")
def wide_box_case() -> tuple[Any, Any]:
    """The random ``n = 4, m = 3`` loop of ``benchmarks/sampled.py --seed 1`` (six detection
    rates in [2, 4]; float64 crossing of its worst vertex 0.546)."""
    rng = np.random.default_rng(1)
    lqr_case(2, 2, rng)
    return lqr_case(4, 3, rng)


def test_the_clock_certificate_decides_where_the_whole_box_proof_fails(wide_box_case: tuple[Any, Any]) -> None:
    system, controller = wide_box_case
    h = 0.5  # 8 % below the crossing: one proof over the whole box fails there
    loop = dataclasses.replace(SampledLoop.build(system, controller), written=(h,))
    first = clock_module.box_verdict(loop, h, max_boxes=1)
    assert first.verdict == "undecided"
    res = sampled_analysis(system, controller, h, h_max=False)
    assert res.verdict == "stable" and "clock-dependent" in res.proof
    # consistent with the float64 radius over the box: below 1 at the rate points and at random rates
    rng = np.random.default_rng(0)
    chain = loop.chain
    points = [*rate_points(chain), *(chain.rate_min + rng.random(chain.rate_min.shape) * (chain.rate_max - chain.rate_min)
                                     for _ in range(20))]
    assert max(spectral_radius(loop, h, p) for p in points) < 1


def test_the_box_decides_first_and_the_clock_is_not_tried_on_easy_or_unstable_loops(
        paper_system: Any, paper_gains_path: Any, monkeypatch: pytest.MonkeyPatch) -> None:
    def no_clock(*args: Any, **kwargs: Any) -> BoxVerdict:
        raise AssertionError("the clock certificate was tried")

    monkeypatch.setattr(clock_module, "clock_verdict", no_clock)
    paper_gains = load_controller(paper_gains_path)
    stable = sampled_analysis(paper_system, paper_gains, 0.05, h_max=False)
    unstable = sampled_analysis(paper_system, paper_gains, 0.1, h_max=False)
    assert stable.verdict == "stable" and stable.boxes == 1 and "clock" not in stable.proof
    assert unstable.verdict == "not stable" and "> 1 proved" in unstable.proof


def test_the_clock_is_skipped_above_a_float_radius_of_one(wide_box_case: tuple[Any, Any],
                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    system, controller = wide_box_case
    loop = SampledLoop.build(system, controller)
    h = 0.6  # above the crossing: the float radius at the worst vertex exceeds 1
    loop = dataclasses.replace(loop, written=(h,))
    rho, _ = worst_radius(loop, h, rate_points(loop.chain))
    assert rho > 1
    tried: list[float] = []
    monkeypatch.setattr(clock_module, "clock_verdict", lambda *a, **k: tried.append(a[1]))
    verdict = clock_module.period_verdict(loop, h, rho, max_boxes=4, max_seconds=60.0)
    assert not tried and verdict.verdict in ("not stable", "undecided")
