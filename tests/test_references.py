"""The SDP-free reference norm of :mod:`ftc_verify.testing.references`.

* on identical-mode loops it reproduces SLICOT's ``ab13dd`` (the LTI norm) to 1e-4;
* on genuine multi-mode loops (one generator: the ``beta`` box is a point) the certified
  nominal gamma of Theorem 3.2 lies above it, by at most 1e-3 relative;
* the pieces: the bracket, the Newton test of one gamma on both sides of the norm, the
  abscissa against the analysis package's, and the degenerate cases.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from ftc_verify.analysis.analyze import analyze
from ftc_verify.analysis.moments.stability import spectral_abscissa
from ftc_verify.testing.illconditioned import identical_mode_loop
from ftc_verify.testing.references import (
    coupled_riccati,
    mjls_abscissa,
    mjls_hinf_bounds,
    mjls_hinf_norm,
    mjls_hinf_norm_of_loop,
    multi_mode_loop,
    point_chain,
)

pytest.importorskip("slycot")  # reference_norm: control.linfnorm is SLICOT's ab13dd


@pytest.mark.parametrize("seed,n,norm", [(1, 2, 0.1), (2, 3, 3.0), (3, 4, 50.0), (4, 5, 800.0), (5, 6, 1.0)])
def test_identical_modes_reproduce_ab13dd(seed: int, n: int, norm: float) -> None:
    p = identical_mode_loop(seed, n, norm=norm, diagonal_condition=1.0, transform_condition=1.0)
    beta = p.original.chain.midpoint()
    ref = p.reference_norm()
    value = mjls_hinf_norm_of_loop(p.original, beta)
    assert value == pytest.approx(ref, rel=1e-4)
    b = mjls_hinf_bounds(p.original.A, p.original.Bw, p.original.Cz, p.original.chain.generator(beta))
    assert b.lower <= ref * (1 + 1e-9) and ref <= b.upper * (1 + 1e-9)  # the bracket holds the LTI norm
    assert b.upper / b.lower - 1 <= 1e-6


@pytest.mark.parametrize("seed,n", [(11, 3), (12, 5)])
def test_multi_mode_loops_below_the_certified_gamma(seed: int, n: int) -> None:
    peer = multi_mode_loop(seed, n)
    loop = peer.original
    chain = loop.chain
    assert np.array_equal(chain.beta_min, chain.beta_max)  # the box is one point
    assert len(loop.A) == 4 and not np.allclose(loop.A[0], loop.A[1])  # genuinely different modes
    ref = mjls_hinf_norm_of_loop(loop, chain.midpoint())
    rep = analyze(loop, cross_validation=False)
    assert rep.mss.verdict == "stable"
    assert rep.nominal.certified, rep.nominal.message
    assert 0.0 <= rep.nominal.gamma / ref - 1.0 <= 1e-3, (rep.nominal.gamma, ref)
    # eq. (2) is the adjoint of the analysis package's second-moment generator: same abscissa
    assert mjls_abscissa(loop.A, peer.generator) == pytest.approx(spectral_abscissa(loop, chain.midpoint()),
                                                                  rel=1e-9, abs=1e-12)


def test_newton_on_both_sides_of_the_norm() -> None:
    peer = multi_mode_loop(11, 3)
    loop, Q = peer.original, peer.generator
    b = mjls_hinf_bounds(loop.A, loop.Bw, loop.Cz, Q, rtol=1e-8)
    above = coupled_riccati(loop.A, loop.Bw, loop.Cz, Q, b.upper * (1 + 1e-4))
    assert above.feasible and above.abscissa < 0 and above.residual < 1e-9, above.reason
    assert all(np.linalg.eigvalsh(P)[0] >= -1e-9 * np.linalg.norm(P) for P in above.P)
    below = coupled_riccati(loop.A, loop.Bw, loop.Cz, Q, b.lower * (1 - 1e-4))
    assert not below.feasible and below.P is None and below.reason
    # the norm is linear in the output: scaling every Cz scales it
    scaled = mjls_hinf_norm(loop.A, loop.Bw, [7.0 * C for C in loop.Cz], Q, rtol=1e-8)
    assert scaled == pytest.approx(7.0 * b.lower, rel=1e-7)


def test_moved_loop_has_the_same_norm_and_abscissa() -> None:
    peer = multi_mode_loop(3, 4, norm=2.5, diagonal_condition=30.0, transform_condition=10.0)
    assert peer.reference_norm() == pytest.approx(2.5, rel=2e-6)
    assert mjls_hinf_norm_of_loop(peer.loop) == pytest.approx(2.5, rel=2e-6)
    assert mjls_abscissa(peer.loop.A, peer.generator) == pytest.approx(peer.abscissa, rel=1e-8)


def test_degenerate_cases() -> None:
    chain = point_chain()
    Q = chain.generator(chain.midpoint())
    A = [np.array([[-1.0, 0.3], [0.0, -2.0]])] * 4
    B, C = [np.array([[1.0], [1.0]])] * 4, [np.array([[1.0, 0.0]])] * 4
    assert mjls_hinf_norm(A, B, [0.0 * c for c in C], Q) == 0.0
    assert mjls_abscissa(A, Q) == pytest.approx(-2.0)  # identical modes: twice the LTI abscissa
    assert math.isinf(mjls_hinf_norm([a + 1.5 * np.eye(2) for a in A], B, C, Q))  # not mean-square stable
    with pytest.raises(ValueError):
        mjls_hinf_norm(A, B, C, Q + 0.1)  # rows do not sum to zero
