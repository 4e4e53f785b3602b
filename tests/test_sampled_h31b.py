"""The sampled loop's ``h_max`` bracket on random loops: the second-order and affine
enclosures of the one-period map over a rate sub-box against a dense float evaluation,
the proofs never claiming a box with an unstable rate, the worst vertex beyond the
corners, and the bracket within 1e-3 checked at many rates of the box."""

from __future__ import annotations

import numpy as np
import pytest

from ftc_verify.analysis.moments.fast_balls import aff_map
from ftc_verify.analysis.moments.quad_balls import pairs, quad_map
from ftc_verify.analysis.moments.sampled import (SampledLoop, crossing, rate_points, scan_periods, scan_range,
                                                 spectral_radius, stability_intervals, worst_radius)
from ftc_verify.analysis.moments.sampled_bracket import h_max_bracket, worst_vertex
from ftc_verify.analysis.moments.sampled_proof import MapParts, box_verdict
from ftc_verify.analysis.moments.sampled_taylor import _rates_affine, affine_stable
from ftc_verify.analysis.rigorous import precision
from ftc_verify.testing.sampled_cases import lqr_case


def _random_loop(n: int, m: int, seed: int) -> SampledLoop:
    """:func:`_draw` with its own generator (other seeds than the benchmark's)."""
    return _draw(n, m, np.random.default_rng(seed))


def _draw(n: int, m: int, rng: np.random.Generator) -> SampledLoop:
    """The loop of :func:`~ftc_verify.testing.sampled_cases.lqr_case` (as ``benchmarks/sampled.py``)."""
    return SampledLoop.build(*lqr_case(n, m, rng))


def _crossing(loop: SampledLoop) -> tuple[float, float, float]:
    lo, hi = scan_range(loop)
    hs, rho = scan_periods(loop, lo, hi)
    k = int(np.searchsorted(hs, stability_intervals(loop, hs, rho)[0][1], side="right"))
    return crossing(loop, float(hs[k - 1]), float(hs[k]), True, 1e-6), float(hs[k - 1]), float(hs[k])


def _box_points(loop: SampledLoop, lo: np.ndarray, hi: np.ndarray, rng: np.random.Generator, count: int) -> list[np.ndarray]:
    pts = []
    for _ in range(count):
        r = np.array(lo, dtype=float)
        for idx in loop.chain.rate_indices:
            r[idx] = lo[idx] + rng.random() * (hi[idx] - lo[idx])
        pts.append(r)
    return pts


@pytest.mark.parametrize("second", [True, False])
def test_forms_contain_the_map_at_random_rates(second: bool) -> None:
    """At 40 random rates of a sub-box (seed 7) the float map lies in the second-order
    (or affine) form evaluated at that rate's symbols, entrywise, up to the float map's
    own error (1e-12 absolute); and the forms' radius is far below the map's spread over
    the sub-box (the point of keeping the rates as symbols)."""
    from ftc_verify.analysis.moments.sampled import one_period_map

    loop = _random_loop(2, 2, 11)
    chain = loop.chain
    h = 0.8
    lo, hi = np.array(chain.rate_min, dtype=float), np.array(chain.rate_max, dtype=float)
    hi = lo + 0.25 * (hi - lo)
    with precision(64):
        parts = MapParts.build(loop, h)
        found = _rates_affine(loop, lo, hi)
        assert found is not None
        q, dirs = found
        res, modes, lift, hb = parts.floats
        if second:
            quad = quad_map(res, modes, q, dirs, hb, lift)
            assert quad is not None
            Tc, Tl, Tq, Tr = quad
        else:
            aff = aff_map(res, modes, q, dirs, hb, lift)
            assert aff is not None
            Tc, Tl, Tr = aff
            Tq = np.zeros((0,) + Tc.shape)
    mid = 0.5 * (lo + hi)
    free = [idx for idx in chain.rate_indices if hi[idx] > lo[idx]]
    w = np.array([0.5 * (hi[idx] - lo[idx]) for idx in free])
    spread = 0.0
    T0 = one_period_map(loop, h, mid, scaled=True)
    for r in _box_points(loop, lo, hi, np.random.default_rng(7), 40):
        d = np.array([(r[idx] - mid[idx]) for idx in free]) / w
        form = Tc + np.tensordot(d, Tl, 1)
        if Tq.shape[0]:
            form = form + np.tensordot(np.array([d[a] * d[b] for a, b in pairs(len(d))]), Tq, 1)
        T = one_period_map(loop, h, r, scaled=True)
        assert np.all(np.abs(T - form) <= Tr + 1e-12)
        spread = max(spread, float(np.max(np.abs(T - T0))))
    assert float(np.max(Tr)) < 0.5 * spread


