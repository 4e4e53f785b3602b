"""The sampled stability proofs in conditioned coordinates (issue 31, ill-conditioned loops).

The paper loop moved by a state similarity :math:`x' = S x` has the same one-period
spectrum at every rate (:mod:`ftc_verify.analysis.moments.sampled_conditioned`), so its
proved ``h_max`` bracket must contain the paper loop's float64 crossing ``H_REF``
(bisection of the worst rate point to 1e-12) and its verdicts must be the paper loop's.
Before the proofs ran in the coordinates of ``conditioned`` (``benchmarks/results/h31r.md``):
condition 1e3 had no bracket, condition 1e4 was "undecided" at 0.05 s.
"""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest

from moved_loops import Units, moved

from ftc_verify.analysis.moments.sampled import H_MAX_RTOL, SampledLoop, crossing, one_period_map, sampled_analysis
from ftc_verify.analysis.moments.sampled_clock import clock_stable
from ftc_verify.analysis.moments.sampled_conditioned import ConditionedLoop, ball_data, conditioned
from ftc_verify.analysis.moments.sampled_proof import ball_one_period_map, ball_resets, box_verdict, written_flow
from ftc_verify.analysis.rigorous import midpoint, precision
from ftc_verify.controllers.controller import Controller
from ftc_verify.controllers.files import load_controller
from ftc_verify.model.files import load_system
from ftc_verify.model.system import FTCSystem
from ftc_verify.testing.illconditioned import similarity

ROOT = Path(__file__).resolve().parents[1]

CASES = [
    Units("similarity of condition 1e3", S=similarity(np.random.default_rng(31), 2, 1.0, 1e3)),
    Units("similarity of condition 1e4", S=similarity(np.random.default_rng(31), 2, 1.0, 1e4)),
    Units("similarity 1e4 in units of condition 1e6", S=similarity(np.random.default_rng(31), 2, 1e6, 1e4)),
    Units("time 1e-6, similarity 1e4", s=1e-6, S=similarity(np.random.default_rng(7), 2, 1.0, 1e4)),
]


@pytest.fixture(scope="module")
def paper() -> tuple[FTCSystem, Controller]:
    return load_system(ROOT / "examples" / "paper.toml"), load_controller(ROOT / "examples" / "paper_gains.toml")


@pytest.fixture(scope="module")
def reference(paper: tuple) -> tuple[float, tuple[float, float]]:
    """``H_REF`` and the paper loop's own proved bracket."""
    loop = SampledLoop.build(*paper)
    res = sampled_analysis(*paper, 0.05, max_seconds=30.0)
    assert res.h_max is not None and res.h_max_unstable is not None
    return crossing(loop, 0.08, 0.09, True, 1e-12), (res.h_max, res.h_max_unstable)


def test_a_well_conditioned_loop_is_proved_as_before(paper: tuple) -> None:
    """No similarity on the paper loop as written: the proofs see the same object."""
    loop = SampledLoop.build(*paper)
    assert conditioned(loop) is loop


@pytest.mark.parametrize("u", CASES, ids=[u.name for u in CASES])
def test_moved_loop_bracket_agrees_with_the_paper_loop(paper: tuple, reference: tuple, u: Units) -> None:
    h_ref, (lo, hi) = reference
    system, controller = moved(*paper, u)
    assert isinstance(conditioned(SampledLoop.build(system, controller)), ConditionedLoop)
    res = sampled_analysis(system, controller, 0.05 / u.s, max_seconds=30.0)
    assert res.verdict == "stable", res.proof
    assert res.h_max is not None and res.h_max_unstable is not None, res.h_max_note
    assert res.h_max <= h_ref / u.s * (1 + 1e-9) <= res.h_max_unstable * (1 + 2e-9)
    assert res.h_max_unstable / res.h_max - 1 <= H_MAX_RTOL
    # the same bracket as the unmoved loop's, to its width
    width = hi - lo
    assert abs(res.h_max * u.s - lo) <= width and abs(res.h_max_unstable * u.s - hi) <= width
    unstable = box_verdict(SampledLoop.build(system, controller), 0.1 / u.s)
    assert unstable.verdict == "not stable", unstable.detail


