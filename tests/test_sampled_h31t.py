"""The cheaper exponentials of the sampled loop's exact energy and proved lower bound
(:mod:`ftc_verify.analysis.moments.sampled_energy`, :mod:`ftc_verify.analysis.moments.sampled_lower`):
one exponential of size ``N + 1`` gives the blocks the ``2N`` Van Loan exponential gave."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.linalg

from ftc_verify.analysis.moments.sampled import SampledLoop
from ftc_verify.analysis.moments.sampled_energy import _augmented
from ftc_verify.analysis.moments.sampled_gamma import augmented_loop
from ftc_verify.analysis.moments.sampled_lower import _blocks, _Ops
from ftc_verify.controllers.controller import Controller
from ftc_verify.controllers.files import load_controller
from ftc_verify.model.files import load_system
from ftc_verify.model.system import FTCSystem

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def paper() -> tuple[FTCSystem, Controller]:
    return load_system(ROOT / "examples" / "paper.toml"), load_controller(ROOT / "examples" / "paper_gains.toml")


def _van_loan(L: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """``(e^{L h}, int_0^h e^{L s} ds)`` from the ``2N`` block ``[[L, I], [0, 0]]``."""
    N = L.shape[0]
    V = np.zeros((2 * N, 2 * N))
    V[:N, :N], V[:N, N:] = L, np.eye(N)
    E = scipy.linalg.expm(V * h)
    return E[:N, :N], E[:N, N:]


@pytest.mark.parametrize("h", [0.01, 0.07, 0.5])
def test_energy_blocks_equal_the_van_loan_ones(paper: tuple[FTCSystem, Controller], h: float) -> None:
    """``_Augmented.blocks``: ``e^{L h}`` and ``ell^T G`` equal those of the ``2N`` Van Loan
    exponential to 1e-10 (relative to the largest entry) at a vertex of the rate box."""
    system, controller = paper
    beta = next(iter(system.chain.vertices()))
    aug = _augmented(system, controller, h, beta, "paper", None, (0, 0))
    F, ellG = aug.blocks(h)
    F2, G2 = _van_loan(aug.L, h)
    assert np.max(np.abs(F - F2)) <= 1e-10 * np.max(np.abs(F2))
    row = aug.ell @ G2
    assert np.max(np.abs(ellG - row)) <= 1e-10 * np.max(np.abs(row))


def test_lower_bound_blocks_obey_the_semigroup(paper: tuple[FTCSystem, Controller]) -> None:
    """The lower bound's float blocks at ``h`` and ``2h``: ``F(2h) = F(h)^2`` and
    ``ell^T G(2h) = ell^T G(h) (I + F(h))`` (``int_0^{2h} = int_0^h + e^{V h} int_0^h``) to
    1e-10; and the 64-bit ball blocks contain the float ones (midpoints within their radii
    plus 1e-12 of the largest entry), so the proof encloses what the search computed."""
    from ftc_verify.analysis.moments.fast_balls import from_arb
    from ftc_verify.analysis.moments.sampled_balls import ball_generator
    from ftc_verify.analysis.rigorous import precision

    system, controller = paper
    h = 0.05
    loop = SampledLoop.build(system, controller)
    P = loop.restriction()
    rates = system.chain.midpoint()
    Q = system.chain.generator(rates)
    aug = augmented_loop(loop, system).nominal()
    one, two = (_blocks(_Ops(False), aug, P, Q, t, 0.0, 1) for t in (h, 2 * h))
    assert np.max(np.abs(two.Fm - one.Fm @ one.Fm)) <= 1e-10 * np.max(np.abs(two.Fm))
    want = one.lg @ (np.eye(one.Fm.shape[0]) + one.Fm)
    assert np.max(np.abs(two.lg - want)) <= 1e-10 * np.max(np.abs(want))
    with precision(64):
        ball = _blocks(_Ops(True), augmented_loop(loop, system, balls=True).nominal(), P,
                       ball_generator(system.chain, rates, rates, loop.literals).value, loop.period_ball(h), 0.0, 1)
    for got, flt in ((ball.Fm, one.Fm), (ball.lg, one.lg)):
        mid, rad = from_arb(got.value)
        assert np.all(np.abs(mid - flt) <= rad + 1e-12 * np.max(np.abs(flt)))


def _slowed(tmp: Path, c: float, d: float = 1.0) -> Path:
    """``examples/paper.toml`` with ``A``, ``B``, ``D`` and every rate divided by ``c``
    (written as floats): the same loop in the time ``c t``, so its gain at period ``c h``
    is the paper loop's at ``h`` (``z`` and ``w`` energies both scale by ``c``); ``D``
    also times ``d`` (the gain times ``d``)."""
    import tomllib

    doc = tomllib.loads((ROOT / "examples" / "paper.toml").read_text())

    def fmt(M: np.ndarray) -> str:
        return "[" + ", ".join("[" + ", ".join(repr(float(v)) for v in row) + "]" for row in M) + "]"

    lines = ['name = "slowed"', "[chain]"] + [f"{k} = {fmt(np.array(doc['chain'][k]) / c)}"
                                             for k in ("alpha", "beta_min", "beta_max")]
    for md in doc["mode"]:
        lines.append("[[mode]]")
        lines += [f"{k} = {fmt(np.array(v) / c * (d if k == 'D' else 1.0) if k in ('A', 'B', 'D') else np.array(v))}"
                  for k, v in md.items()]
    path = tmp / "slowed.toml"
    path.write_text("\n".join(lines) + "\n")
    return path


def test_lower_bound_is_time_scale_invariant(paper: tuple[FTCSystem, Controller], tmp_path: Path) -> None:
    """The paper loop slowed 32 times, at period 32 h (h = 0.05), has the same gain; its
    proved lower bound is within 1 % of the paper loop's at h. (With the disturbance
    acting over a fixed 200 time units, as before ``SPAN_TIMES``, it was 3.2 % below.)"""
    from ftc_verify.analysis.moments.sampled_lower import sampled_lower_bound

    system, controller = paper
    fast = sampled_lower_bound(system, controller, 0.05, robust=False)
    slow = sampled_lower_bound(load_system(_slowed(tmp_path, 32.0)), controller, 32 * 0.05, robust=False)
    assert fast.value is not None and slow.value is not None, slow.where
    assert slow.value >= 0.99 * fast.value


def test_certificate_of_a_tiny_disturbance_input(paper: tuple[FTCSystem, Controller], tmp_path: Path) -> None:
    """``D`` divided by 2^14 (gain divided by 2^14, exactly): the certificates, nominal
    and robust (affine storage, 2 pieces, h = 0.05), times 2^14 are within 0.5 % of the
    paper loop's -- the
    program is solved on the loop with ``Bw`` scaled back up by :func:`io_scale`. (Without
    the scaling: 9 times above here.)"""
    from ftc_verify.analysis.moments.sampled_gamma import io_scale, sampled_gamma

    system, controller = paper
    tiny = load_system(_slowed(tmp_path, 1.0, 2.0 ** -14))
    assert io_scale(augmented_loop(SampledLoop.build(tiny, controller), tiny)) > 1.0
    assert io_scale(augmented_loop(SampledLoop.build(system, controller), system)) == 1.0  # never down
    ref = sampled_gamma(system, controller, 0.05, robust=False, pieces=((1, 2),))
    got = sampled_gamma(tiny, controller, 0.05, robust=False, pieces=((1, 2),))
    assert ref.gamma is not None and got.gamma is not None, got.note
    assert got.gamma * 2.0 ** 14 == pytest.approx(ref.gamma, rel=5e-3)
    ref = sampled_gamma(system, controller, 0.05, robust=True, pieces=((1, 2),))  # Delta's channels unscaled
    got = sampled_gamma(tiny, controller, 0.05, robust=True, pieces=((1, 2),))
    assert ref.gamma is not None and got.gamma is not None and got.robust, got.note
    assert got.gamma * 2.0 ** 14 == pytest.approx(ref.gamma, rel=5e-3)


def test_prove_below_falls_back_to_coarse_distances(paper: tuple[FTCSystem, Controller]) -> None:
    """A crossing given 30 % too high (the paper loop's is about 0.0843): the tight
    attempts and the first ``LADDER`` distance lie above the true crossing, are not
    proved, and the ladder stops; the first ``COARSE`` distance (0.3) lies below it and
    is proved -- before ``COARSE`` the answer was ``None``."""
    import math
    import time

    from ftc_verify.analysis.moments.sampled_bracket import COARSE, prove_below
    from ftc_verify.analysis.moments.sampled_proof import box_verdict

    system, controller = paper
    loop = SampledLoop.build(system, controller)
    a = 1.3 * 0.0843
    got = prove_below(loop, a, 1e-3, 64, 3.0, math.inf)
    assert got == a * (1 - COARSE[0])
    assert box_verdict(loop, a * 0.9, max_boxes=4, clock=time.process_time).verdict != "stable"
