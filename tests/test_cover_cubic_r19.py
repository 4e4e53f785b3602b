"""The ``h_max`` cover with third-order forms and the moving enclosure
(:data:`~ftc_verify.analysis.moments.sampled_cover.CUBIC_RATES`,
:mod:`~ftc_verify.analysis.moments.sampled_eigen3`).

On the random ``n = 2, m = 2`` loop of ``tests/test_cover_frames_r17.py`` (two free
rates; ``CUBIC_RATES`` lowered to 2 here so that its cover takes this route) in the same
frames (states scaled by 1e-6 and 1e6, time by 1e3 and 1e-3, inputs by 1e6, an
ill-conditioned similarity), 1 % below the crossing the cover by map proofs alone is
exactly the box, every form a third-order one with its signed terms, with about as many
sub-boxes as in good units; 1 % above it no cover is claimed. On held-out seed 13 (six
rates, the route by default), 9e-4 below its proved-unstable end, a sub-box at the worst
vertex that the second-order route must split is one leaf, charged one envelope and one
third-order form."""

from __future__ import annotations

import pytest

from moved_loops import Units, moved
from sampled_forms import vertex_exponents

from ftc_verify.analysis.moments import cubic_balls, sampled_cover
from ftc_verify.analysis.moments.sampled import SampledLoop, crossing
from ftc_verify.analysis.moments.sampled_bracket import envelope_work, third_order_work
from ftc_verify.analysis.moments.sampled_conditioned import conditioned
from ftc_verify.analysis.moments.sampled_cover import cover_box

from test_cover_frames_r17 import FRAMES, _case
from test_cover_mixed_h31t import _assert_exact_cover, _box
from test_cover_probe_r17 import held_out_rung
from test_cover_reach_r16 import _Count


@pytest.fixture(scope="module")
def h_u() -> float:
    """The crossing in good units (float64 bisection of the worst rate point, 1e-10)."""
    return crossing(SampledLoop.build(*_case()), 1e-3, 10.0, True, 1e-10)


def _cover(monkeypatch: pytest.MonkeyPatch, loop: SampledLoop, h: float) -> tuple[object, _Count, _Count]:
    terms, folded = _Count(cubic_balls.cubic_terms), _Count(cubic_balls.cubic_map)
    monkeypatch.setattr(cubic_balls, "cubic_terms", terms)
    monkeypatch.setattr(cubic_balls, "cubic_map", folded)
    return cover_box(loop, h, None, _box(loop), 1e12), terms, folded


@pytest.mark.parametrize("u", FRAMES, ids=[u.name for u in FRAMES])
def test_cover_by_the_moving_enclosure_in_every_frame(monkeypatch: pytest.MonkeyPatch, h_u: float, u: Units) -> None:
    monkeypatch.setattr(sampled_cover, "CUBIC_RATES", 2)
    good = conditioned(SampledLoop.build(*_case()))
    (good_leaves, *_), _, _ = _cover(monkeypatch, good, h_u * (1 - 1e-2))
    assert good_leaves is not None
    loop = conditioned(SampledLoop.build(*moved(*_case(), u)))
    (leaves, _, attempts, _), terms, folded = _cover(monkeypatch, loop, h_u * (1 - 1e-2) / u.s)
    assert leaves is not None and attempts == 0, u.name
    _assert_exact_cover(loop, leaves)
    assert terms.calls > 0 and folded.calls == 0, u.name
    assert len(good_leaves) / 2 <= len(leaves) <= 2 * len(good_leaves), (u.name, len(leaves), len(good_leaves))
    (above, *_), _, _ = _cover(monkeypatch, loop, h_u * (1 + 1e-2) / u.s)
    assert above is None, u.name


def test_a_vertex_box_of_held_out_seed_13_is_one_leaf(monkeypatch: pytest.MonkeyPatch) -> None:
    loop, h, worst = held_out_rung(9e-4)
    lo, hi = vertex_exponents(loop, worst, (2, 2, 2, 4, 4, 2))
    box = [(lo, hi, 8)]
    leaves, units, attempts, maps = cover_box(loop, h, None, box, 1e12, worst, bulk=False)
    assert leaves is not None and len(leaves) == 1 and maps == 1 and attempts == 0
    assert units == envelope_work(loop) + third_order_work(loop)
    monkeypatch.setattr(sampled_cover, "CUBIC_RATES", 7)  # the second-order route
    leaves = cover_box(loop, h, None, box, 1e12, worst, bulk=False)[0]
    assert leaves is None or len(leaves) > 1


def test_a_bulk_certificate_where_the_enclosure_does_not_contract() -> None:
    """Held-out seed 13, 4.331e-2 below its proved-unstable end: the whole box's map proof
    fails with the enclosure's reach far above 1 (the box too wide for it), so a bulk
    certificate is tried there, although the corner nearest to the worst vertex is the
    worst vertex itself (the margin rule would not try one), and it proves the box: one
    leaf, one map proof, one program."""
    loop, h, worst = held_out_rung(4.331e-2)
    leaves, units, attempts, maps = cover_box(loop, h, None, _box(loop), 1e12, worst)
    assert leaves is not None and len(leaves) == 1 and attempts == 1 and maps == 1
    assert units == envelope_work(loop) + third_order_work(loop) + sampled_cover.cubic_work(loop, sampled_cover.BULK_PIECES)


def test_no_bulk_certificate_where_the_enclosure_contracts() -> None:
    """Seed 13, 9e-4 below: the sub-box of half of rates 1, 2, 3, 6 and a sixteenth of
    rates 4, 5 at the worst vertex fails with the enclosure's reach below 1 (what is
    missing is margin, which halving gives): the budget could pay a program, none is
    tried."""
    loop, h, worst = held_out_rung(9e-4)
    lo, hi = vertex_exponents(loop, worst, (1, 1, 1, 4, 4, 1))
    one = envelope_work(loop) + third_order_work(loop)
    budget = one + sampled_cover.cubic_work(loop, sampled_cover.BULK_PIECES)
    _, _, attempts, maps = cover_box(loop, h, None, [(lo, hi, 10)], budget, worst)
    assert attempts == 0 and maps >= 2
