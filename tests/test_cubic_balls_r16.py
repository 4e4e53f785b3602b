"""The third-order forms of ``cubic_balls``: the product's coefficients against an
exact polynomial product, its enclosure of products of matrices drawn from the forms'
sets, and the one-period map's third-order form against dense float maps at the seed-1
loop's worst vertex, with a remainder below the second-order form's."""

from __future__ import annotations

import itertools
from collections import defaultdict
from fractions import Fraction

import numpy as np
import pytest
import scipy.linalg

from ftc_verify.analysis.moments.cubic_balls import CUBIC_SQUARINGS, cubic_forms, cubic_map, cubic_mul, triples
from ftc_verify.analysis.moments.quad_balls import pairs, quad_map
from ftc_verify.analysis.moments.sampled import one_period_map
from ftc_verify.analysis.moments.sampled_eigen import eigen_radius_bound
from ftc_verify.analysis.moments.sampled_proof import MapParts
from ftc_verify.analysis.moments.sampled_taylor import _rates_affine
from ftc_verify.analysis.rigorous import precision

from sampled_forms import seed1_crossing, vertex_corner


def _monomials(K: int) -> list[tuple[int, ...]]:
    return [()] + [(a,) for a in range(K)] + list(pairs(K)) + list(triples(K))


def _random_form(rng: np.random.Generator, K: int, n: int, m: int, scale: float) -> tuple[np.ndarray, ...]:
    c = rng.standard_normal((n, m))
    l = scale * rng.standard_normal((K, n, m))
    q = scale ** 2 * rng.standard_normal((len(pairs(K)), n, m))
    t = scale ** 3 * rng.standard_normal((len(triples(K)), n, m))
    r = scale ** 4 * rng.random((n, m))
    return c, l, q, t, r


def _coefficients(x: tuple[np.ndarray, ...], K: int) -> list[np.ndarray]:
    return [x[0]] + list(x[1]) + list(x[2]) + list(x[3])


def _evaluate(x: tuple[np.ndarray, ...], d: np.ndarray) -> np.ndarray:
    K = d.shape[0]
    out = np.zeros(x[0].shape)
    for mono, coef in zip(_monomials(K), _coefficients(x, K)):
        out = out + np.prod(d[list(mono)]) * coef
    return out


def test_product_coefficients_are_the_exact_polynomial_product() -> None:
    """Every coefficient of degree up to three of ``cubic_mul`` equals the exact product's
    (collected monomial by monomial in rationals) up to the float rounding, and what the
    product leaves out (degrees four to six, exact) is below its radius entrywise."""
    rng = np.random.default_rng(3)
    K, n = 3, 4
    x, y = _random_form(rng, K, n, n, 0.3), _random_form(rng, K, n, n, 0.3)
    z = cubic_mul(x, y)
    exact: dict[tuple[int, ...], list[list[Fraction]]] = defaultdict(lambda: [[Fraction(0)] * n for _ in range(n)])
    for (ma, A), (mb, B) in itertools.product(zip(_monomials(K), _coefficients(x, K)), zip(_monomials(K), _coefficients(y, K))):
        key = tuple(sorted(ma + mb))
        for i, j in itertools.product(range(n), repeat=2):
            exact[key][i][j] += sum(Fraction(float(A[i, k])) * Fraction(float(B[k, j])) for k in range(n))
    for mono, coef in zip(_monomials(K), _coefficients(z, K)):
        ref = np.array([[float(v) for v in row] for row in exact[mono]])
        assert np.allclose(coef, ref, rtol=1e-13, atol=1e-14)
    high = np.zeros((n, n))
    for mono, entries in exact.items():
        if len(mono) > 3:
            high += np.abs(np.array([[float(v) for v in row] for row in entries]))
    assert np.all(high <= z[4])


