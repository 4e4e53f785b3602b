"""Where the ``h_max`` cover computes a sub-box's polynomial form
(:mod:`ftc_verify.analysis.moments.sampled_cover`): only where the eigenpair
enclosure's reach, estimated from the parent's form, is at most 1; the forms and the
third-order forms charged when they are computed, the envelope alone otherwise; the
cover is the box whatever the estimates say."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from ftc_verify.analysis.moments import cubic_balls, quad_balls, sampled_cover, sampled_eigen
from ftc_verify.analysis.moments.sampled import SampledLoop
from ftc_verify.analysis.moments.sampled_bracket import box_work, envelope_work, third_order_work
from ftc_verify.analysis.moments.sampled_conditioned import conditioned
from ftc_verify.analysis.moments.sampled_cover import MAP_DEPTH, REACH_MAX, REACH_SHRINK, _spend, cover_box
from ftc_verify.testing.sampled_cases import lqr_case

from test_cover_mixed_h31t import _assert_exact_cover, _box



def test_spend_asks_for_forms_only_where_expected() -> None:
    """A sub-box expected above ``REACH_MAX`` is not asked to pay for a form; one at or
    below it pays the form's units, the third-order form its own, and a failed form's
    reach is kept for its halves."""
    paid: list[float] = []

    def pay(units: float) -> bool:
        paid.append(units)
        return True

    seen: list[float] = []
    assert not _spend(1.01 * REACH_MAX, seen, pay, (3.0, 7.0, 11.0, False)).second() and paid == []
    spend = _spend(REACH_MAX, seen, pay, (3.0, 7.0, 11.0, False))
    assert spend.second() and spend.third is not None and spend.third() and paid == [7.0, 11.0]
    assert not spend.cubic
    assert _spend(REACH_MAX, seen, pay, (3.0, 7.0, None, False)).third is None  # a third-order form never paid
    assert _spend(REACH_MAX, seen, pay, (3.0, 7.0, None, True)).cubic  # the moving enclosure's route
    spend.reach(2.5)
    assert seen == [2.5]
    assert 0 < REACH_SHRINK < 1


class _Count:
    def __init__(self, inner: Any) -> None:
        self.inner, self.calls = inner, 0

    def __call__(self, *args: Any) -> Any:
        self.calls += 1
        return self.inner(*args)


def _small_loop() -> SampledLoop:
    """A random ``n = 2, m = 2`` loop (two free rates, conditioned as the refinement runs
    it) whose envelope proof needs hundreds of sub-boxes 1 % below its float64 crossing
    (2.49038), where the second-order forms prove a dozen."""
    return conditioned(SampledLoop.build(*lqr_case(2, 2, np.random.default_rng(11))))


@pytest.mark.parametrize("reach", [0.0, 50.0])
def test_forms_only_where_the_reach_is_expected(monkeypatch: pytest.MonkeyPatch, reach: float) -> None:
    """With every failed form's reach estimated 0, every sub-box the envelope does not
    prove gets a form, and a dozen sub-boxes cover the box; estimated 50, the halves of
    the whole box's failed form expect 42.5 and none of their sub-boxes gets a form
    (``REACH_SHRINK`` per halving, never below ``REACH_MAX`` within ``MAP_DEPTH``): the
    envelope alone covers the box with many more. Either way the leaves are exactly the
    box, and the units spent are the envelope's per sub-box plus each form's and
    third-order form's as computed."""
    loop = _small_loop()
    quad, cubic = _Count(quad_balls.quad_map), _Count(cubic_balls.cubic_map)
    monkeypatch.setattr(quad_balls, "quad_map", quad)
    monkeypatch.setattr(cubic_balls, "cubic_map", cubic)
    monkeypatch.setattr(sampled_eigen, "enclosure_reach", lambda form: reach)
    leaves, spent, attempts, maps = cover_box(loop, 2.4903765732885614 * (1 - 1e-2), None, _box(loop), 1e12)
    assert leaves is not None and attempts == 0
    _assert_exact_cover(loop, leaves)
    forms = box_work(loop) - envelope_work(loop)
    assert spent == pytest.approx(maps * envelope_work(loop) + quad.calls * forms + cubic.calls * third_order_work(loop))
    if reach == 0.0:
        assert quad.calls >= maps - len(leaves) and len(leaves) < 30
    else:
        assert 50.0 * REACH_SHRINK ** MAP_DEPTH > REACH_MAX
        assert quad.calls == 1 and len(leaves) > 100


def test_reach_is_below_one_where_the_enclosure_proves() -> None:
    """The seed-1 loop 1 % below its crossing, sub-boxes at its worst vertex: where the
    enclosure proves a sub-box its reach is below 1 (the proof needs a contraction whose
    linear part the reach estimates), the whole box's is above 1 and the estimate falls
    as the sub-box shrinks."""
    from ftc_verify.analysis.moments.sampled_eigen import eigen_radius_bound, enclosure_reach

    from sampled_forms import second_order_form, seed1_crossing, vertex_corner

    loop, a, v = seed1_crossing()
    reaches = []
    for width in (1.0, 0.5, 0.25, 0.125):
        lo, hi = vertex_corner(loop, v, width)
        form = second_order_form(loop, a * (1 - 1e-2), lo, hi)
        reach = enclosure_reach(form)
        assert reach is not None
        bound = eigen_radius_bound(form, loop.states, loop.r)
        assert bound is None or reach < 1.0
        reaches.append(reach)
    assert reaches[0] > 1.0 > reaches[-1] and reaches == sorted(reaches, reverse=True)


@pytest.mark.parametrize("n, m, taken", [(2, 2, True), (4, 3, False)])
def test_third_order_form_paid_only_where_no_dearer_than_a_form(monkeypatch: pytest.MonkeyPatch, n: int, m: int,
                                                                 taken: bool) -> None:
    """Two free rates: a third-order form costs less than a second-order one and the cover
    pays for it; six (``n = 4, m = 3``, 567 units against 334): never."""
    loop = conditioned(SampledLoop.build(*lqr_case(n, m, np.random.default_rng(1))))
    asked: list[bool] = []

    def record(loop_: SampledLoop, h: float, parts: Any, lo: Any, hi: Any, spend: Any = None) -> bool:
        asked.append(spend.third is not None and spend.third())
        return True

    monkeypatch.setattr(sampled_cover, "subbox_stable", record)
    leaves, spent, _, maps = cover_box(loop, 0.01, None, _box(loop), 1e12)
    assert leaves is not None and maps == 1 and asked == [taken]
    assert (third_order_work(loop) <= box_work(loop) - envelope_work(loop)) is taken
    assert spent == pytest.approx(envelope_work(loop) + (third_order_work(loop) if taken else 0.0))
