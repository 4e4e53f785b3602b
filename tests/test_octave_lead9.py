"""The float64 screen behind ``synthesize``'s short-``h_max`` warning
(:func:`ftc_verify.analysis.moments.sampled_scan.octave_verdicts`): its LU test agrees with
the eigenvalues of the one-period map at every period and rate point, and keeps the
paper loop's verdicts when the loop is moved to ill-conditioned coordinates."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from moved_loops import Units, moved

from ftc_verify.analysis.moments.sampled import SampledLoop, rate_points, spectral_radius
from ftc_verify.analysis.moments.sampled_scan import octave_verdicts
from ftc_verify.controllers.controller import Controller
from ftc_verify.controllers.files import load_controller
from ftc_verify.model.files import load_system
from ftc_verify.testing.illconditioned import similarity

ROOT = Path(__file__).resolve().parents[1]


def _agrees(loop: SampledLoop, hi: float, octaves: int) -> list[bool]:
    verdicts = octave_verdicts(loop, hi, octaves)
    assert [h for h, _ in verdicts] == [hi / 2 ** k for k in range(octaves, -1, -1)]
    for h, stable in verdicts:
        rho = max(spectral_radius(loop, h, p) for p in rate_points(loop.chain))
        assert abs(rho - 1.0) > 1e-9  # no tie on these loops: the two tests must agree
        assert stable == (rho < 1.0), (h, rho)
    return [s for _, s in verdicts]


def test_paper_gains_stable_up_to_their_h_max_then_not() -> None:
    loop = SampledLoop.build(load_system(ROOT / "examples" / "paper.toml"),
                             load_controller(ROOT / "examples" / "paper_gains.toml"))
    # h_max of these gains is 0.0843 (digital-implementation page): 0.08 stable, 0.16 not
    assert _agrees(loop, 0.16, 9) == [True] * 9 + [False]


@pytest.mark.parametrize("seed", [3, 11])
def test_random_dynamic_controller_loops(seed: int) -> None:
    """The paper's gains as the feedthrough of a dynamic controller on the plant with both
    states measured, plus a random stable controller state coupled both ways: the screen
    equals the eigenvalue verdicts at every octave, stable below its ``h_max`` and not above."""
    system = load_system(ROOT / "examples" / "paper_two_outputs.toml")
    rng = np.random.default_rng(seed)
    nu, ny, m = system.dims[1], system.modes[0].ny_measured, system.m
    gains = load_controller(ROOT / "examples" / "paper_gains.toml").Dc
    controller = Controller.dynamic([np.array([[-1.0 - abs(rng.normal())]]) for _ in range(m)],
                                    [0.3 * rng.normal(size=(1, ny)) for _ in range(m)],
                                    [0.3 * rng.normal(size=(nu, 1)) for _ in range(m)], list(gains))
    verdicts = _agrees(SampledLoop.build(system, controller), 0.16, 9)
    assert verdicts[0] and not verdicts[-1]


ILL_CONDITIONED = [
    Units("similarity of condition 1e4", S=similarity(np.random.default_rng(31), 2, 1.0, 1e4)),
    Units("similarity of condition 1e4 in units of condition 1e6", S=similarity(np.random.default_rng(31), 2, 1e6, 1e4)),
    Units("states in units 1e-6 and 1e6", S=np.diag([1e-6, 1e6])),
    Units("time 1e-6, states in units 1e-6 and 1e6", s=1e-6, S=np.diag([1e-6, 1e6])),
]


@pytest.mark.parametrize("u", ILL_CONDITIONED, ids=[u.name for u in ILL_CONDITIONED])
def test_ill_conditioned_loops(u: Units) -> None:
    """The paper loop moved by a state similarity (and time unit) has the paper loop's
    one-period spectrum, but its float64 map in the user's coordinates does not: at
    ``h = 0.083`` (1.5 % below ``h_max`` 0.0843, true radius 0.940) the map of the
    similarity of condition 1e4 in units of condition 1e6 has float radius 1.08. So,
    asserted: (1) on the octaves of 0.16 (every period at least 5 % from ``h_max``: true
    radius at most 0.93 or at least 8.2) the screen gives the paper loop's verdicts;
    (2) on octaves ending just above and below ``h_max`` it never says stable where the
    paper loop's eigenvalues say unstable (a missed warning; a spurious one near the
    crossing is allowed: the screen only warns)."""
    system, controller = load_system(ROOT / "examples" / "paper.toml"), load_controller(ROOT / "examples" / "paper_gains.toml")
    paper = SampledLoop.build(system, controller)
    loop = SampledLoop.build(*moved(system, controller, u))
    reference = octave_verdicts(paper, 0.16, 9)
    assert [s for _, s in reference] == [True] * 9 + [False]
    assert [s for _, s in octave_verdicts(loop, 0.16 / u.s, 9)] == [s for _, s in reference]
    for hi in (0.083, 0.0845, 0.085, 0.09):
        for (h, stable), (h0, _) in zip(octave_verdicts(loop, hi / u.s, 3), octave_verdicts(paper, hi, 3)):
            assert h == pytest.approx(h0 / u.s, rel=1e-15)
            rho = max(spectral_radius(paper, h0, p) for p in rate_points(paper.chain))
            assert not (stable and rho > 1.0), (u.name, h0, rho)
