"""The sampled-loop speed-ups of issue 37, item 5 (branch h37x) give the same numbers.

* ``sampled_energy.sampled_energies`` (the rate-independent parts built once for every
  rate array) equals ``sampled_energy`` at each rate vertex, bit for bit, on the nominal
  and a perturbed paper loop; ``None`` exactly where ``sampled_energy`` refuses an
  unstable loop;
* ``spectral_radius`` kept in ``loop.memo`` returns what a fresh loop computes, and
  ``crossing``'s early stop finds the same end as a bisection on the worst radius;
* ``verify``'s sampled stages with the gains in a forked grandchild (``here=True``, as in
  ``SampledRun``'s child) report the same ``sampled`` object, checks and energies as the
  stages computed in turn (``here=False``).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from ftc_verify.analysis.moments.sampled import (SampledLoop, crossing, rate_points, sampled_analysis,
                                                 spectral_radius, worst_radius)
from ftc_verify.analysis.moments.sampled_energy import perturbed_system, sampled_energies, sampled_energy
from ftc_verify.controllers.controller import Controller
from ftc_verify.controllers.files import load_controller
from ftc_verify.errors import FTCError
from ftc_verify.simulation.delta import delta_shapes
from ftc_verify.verification.sampled_stage import sampled_stages


@pytest.fixture(scope="module")
def paper_gains(paper_gains_path) -> Controller:
    """The paper's Section VI gains as a :class:`Controller` (the session fixture is the raw gains)."""
    return load_controller(paper_gains_path)


def test_sampled_energies_equal_sampled_energy_at_every_vertex(paper_system, paper_gains) -> None:
    betas = list(paper_system.chain.vertices())
    s1, s2 = delta_shapes(paper_system)
    assert s1 is not None or s2 is not None  # the paper loop has uncertainty channels
    plus = perturbed_system(paper_system, None if s1 is None else np.eye(*s1), None if s2 is None else -np.eye(*s2))
    for system in (paper_system.nominal(), plus):
        batch = sampled_energies(system, paper_gains, 0.01, betas)
        for beta, got in zip(betas, batch, strict=True):
            want = sampled_energy(system, paper_gains, 0.01, beta=beta)
            assert got is not None
            assert (got.y_energy, got.w_energy, got.ratio) == (want.y_energy, want.w_energy, want.ratio)


def test_sampled_energies_is_none_exactly_where_the_loop_is_unstable(paper_system, paper_gains) -> None:
    betas = list(paper_system.chain.vertices())
    wild = dataclasses.replace(paper_gains, Dc=tuple(100.0 * K for K in paper_gains.Dc))  # unstable at h = 0.1
    for beta, got in zip(betas, sampled_energies(paper_system.nominal(), wild, 0.1, betas), strict=True):
        with pytest.raises(FTCError) if got is None else _no_error():
            sampled_energy(paper_system.nominal(), wild, 0.1, beta=beta)
    assert any(got is None for got in sampled_energies(paper_system.nominal(), wild, 0.1, betas))


class _no_error:
    def __enter__(self) -> None:
        return None

    def __exit__(self, *exc: object) -> bool:
        return False


def test_kept_radius_and_early_stopping_crossing_agree_with_fresh_work(paper_system, paper_gains) -> None:
    loop = SampledLoop.build(paper_system, paper_gains)
    pts = rate_points(loop.chain)
    for h in (0.01, 0.05, 0.11, 0.2):
        for p in pts:
            first = spectral_radius(loop, h, p)
            assert spectral_radius(loop, h, p) == first == spectral_radius(SampledLoop.build(paper_system, paper_gains), h, p)
    a, b = 0.05, 0.2  # stable at 0.05, unstable at 0.2
    assert worst_radius(loop, a, pts)[0] < 1.0 <= worst_radius(loop, b, pts)[0]
    fresh = SampledLoop.build(paper_system, paper_gains)
    lo, hi = a, b
    while (hi - lo) > 1e-4 * hi:  # the bisection before the early stop: the worst radius decides
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if worst_radius(fresh, mid, pts)[0] < 1.0 else (lo, mid)
    assert crossing(loop, a, b, True, 1e-4) == lo  # the memo of the loop above already holds some radii
    assert crossing(SampledLoop.build(paper_system, paper_gains), a, b, True, 1e-4) == lo
    assert worst_radius(fresh, lo, pts)[0] < 1.0 <= worst_radius(fresh, hi, pts)[0]


def _plain(found: dict[str, object]) -> dict[str, object]:
    """``found`` with the ``sampled`` result as JSON, its time left out."""
    d = found["sampled"].to_dict()  # type: ignore[attr-defined]
    d.pop("seconds")
    return {**found, "sampled": d}


@pytest.mark.skipif(not hasattr(__import__("os"), "fork"), reason="the gains run beside the analysis only with fork")
def test_gains_beside_the_analysis_give_the_same_stages(paper_system, paper_gains,
                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    import ftc_verify.verification.sampled_stage as stage

    def no_bracket(*args: object, **kw: object) -> object:  # the verdict only: the h_max bracket is not compared
        return sampled_analysis(*args, **kw, h_max=False)  # type: ignore[arg-type]

    monkeypatch.setattr(stage, "sampled_analysis", no_bracket)
    runs = []
    for here in (True, False):
        checks: list[object] = []
        seconds: dict[str, float] = {}
        found = sampled_stages(paper_system, paper_gains, 0.01, 0.8 ** 2, checks, seconds, None, here=here)
        runs.append((_plain(found), [(c.name, bool(c.ok), c.detail) for c in checks]))  # type: ignore[attr-defined]
        assert math.isfinite(seconds["sampled"]) and "sampled_gains_wait" in seconds
    assert runs[0] == runs[1]
    assert runs[0][0]["sampled"]["nominal_gamma"] is not None  # the gains were computed (in the grandchild)
