"""The sampled stages on loops in physical units (issue 31, item 6 / b).

Exact references, no tolerance on what is proved:

* a time scaling :math:`t \\to s t` of the plant (``A, B, D`` times ``s``, every rate
  times ``s``, gains unchanged) moves the moments' generator to :math:`s \\mathcal L`,
  so :math:`T_s(h) = T(s h)`: ``h_max`` becomes ``h_max / s`` exactly;
* a state similarity :math:`x' = S x` or an input scaling :math:`u = a u'` leaves
  :math:`\\rho(T)` and ``h_max`` unchanged.

So the proved bracket ``[h_max, h_max_unstable]`` of every moved loop must contain the
paper loop's crossing ``H_REF / s`` (``H_REF``: float64 bisection of the worst vertex's
radius to 1e-12, whose error is far below the bracket's 1e-3), its verdicts must be
those of the paper loop (stable at ``0.05 / s``, proved NOT stable at ``0.1 / s``), and
the clock-dependent certificate (:func:`~ftc_verify.analysis.moments.sampled_clock.clock_stable`,
2 quadratic pieces) must prove ``0.08 / s`` and never ``0.1 / s``.

Found by these tests and fixed (the clock at time 1e-6: h31k, a time-normalised frame): the scan's range came from the 2-norms of the loop's
matrices in the user's coordinates, so a similarity of condition 1e3 started the scan at
``3e-11`` (condition 1e4 in units 1e6: ``3e-14``, where float64 rounding puts the radius
above 1 and the analysis reported the loop "not stable at the smallest scanned period");
:attr:`SampledLoop.speed` is now measured in the coordinates of
:func:`~ftc_verify.analysis.moments.sampled_frame.loop_similarity`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from moved_loops import Units, moved

from ftc_verify.analysis.moments.sampled import H_MAX_RTOL, SampledLoop, crossing, sampled_analysis
from ftc_verify.analysis.moments.sampled_clock import clock_stable
from ftc_verify.controllers.controller import Controller
from ftc_verify.controllers.files import load_controller
from ftc_verify.model.files import load_system
from ftc_verify.model.system import FTCSystem
from ftc_verify.testing.illconditioned import similarity

ROOT = Path(__file__).resolve().parents[1]


CASES = [
    Units("time 1e-6 (microseconds of a slow plant)", s=1e-6),
    Units("time 1e6", s=1e6),
    Units("time 3e3, inputs 1e6", s=3e3, a=1e6),
    Units("states in units 1 and 1e4", S=np.diag([1.0, 1e4])),
    Units("similarity of condition 1e2", S=similarity(np.random.default_rng(31), 2, 1.0, 1e2)),
    Units("time 1e-3, inputs 1e-4, similarity 1e2 in units of condition 1e4", s=1e-3,
          S=similarity(np.random.default_rng(5), 2, 1e4, 1e2), a=1e-4),
]


@pytest.fixture(scope="module")
def paper() -> tuple[FTCSystem, Controller]:
    return load_system(ROOT / "examples" / "paper.toml"), load_controller(ROOT / "examples" / "paper_gains.toml")


@pytest.fixture(scope="module")
def h_ref(paper: tuple[FTCSystem, Controller]) -> float:
    """The paper loop's float64 crossing (worst over the rate points), to 1e-12."""
    system, controller = paper
    loop = SampledLoop.build(*moved(system, controller, Units("as written")))
    return crossing(loop, 0.08, 0.09, True, 1e-12)


def test_moved_loops_keep_the_speed(paper: tuple[FTCSystem, Controller]) -> None:
    """The scan's rate is the paper loop's times ``s`` (within 10 %) in every case --
    before, 1e6 times larger under a similarity of condition 1e3."""
    base = SampledLoop.build(*paper).speed
    for u in CASES + [Units("similarity of condition 1e4 in units of condition 1e6",
                            S=similarity(np.random.default_rng(31), 2, 1e6, 1e4))]:
        speed = SampledLoop.build(*moved(*paper, u)).speed
        assert speed / u.s == pytest.approx(base, rel=0.1), u.name


@pytest.mark.parametrize("u", CASES, ids=[u.name for u in CASES])
def test_bracket_contains_the_moved_crossing(paper: tuple[FTCSystem, Controller], h_ref: float, u: Units) -> None:
    system, controller = moved(*paper, u)
    res = sampled_analysis(system, controller, 0.05 / u.s, max_seconds=30.0)
    assert res.verdict == "stable", res.proof
    assert res.h_max is not None and res.h_max_unstable is not None, res.h_max_note
    assert res.h_max <= h_ref / u.s * (1 + 1e-9)
    assert res.h_max_unstable >= h_ref / u.s * (1 - 1e-9)
    assert res.h_max_unstable / res.h_max - 1 <= H_MAX_RTOL
    assert res.stability_intervals[0][1] <= res.h_max_unstable * (1 + 1e-12)
    unstable = sampled_analysis(system, controller, 0.1 / u.s, h_max=False, max_seconds=30.0)
    assert unstable.verdict == "not stable", unstable.proof


CLOCK_CASES = [CASES[0], CASES[1]] + CASES[3:]  # time 3e3 takes 8 s of the solver


@pytest.mark.parametrize("u", CLOCK_CASES, ids=[u.name for u in CLOCK_CASES])
def test_clock_certificate_in_physical_units(paper: tuple[FTCSystem, Controller], u: Units) -> None:
    """Proved at ``0.08 / s`` (5 % below the crossing), never at the unstable ``0.1 / s``."""
    loop = SampledLoop.build(*moved(*paper, u))
    found = clock_stable(loop, 0.08 / u.s, pieces=2, quadratic=True)
    assert found is not None and found.proved, u.name
    above = clock_stable(loop, 0.1 / u.s, pieces=2, quadratic=True)
    assert above is None or not above.proved
