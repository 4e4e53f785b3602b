"""The ``h_max`` bracket (issue 31, item 2) on held-out random loops: its budget a
count of sub-boxes fixed by the problem (the same bracket twice, and on a machine whose
clocks run a thousand times slower), its ends checked against an independent float64
evaluation at many rates of the box, the second-order certificate with the
Perron-aligned right-hand side proving what the identity right-hand side cannot, and
the one Taylor routine of the three exponentials against ``scipy.linalg.expm``."""

from __future__ import annotations

import time

import numpy as np
import pytest
import scipy.linalg

from sampled_forms import second_order_form
from ftc_verify.analysis.moments.fast_balls import aff_expm, ball_expm
from ftc_verify.analysis.moments.quad_balls import pairs, quad_expm
from ftc_verify.analysis.moments.sampled import (SampledLoop, crossing, scan_periods,
                                                 scan_range, spectral_radius, stability_intervals)
from ftc_verify.analysis.moments.sampled_bracket import box_work, h_max_bracket
from ftc_verify.analysis.moments.sampled_proof import prove_point_unstable
from ftc_verify.analysis.moments.sampled_second import certify_second_order
from ftc_verify.analysis.moments.sampled_taylor import _certify
from ftc_verify.testing.sampled_cases import lqr_case


def _loop(seed: int) -> SampledLoop:
    """A held-out ``n = 2, m = 2`` loop (its own generator: not a benchmark draw)."""
    return SampledLoop.build(*lqr_case(2, 2, np.random.default_rng(seed)))


def _scan_bracket(loop: SampledLoop) -> tuple[float, float]:
    lo, hi = scan_range(loop)
    hs, rho = scan_periods(loop, lo, hi)
    k = int(np.searchsorted(hs, stability_intervals(loop, hs, rho)[0][1], side="right"))
    return float(hs[k - 1]), float(hs[k])


def _box_points(loop: SampledLoop, rng: np.random.Generator, count: int) -> list[np.ndarray]:
    chain = loop.chain
    lo, hi = np.asarray(chain.rate_min, dtype=float), np.asarray(chain.rate_max, dtype=float)
    return [lo + rng.random(lo.shape) * (hi - lo) for _ in range(count)] + [np.asarray(v, dtype=float)
                                                                          for v in chain.vertices()]


@pytest.mark.parametrize("seed", [29, 37])
def test_bracket_on_held_out_loops_against_dense_float_rates(seed: int) -> None:
    """Held-out loops (seeds 29, 37): the bracket is within 1e-3 relative; at ``h_max``
    the float64 radius is below 1 at 150 uniform random rates of the box (seed 5) and at
    every vertex; at ``h_max_unstable`` some of them is above 1 and instability is proved
    again at it in ball arithmetic (independently of the bracket's own point)."""
    loop = _loop(seed)
    hm, hu, note = h_max_bracket(loop, *_scan_bracket(loop))
    assert hm is not None and hu is not None, note
    assert 0 < (hu - hm) / hu <= 1e-3, note
    pts = _box_points(loop, np.random.default_rng(5), 150)
    assert max(spectral_radius(loop, hm, p) for p in pts) < 1.0
    rho, where = max(((spectral_radius(loop, hu, p), k) for k, p in enumerate(pts)))
    assert rho > 1.0 and prove_point_unstable(loop, hu, pts[where])


def test_bracket_identical_twice_and_on_a_slow_machine(monkeypatch: pytest.MonkeyPatch) -> None:
    """The budget is a count of sub-boxes (``box_work``), not seconds: the bracket is the
    same when run twice, and when every CPU-clock reading advances by 1000 s (a machine
    a thousand times slower, or loaded) -- a budget in seconds would stop at once."""
    loop = _loop(30)
    ends = _scan_bracket(loop)
    first = h_max_bracket(loop, *ends)
    assert first[0] is not None
    assert h_max_bracket(loop, *ends) == first
    ticks = iter(range(0, 10 ** 9, 1000))
    monkeypatch.setattr(time, "process_time", lambda: float(next(ticks)))
    assert h_max_bracket(loop, *ends) == first
    assert box_work(loop) == box_work(_loop(30)) > 0


def test_box_work_grows_with_the_problem() -> None:
    """The work charged per sub-box depends on the sizes only: the ``n = 4, m = 3`` loop
    (189 generator rows, six rates) costs more than ten ``n = 2, m = 2`` ones."""
    small = box_work(_loop(29))
    big = box_work(SampledLoop.build(*lqr_case(4, 3, np.random.default_rng(21))))
    assert big > 10 * small


