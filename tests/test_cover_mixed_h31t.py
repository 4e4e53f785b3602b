"""The mixed cover of the ``h_max`` refinement (:mod:`ftc_verify.analysis.moments.sampled_cover`):
each sub-box proved by its one-period map (:func:`~ftc_verify.analysis.moments.sampled_proof.subbox_stable`)
or by a cubic clock certificate, the map first; below :data:`COVER_DEPTH` the map's proofs
alone; the real map proofs prove and refuse what they should, and a cover they build is
exactly the box and confirmed by the independent whole-box verdict."""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from ftc_verify.analysis.moments import sampled_cover
from ftc_verify.analysis.moments.sampled import SampledLoop
from ftc_verify.analysis.moments.sampled_bracket import envelope_work
from ftc_verify.analysis.moments.sampled_cover import COVER_DEPTH, MAP_DEPTH, PROBE_DEPTH, cover_box, cover_h_max, cubic_work
from ftc_verify.analysis.moments.sampled_proof import MapParts, box_verdict, split_rate, subbox_stable
from ftc_verify.analysis.rigorous import precision
from ftc_verify.controllers.files import load_controller
from ftc_verify.model.files import load_system

ROOT = Path(__file__).resolve().parents[1]
PAPER_UNSTABLE = 0.0843  # above the paper loop's float64 crossing 0.08426 (h31c)


def _paper() -> SampledLoop:
    return SampledLoop.build(load_system(ROOT / "examples" / "paper.toml"),
                             load_controller(ROOT / "examples" / "paper_gains.toml"))


class _Never:
    """A stand-in for :func:`cubic_stable` that never proves (records the calls)."""

    def __init__(self) -> None:
        self.calls = 0

    def __call__(self, *args: Any) -> object:
        self.calls += 1
        return type("Cert", (), {"proved": False})()


def _box(loop: SampledLoop) -> list[tuple[np.ndarray, np.ndarray, int]]:
    return [(loop.chain.rate_min.copy(), loop.chain.rate_max.copy(), 0)]


def _assert_exact_cover(loop: SampledLoop, leaves: Any) -> None:
    """The leaves lie in the box, are pairwise disjoint up to shared faces, and their
    volumes (exact rationals of the floats) add up to the box's."""
    idx = loop.chain.rate_indices

    def volume(lo: Any, hi: Any) -> Fraction:
        out = Fraction(1)
        for r in idx:
            out *= Fraction(float(hi[r])) - Fraction(float(lo[r]))
        return out

    for a, (la, ha, _) in enumerate(leaves):
        assert all(loop.chain.rate_min[r] <= la[r] < ha[r] <= loop.chain.rate_max[r] for r in idx)
        for lb, hb, _ in leaves[a + 1:]:
            assert any(ha[r] <= lb[r] or hb[r] <= la[r] for r in idx)
    assert sum((volume(lo, hi) for lo, hi, _ in leaves), Fraction(0)) == volume(loop.chain.rate_min,
                                                                                 loop.chain.rate_max)


def test_subbox_proof_proves_below_and_refuses_above_the_crossing() -> None:
    loop = _paper()
    lo, hi = loop.chain.rate_min.copy(), loop.chain.rate_max.copy()
    below, above = PAPER_UNSTABLE * 0.95, PAPER_UNSTABLE * 1.01
    with precision(64):
        assert subbox_stable(loop, below, MapParts.build(loop, below), lo, hi)
        assert not subbox_stable(loop, above, MapParts.build(loop, above), lo, hi)
        # a single rate array, the worst vertex above the crossing: refused too
        assert not subbox_stable(loop, above, MapParts.build(loop, above), hi, hi)


