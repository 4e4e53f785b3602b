"""The second- and third-order forms of a sub-box's one-period map, for the tests of
the sampled sub-box proofs (``test_bracket_h31x.py``, ``test_second_order_h31w.py``,
``test_eigen_enclosure_r14.py``, ``test_eigen3_r19.py``):
:func:`~ftc_verify.analysis.moments.quad_balls.quad_map` and
:func:`~ftc_verify.analysis.moments.cubic_balls.cubic_terms` on the float parts of
:class:`~ftc_verify.analysis.moments.sampled_proof.MapParts` at 64 bits; the seed-1
``n = 4, m = 3`` loop those tests share, its worst vertex's crossing and the sub-boxes at
that vertex."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import scipy.optimize

from ftc_verify.analysis.moments.cubic_balls import cubic_terms
from ftc_verify.analysis.moments.quad_balls import quad_map
from ftc_verify.analysis.moments.sampled import SampledLoop, rate_points, spectral_radius
from ftc_verify.analysis.moments.sampled_bracket import worst_vertex
from ftc_verify.analysis.moments.sampled_conditioned import conditioned
from ftc_verify.analysis.moments.sampled_proof import MapParts
from ftc_verify.analysis.moments.sampled_taylor import _rates_affine
from ftc_verify.analysis.rigorous import precision
from ftc_verify.controllers.controller import Controller
from ftc_verify.model.system import FTCSystem
from ftc_verify.testing.sampled_cases import lqr_case


def _map_form(loop: SampledLoop, h: float, lo: np.ndarray, hi: np.ndarray, build: Callable[..., Any]) -> tuple[np.ndarray, ...]:
    with precision(64):
        res, modes, lift, hb = MapParts.build(loop, h).floats
        found = _rates_affine(loop, lo, hi)
        assert found is not None
        out = build(res, modes, found[0], found[1], hb, lift)
    assert out is not None
    return tuple(out)


def second_order_form(loop: SampledLoop, h: float, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, ...]:
    """``T(delta)`` on ``[lo, hi]`` at period ``h`` as ``(T_c, T_a, T_ab, radius)``."""
    return _map_form(loop, h, lo, hi, quad_map)


def third_order_form(loop: SampledLoop, h: float, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, ...]:
    """``T(delta)`` on ``[lo, hi]`` at period ``h`` as ``(T_c, T_a, T_ab, T_abe, radius)``
    (:func:`~ftc_verify.analysis.moments.cubic_balls.cubic_terms`)."""
    return _map_form(loop, h, lo, hi, cubic_terms)


def crossing_family(spread: float) -> tuple[np.ndarray, np.ndarray]:
    """``(T_c, T_a)`` of one rate: two weakly coupled positive blocks ``[[(0.99 + spread
    delta) a, 0.05], [0, a]]`` (found by the review of round 14): for a spread of 0.1 the
    first block's root passes the second's inside the box."""
    a = np.array([[0.5, 0.2], [0.2, 0.5]])
    Tc = np.zeros((4, 4))
    Tc[:2, :2] = 0.99 * a
    Tc[2:, 2:] = a
    Tc[:2, 2:] = 0.05
    Tl = np.zeros((1, 4, 4))
    Tl[0, :2, :2] = spread * a
    return Tc, Tl


def sampled_radii(loop: SampledLoop, h: float, lo: np.ndarray, hi: np.ndarray, rng: np.random.Generator) -> list[float]:
    """The float64 radius at 40 random vertices of ``[lo, hi]`` and 40 uniform rate arrays."""
    out = []
    for k in range(80):
        t = rng.integers(0, 2, lo.shape) if k < 40 else rng.uniform(0.0, 1.0, lo.shape)
        out.append(spectral_radius(loop, h, lo + (hi - lo) * t))
    return out


def seed1_case() -> tuple[FTCSystem, Controller]:
    """The seed-1 ``n = 4, m = 3`` loop of ``benchmarks/sampled.py`` (not a held-out draw)."""
    rng = np.random.default_rng(1)
    lqr_case(2, 2, rng)
    return lqr_case(4, 3, rng)


def seed1_crossing() -> tuple[SampledLoop, float, np.ndarray]:
    """The conditioned seed-1 loop, the float64 crossing ``a`` of its worst vertex ``v``."""
    loop = conditioned(SampledLoop.build(*seed1_case()))
    v = worst_vertex(loop, 0.546, rate_points(loop.chain))[1]
    a = scipy.optimize.brentq(lambda h: spectral_radius(loop, h, v) - 1.0, 0.5, 0.6, xtol=1e-12)
    return loop, float(a), v


def vertex_corner(loop: SampledLoop, v: np.ndarray, width: float) -> tuple[np.ndarray, np.ndarray]:
    """The sub-box at the vertex ``v`` with ``width`` of every rate's range."""
    chain = loop.chain
    lo, hi = np.array(chain.rate_min, dtype=float), np.array(chain.rate_max, dtype=float)
    for r in chain.rate_indices:
        w = width * (chain.rate_max[r] - chain.rate_min[r])
        if v[r] == chain.rate_min[r]:
            hi[r] = lo[r] + w
        else:
            lo[r] = hi[r] - w
    return lo, hi


def vertex_exponents(loop: SampledLoop, v: np.ndarray, exponents: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    """The sub-box at the vertex ``v`` with ``2^-k`` of each free rate's range, ``k`` from
    ``exponents`` in the order of the free rates."""
    chain = loop.chain
    lo, hi = np.array(chain.rate_min, dtype=float), np.array(chain.rate_max, dtype=float)
    for r, k in zip(chain.free_rate_indices, exponents):
        w = (chain.rate_max[r] - chain.rate_min[r]) * 2.0 ** -k
        if v[r] == chain.rate_min[r]:
            hi[r] = lo[r] + w
        else:
            lo[r] = hi[r] - w
    return lo, hi
