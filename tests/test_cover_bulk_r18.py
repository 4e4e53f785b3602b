"""Bulk certificates of the ``h_max`` cover (``sampled_cover._bulk`` in
:func:`~ftc_verify.analysis.moments.sampled_cover.cover_box`) on a held-out ``n = 4,
m = 3`` loop with six detection rates (seed 13 of ``benchmarks/h_max_heldout.py``'s draw,
conditioned as the refinement runs it), 9e-4 below the default bracket's proved-unstable
end 0.6022096970393988: where only map proofs are tried and a sub-box's map proof fails,
a certificate of two cubic pieces is tried on it when the float64 margin at its corner
nearest to the worst vertex is wide; near the worst vertex, below a certificate that
failed at a similar margin, on boxes with few free rates, or when the budget cannot pay
it, none is tried (``benchmarks/results/bulk18.md``). These are the rules of the
second-order route (:data:`~ftc_verify.analysis.moments.sampled_cover.CUBIC_RATES`
raised above six here); the moving enclosure's rule is tested in
``tests/test_cover_cubic_r19.py``."""

from __future__ import annotations

import numpy as np
import pytest

from ftc_verify.analysis.moments import sampled_cover
from ftc_verify.analysis.moments.sampled import SampledLoop, spectral_radius
from ftc_verify.analysis.moments.sampled_bracket import box_work
from ftc_verify.analysis.moments.sampled_conditioned import conditioned
from ftc_verify.analysis.moments.sampled_cover import (BULK_MARGIN, BULK_PIECES, BULK_RETRY, _bulk, _corner, cover_box,
                                                       cubic_work)
from ftc_verify.testing.sampled_cases import lqr_case

from test_cover_mixed_h31t import _box
from test_cover_probe_r17 import held_out_rung


@pytest.fixture(autouse=True)
def second_order_route(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(sampled_cover, "CUBIC_RATES", 7)


@pytest.fixture(scope="module")
def rung() -> tuple[SampledLoop, float, np.ndarray]:
    return held_out_rung(9e-4)


def _cell(loop: SampledLoop, worst: np.ndarray, a: int, b: int) -> tuple[np.ndarray, np.ndarray]:
    """The sub-box of a quarter of every rate's range, ``a`` quarters from the worst vertex
    along the first, third and fifth free rates and ``b`` along the others."""
    lo0, hi0 = loop.chain.rate_min, loop.chain.rate_max
    quarter = (hi0 - lo0) / 4
    idx = np.zeros_like(lo0)
    for j, r in enumerate(loop.chain.rate_indices):
        idx[r] = a if j % 2 == 0 else b
    lo = np.where(worst <= lo0, lo0 + idx * quarter, hi0 - (idx + 1) * quarter)
    return lo, lo + quarter


def _margin(loop: SampledLoop, h: float, rates: np.ndarray) -> float:
    return 1.0 - spectral_radius(loop, h, rates)


def test_a_wide_margin_sub_box_is_one_bulk_certificate(rung: tuple[SampledLoop, float, np.ndarray]) -> None:
    """Its map proof fails and its margin is a hundred times the worst vertex's: one certificate
    proves it (a leaf, the units of one map proof with its form and of one program); with
    bulk certificates left out, map proofs split it."""
    loop, h, worst = rung
    lo, hi = _cell(loop, worst, 0, 3)
    assert _margin(loop, h, _corner(lo, hi, worst)) >= 40 * BULK_MARGIN * _margin(loop, h, worst)
    leaves, spent, attempts, maps = cover_box(loop, h, None, [(lo, hi, 2)], 1e12, worst)
    assert leaves is not None and len(leaves) == 1 and attempts == 1 and maps == 1
    assert np.array_equal(leaves[0][0], lo) and np.array_equal(leaves[0][1], hi)
    assert spent == pytest.approx(box_work(loop) + cubic_work(loop, BULK_PIECES))
    split, _, none, maps_alone = cover_box(loop, h, None, [(lo, hi, 2)], 1e12, worst, bulk=False)
    assert split is not None and none == 0 and len(split) > 1 and maps_alone > 1


def test_no_bulk_certificate_near_the_worst_vertex_after_a_failure_or_unpaid(
        rung: tuple[SampledLoop, float, np.ndarray]) -> None:
    """At the worst vertex's quarter the margin is the vertex's: not tried, nothing paid.
    Where one failed at a margin within ``BULK_RETRY`` of the sub-box's, or the budget
    refuses it, not tried either; beyond ``BULK_RETRY`` it is tried and paid once."""
    loop, h, worst = rung
    paid: list[float] = []

    def pay(units: float) -> bool:
        paid.append(units)
        return True

    lo, hi = _cell(loop, worst, 0, 0)
    assert _bulk(loop, h, (lo, hi, 2), worst, 0.0, pay) == (None, 0.0) and paid == []
    lo, hi = _cell(loop, worst, 0, 3)
    margin = _margin(loop, h, _corner(lo, hi, worst))
    close = margin / (0.9 * BULK_RETRY)
    assert _bulk(loop, h, (lo, hi, 2), worst, close, pay) == (None, close) and paid == []
    assert _bulk(loop, h, (lo, hi, 2), worst, 0.0, lambda units: False) == (None, 0.0)
    far = margin / (1.1 * BULK_RETRY)
    assert _bulk(loop, h, (lo, hi, 2), worst, far, pay) == (True, far)
    assert paid == [cubic_work(loop, BULK_PIECES)]


def test_no_bulk_certificates_on_boxes_with_two_rates() -> None:
    """A random ``n = 2, m = 2`` loop (two free rates) 1e-3 below its crossing: the same
    cover, units and map proofs with and without bulk certificates, no program."""
    loop = conditioned(SampledLoop.build(*lqr_case(2, 2, np.random.default_rng(11))))
    h = 2.4903765732885614 * (1 - 1e-3)
    with_bulk = cover_box(loop, h, None, _box(loop), 1e12)
    without = cover_box(loop, h, None, _box(loop), 1e12, bulk=False)
    assert with_bulk[0] is not None and without[0] is not None and len(with_bulk[0]) == len(without[0])
    assert with_bulk[1:] == without[1:] and with_bulk[2] == 0
