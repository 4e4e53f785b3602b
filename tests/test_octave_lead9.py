"""The float64 screen behind ``synthesize``'s short-``h_max`` warning
(:func:`ftc_verify.analysis.moments.sampled_scan.octave_verdicts`): its LU test agrees with
the eigenvalues of the one-period map at every period and rate point."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ftc_verify.analysis.moments.sampled import SampledLoop, rate_points, spectral_radius
from ftc_verify.analysis.moments.sampled_scan import octave_verdicts
from ftc_verify.controllers.controller import Controller
from ftc_verify.controllers.files import load_controller
from ftc_verify.model.files import load_system

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