def test_map_proof_first_then_the_cubic(monkeypatch: pytest.MonkeyPatch) -> None:
    """Where the map proves the box, no cubic certificate is tried or charged; where it
    does not, the cubic is (and the probe below it and the bisection of its path), up to
    :data:`COVER_DEPTH`, and then only map proofs."""
    loop = _paper()
    never = _Never()
    monkeypatch.setattr(sampled_cover, "cubic_stable", never)
    leaves, spent, attempts, maps = cover_box(loop, PAPER_UNSTABLE * 0.95, 2, _box(loop), 1e12)
    assert leaves is not None and len(leaves) == 1 and (attempts, maps, never.calls) == (0, 1, 0)
    assert spent == pytest.approx(envelope_work(loop))  # the envelope proves it: no form paid
    calls: list[int] = []

    def refuse_above(loop: SampledLoop, h: float, parts: Any, lo: np.ndarray, hi: np.ndarray, spend: Any = None) -> bool:
        calls.append(1)
        return False

    monkeypatch.setattr(sampled_cover, "subbox_stable", refuse_above)
    leaves, spent, attempts, maps = cover_box(loop, PAPER_UNSTABLE * 0.95, 2, _box(loop), 1e12)
    # the box's cubic fails, then its probe (COVER_DEPTH halvings down) and the deeper one
    # (PROBE_DEPTH): no more programs, map proofs alone below the box, down to MAP_DEPTH
    assert leaves is None and attempts == 3 == never.calls and maps == len(calls) == 1 + MAP_DEPTH
    assert spent == pytest.approx(attempts * cubic_work(loop, 2) + maps * envelope_work(loop))  # no form asked for
    # only the box's probe proved: the top of its path (1 halving) and the bisection (5, 7,
    # 8, 9 halvings) fail, so the probe is the path's leaf; the other half at COVER_DEPTH
    # is tried, then its deeper probe (PROBE_DEPTH), then only map proofs below it, to
    # MAP_DEPTH
    full = loop.chain.rate_max - loop.chain.rate_min
    depths: list[int] = []

    def probe_only(loop_: SampledLoop, h: float, pieces: int, lo: np.ndarray, hi: np.ndarray) -> object:
        depths.append(round(float(sum(np.log2(full[r] / (hi[r] - lo[r])) for r in loop_.chain.rate_indices))))
        return type("Cert", (), {"proved": depths[-1] == COVER_DEPTH and depths.count(COVER_DEPTH) == 1})()

    monkeypatch.setattr(sampled_cover, "cubic_stable", probe_only)
    calls.clear()
    leaves, spent, attempts, maps = cover_box(loop, PAPER_UNSTABLE * 0.95, 2, _box(loop), 1e12)
    assert leaves is None and attempts == len(depths) == 9 and maps == len(calls) == 2 + MAP_DEPTH - COVER_DEPTH
    assert depths == [0, COVER_DEPTH, 1, 5, 7, 8, 9, COVER_DEPTH, PROBE_DEPTH]


def test_cover_stops_where_the_float_radius_is_not_below_one(monkeypatch: pytest.MonkeyPatch) -> None:
    """Above the crossing no sub-box can be proved: the cover stops at the first
    midpoint with a float64 radius >= 1 instead of splitting to the depth limit."""
    loop = _paper()
    monkeypatch.setattr(sampled_cover, "cubic_stable", _Never())
    leaves, _, attempts, maps = cover_box(loop, PAPER_UNSTABLE * 1.05, None, _box(loop), 1e12)
    assert leaves is None and attempts == 0 and maps < 5


def test_map_only_cover_is_the_box_and_confirmed(monkeypatch: pytest.MonkeyPatch) -> None:
    """No cubic certificate ever proves (nor the worst vertex, so after the first rung
    none is tried): the cover by the real map proofs alone still proves a period closer
    than the bracket's stable end; its leaves are exactly the box, and the whole-box
    verdict of ``box_verdict`` confirms the period independently of the cover."""
    loop = _paper()
    never = _Never()
    monkeypatch.setattr(sampled_cover, "cubic_stable", never)
    hu = PAPER_UNSTABLE
    got = cover_h_max(loop, 0.9 * hu, hu, 1e12, 1e-3)
    assert got.h_max is not None and 0.9 * hu < got.h_max < hu and got.pieces is None
    assert never.calls == 2 * len(sampled_cover.PIECES)  # both probes once, every number of pieces
    assert box_verdict(loop, got.h_max, max_boxes=64, max_seconds=float("inf")).verdict == "stable"
    leaves, _, _, _ = cover_box(loop, got.h_max, None, _box(loop), 1e12)
    assert leaves is not None and len(leaves) == got.boxes
    _assert_exact_cover(loop, leaves)


