"""The sampled proofs at extreme periods and time scales (issue 31: physical units).

* A dynamic controller's held exponential over the period as written (a ball of radius
  ``1.1e-12`` at ``h = 1e4``) is split at the period's exact midpoint
  (``sampled_proof._held_exponential``): the observer of ``examples/paper_observer.toml``
  at ``h = 1e3`` and ``1e4`` was "undecided" (radii ``8e15``), it is proved NOT stable.
* The clock-dependent certificate is solved in a time-normalised frame
  (:func:`~ftc_verify.analysis.moments.sampled_clock.time_unit`): on the paper loop in
  time units of ``1e-6`` and ``1e6`` (``t -> s t``: the moment generator is ``s`` times
  the paper loop's, so ``T_s(h) = T(s h)``) it proves ``0.08 / s`` (5 % below the
  crossing) and never ``0.1 / s`` (proved unstable).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ftc_verify.analysis.exact import written
from ftc_verify.analysis.moments.sampled import SampledLoop, sampled_analysis
from ftc_verify.analysis.moments.sampled_clock import clock_stable, time_unit
from ftc_verify.analysis.moments.sampled_proof import ball_resets
from ftc_verify.analysis.rigorous import precision
from ftc_verify.controllers.controller import Controller
from ftc_verify.controllers.files import load_controller
from ftc_verify.model.files import load_system
from ftc_verify.model.system import FTCSystem

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def paper() -> FTCSystem:
    return load_system(ROOT / "examples" / "paper.toml")


@pytest.mark.parametrize("h", [1e3, 1e4])
def test_observer_at_an_overflowing_period_is_proved_not_stable(paper: FTCSystem, h: float) -> None:
    observer = load_controller(ROOT / "examples" / "paper_observer.toml")
    res = sampled_analysis(paper, observer, h, h_max=False)
    assert res.verdict == "not stable", res.proof


def test_split_held_exponential_is_tight_and_contains_the_exact_one(paper: FTCSystem) -> None:
    """The resets' ball over the written period (every decimal read as ``1e4``) against
    Arb's exponential at the exact float period: they overlap (both contain the true
    value at ``t = 1e4``) and the split ball's radii stay below ``1e-6`` of its entries."""
    import dataclasses

    import flint

    observer = load_controller(ROOT / "examples" / "paper_observer.toml")
    loop = dataclasses.replace(SampledLoop.build(paper, observer), written=(1e4,))
    with precision(128):
        assert loop.period_ball(1e4).rad() > 0
        R = ball_resets(loop, 1e4)[0].value
        c = observer
        V = np.zeros((c.n_c + c.n_v,) * 2)
        V[:c.n_c, :c.n_c], V[:c.n_c, c.n_c:] = c.Ac[loop.entry[0]], c.Bc[loop.entry[0]]
        exact = (written(V, loop.literals).value * flint.arb(1e4)).exp()
    n, nu = loop.n, loop.nu
    for i in range(c.n_c):
        for j in range(c.n_c):
            a, b = R[n + nu + i, n + j], exact[i, j] * (loop.scale_r[n + j] / loop.scale[n + nu + i])
            assert a.overlaps(b)
            assert float(a.rad()) <= 1e-6 * max(float(abs(a.mid())), 1e-300) or float(a.rad()) < 1e-300


def _time_scaled(system: FTCSystem, controller: Controller, s: float) -> tuple[FTCSystem, Controller]:
    modes = [{"A": s * md.A, "B": s * md.B, "C": md.C, "D": s * md.D} for md in system.modes]
    ch = system.chain
    return (FTCSystem.from_arrays(name=f"time {s:g}", modes=modes, alpha=s * ch.alpha, beta_min=s * ch.beta_min,
                                  beta_max=s * ch.beta_max), controller)


@pytest.mark.parametrize("s", [1e-6, 1e6])
def test_clock_certificate_at_extreme_time_scales(paper: FTCSystem, s: float) -> None:
    loop = SampledLoop.build(*_time_scaled(paper, load_controller(ROOT / "examples" / "paper_gains.toml"), s))
    assert time_unit(loop) != 1.0  # the frame is moved (a power of two near 1 / speed)
    found = clock_stable(loop, 0.08 / s, pieces=2, quadratic=True)
    assert found is not None and found.proved
    above = clock_stable(loop, 0.1 / s, pieces=2, quadratic=True)
    assert above is None or not above.proved


def test_clock_frame_is_unchanged_in_ordinary_units(paper: FTCSystem) -> None:
    loop = SampledLoop.build(paper, load_controller(ROOT / "examples" / "paper_gains.toml"))
    assert time_unit(loop) == 1.0
