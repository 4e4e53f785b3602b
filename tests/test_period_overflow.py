"""A period so long that the one-period map overflows float64 (issue 31, item 6: bad and
extreme periods keep the exit-code contract)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ftc_verify.analysis.moments.sampled import SampledLoop, spectral_radius
from ftc_verify.cli.main import main
from ftc_verify.controllers.files import load_controller
from ftc_verify.model.files import load_system


def test_overflowing_map_has_infinite_radius_without_lapack() -> None:
    system = load_system("examples/paper.toml")
    loop = SampledLoop.build(system, load_controller("examples/paper_gains.toml"))
    rates = next(iter(system.chain.vertices()))
    assert spectral_radius(loop, 1e4, np.asarray(rates)) == math.inf
    assert spectral_radius(loop, 0.05, np.asarray(rates)) < 1.0


def test_analyze_at_an_overflowing_period_is_proved_unstable_not_an_internal_error(
        capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["analyze", "examples/paper.toml", "--gains", "examples/paper_gains.toml", "--period", "1e4"])
    out, err = capsys.readouterr()
    assert code == 1, (out, err)  # proved in Arb (analysis.moments.sampled_overflow)
    assert "internal error" not in err and "Traceback" not in err
    assert "NOT mean-square stable (proved)" in out
    assert "NOT certified" in out  # no gain certificate is attempted at radius inf