def test_failed_rung_bisected_geometrically(monkeypatch: pytest.MonkeyPatch) -> None:
    """Cubic certificates proving exactly the periods at least 4e-3 below ``hu``, map
    proofs never: rungs 1e-2 (covered), 2.5e-3 (not), then at the geometric mean of the
    last covered and the closest failed distance, 5e-3 (covered), 3.5e-3 (not), 4.2e-3
    (covered), and none once these are less than ``BISECT`` apart."""
    loop = _paper()
    hu = PAPER_UNSTABLE

    def cubic(loop: SampledLoop, h: float, pieces: int, lo: np.ndarray, hi: np.ndarray) -> object:
        return type("Cert", (), {"proved": h <= hu * (1 - 4e-3)})()

    monkeypatch.setattr(sampled_cover, "cubic_stable", cubic)
    monkeypatch.setattr(sampled_cover, "subbox_stable", lambda *args, spend=None: False)
    got = cover_h_max(loop, 0.96 * hu, hu, 1e12, 1e-3)
    assert [ok for _, ok in got.rungs] == [True, False, True, False, True]
    mid = (5e-3 * 2.5e-3) ** 0.5
    assert [h for h, _ in got.rungs] == pytest.approx([hu * (1 - f) for f in (1e-2, 2.5e-3, 5e-3, mid,
                                                                             (5e-3 * mid) ** 0.5)])
    assert got.h_max == pytest.approx(hu * (1 - (5e-3 * mid) ** 0.5))
    assert (5e-3 * mid) ** 0.5 / mid < sampled_cover.BISECT


def test_split_cover_by_real_map_proofs_is_exactly_the_box(monkeypatch: pytest.MonkeyPatch) -> None:
    """The real map proof refused on every sub-box wider than half the box in some rate
    (review: the map-only cover above is one leaf): the cover splits, every leaf is one the
    real proof accepted, the leaves are pairwise disjoint (up to shared faces) and their
    volumes add up exactly to the box's."""
    loop = _paper()
    idx = loop.chain.rate_indices
    full = {r: float(loop.chain.rate_max[r] - loop.chain.rate_min[r]) for r in idx}
    proved: list[tuple[bytes, bytes]] = []

    def narrow_only(loop_: SampledLoop, h: float, parts: Any, lo: Any, hi: Any, *rest: Any, spend: Any = None) -> bool:
        if any(float(hi[r] - lo[r]) > 0.5 * full[r] for r in idx):
            return False
        ok = subbox_stable(loop_, h, parts, lo, hi, *rest, spend=spend)
        if ok:
            proved.append((np.asarray(lo).tobytes(), np.asarray(hi).tobytes()))
        return bool(ok)

    monkeypatch.setattr(sampled_cover, "cubic_stable", _Never())
    monkeypatch.setattr(sampled_cover, "subbox_stable", narrow_only)
    leaves, _, attempts, maps = cover_box(loop, 0.9 * PAPER_UNSTABLE, None, _box(loop), 1e12)
    assert leaves is not None and len(leaves) >= 2 ** len(idx) and attempts == 0 and maps > len(leaves)
    assert sorted(proved) == sorted((np.asarray(lo).tobytes(), np.asarray(hi).tobytes()) for lo, hi, _ in leaves)
    _assert_exact_cover(loop, leaves)