def test_affine_proof_never_claims_an_unstable_box() -> None:
    """Just above the crossing (some rate of the box unstable, float64) the proof on the
    whole box fails, and box_verdict says "not stable"; just below it proves the box."""
    loop = _random_loop(2, 2, 4)
    a, _, _ = _crossing(loop)
    chain = loop.chain
    above = a * (1 + 2e-3)
    assert worst_radius(loop, above, rate_points(chain))[0] > 1.0
    with precision(64):
        assert not affine_stable(loop, MapParts.build(loop, above), chain.rate_min, chain.rate_max)
    assert box_verdict(loop, above).verdict == "not stable"
    assert box_verdict(loop, a * (1 - 5e-4), max_boxes=512, max_seconds=30.0).verdict == "stable"


def test_worst_vertex_beyond_the_corners() -> None:
    """Six detection rates (n = 4, m = 3, seed 1 of the benchmark's draws): at h = 0.5466
    both corners and the midpoint have rho < 1, the climb finds a vertex with rho > 1
    (the float64 crossing of the corners is not that of the box)."""
    rng = np.random.default_rng(1)
    _draw(2, 2, rng)  # the benchmark draws n = 2 first, then n = 4 from the same stream
    loop = _draw(4, 3, rng)
    pts = rate_points(loop.chain)
    h = 0.5466
    assert worst_radius(loop, h, pts)[0] < 1.0
    rho, v = worst_vertex(loop, h, pts)
    assert rho > 1.0 and rho == spectral_radius(loop, h, v)
    chain = loop.chain
    assert all(v[idx] in (chain.rate_min[idx], chain.rate_max[idx]) for idx in chain.rate_indices)


@pytest.mark.parametrize("seed", [4, 1])
def test_bracket_within_rtol_and_consistent_with_dense_rates(seed: int) -> None:
    """Held-out random loops (n = 2, m = 2, seeds 4 and 1): the proved bracket is within
    1e-3 relative; at h_max the float radius is below 1 at 150 random rates of the box
    and every vertex (seed 5), and at h_max_unstable some rate of the box has rho > 1."""
    loop = _random_loop(2, 2, seed)
    _, stable_h, unstable_h = _crossing(loop)
    hm, hu, note = h_max_bracket(loop, stable_h, unstable_h)
    assert hm is not None and hu is not None, note
    assert (hu - hm) / hu <= 1e-3, note
    chain = loop.chain
    pts = _box_points(loop, chain.rate_min, chain.rate_max, np.random.default_rng(5), 150)
    pts += list(chain.vertices())
    assert max(spectral_radius(loop, hm, p) for p in pts) < 1.0
    assert max(spectral_radius(loop, hu, p) for p in pts) > 1.0



def test_first_stability_interval_ends_at_the_proved_unstable_period(monkeypatch: pytest.MonkeyPatch) -> None:
    """When the bracket proves instability below the end of the scan's first interval
    (a worse vertex than the scan's rate points), the reported interval ends there; the
    paper loop's own interval (ending near 0.0843, above the 0.08 faked here) is cut."""
    from pathlib import Path

    from ftc_verify.analysis.moments import sampled
    from ftc_verify.controllers.files import load_controller
    from ftc_verify.model.files import load_system

    root = Path(__file__).resolve().parents[1]
    system, gains = load_system(root / "examples" / "paper.toml"), load_controller(root / "examples" / "paper_gains.toml")
    honest = sampled.sampled_analysis(system, gains, 0.01, max_boxes=4)
    assert honest.stability_intervals[0][1] > 0.0842
    monkeypatch.setattr(sampled, "h_max_bracket", lambda *a, **k: (None, 0.08, "faked"))
    res = sampled.sampled_analysis(system, gains, 0.01, max_boxes=4)
    assert res.stability_intervals[0] == (honest.stability_intervals[0][0], 0.08)