@pytest.mark.parametrize("cubic_only", [False, True])
def test_product_encloses_products_of_members(cubic_only: bool) -> None:
    """At 200 random symbols (and the 8 corners) with remainders drawn inside the
    radii, the exact product of the two matrices lies in the product form; also for
    forms with third-order terms only (the product's terms of degree six alone)."""
    rng = np.random.default_rng(5)
    K, n = 3, 5
    x, y = _random_form(rng, K, n, n, 1.0), _random_form(rng, K, n, n, 1.0)
    if cubic_only:
        x, y = ((f[0], 0 * f[1], 0 * f[2], f[3], 0 * f[4]) for f in (x, y))
    z = cubic_mul(x, y)
    points = [np.array(c) for c in itertools.product((-1.0, 1.0), repeat=K)] + [rng.uniform(-1, 1, K) for _ in range(200)]
    worst = 0.0
    for d in points:
        X = _evaluate(x, d) + x[4] * rng.uniform(-1, 1, (n, n))
        Y = _evaluate(y, d) + y[4] * rng.uniform(-1, 1, (n, n))
        worst = max(worst, float(np.max(np.abs(X @ Y - _evaluate(z, d)) / z[4])))
    assert worst <= 1.0


def test_third_order_map_contains_the_map_with_a_smaller_remainder() -> None:
    """On the seed-1 loop's sub-box of a quarter of every width at its worst vertex,
    1 % below the crossing: ``cubic_map`` has ``quad_map``'s coefficients, contains the
    float map (its own error 1e-12) at the 64 corners and 40 random rates, and its
    remainder is below 0.6 times the second-order form's (the point of the module)."""
    loop, a, v = seed1_crossing()
    h = a * (1 - 1e-2)
    lo, hi = vertex_corner(loop, v, 0.25)
    with precision(64):
        res, modes, lift, hb = MapParts.build(loop, h).floats
        found = _rates_affine(loop, lo, hi)
        assert found is not None
        q, dirs = found
        tight = cubic_map(res, modes, q, dirs, hb, lift)
        quad = quad_map(res, modes, q, dirs, hb, lift)
    assert tight is not None and quad is not None
    assert cubic_forms(dirs.shape[0], modes[0].shape[0]) and CUBIC_SQUARINGS >= 1
    for x, y in zip(tight[:3], quad[:3]):
        assert np.allclose(x, y, rtol=0, atol=1e-13)
    Tc, Tl, Tq, Tr = tight
    assert float(np.max(Tr)) < 0.6 * float(np.max(quad[3]))
    chain = loop.chain
    free = [idx for idx in chain.rate_indices if hi[idx] > lo[idx]]
    mid = 0.5 * (lo + hi)
    rng = np.random.default_rng(9)
    deltas = [np.array(c) for c in itertools.product((-1.0, 1.0), repeat=len(free))]
    deltas += [rng.uniform(-1, 1, len(free)) for _ in range(40)]
    for d in deltas:
        r = mid.copy()
        for k, idx in enumerate(free):
            r[idx] = mid[idx] + d[k] * 0.5 * (hi[idx] - lo[idx])
        T = one_period_map(loop, h, r, scaled=True)
        mu = np.array([d[p] * d[s] for p, s in pairs(len(free))])
        form = Tc + np.tensordot(d, Tl, 1) + np.tensordot(mu, Tq, 1)
        assert np.all(np.abs(T - form) <= Tr + 1e-12)
    bound = eigen_radius_bound(tight, loop.states, loop.r)
    assert bound is None or bound > max(float(np.max(np.abs(scipy.linalg.eigvals(one_period_map(loop, h, p, scaled=True)))))
                                        for p in (lo, hi, mid))


def test_the_sub_box_proof_uses_the_third_order_form_where_the_remainder_limits_it() -> None:
    """``sampled_taylor.affine_stable`` on the seed-1 loop's vertex sub-box of a quarter
    of every width, 1.3e-3 below its float64 crossing: proved when the third-order form
    may be paid for (asked once), not proved when the caller declines or gives no
    ``third_order`` (the second-order form's proofs fail there); just above the
    crossing (the vertex unstable) not proved."""
    from ftc_verify.analysis.moments.sampled_taylor import FormSpend, affine_stable

    loop, a, v = seed1_crossing()
    lo, hi = vertex_corner(loop, v, 0.25)
    asked: list[bool] = []

    def proved(h: float, answer: bool | None) -> bool | None:
        def pay() -> bool:
            assert answer is not None
            asked.append(answer)
            return answer

        with precision(64):
            spend = None if answer is None else FormSpend(lambda: True, pay, lambda r: None)
            return affine_stable(loop, MapParts.build(loop, h), lo, hi, spend)

    assert proved(a * (1 - 1.3e-3), True) is True and asked == [True]
    assert proved(a * (1 - 1.3e-3), False) is False and asked == [True, False]
    assert proved(a * (1 - 1.3e-3), None) is False
    assert proved(a * (1 + 1e-3), True) is False
