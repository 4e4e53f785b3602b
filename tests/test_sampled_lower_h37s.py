"""The sampled lower bound's proof arithmetic (``analysis/moments/sampled_lower_ops.py``):

* the Van Loan output row scaled by ``2^-k`` before the ball exponential and the row
  multiplied back by ``2^k`` encloses the same exponential as the unscaled one (the two
  Arb enclosures overlap in every entry), narrower and with ``row_exponent`` bringing the
  row's sum to the others'; in ``_blocks`` on balls (output scaled by 2^10, so ``k > 0``)
  the blocks still contain the float64 ones (without the multiplication back they would
  be 2^k off);
* the doubling in the eigenbasis (``eigen_sums``) encloses the sums of the plain doubling
  computed at 512 bits at every level, ends far narrower than the plain 64-bit doubling on
  a non-normal map (the wrapping), and refuses a defective map;
* on the paper loop the 64-bit proof of the lower bound reaches within ``PROOF_RTOL`` of
  the float64 value (no 128-bit redo needed).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ftc_verify.analysis.moments.sampled_lower_ops import eigen_sums, row_exponent

flint = pytest.importorskip("flint")

ROOT = Path(__file__).resolve().parents[1]


def _arb(M: np.ndarray) -> object:
    return flint.arb_mat(M.shape[0], M.shape[1], [float(x) for x in M.ravel()])


def _entries(M: object) -> list:
    return list(M.entries())


def test_scaled_output_row_encloses_the_same_exponential() -> None:
    """Random stable ``V`` (size 24, row sums below 1) and an output row of sum 100: the
    scaled and unscaled 128-bit exponentials overlap in every entry of ``F`` and of the
    first row, the scaled one narrower in that row; ``row_exponent`` gives ``k`` with the
    scaled sum at most the largest other row (0.25 at least)."""
    rng = np.random.default_rng(37)
    n = 24
    V = rng.normal(size=(n, n)) * 0.02 - 0.3 * np.eye(n)
    ell = np.abs(rng.normal(size=n))
    ell *= 100.0 / ell.sum()
    other = float(np.abs(V).sum(axis=1).max())
    k = row_exponent(float(ell.sum()), other)
    assert k > 0 and ell.sum() / 2.0 ** k <= max(other, 0.25) < ell.sum() / 2.0 ** (k - 1)
    assert row_exponent(0.1, 0.5) == 0 and row_exponent(float("nan"), 1.0) == 0

    def vanloan(row: np.ndarray) -> object:
        M = np.zeros((n + 1, n + 1))
        M[0, 1:], M[1:, 1:] = row, V
        return _arb(M).exp()

    ctx = flint.ctx.prec
    flint.ctx.prec = 128
    try:
        plain = vanloan(ell)
        scaled = vanloan(ell * 2.0 ** -k)  # exact: a power of two
        first = [scaled[0, j] * flint.arb(2.0 ** k) for j in range(1, n + 1)]
        assert all(first[j - 1].overlaps(plain[0, j]) for j in range(1, n + 1))
        assert all(scaled[i, j].overlaps(plain[i, j]) for i in range(1, n + 1) for j in range(1, n + 1))
        assert max(float(x.rad()) for x in first) < max(float(plain[0, j].rad()) for j in range(1, n + 1))
    finally:
        flint.ctx.prec = ctx


def test_ball_blocks_with_a_scaled_row_contain_the_float_ones() -> None:
    """The paper loop with its output scaled by 2^10 (the row's sum far above the others:
    ``k > 0``): the 64-bit ball blocks ``F`` and ``ell^T G`` of ``_blocks`` contain the
    float64 ones (midpoints within their radii plus 1e-12 of the largest entry)."""
    from ftc_verify.analysis.moments.fast_balls import from_arb
    from ftc_verify.analysis.moments.sampled import SampledLoop
    from ftc_verify.analysis.moments.sampled_balls import ball_generator
    from ftc_verify.analysis.moments.sampled_gamma import augmented_loop
    from ftc_verify.analysis.moments.sampled_lower import _blocks, _Ops
    from ftc_verify.analysis.rigorous import precision
    from ftc_verify.controllers.files import load_controller
    from ftc_verify.model.files import load_system

    system = load_system(ROOT / "examples" / "paper.toml")
    loop = SampledLoop.build(system, load_controller(ROOT / "examples" / "paper_gains.toml"))
    h, P, rates = 0.5, loop.restriction(), system.chain.midpoint()
    flt = _blocks(_Ops(False), augmented_loop(loop, system, z_scale=1024.0).nominal(), P,
                  system.chain.generator(rates), h, 0.0, 1)
    assert np.abs(flt.lg).sum() > 1e3 * np.abs(flt.Fm).sum(axis=1).max()  # the row dominates
    with precision(64):
        ball = _blocks(_Ops(True), augmented_loop(loop, system, balls=True, z_scale=1024.0).nominal(), P,
                       ball_generator(system.chain, rates, rates, loop.literals).value, loop.period_ball(h), 0.0, 1)
    for got, want in ((ball.Fm, flt.Fm), (ball.lg, flt.lg)):
        mid, rad = from_arb(got.value)
        assert np.all(np.abs(mid - want) <= rad + 1e-12 * np.max(np.abs(want)))


def _plain(T: object, v1: object, g: object, f: object, p: int) -> list:
    S, Pw, out = v1, T, []
    for k in range(p + 1):
        if k:
            S = S + Pw * S
            Pw = Pw * Pw
        out.append(((g * S)[0, 0], (f * S)[0, 0]))
    return out


def test_eigenbasis_doubling_encloses_the_sums_without_wrapping() -> None:
    """A non-normal map of size 16 (spectral radius 0.995, eigenvalues of both signs,
    eigenvectors of condition about 600, ``|T|`` of spectral radius about 50): at every level of 12 doublings the eigenbasis enclosures
    (64 bits) overlap the plain doubling's at 512 bits, and at the last level the
    eigenbasis radius is below 1e-6 relative while the plain 64-bit doubling's is above
    1e-3 (or not finite); a defective map (a Jordan block) gives ``[]``."""
    rng = np.random.default_rng(2026)
    n, p = 16, 12
    X = np.eye(n) + 3.0 * rng.normal(size=(n, n))
    lam = 0.995 * np.exp(-np.linspace(0.0, 3.0, n)) * np.where(np.arange(n) % 2, 1.0, -1.0)
    T = X @ np.diag(lam) @ np.linalg.inv(X)
    assert max(abs(np.linalg.eigvals(np.abs(T)))) > 1.0
    v1, g, f = rng.normal(size=(n, 1)), np.abs(rng.normal(size=(1, n))), np.abs(rng.normal(size=(1, n)))
    ctx = flint.ctx.prec
    try:
        flint.ctx.prec = 512
        exact = _plain(_arb(T), _arb(v1), _arb(g), _arb(f), p)
        flint.ctx.prec = 64
        eig = eigen_sums(_arb(T), _arb(v1), _arb(g), _arb(f), p)
        plain = _plain(_arb(T), _arb(v1), _arb(g), _arb(f), p)
        assert len(eig) == p + 1
        for (ge, fe), (gx, fx) in zip(eig, exact):
            assert ge.overlaps(gx) and fe.overlaps(fx)
        ge, gp = eig[-1][0], plain[-1][0]
        assert float(ge.rad()) < 1e-6 * abs(float(ge.mid()))
        assert not float(gp.rad()) < 1e-3 * abs(float(gp.mid()))  # 7.7e-3 (seed 2026)
        J = _arb(np.array([[0.5, 1.0], [0.0, 0.5]]))
        assert eigen_sums(J, _arb(np.ones((2, 1))), _arb(np.ones((1, 2))), _arb(np.ones((1, 2))), 3) == []
    finally:
        flint.ctx.prec = ctx


def test_paper_lower_bound_is_proved_at_64_bits_within_the_tolerance() -> None:
    """The paper loop at h = 0.05 (nominal): the 64-bit proof alone (``_prove_at``) of the
    float64 search's best candidate lies within ``PROOF_RTOL`` of its float64 value, at the
    last level of the doublings."""
    import math

    from ftc_verify.analysis.moments import sampled_lower as sl
    from ftc_verify.analysis.moments.sampled import SampledLoop
    from ftc_verify.controllers.files import load_controller
    from ftc_verify.model.files import load_system

    system = load_system(ROOT / "examples" / "paper.toml")
    controller = load_controller(ROOT / "examples" / "paper_gains.toml")
    loop, h = SampledLoop.build(system, controller), 0.05
    value, rates, delta, F, _, _, p = sl._search(system, controller, loop, h, (0.0,), sl.SCALES)[0.0]
    lower, level = sl._prove_at(system, loop, h, rates, delta, F, p, sl.PROOF_BITS)
    assert lower is not None and level == p
    assert math.sqrt(value) * (1.0 - sl.PROOF_RTOL) <= lower <= math.sqrt(value) * (1.0 + 1e-9)
