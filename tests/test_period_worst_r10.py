"""The radius reported at the period asked for, and the "not stable" decision, on a loop
whose rate box has more vertices (64) than :func:`~ftc_verify.analysis.moments.sampled.rate_points`
lists (the corners and the midpoint above 16): an independent check (round 10) found the
report 0.8702 at a corner where an inner vertex has 0.8741, and "undecided" at a period
where an inner vertex is unstable (radius 1.00022, proved when the box is that vertex).

The loop (``tests/data/sampled_64_vertices.toml``): ``n = 2``, ``m = 3``, Erlang-2 delays,
fixed false-alarm rates, six detection-rate intervals; random gains."""

from __future__ import annotations

from pathlib import Path

import pytest

from ftc_verify.analysis.moments.sampled import SampledLoop, sampled_analysis, worst_radius
from ftc_verify.controllers.files import load_controller
from ftc_verify.model.files import load_system

DATA = Path(__file__).resolve().parent / "data"


@pytest.fixture(scope="module")
def case() -> tuple:
    return load_system(DATA / "sampled_64_vertices.toml"), load_controller(DATA / "sampled_64_vertices_K.toml")


def test_reported_radius_is_the_worst_vertex(case: tuple) -> None:
    """At 0.1816 the reported radius equals the largest over all 64 vertices and the
    midpoint (every one evaluated here), and it is not at the corners the scan lists."""
    system, K = case
    loop = SampledLoop.build(system, K)
    every = list(loop.chain.vertices()) + [loop.chain.midpoint()]
    assert len(every) == 65
    exhaustive, _ = worst_radius(loop, 0.1816, every)
    corners, _ = worst_radius(loop, 0.1816, [loop.chain.rate_min, loop.chain.rate_max, loop.chain.midpoint()])
    res = sampled_analysis(system, K, 0.1816, h_max=False)
    assert res.verdict == "stable"
    assert res.spectral_radius == pytest.approx(exhaustive, rel=1e-12)
    assert corners < exhaustive * (1 - 1e-3)  # the corners alone miss it


def test_unstable_inner_vertex_is_proved(case: tuple) -> None:
    """At 0.3042 an inner vertex has radius above 1: "not stable", proved at that vertex."""
    system, K = case
    res = sampled_analysis(system, K, 0.3042, h_max=False)
    assert res.verdict == "not stable", res.proof
    assert res.spectral_radius > 1.0
    assert "proved" in res.proof
