"""The sampled gain certificate's escalation over the pieces ``N`` and the shared,
faster lower-bound search (:mod:`ftc_verify.analysis.moments.sampled_gamma`,
:mod:`ftc_verify.analysis.moments.sampled_lower`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ftc_verify.analysis.moments.sampled import SampledLoop
from ftc_verify.analysis.moments.sampled_gamma import augmented_loop, sample_jumps, sampled_gamma
from ftc_verify.analysis.moments.sampled_lower import (_blocks, _FloatRatio, _Ops, _ratio, sampled_lower_bound,
                                                       sampled_lower_bounds)
from ftc_verify.controllers.controller import Controller
from ftc_verify.controllers.files import load_controller
from ftc_verify.model.files import load_system
from ftc_verify.model.system import FTCSystem

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def paper() -> tuple[FTCSystem, Controller]:
    return load_system(ROOT / "examples" / "paper.toml"), load_controller(ROOT / "examples" / "paper_gains.toml")


def test_float_ratio_equals_the_generic_one(paper: tuple[FTCSystem, Controller]) -> None:
    """The precomputed float64 ratio (search and refinement) equals :func:`_ratio` on
    random held feedbacks (fixed seed 11), three doublings counts, to 1e-12."""
    system, controller = paper
    h = 0.03
    loop = SampledLoop.build(system, controller)
    aug = augmented_loop(loop, system)
    P = loop.restriction()
    resets = [J @ P.T for J in sample_jumps(loop, h)]
    rng = np.random.default_rng(11)
    b = _blocks(_Ops(False), aug, P, system.chain.generator(system.chain.midpoint()), h, 1.0, 1)
    fast = _FloatRatio(b, loop.r)
    for p in (1, 4, 9):
        F = [rng.normal(size=(1, loop.r)) for _ in resets]
        num, den = _ratio(_Ops(False), b, resets, F, h, p)
        assert fast(resets, F, h, p) == pytest.approx(float(num[0, 0] / den[0, 0]), rel=1e-12)


def test_shared_lower_bounds_equal_the_separate_ones(paper: tuple[FTCSystem, Controller]) -> None:
    """One shared search gives the nominal bound of the separate call exactly and a robust
    bound at least the nominal one's float value, both proved."""
    system, controller = paper
    h = 0.05
    nominal, robust = sampled_lower_bounds(system, controller, h)
    alone = sampled_lower_bound(system, controller, h, robust=False)
    assert nominal.value is not None and robust is not None and robust.value is not None
    assert nominal.value == alone.value
    assert robust.float_value is not None and nominal.float_value is not None
    assert robust.float_value >= nominal.float_value


def test_pieces_escalate_until_one_is_proved(paper: tuple[FTCSystem, Controller]) -> None:
    """h = 0.07 (0.83 h_max): two and four pieces cannot prove a gain (the affine storage
    is too coarse), eight can."""
    system, controller = paper
    cert = sampled_gamma(system, controller, 0.07, robust=False, pieces=(2, 4, 8))
    assert cert.gamma is not None and cert.pieces == 8, cert.note


def test_budget_stops_the_escalation(paper: tuple[FTCSystem, Controller]) -> None:
    """With ``max_rows = 0`` only the first N is tried: at h = 0.07 it fails, and the
    note names the failure and says that N = 8 was not tried."""
    system, controller = paper
    cert = sampled_gamma(system, controller, 0.07, robust=False, pieces=(4, 8), max_rows=0)
    assert cert.gamma is None and "N = 4 (affine):" in cert.note and "N = 8 not tried" in cert.note


def test_target_decides_whether_more_pieces_are_tried(paper: tuple[FTCSystem, Controller]) -> None:
    """h = 0.05: a target (lower bound) met by N = 4 stops there; one far below makes it
    try N = 8, which tightens gamma by under GAIN_RTOL and stops: the smaller gamma kept."""
    system, controller = paper
    near = sampled_gamma(system, controller, 0.05, robust=False, pieces=(4, 8), target=0.47)
    far = sampled_gamma(system, controller, 0.05, robust=False, pieces=(4, 8, 16), target=0.1)
    assert near.pieces == 4 and near.gamma is not None
    assert far.pieces == 8 and far.gamma is not None and far.gamma < near.gamma


