"""The order of the ``h_max`` refinement's cover (:mod:`ftc_verify.analysis.moments.sampled_cover`):
the harder half of every split first, a failed sub-box's probe (its hardest sub-box at
:data:`COVER_DEPTH`) tried before its halves and a leaf when the cover reaches it, the
union of the leaves exactly the box, the same loop and budget giving the same bracket
with the real certificates, and a certificate moved to another period proved again, not
trusted."""

from __future__ import annotations

import dataclasses
from fractions import Fraction
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from ftc_verify.analysis.moments import sampled_cover
from ftc_verify.analysis.moments.sampled import SampledLoop, rate_points
from ftc_verify.analysis.moments.sampled_bracket import worst_vertex
from ftc_verify.analysis.moments.sampled_cover import COVER_DEPTH, cover_box, cover_h_max, probe_box
from ftc_verify.analysis.moments.sampled_cubic import cubic_stable, prove_cubic
from ftc_verify.controllers.files import load_controller
from ftc_verify.model.files import load_system

ROOT = Path(__file__).resolve().parents[1]
PAPER_UNSTABLE = 0.0843  # above the paper loop's float64 crossing 0.08426 (h31c)


def _paper() -> SampledLoop:
    return SampledLoop.build(load_system(ROOT / "examples" / "paper.toml"),
                             load_controller(ROOT / "examples" / "paper_gains.toml"))


def _halvings(loop: SampledLoop, lo: Any, hi: Any) -> int:
    full = loop.chain.rate_max - loop.chain.rate_min
    return round(float(sum(np.log2(full[r] / (hi[r] - lo[r])) for r in loop.chain.rate_indices)))


class _Narrow:
    """A stand-in for :func:`cubic_stable` proving the sub-boxes of at least ``least``
    halvings of the box (records what it was asked)."""

    def __init__(self, least: int) -> None:
        self.least = least
        self.asked: list[tuple[np.ndarray, np.ndarray]] = []

    def __call__(self, loop: SampledLoop, h: float, pieces: int, lo: np.ndarray, hi: np.ndarray) -> object:
        self.asked.append((lo.copy(), hi.copy()))
        return type("Cert", (), {"proved": _halvings(loop, lo, hi) >= self.least})()


def test_harder_half_and_probe_first(monkeypatch: pytest.MonkeyPatch) -> None:
    """The box fails, then its probe is asked (COVER_DEPTH halvings down, at the corner of
    the worst vertex), then the shallowest proved sub-box on the path to it: the top of the
    path, then by bisection; then the other halves along the path, the deepest first; no
    sub-box is asked twice and the leaves are exactly the box."""
    loop = _paper()
    h = 0.95 * PAPER_UNSTABLE
    worst = worst_vertex(loop, h, rate_points(loop.chain))[1]
    box = (loop.chain.rate_min.copy(), loop.chain.rate_max.copy(), 0)
    plo, phi, depth = probe_box(loop, h, box, worst)
    assert depth == COVER_DEPTH == _halvings(loop, plo, phi)
    assert np.all(plo <= worst) and np.all(worst <= phi)
    assert probe_box(loop, h, (plo, phi, depth), worst)[2] == depth  # that deep: itself
    fake = _Narrow(2)
    monkeypatch.setattr(sampled_cover, "cubic_stable", fake)
    monkeypatch.setattr(sampled_cover, "subbox_stable", lambda *args, spend=None: False)
    leaves, _, attempts, _ = cover_box(loop, h, 2, [box], 1e12, worst)
    assert leaves is not None and attempts == len(fake.asked)
    assert np.array_equal(fake.asked[1][0], plo) and np.array_equal(fake.asked[1][1], phi)
    # the box, its probe, the top of its path (1 halving: not proved), the bisection (5, 3,
    # 2: proved); the other half at 2 halvings (proved), the one at 1 (not: its own probe,
    # the top of its path at 2, proved, and the other half at 2)
    assert [_halvings(loop, lo, hi) for lo, hi in fake.asked] == [0, 10, 1, 5, 3, 2, 2, 1, 10, 2, 2]
    keys = [(lo.tobytes(), hi.tobytes()) for lo, hi in fake.asked]
    assert len(keys) == len(set(keys))
    assert sorted(_halvings(loop, lo, hi) for lo, hi, _ in leaves) == [2, 2, 2, 2]
    assert any(np.all(lo <= worst) and np.all(worst <= hi) for lo, hi, _ in leaves[:1])
    _assert_union_is_the_box(loop, leaves)


def _assert_union_is_the_box(loop: SampledLoop, leaves: Any) -> None:
    """Inside the box, pairwise disjoint interiors, volumes adding up exactly (rationals of
    the floats) to the box's: the union is the box."""
    idx = loop.chain.rate_indices
    lo0, hi0 = loop.chain.rate_min, loop.chain.rate_max

    def volume(lo: Any, hi: Any) -> Fraction:
        out = Fraction(1)
        for r in idx:
            out *= Fraction(float(hi[r])) - Fraction(float(lo[r]))
        return out

    assert all(lo0[r] <= lo[r] < hi[r] <= hi0[r] for lo, hi, _ in leaves for r in idx)
    for a, (la, ha, _) in enumerate(leaves):
        assert all(any(ha[r] <= lb[r] or hb[r] <= la[r] for r in idx) for lb, hb, _ in leaves[a + 1:])
    assert sum((volume(lo, hi) for lo, hi, _ in leaves), Fraction(0)) == volume(lo0, hi0)


def test_rung_probe_proved_once_then_a_leaf(monkeypatch: pytest.MonkeyPatch) -> None:
    """A rung's probe, proved when the rung's pieces are chosen, is not solved again when
    the cover reaches it; the cover is exactly the box."""
    loop = _paper()
    fake = _Narrow(2)
    monkeypatch.setattr(sampled_cover, "cubic_stable", fake)
    monkeypatch.setattr(sampled_cover, "subbox_stable", lambda *args, spend=None: False)
    got = cover_h_max(loop, 0.99 * PAPER_UNSTABLE, PAPER_UNSTABLE, 1e12, 1e-3)
    assert got.h_max is not None and all(ok for _, ok in got.rungs)
    rungs = len(got.rungs)
    probes = [a for a in fake.asked if _halvings(loop, *a) == COVER_DEPTH]
    # one probe per rung (the first: the one below the box, then below the leaf holding
    # the worst vertex) plus, on the first rung, the probe of the half not holding it
    assert len(probes) == rungs + 1 and got.attempts == len(fake.asked)


def test_same_loop_and_budget_same_bracket() -> None:
    """The real certificates and map proofs, twice: the same rungs, sub-boxes, units."""
    loop = _paper()
    hu = PAPER_UNSTABLE
    first = cover_h_max(loop, 0.98 * hu, hu, 15000, 1e-3)
    assert first.h_max is not None and 0.98 * hu < first.h_max < hu
    assert cover_h_max(loop, 0.98 * hu, hu, 15000, 1e-3) == first


def test_certificate_moved_to_another_period_is_proved_again() -> None:
    """A cubic certificate proved at ``h`` is checked again at another period (the proof
    uses the period it is given): above the crossing it is refused."""
    from ftc_verify.analysis.moments.sampled_conditioned import conditioned

    loop = conditioned(_paper())
    cert = cubic_stable(loop, 0.08, 2)
    assert cert is not None and cert.proved
    assert prove_cubic(loop, cert)
    assert not prove_cubic(loop, dataclasses.replace(cert, h=1.001 * PAPER_UNSTABLE))