def test_rung_without_cubic_splits_by_the_maps_rule(monkeypatch: pytest.MonkeyPatch) -> None:
    """A rung with no cubic certificate (``pieces`` None): every split of its cover is
    the map proofs' rule (``map_split``, from ``split_rate``) from the top, not the widest rate of the cubic
    certificates' probes; the leaves are still exactly the box."""
    loop = _paper()
    idx = loop.chain.rate_indices
    full = {r: float(loop.chain.rate_max[r] - loop.chain.rate_min[r]) for r in idx}
    chosen: list[tuple[int, ...] | None] = []

    def recording(loop_: SampledLoop, h: float, lo: Any, hi: Any) -> tuple[int, ...] | None:
        chosen.append(split_rate(loop_, h, lo, hi))
        return chosen[-1]

    def narrow_only(loop_: SampledLoop, h: float, parts: Any, lo: Any, hi: Any, *rest: Any, spend: Any = None) -> bool:
        return all(float(hi[r] - lo[r]) <= 0.25 * full[r] for r in idx)

    monkeypatch.setattr(sampled_cover, "cubic_stable", _Never())
    monkeypatch.setattr(sampled_cover, "subbox_stable", narrow_only)
    monkeypatch.setattr(sampled_cover, "split_rate", recording)
    leaves, _, attempts, maps = cover_box(loop, 0.9 * PAPER_UNSTABLE, None, _box(loop), 1e12)
    assert leaves is not None and attempts == 0 and len(leaves) == 4 ** len(idx)
    assert len(chosen) == maps - len(leaves) > 0 and None not in chosen
    _assert_exact_cover(loop, leaves)


@pytest.mark.parametrize(("closest", "covered"), [(3e-3, [True, False, True, True, False]),
                                                 (0.0, [True, True, True])])
def test_a_rung_spends_at_most_half_the_budget_left_but_the_target(monkeypatch: pytest.MonkeyPatch, closest: float,
                                                                   covered: list[bool]) -> None:
    """Every rung's cover is given ``RUNG_SHARE`` of the budget left, the target's rung
    (``0.9 rtol``) all of it: a rung that fails (here those closer than ``closest``,
    spending 90 % of what they are given) leaves units for the bisection's rungs."""
    loop = _paper()
    hu, work = PAPER_UNSTABLE, 1e6
    given: list[tuple[float, float, float]] = []
    spent = [0.0]

    def fake_cover(loop_: SampledLoop, h: float, pieces: Any, boxes: Any, budget: float, *rest: Any) -> Any:
        given.append((1 - h / hu, budget, work - spent[0]))
        fails = 1 - h / hu < closest
        use = 0.9 * budget if fails else 10.0
        spent[0] += use
        return (None if fails else boxes), use, 0, 1

    monkeypatch.setattr(sampled_cover, "rung_pieces", lambda *args: (None, 0.0, 0))
    monkeypatch.setattr(sampled_cover, "cover_box", fake_cover)
    got = cover_h_max(loop, 0.96 * hu, hu, work, 1e-3)
    assert [ok for _, ok in got.rungs] == covered
    for f, budget, left in given:
        target = f == pytest.approx(0.9e-3)
        assert budget == pytest.approx((1.0 if target else sampled_cover.RUNG_SHARE) * left)
    assert all(budget > 0.1 * work for _, budget, _ in given)  # a failure did not use up the rest
    assert got.work == pytest.approx(spent[0])


def test_map_split_bounds_the_aspect_of_the_sub_boxes(monkeypatch: pytest.MonkeyPatch) -> None:
    """``map_split`` is ``split_rate``'s choice (here a stand-in choosing the narrow rate)
    unless another rate is more than ``ASPECT`` times as wide relative to the box, then
    the widest; with the real ``split_rate`` it is that rule's choice at any aspect up to
    ``ASPECT``."""
    loop = _paper()
    h = 0.9 * PAPER_UNSTABLE
    lo, hi = loop.chain.rate_min.copy(), loop.chain.rate_max.copy()
    a, b = loop.chain.rate_indices
    for narrow, wide in ((a, b), (b, a)):
        for share, expect in ((1.0 / (2 * sampled_cover.ASPECT), wide), (1.0 / sampled_cover.ASPECT, narrow)):
            top = hi.copy()
            top[narrow] = lo[narrow] + share * (hi[narrow] - lo[narrow])
            real = split_rate(loop, h, lo, top)
            if share == 1.0 / sampled_cover.ASPECT:
                assert sampled_cover.map_split(loop, h, lo, top) == real
            with monkeypatch.context() as m:
                m.setattr(sampled_cover, "split_rate", lambda *args, r=narrow: r)
                assert sampled_cover.map_split(loop, h, lo, top) == expect
