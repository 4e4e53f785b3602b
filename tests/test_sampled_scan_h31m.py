"""The ``h_max`` scan's engine (:mod:`ftc_verify.analysis.moments.sampled_scan`): its grid
the geometric one of the eigenvalue scan and its binary pieces, the Collatz--Wielandt bounds around the eigenvalue
radius, and the scan's verdict at every period equal to the dense eigenvalue verdict
(static and dynamic controllers), with most periods decided without eigenvalues."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg

from ftc_verify.analysis.moments.sampled import (SCAN_PER_OCTAVE, SampledLoop, one_period_map, rate_points,
                                                 scan_periods, scan_range, spectral_radius)
from ftc_verify.analysis.moments import sampled_scan
from ftc_verify.analysis.moments.sampled_scan import (BITS, MARGIN, ScanCount, binary_pieces, cone_bounds,
                                                      perron_stack, scan, scan_grid)
from ftc_verify.controllers.controller import Controller
from ftc_verify.controllers.files import load_controller
from ftc_verify.model.files import load_system
from ftc_verify.testing.sampled_cases import lqr_case
from ftc_verify.analysis.moments.stability import vech_order

ROOT = Path(__file__).resolve().parents[1]


def dynamic_controller() -> Controller:
    """A dynamic controller on ``y_m = x`` of ``paper_two_outputs.toml`` (as in
    ``test_sampled.py``): the paper gains on ``0.8 y_m + 0.2 x_c``, ``x_c`` a filter of
    ``y_m`` with pole -20."""
    K = load_controller(ROOT / "examples" / "paper_gains.toml").gains
    return Controller.dynamic(Ac=[-20 * np.eye(2)] * 2, Bc=[20 * np.eye(2)] * 2, Cc=[0.2 * k for k in K],
                              Dc=[0.8 * k for k in K])


def _loops() -> dict[str, SampledLoop]:
    return {
        "random n=2 m=2": SampledLoop.build(*lqr_case(2, 2, np.random.default_rng(5))),
        "paper": SampledLoop.build(load_system(ROOT / "examples" / "paper.toml"),
                                   load_controller(ROOT / "examples" / "paper_gains.toml")),
        "dynamic": SampledLoop.build(load_system(ROOT / "examples" / "paper_two_outputs.toml"),
                                     dynamic_controller()),
    }


@pytest.mark.parametrize(("lo", "hi"), [(1e-4, 5.0), (0.3, 0.31), (2.0, 1.0)])
def test_grid_is_the_geometric_one(lo: float, hi: float) -> None:
    """``lo 2^{k/8}`` up to the first at or above ``hi``, at least one octave (the grid of
    the eigenvalue scan, so its intervals and the bracket seeded from it are unchanged)."""
    hs = scan_grid(lo, hi)
    k = np.arange(hs.size)
    assert np.array_equal(hs, lo * 2.0 ** (k / SCAN_PER_OCTAVE))
    assert hs.size >= SCAN_PER_OCTAVE + 1 and hs[-1] >= hi and (hs.size == SCAN_PER_OCTAVE + 1 or hs[-2] < hi)


def test_binary_pieces_sum_to_the_period() -> None:
    """``h = lo sum 2^{l - BITS} + rest`` with ``0 <= rest <= h 2^-BITS`` (to rounding), on
    every period of a grid of 14 octaves and on awkward ones (a power of two, just below one)."""
    lo = 2.5519e-4
    periods = list(scan_grid(lo, 5.1)) + [lo * 8, np.nextafter(lo * 8, 0.0), lo * (2 - 2.0 ** -30)]
    for h in periods:
        levels, rest = binary_pieces(float(h), lo)
        assert len(set(levels)) == len(levels) and min(levels) >= 0
        assert math.isclose(lo * sum(2.0 ** (level - BITS) for level in levels) + rest, h, rel_tol=1e-15)
        assert -1e-15 * h <= rest <= h * 2.0 ** -BITS


def test_cone_bounds_enclose_the_eigenvalue_radius() -> None:
    """For a positive definite stack, ``c_- <= rho(T) <= c_+`` (Collatz--Wielandt): at
    random stacks and at the Perron stack (where the upper one is within 5 % of ``rho``: a Perron stack with singular blocks is moved by the shift), on three
    loops at several periods and rate points; float tolerance 1e-9 relative."""
    rng = np.random.default_rng(31)
    for loop in _loops().values():
        for h in (0.01, 0.08, 0.3):
            for p in rate_points(loop.chain)[:3]:
                T = one_period_map(loop, h, p, scaled=True)
                rho = spectral_radius(loop, h, p)
                _, Y = perron_stack(loop, T)
                assert Y is not None
                stacks = [Y]
                for _ in range(3):
                    G = rng.standard_normal((loop.states, loop.r, loop.r))
                    stacks.append(G @ G.transpose(0, 2, 1) + 0.1 * np.eye(loop.r))
                for Y in stacks:
                    c_lo, c_hi = cone_bounds(loop, Y, _image(loop, T, Y))
                    assert c_lo <= rho * (1 + 1e-9) and rho <= c_hi * (1 + 1e-9)
                _, c_hi = cone_bounds(loop, stacks[0], _image(loop, T, stacks[0]))
                assert c_hi <= rho * 1.05  # the Perron stack, shifted by SHIFT (singular blocks: 1 %)


def _image(loop: SampledLoop, T: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """:math:`T(Y)` from the dense map (an independent route to the scan's matrix-free one)."""
    rows, cols = vech_order(loop.r)
    ty = (T @ Y[:, rows, cols].ravel()).reshape(loop.states, -1)
    out = np.zeros_like(Y)
    out[:, rows, cols] = ty
    out[:, cols, rows] = ty
    return out


def test_cone_bounds_refuse_a_singular_stack() -> None:
    loop = _loops()["paper"]
    Y = np.zeros((loop.states, loop.r, loop.r))
    assert cone_bounds(loop, Y, Y) == (-math.inf, math.inf)


@pytest.mark.parametrize("name", ["random n=2 m=2", "paper", "dynamic"])
def test_scan_verdicts_equal_the_dense_eigenvalues(name: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """At every third period of the scan and on both sides of each change of its verdict,
    ``rho < 1`` exactly where every rate point's eigenvalue radius is below 1 (periods within 1e-9 of 1 excepted: float ties), and
    the cone test decided most of the evaluations (the cone route forced, ``DENSE_SIZE`` 0:
    two of these maps are small enough for the eigenvalue route); the default route
    gives the same verdicts."""
    loop = _loops()[name]
    lo, hi = scan_range(loop)
    default = scan_periods(loop, lo, hi)[1] < 1.0
    monkeypatch.setattr(sampled_scan, "DENSE_SIZE", 0)
    count = ScanCount()
    hs, rho = scan(loop, lo, hi, count=count)
    pts = rate_points(loop.chain)
    change = np.flatnonzero(np.diff(rho < 1.0))
    checked = set(range(0, hs.size, 3)) | set(change) | set(change + 1)  # every third period and each change
    for k in sorted(checked):
        radii = []
        for p in pts:  # up to the first unstable point, as the scan
            radii.append(spectral_radius(loop, float(hs[k]), p))
            if not radii[-1] < 1.0:
                break
        if all(abs(x - 1.0) > MARGIN for x in radii):
            assert (rho[k] < 1.0) == (max(radii) < 1.0), (hs[k], rho[k], radii)
        if rho[k] < 1.0:
            assert max(radii) <= rho[k] * (1 + 1e-9)  # the cone bound is an upper bound there
    assert count.periods == hs.size and count.cone >= 0.8 * count.evaluations
    assert np.array_equal(default, rho < 1.0)


def test_the_ladders_flow_is_the_exponential_to_a_tenth_of_the_margin() -> None:
    """:class:`~ftc_verify.analysis.moments.sampled_scan.Flow` (the ladder's squares at the
    period's binary digits and the Taylor series of the rest) applied to a vector equals
    ``expm(G h)`` applied to it within ``MARGIN / 10`` relative, at EVERY period of the
    scan's grid over its whole range (periods with a non-zero rest: all but the powers of
    two), on the random ``n = 4, m = 3`` loop (90 rows, above ``DENSE_SIZE``) at two rate
    points. Dropping the rest's series misses by about ``1e-4``; a ladder not started
    below ``lo`` fails at the first octave."""
    rng = np.random.default_rng(1)
    lqr_case(2, 2, rng)
    loop = SampledLoop.build(*lqr_case(4, 3, rng))
    assert loop.size > sampled_scan.DENSE_SIZE
    lo, hi = scan_range(loop, 0.01)
    hs = scan_grid(lo, hi)
    top = max(binary_pieces(float(hs[-1]), lo)[0]) + 1
    vd = loop.d * (loop.d + 1) // 2
    u = np.random.default_rng(0).standard_normal(loop.modes_part.shape[0])
    for p in rate_points(loop.chain)[:2]:
        G = loop.modes_part + np.kron(loop.chain.generator(p).T, np.eye(vd))
        F = sampled_scan.ladder(G, lo, top)
        for h in hs:
            levels, rest = binary_pieces(float(h), lo)
            w = sampled_scan.Flow(G, F, levels, rest).apply(u)
            exact = scipy.linalg.expm(G * h) @ u
            assert w is not None
            assert np.linalg.norm(w - exact) <= MARGIN / 10 * np.linalg.norm(exact), h