@pytest.mark.parametrize("u", CASES, ids=[u.name for u in CASES])
def test_clock_certificate_on_moved_loops(paper: tuple[FTCSystem, Controller], u: Units) -> None:
    """Proved at ``0.08 / s`` (5 % below the crossing) in the conditioned coordinates,
    never at the unstable ``0.1 / s`` (before: none found at condition 1e3 and 1e4)."""
    loop = SampledLoop.build(*moved(*paper, u))
    found = clock_stable(loop, 0.08 / u.s, pieces=2, quadratic=True)
    assert found is not None and found.proved, u.name
    above = clock_stable(loop, 0.1 / u.s, pieces=2, quadratic=True)
    assert above is None or not above.proved


def test_conditioned_map_is_similar_and_its_ball_contains_the_moved_written_map(paper: tuple) -> None:
    """The conditioned float map has the unmoved paper loop's spectral radius (the moved
    loop's float map in the user's coordinates is off by 1e-3 at condition 1e4), and the
    ball formed from the written balls moved by the similarity has relative radii far
    below the unmoved-coordinates ball's (the point of the change)."""
    system, controller = moved(*paper, CASES[1])
    loop = SampledLoop.build(system, controller)
    cl = conditioned(loop)
    rates = loop.chain.midpoint()
    rho = [max(abs(np.linalg.eigvals(one_period_map(x, 0.05, rates, scaled=True))))
           for x in (SampledLoop.build(*paper), cl)]
    assert rho[1] == pytest.approx(rho[0], rel=1e-9)
    with precision(64):
        plain, moved_ball = (ball_one_period_map(x, 0.05, rates, rates) for x in (loop, cl))
    rel = [float(np.max(np.abs(np.array([[float(b.value[i, j].rad()) for j in range(b.shape[1])]
                                           for i in range(b.shape[0])])))) / float(np.max(np.abs(midpoint(b))))
           for b in (plain, moved_ball)]
    assert rel[1] < 1e-3 * rel[0], rel
    assert max(abs(np.linalg.eigvals(midpoint(moved_ball)))) == pytest.approx(rho[0], rel=1e-6)


def test_the_written_balls_are_never_read_from_moved_floats(paper: tuple) -> None:
    """``written_flow`` / ``ball_resets`` of a conditioned loop would enclose its moved floats
    as if written: refused."""
    cl = conditioned(SampledLoop.build(*moved(*paper, CASES[0])))
    with pytest.raises(TypeError):
        written_flow(cl, cl.flow[0])
    with pytest.raises(TypeError):
        ball_resets(cl, 0.05)


def test_dynamic_controller_moved_loop_keeps_its_spectrum(paper: tuple[FTCSystem, Controller]) -> None:
    """The observer of ``paper_observer.toml`` (its own loop has a conditioning transform of
    condition about 1.5e3, so it is moved): the float map and the ball map formed from the
    moved written balls (the controller's discretisation in Arb) have the loop's spectral
    radius; the moved resets follow the period (``ConditionedLoop.resets``)."""
    loop = SampledLoop.build(paper[0], load_controller(ROOT / "examples" / "paper_observer.toml"))
    cl = conditioned(loop)
    assert isinstance(cl, ConditionedLoop)
    rates = loop.chain.midpoint()
    for h in (1e-3, 0.05):
        rho = max(abs(np.linalg.eigvals(one_period_map(loop, h, rates, scaled=True))))
        moved_rho = max(abs(np.linalg.eigvals(one_period_map(cl, h, rates, scaled=True))))
        assert moved_rho == pytest.approx(rho, rel=1e-9)
        with precision(64):
            B = ball_one_period_map(cl, h, rates, rates)
        assert max(abs(np.linalg.eigvals(midpoint(B)))) == pytest.approx(rho, rel=1e-9)
    assert not np.allclose(cl.resets(1e-3)[0], cl.resets(0.05)[0])


