"""The eigenpair enclosure of a sub-box's one-period map (``sampled_eigen``, issue 31,
item 2): its bound lies above every spectral radius of the family it encloses (random
nonnegative families, where the orthant is the cone of ``1 x 1`` blocks, and the seed-1
``n = 4, m = 3`` loop's sub-boxes), it proves a sub-box at the worst vertex that the
cone certificates of ``sampled_second`` do not, and it claims nothing on a sub-box that
holds a rate array with radius above 1 or where the Perron root is not simple."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import scipy.optimize
from hypothesis import given, settings
from hypothesis import strategies as st

from sampled_forms import second_order_form
from ftc_verify.analysis.moments.quad_balls import pairs
from ftc_verify.analysis.moments.sampled import SampledLoop, rate_points, spectral_radius
from ftc_verify.analysis.moments.sampled_bracket import worst_vertex
from ftc_verify.analysis.moments.sampled_conditioned import conditioned
from ftc_verify.analysis.moments.sampled_eigen import eigen_radius_bound, eigen_stable
from ftc_verify.analysis.moments.sampled_proof import MapParts, subbox_stable
from ftc_verify.analysis.moments.sampled_second import certify_second_order
from ftc_verify.analysis.rigorous import precision
from ftc_verify.testing.sampled_cases import lqr_case


def _family(rng: np.random.Generator, n: int, K: int, spread: float) -> tuple[np.ndarray, ...]:
    """A nonnegative family ``T(delta) = T_c + sum_a delta_a T_a + sum_p mu_p T_p`` (every
    member nonnegative for ``delta`` in ``[-1, 1]^K``) as a form with radius ``1e-12``."""
    Tc = rng.uniform(0.2, 1.0, (n, n))
    Tl = spread * rng.uniform(-1.0, 1.0, (K, n, n)) * Tc / K
    Tq = 0.5 * spread * rng.uniform(-1.0, 1.0, (len(pairs(K)), n, n)) * Tc / len(pairs(K))
    return Tc, Tl, Tq, np.full((n, n), 1e-12)


def _member(form: tuple[np.ndarray, ...], d: np.ndarray) -> np.ndarray:
    Tc, Tl, Tq, _ = form
    mu = np.array([d[a] * d[b] for a, b in pairs(len(d))])
    return Tc + np.tensordot(d, Tl, 1) + np.tensordot(mu, Tq, 1)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), n=st.integers(2, 8), K=st.integers(1, 3),
       spread=st.sampled_from([0.01, 0.1, 0.5]))
def test_bound_above_every_radius_of_a_nonnegative_family(seed: int, n: int, K: int, spread: float) -> None:
    """Nonnegative families (the orthant: ``n`` states of ``1 x 1`` blocks): when a bound
    is proved it is at least the spectral radius at every vertex and at 50 random
    ``delta`` (the seed drawn by hypothesis), and for the small spreads it is proved and
    within ``10 spread^2`` of the largest of them."""
    rng = np.random.default_rng(seed)
    form = _family(rng, n, K, spread)
    top = eigen_radius_bound(form, n, 1)
    points = [np.array(c) for c in itertools.product((-1.0, 1.0), repeat=K)] + list(rng.uniform(-1, 1, (50, K)))
    radii = [float(np.max(np.abs(np.linalg.eigvals(_member(form, d))))) for d in points]
    if spread <= 0.1:
        assert top is not None
    if top is not None:
        assert top >= max(radii)
        if spread <= 0.1:
            assert top - max(radii) <= 10 * spread ** 2 * max(radii)


def test_no_claim_where_the_perron_root_is_not_simple() -> None:
    """A reducible family ``diag(a(delta), b(delta))`` of two ``2 x 2`` positive blocks
    whose Perron roots cross inside the box: the centre's eigenvector is not inside the
    cone, the bound is not proved (a bound from the centre's branch alone would be below
    the radius where the other block's root is larger)."""
    a = np.array([[0.5, 0.2], [0.2, 0.5]])
    Tc = np.zeros((4, 4))
    Tc[:2, :2] = a
    Tc[2:, 2:] = a * 0.99
    Tl = np.zeros((1, 4, 4))
    Tl[0, 2:, 2:] = 0.1 * a
    form = (Tc, Tl, np.zeros((1, 4, 4)), np.full((4, 4), 1e-14))
    assert eigen_radius_bound(form, 4, 1) is None


def _case() -> tuple:
    """The seed-1 ``n = 4, m = 3`` loop of ``benchmarks/sampled.py`` (not a held-out draw)."""
    rng = np.random.default_rng(1)
    lqr_case(2, 2, rng)
    return lqr_case(4, 3, rng)


@pytest.fixture(scope="module")
def setting() -> tuple[SampledLoop, float, np.ndarray]:
    """The conditioned loop, the float64 crossing ``a`` of its worst vertex ``v``."""
    loop = conditioned(SampledLoop.build(*_case()))
    v = worst_vertex(loop, 0.546, rate_points(loop.chain))[1]
    a = scipy.optimize.brentq(lambda h: spectral_radius(loop, h, v) - 1.0, 0.5, 0.6, xtol=1e-12)
    return loop, float(a), v


def _corner(loop: SampledLoop, v: np.ndarray, width: float) -> tuple[np.ndarray, np.ndarray]:
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


def _radii(loop: SampledLoop, h: float, lo: np.ndarray, hi: np.ndarray, rng: np.random.Generator) -> list[float]:
    """The float64 radius at 40 random vertices of ``[lo, hi]`` and 40 uniform rate arrays."""
    out = []
    for k in range(80):
        t = rng.integers(0, 2, lo.shape) if k < 40 else rng.uniform(0.0, 1.0, lo.shape)
        out.append(spectral_radius(loop, h, lo + (hi - lo) * t))
    return out


def test_proves_a_vertex_box_the_cone_certificates_do_not(setting: tuple[SampledLoop, float, np.ndarray]) -> None:
    """0.1 % below the crossing, the sub-box of a sixteenth of every width at the worst
    vertex: none of the cone certificates of ``sampled_second`` proves it, the
    eigenpair enclosure does, and its bound lies above the float64 radius at 80 rate
    arrays of the sub-box (40 vertices, 40 uniform; seed 5), within 1e-3 of the largest."""
    loop, a, v = setting
    h = a * (1 - 1e-3)
    lo, hi = _corner(loop, v, 1 / 8)
    form = second_order_form(loop, h, lo, hi)
    with precision(64):
        assert not any(certify_second_order(loop, form, mix) for mix in (None, 0.05))
        assert not certify_second_order(loop, form, shifted=True)
        assert eigen_stable(loop, form)
    top = eigen_radius_bound(form, loop.states, loop.r)
    radii = _radii(loop, h, lo, hi, np.random.default_rng(5))
    assert top is not None and max(radii) <= top <= max(radii) + 1e-3


def test_refuses_a_sub_box_with_radius_above_one(setting: tuple[SampledLoop, float, np.ndarray]) -> None:
    """0.1 % above the crossing the worst vertex has radius above 1: the enclosure claims
    no sub-box holding it (a sixteenth, a sixty-fourth, a 1024th of every width; its bound,
    when proved, is above 1), nor does ``subbox_stable``."""
    loop, a, v = setting
    h = a * (1 + 1e-3)
    assert spectral_radius(loop, h, v) > 1.0
    with precision(64):
        parts = MapParts.build(loop, h)
    for width in (1 / 16, 1 / 64, 1 / 1024):
        lo, hi = _corner(loop, v, width)
        form = second_order_form(loop, h, lo, hi)
        top = eigen_radius_bound(form, loop.states, loop.r)
        assert top is None or top > 1.0
        assert not eigen_stable(loop, form)
        assert not subbox_stable(loop, h, parts, lo, hi)
