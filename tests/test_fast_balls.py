"""The float64 midpoint-radius ball exponential against Arb's (``arb_mat.exp``)."""

from __future__ import annotations

import flint
import numpy as np
import pytest

from ftc_verify.analysis.moments.fast_balls import arb_expm, ball_expm, from_arb, to_arb


def _arb(A: np.ndarray, R: np.ndarray | None = None) -> flint.arb_mat:
    R = np.zeros_like(A) if R is None else R
    n, m = A.shape
    return flint.arb_mat(n, m, [flint.arb(a, r) for a, r in zip(A.ravel().tolist(), R.ravel().tolist())])


@pytest.mark.parametrize("n, scale, shift", [(1, 3.0, 0.0), (4, 1.0, 0.0), (12, 0.8, -1.0), (40, 0.4, -2.0)])
def test_contains_arb_and_not_much_wider(n: int, scale: float, shift: float) -> None:
    rng = np.random.default_rng(n)
    for _ in range(3):
        A = rng.standard_normal((n, n)) * scale + shift * np.eye(n)
        E = _arb(A).exp()
        F = arb_expm(_arb(A))
        em, _ = from_arb(E)
        fm, fr = from_arb(F)
        assert all(F[i, j].contains(E[i, j]) for i in range(n) for j in range(n))
        # the width: float64 rounding (about 1e-16 relative) amplified by the squarings
        assert fr.max() <= 1e-10 * max(1.0, np.abs(em).max())
        assert np.abs(fm - em).max() <= 1e-10 * max(1.0, np.abs(em).max())


def test_wide_ball_contains_every_member() -> None:
    """A ball of matrices: its exponential contains the exponential (Arb, a point) of
    random members, and is about as wide as Arb's over the same ball."""
    rng = np.random.default_rng(7)
    n = 6
    A = rng.standard_normal((n, n)) - np.eye(n)
    R = np.full((n, n), 1e-3)
    F = arb_expm(_arb(A, R))
    wide = from_arb(_arb(A, R).exp())[1].max()
    assert from_arb(F)[1].max() <= 10 * wide
    for _ in range(5):
        B = A + R * rng.uniform(-1, 1, size=(n, n))
        E = _arb(B).exp()
        assert all(F[i, j].contains(E[i, j]) for i in range(n) for j in range(n))
    # a member just outside is not needed to be contained, but the ball is not the whole line
    assert np.all(np.isfinite(from_arb(F)[1]))


def test_known_exponentials() -> None:
    """exp(diag(d)) = diag(e^d); exp of a nilpotent Jordan block is I + N."""
    d = np.array([-3.0, 0.5, 2.0])
    F = arb_expm(_arb(np.diag(d)))
    for i, x in enumerate(d):
        assert F[i, i].contains(flint.arb(x).exp())
    N = np.diag([1.0, 1.0], 1)
    G = arb_expm(_arb(N))
    exact = np.eye(3) + N + N @ N / 2
    assert all(G[i, j].contains(flint.arb(exact[i, j])) for i in range(3) for j in range(3))


def test_overflow_falls_back() -> None:
    """Numbers that overflow float64: ``None`` from the float routine, Arb's exponential
    from :func:`arb_expm` (still an enclosure)."""
    A = np.array([[800.0]])
    assert ball_expm((A, np.zeros((1, 1)))) is None
    assert arb_expm(_arb(A))[0, 0].contains(flint.arb(800).exp())
    assert ball_expm((np.array([[np.nan]]), np.zeros((1, 1)))) is None


def test_round_trip_encloses() -> None:
    """``from_arb`` of a 64-bit Arb ball contains it; ``to_arb`` is exact on floats."""
    with flint.ctx.workprec(64):
        x = flint.arb(1) / 3
        M = flint.arb_mat(1, 1, [x])
        back = to_arb(from_arb(M))
        assert back[0, 0].contains(x)


def test_one_period_map_ball_contains_arbs() -> None:
    """The sampled proofs' map ball (float64 midpoint-radius) against the same map in
    Arb (``arb_mat.exp`` and Arb products), on the paper's loop over its whole rate box
    and at a point: it contains Arb's midpoints and is not much wider."""
    from pathlib import Path

    from ftc_verify.analysis.moments.sampled import SampledLoop
    from ftc_verify.analysis.moments.sampled_balls import ball_generator
    from ftc_verify.analysis.moments.sampled_proof import MapParts
    from ftc_verify.analysis.rigorous import precision
    from ftc_verify.controllers.files import load_controller
    from ftc_verify.model.files import load_system

    root = Path(__file__).resolve().parents[1]
    loop = SampledLoop.build(load_system(root / "examples" / "paper.toml"),
                             load_controller(root / "examples" / "paper_gains.toml"))
    chain = loop.chain
    with precision(64):
        parts = MapParts.build(loop, 0.08)
        for lo, hi in ((chain.rate_min, chain.rate_max), (chain.midpoint(), chain.midpoint())):
            Q = ball_generator(chain, lo, hi, loop.literals).value
            fast = parts.map(Q)
            arb = parts.res * (parts.generator(Q) * parts.h).exp() * parts.lift
            n = arb.nrows()
            assert all(fast[i, j].contains(arb[i, j].mid()) for i in range(n) for j in range(n))
            fr, ar = from_arb(fast)[1], from_arb(arb)[1]
            assert fr.max() <= 2 * ar.max() + 1e-12


def test_higher_precision_uses_arb() -> None:
    """Above 64 bits :func:`arb_expm` is Arb's exponential (narrower balls for the
    proofs' precise retries); at 64 bits the float64 one (wider than Arb's)."""
    A = np.array([[0.3, -1.0], [0.5, -0.2]])

    def widest(m: flint.arb_mat) -> float:
        return max(float(x.rad()) for x in m.entries())

    with flint.ctx.workprec(128):
        assert widest(arb_expm(_arb(A))) < 1e-30
    with flint.ctx.workprec(64):
        assert widest(arb_expm(_arb(A))) > 1e-17
