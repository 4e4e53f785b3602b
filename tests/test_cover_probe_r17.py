"""The ``h_max`` cover's probes (:func:`~ftc_verify.analysis.moments.sampled_cover.probe_box`)
on a held-out ``n = 4, m = 3`` loop with six detection rates (seed 13 of
``benchmarks/h_max_heldout.py``'s draw, conditioned as the refinement runs it), 1.083e-2
below the default bracket's proved-unstable end 0.6022096970393988.

The path to the probes halves the widest rate for :data:`COVER_DEPTH` halvings (the
probe), then :func:`map_split`'s down to :data:`PROBE_DEPTH` (the deeper probe). The
deeper probe is thin in the rates that move the radius and wide in the others, and a
certificate of four cubic pieces proves it. No such certificate is found for the first
probe, which is wider in those rates, so the rung would be covered by map proofs alone
(``benchmarks/results/split17.md``)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from ftc_verify.analysis.moments.sampled import SampledLoop, rate_points
from ftc_verify.analysis.moments.sampled_bracket import worst_vertex
from ftc_verify.analysis.moments.sampled_conditioned import conditioned
from ftc_verify.analysis.moments.sampled_cover import COVER_DEPTH, PROBE_DEPTH, _path, _widest, map_split, probe_box
from ftc_verify.analysis.moments.sampled_cubic import cubic_stable
from ftc_verify.testing.sampled_cases import lqr_case

HU = 0.6022096970393988


def held_out_rung(f: float) -> tuple[SampledLoop, float, np.ndarray]:
    """Held-out seed 13's loop (conditioned, at the analysed period 0.01), the period
    ``HU (1 - f)`` and the worst vertex at ``HU``."""
    rng = np.random.default_rng(13)
    lqr_case(2, 2, rng)  # the draw's first case, as benchmarks/sampled.py draws it
    loop = conditioned(dataclasses.replace(SampledLoop.build(*lqr_case(4, 3, rng)), written=(0.01,)))
    return loop, HU * (1 - f), worst_vertex(loop, HU, rate_points(loop.chain))[1]


@pytest.fixture(scope="module")
def rung() -> tuple[SampledLoop, float, np.ndarray]:
    return held_out_rung(1.083e-2)


def test_probe_widest_then_radius_rule(rung: tuple[SampledLoop, float, np.ndarray]) -> None:
    loop, h, worst = rung
    box = (np.array(loop.chain.rate_min, dtype=float), np.array(loop.chain.rate_max, dtype=float), 0)
    path = _path(loop, h, box, worst)
    assert len(path) == PROBE_DEPTH
    parent = box
    for depth, (harder, other) in enumerate(path):
        lo, hi, _ = parent
        rule = _widest(loop, h, lo, hi, worst) if depth < COVER_DEPTH else map_split(loop, h, lo, hi)
        moved = [r for r in loop.chain.rate_indices if harder[0][r] != lo[r] or harder[1][r] != hi[r]]
        assert moved == [rule] and harder[2] == other[2] == depth + 1
        v = np.where(np.abs(worst - lo) <= np.abs(worst - hi), lo, hi)  # the corner nearest the worst vertex
        assert np.all((harder[0] <= v) & (v <= harder[1])) and not np.all((other[0] <= v) & (v <= other[1]))
        parent = harder
    assert probe_box(loop, h, box, worst)[2] == COVER_DEPTH and probe_box(loop, h, box, worst, PROBE_DEPTH)[2] == PROBE_DEPTH


def test_probe_proved_by_four_cubic_pieces_where_the_widest_one_is_not(rung: tuple[SampledLoop, float, np.ndarray]) -> None:
    loop, h, worst = rung
    box = (np.array(loop.chain.rate_min, dtype=float), np.array(loop.chain.rate_max, dtype=float), 0)
    lo, hi, _ = probe_box(loop, h, box, worst, PROBE_DEPTH)
    assert np.all((lo <= worst) & (worst <= hi))
    cert = cubic_stable(loop, h, 4, lo, hi)
    assert cert is not None and cert.proved
    wlo, whi, _ = probe_box(loop, h, box, worst)  # ten widest-rate halvings
    wide = cubic_stable(loop, h, 4, wlo, whi)
    assert wide is None or not wide.proved