def test_quadratic_coefficients_reproduce_the_instance(paper: tuple[FTCSystem, Controller]) -> None:
    """The coefficients M0, M1, M2 obtained from s = 0, 1/2, 1 give the instance of the
    quadratic storage at other s (random nodes and slopes, seed 5) to 1e-9 relative: the
    instance is a quadratic polynomial in the clock on a piece."""
    from ftc_verify.analysis.lmi import BlockSpec, block_specs
    from ftc_verify.analysis.moments.sampled_gamma import clock_instance
    from ftc_verify.analysis.moments.sampled_quadratic import _poly

    system, controller = paper
    loop = SampledLoop.build(system, controller)
    aug = augmented_loop(loop, system)
    rng = np.random.default_rng(5)

    def sym() -> np.ndarray:
        m = rng.normal(size=(loop.d, loop.d))
        return m + m.T

    delta = 0.01
    P0, D, E = ([sym() for _ in range(loop.states)] for _ in range(3))
    for spec in block_specs(aug)[:3]:
        lam = [float(v) for v in rng.uniform(0.1, 1.0, size=len(aug.channels[spec.s]))]

        def inst(P: list[np.ndarray], Pdot: list[np.ndarray], la: list[float] | None,
                 spec: BlockSpec = spec) -> np.ndarray:
            return np.asarray(clock_instance(aug, spec, P, Pdot[spec.s], la, 0.3, np.block))

        M0, M1, M2 = _poly(inst, P0, D, E, lam, delta)
        for s in (0.2, 0.77):
            P = [p + d * (delta * s) + e * s * s for p, d, e in zip(P0, D, E)]
            Pdot = [d + e * (2 * s / delta) for d, e in zip(D, E)]
            direct = inst(P, Pdot, lam)
            assert np.allclose(M0 + s * M1 + s * s * M2, direct, rtol=1e-9, atol=1e-9 * np.abs(direct).max())


def test_quadratic_storage_reaches_closer_to_h_max(paper: tuple[FTCSystem, Controller]) -> None:
    """h = 0.075 (0.89 h_max): the affine storage on 4 or 8 pieces proves nothing; the
    quadratic one on 2 pieces proves a gamma within 5 % of the proved lower bound, and a
    gamma 10 % below it is not proved (the proof rejects it)."""
    from ftc_verify.analysis.moments.sampled_quadratic import quadratic_check, quadratic_program
    from ftc_verify.analysis.solvers import solve_conic_dual

    system, controller = paper
    h = 0.075
    affine = sampled_gamma(system, controller, h, robust=False, pieces=(4, 8))
    assert affine.gamma is None
    quad = sampled_gamma(system, controller, h, robust=False, pieces=((2, 2),))
    low = sampled_lower_bound(system, controller, h, robust=False)
    assert quad.gamma is not None and quad.degree == 2 and low.value is not None, quad.note
    assert low.value <= quad.gamma <= 1.05 * low.value
    loop = SampledLoop.build(system, controller)
    aug = augmented_loop(loop, system).nominal()
    problem, lay = quadratic_program(aug, sample_jumps(loop, h), h, 2, False)
    _, x, _ = solve_conic_dual(problem.fix(lay.g + 1, 1e-7))
    assert x is not None
    assert not quadratic_check(loop, system, h, x, lay, 0.81 * float(x[lay.g]), False)


def test_quadratic_storage_with_a_dynamic_controller() -> None:
    """A filtered dynamic controller (its state in the storage, its discretisation in the
    jump, enclosed by the rigorous exponential) at h = 0.02: the quadratic storage on one
    piece proves a gamma within 1 % of the affine one on 2 pieces."""
    system = load_system(ROOT / "examples" / "paper_two_outputs.toml")
    K = load_controller(ROOT / "examples" / "paper_gains.toml").gains
    controller = Controller.dynamic(Ac=[-20 * np.eye(2)] * 2, Bc=[20 * np.eye(2)] * 2, Cc=[0.2 * k for k in K],
                                    Dc=[0.8 * k for k in K])
    affine = sampled_gamma(system, controller, 0.02, robust=False, pieces=((1, 2),))
    quad = sampled_gamma(system, controller, 0.02, robust=False, pieces=((2, 1),))
    assert affine.gamma is not None and quad.gamma is not None and quad.degree == 2, quad.note
    assert quad.gamma == pytest.approx(affine.gamma, rel=0.01)


def test_the_proved_lower_bound_keeps_its_float_value(paper: tuple[FTCSystem, Controller]) -> None:
    """Gains that ``verify --seed 1`` synthesises, h = 0.01 (2^15 + 1 periods): the 64-bit
    enclosure is widened by the doublings to about 1 % here; the proof is then redone at
    128 bits, so the proved bound stays within PROOF_RTOL of the float64 value."""
    from ftc_verify.analysis.moments.sampled_lower import PROOF_RTOL

    system, _ = paper
    gains = [np.array([[9.409990714455295, 23.851143478389673], [-11.539268313003962, -11.804915307650663]]),
             np.array([[9.409956993218872, 23.851146583919252], [-11.539316951202323, -11.804913241447615]])]
    low = sampled_lower_bound(system, Controller.state_feedback(gains), 0.01, robust=False)
    assert low.value is not None and low.float_value is not None
    assert low.float_value * (1 - PROOF_RTOL) <= low.value <= low.float_value * (1 + 1e-9)