def test_a_bad_similarity_never_loses_a_verdict(paper: tuple[FTCSystem, Controller]) -> None:
    """Whatever float similarity is chosen (here one of condition 1e7, far worse than the
    loop as written), the verdicts stay the paper loop's: the loop as written is tried
    when the moved one leaves the verdict undecided, and a proof in any similar
    coordinates is a proof for the written loop."""
    from ftc_verify.analysis.moments.sampled_conditioned import moved_loop

    loop = SampledLoop.build(*paper)
    T = np.eye(loop.d)
    T[:2, :2] = similarity(np.random.default_rng(3), 2, 1.0, 1e7)
    bad = moved_loop(loop, T, np.linalg.inv(T))
    loop.memo["conditioned"] = bad
    assert conditioned(loop) is bad
    assert box_verdict(loop, 0.05).verdict == "stable"
    assert box_verdict(loop, 0.1).verdict == "not stable"


def _exact(x: object) -> Fraction:
    """An exact Arb value (a midpoint or a radius) as a fraction."""
    man, exp = x.man_exp()  # type: ignore[attr-defined]
    return Fraction(int(man)) * Fraction(2) ** int(exp)


def test_the_moved_balls_contain_the_exact_similarity_of_the_written_balls_midpoints(paper: tuple) -> None:
    """:func:`ball_data` against exact rational arithmetic: for every flow and reset of the
    paper loop moved by a similarity of condition 1e4, the ball of ``T^-1 F T`` (``T^-1
    R T_r``) contains the exact rational product of the exact inverse of the float ``T``
    with the midpoints of the written balls ``F`` (``R``) -- a point of the set the ball
    must enclose, checked entry by entry without floating point."""
    cl = conditioned(SampledLoop.build(*moved(*paper, CASES[1])))
    assert isinstance(cl, ConditionedLoop) and cl.base is not None and cl.T is not None

    def exact_matrix(a: np.ndarray) -> list[list[Fraction]]:
        return [[Fraction(float(v)) for v in row] for row in a]

    def inverse(a: list[list[Fraction]]) -> list[list[Fraction]]:  # Gauss-Jordan over the rationals
        n = len(a)
        m = [row[:] + [Fraction(int(i == j)) for j in range(n)] for i, row in enumerate(a)]
        for c in range(n):
            p = next(r for r in range(c, n) if m[r][c] != 0)
            m[c], m[p] = m[p], m[c]
            m[c] = [v / m[c][c] for v in m[c]]
            for r in range(n):
                if r != c and m[r][c] != 0:
                    m[r] = [v - m[r][c] * w for v, w in zip(m[r], m[c])]
        return [row[n:] for row in m]

    def product(*ms: list[list[Fraction]]) -> list[list[Fraction]]:
        out = ms[0]
        for b in ms[1:]:
            out = [[sum((x * b[k][j] for k, x in enumerate(row)), Fraction(0)) for j in range(len(b[0]))]
                   for row in out]
        return out

    T = exact_matrix(cl.T)
    T_inv, T_r = inverse(T), exact_matrix(cl.T_r)
    with precision(64):
        base = cl.base
        flows, resets = [written_flow(base, A) for A in base.flow], ball_resets(base, 0.05)
        moved_flows, moved_resets = ball_data(cl, flows, resets)
        pairs = [(F, G, T) for F, G in zip(flows, moved_flows)] + [(R, G, T_r) for R, G in zip(resets, moved_resets)]
        for written, moved_ball, right in pairs:
            mid = [[_exact(written.value[i, j].mid()) for j in range(written.shape[1])] for i in range(written.shape[0])]
            exact = product(T_inv, mid, right)
            for i, row in enumerate(exact):
                for j, v in enumerate(row):
                    entry = moved_ball.value[i, j]
                    assert abs(v - _exact(entry.mid())) <= _exact(entry.rad()), (i, j)