def test_perron_aligned_second_order_certificate_proves_what_the_identity_cannot() -> None:
    """Benchmark loop ``n = 2, m = 2`` seed 2, 0.3 % below its float64 crossing, on the
    quarter of the box at the worst vertex: the first-order certificate with the identity
    right-hand side fails (a Perron block with eigenvalues 456 and 1.7: the identity
    margin is lost along it), the second-order one with the Perron-aligned right-hand
    side proves it. And just above the crossing, on the quarter at the vertex with
    :math:`\\rho > 1`, neither claims anything."""
    rng = np.random.default_rng(2)
    loop = SampledLoop.build(*lqr_case(2, 2, rng))
    ends = _scan_bracket(loop)
    a = crossing(loop, *ends, True, 1e-7)
    lo = np.array(loop.chain.rate_min, dtype=float)
    hi = lo.copy()
    lo[0, 1], hi[0, 1], hi[1, 0] = 3.5, 4.0, 2.5

    below = second_order_form(loop, a * (1 - 3e-3), lo, hi)
    assert not _certify(loop, below, pairs(2), None)
    assert certify_second_order(loop, below, 0.05)
    h_up = a * (1 + 2e-3)
    assert spectral_radius(loop, h_up, hi * 0 + np.where(lo == 3.5, 4.0, lo)) > 1.0
    above = second_order_form(loop, h_up, lo, hi)
    for mix in (None, 0.05, 0.3):
        assert not certify_second_order(loop, above, mix)
        assert not _certify(loop, above, pairs(2), mix)


@pytest.mark.parametrize("kind", ["ball", "affine", "quadratic"])
def test_one_taylor_routine_contains_scipy_expm(kind: str) -> None:
    """The three exponentials (one ``taylor_expm``) contain ``scipy.linalg.expm`` of 30
    random members of their sets (seed 3; 1e-13 relative slack for scipy's own error),
    and their radii stay below 1e-8 of the norm for the ball, 0.1 for the forms (whose
    radius holds the terms of higher degree: not vacuous)."""
    rng = np.random.default_rng(3)
    n, K = 6, 2
    c = rng.standard_normal((n, n)) * 0.8
    lin = rng.standard_normal((K, n, n)) * 0.05
    quad = rng.standard_normal((len(pairs(K)), n, n)) * 0.01
    rad = np.full((n, n), 1e-12)
    for _ in range(30):
        d = rng.uniform(-1, 1, K)
        mu = np.array([d[a] * d[b] for a, b in pairs(K)])
        E = rng.uniform(-1, 1, (n, n)) * rad
        if kind == "ball":
            X = c + E
            out = ball_expm((c, rad))
            assert out is not None
            mid, r = out
        elif kind == "affine":
            X = c + np.tensordot(d, lin, 1) + E
            aff = aff_expm((c, lin, rad))
            assert aff is not None
            mid, r = aff[0] + np.tensordot(d, aff[1], 1), aff[2]
        else:
            X = c + np.tensordot(d, lin, 1) + np.tensordot(mu, quad, 1) + E
            q = quad_expm((c, lin, quad, rad))
            assert q is not None
            mid, r = q[0] + np.tensordot(d, q[1], 1) + np.tensordot(mu, q[2], 1), q[3]
        F = scipy.linalg.expm(X)
        assert np.all(np.abs(F - mid) <= r + 1e-13 * np.abs(F).max())
        assert float(r.max()) < (1e-8 if kind == "ball" else 0.1) * float(np.abs(F).max())


def test_quadratic_max_bounds_the_maximum_over_the_box() -> None:
    """``quadratic_max`` is an upper bound of a random quadratic's maximum over
    ``[-1, 1]^4`` (seed 9; a grid of 9^4 points and every vertex never exceeds it) and
    within its tolerance of the grid's best value (the bound is not loose)."""
    import itertools

    from ftc_verify.analysis.moments.sampled_second import quadratic_max

    rng = np.random.default_rng(9)
    K = 4
    lin, quad = rng.standard_normal(K), rng.standard_normal(len(pairs(K)))
    bound = quadratic_max(lin, quad)
    grid = np.linspace(-1, 1, 9)
    best = max(float(lin @ np.array(d) + sum(q * d[a] * d[b] for q, (a, b) in zip(quad, pairs(K))))
               for d in itertools.product(grid, repeat=K))
    scale = float(np.abs(lin).sum() + np.abs(quad).sum())
    assert best <= bound <= best + 0.05 * scale
