"""The clock-dependent certificate of the sampled loop's second moments
(:mod:`ftc_verify.analysis.moments.sampled_clock`): what it proves is true at rates of the
box, it never proves an unstable period, and its conditions are the ones that decide."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from ftc_verify.analysis.moments.sampled import SampledLoop, spectral_radius
from ftc_verify.analysis.moments.sampled_clock import clock_certificate, clock_stable, prove_clock
from ftc_verify.controllers.files import load_controller
from ftc_verify.model.files import load_system
from ftc_verify.testing.sampled_cases import lqr_case

ROOT = Path(__file__).resolve().parents[1]


def _paper() -> SampledLoop:
    return SampledLoop.build(load_system(ROOT / "examples" / "paper.toml"),
                             load_controller(ROOT / "examples" / "paper_gains.toml"))


def _worst_vertex_radius(loop: SampledLoop, h: float) -> float:
    return max(spectral_radius(loop, h, v) for v in loop.chain.vertices())


def _random_rates(loop: SampledLoop, rng: np.random.Generator) -> np.ndarray:
    lo, hi = loop.chain.rate_min, loop.chain.rate_max
    return lo + rng.uniform(size=lo.shape) * (hi - lo)


@pytest.mark.parametrize("seed", [29, 37])
def test_proved_period_is_stable_at_random_rates_of_the_box(seed: int) -> None:
    """Held-out n = 2, m = 2 loops (seeds not in the benchmark): at 60 % of the worst
    vertex's float64 crossing (found here by bisection) the certificate with 4 affine
    pieces is proved in balls, at 95 % the one with 4 quadratic pieces, and the float64
    radius is below 1 at 40 uniform random rates of the box at each (a proved claim: a
    radius >= 1 there would be a bug, no false-failure probability); 2 % above the
    crossing nothing is proved."""
    system, controller = lqr_case(2, 2, np.random.default_rng(seed))
    loop = SampledLoop.build(system, controller)
    lo, hi = 1e-3, 8.0
    assert _worst_vertex_radius(loop, lo) < 1.0  # both seeds have a stability interval
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if _worst_vertex_radius(loop, mid) < 1.0 else (lo, mid)
    rng = np.random.default_rng(seed + 1000)
    for h, quadratic in ((0.6 * lo, False), (0.95 * lo, True)):
        cert = clock_stable(loop, h, pieces=4, quadratic=quadratic)
        assert cert is not None and cert.proved
        assert max(spectral_radius(loop, h, _random_rates(loop, rng)) for _ in range(40)) < 1.0
    above = clock_stable(loop, 1.02 * lo, pieces=4, quadratic=True)  # a vertex is unstable there
    assert above is None or not above.proved


def test_paper_example_proved_on_the_numbers_as_written_and_never_above_the_crossing() -> None:
    """The paper's gains (crossing 0.0843 s): proved at 0.06 s with 4 pieces; at 0.09 s, where
    a vertex has radius above 1, no certificate is proved."""
    loop = _paper()
    cert = clock_stable(loop, 0.06, pieces=4)
    assert cert is not None and cert.proved
    assert _worst_vertex_radius(loop, 0.09) > 1.0
    above = clock_stable(loop, 0.09, pieces=4)
    assert above is None or not above.proved


def test_each_condition_decides() -> None:
    """Nodes found at 0.06 s are proved there; reversed in the clock (the flow condition
    breaks) or with the last node halved (the jump condition breaks) they are not."""
    loop = _paper()
    cert = clock_certificate(loop, 0.06, pieces=4)
    assert cert is not None and prove_clock(loop, cert)
    nodes = cert.nodes
    assert not prove_clock(loop, dataclasses.replace(cert, nodes=nodes[::-1]))
    halved = nodes[:-1] + (tuple(0.5 * y for y in nodes[-1]),)
    assert not prove_clock(loop, dataclasses.replace(cert, nodes=halved))


def test_bracket_uses_the_clock_certificate_when_the_tight_sub_box_attempts_fail() -> None:
    """A crossing given 1 % too high (the paper loop's is 0.08426): the tight sub-box
    attempts lie above the true crossing and fail, the clock certificate proves the first
    :data:`CLOCK_LADDER` distance (2 % below, under the true crossing) and not the next (above
    it); the sub-box ladder then proves the closer 1 % (a third of the budget each) -- the
    period returned is never farther than the sub-box route's alone, and is stable at 40
    random rates of the box (float64, a proved claim)."""
    from ftc_verify.analysis.moments.sampled_bracket import CLOCK_LADDER, CLOCK_WORK, clock_below, prove_below

    loop = _paper()
    a = 1.01 * 0.08426
    got = prove_below(loop, a, 1e-3, 8, CLOCK_WORK, math.inf)
    assert clock_below(loop, a) == a * (1 - CLOCK_LADDER[0])
    assert got is not None and got >= a * (1 - CLOCK_LADDER[0])
    rng = np.random.default_rng(7)
    assert max(spectral_radius(loop, got, _random_rates(loop, rng)) for _ in range(40)) < 1.0
    without = prove_below(loop, a, 1e-3, 8, CLOCK_WORK - 1.0, math.inf)  # below CLOCK_WORK: sub-boxes only
    assert without is None or without <= got
