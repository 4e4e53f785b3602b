r"""The clock certificates of the sampled loop in any units (round 11, frame11).

A random loop with two rates (:func:`~ftc_verify.testing.sampled_cases.lqr_case` ``(2, 2)``,
seed 3) moved to other units: states :math:`x' = S x` (``S`` diagonal, ``1e-6..1e6``, or
a similarity of condition 1e4 with units of condition 1e8), inputs :math:`u = a u'`, time
:math:`t \to s t` (every rate times ``s``). Exact references: a state similarity and an
input scaling leave the one-period spectrum unchanged, a time scaling maps period
``h`` to ``h / s`` (``tests/moved_loops.py``), so the crossing of the moved loop is
:math:`h_u / s`, :math:`h_u` the float64 crossing of the loop in good units.

Asserted per frame, as in good units: the clock certificate of the whole box
(:func:`~ftc_verify.analysis.moments.sampled_clock.clock_stable`, 2 quadratic pieces) found
and proved at :math:`0.8\, h_u / s`, the common cubic one
(:func:`~ftc_verify.analysis.moments.sampled_cubic.cubic_stable`, 4 pieces) at
:math:`0.99\, h_u / s`; neither proved at :math:`1.01\, h_u / s` (above the crossing); the
proved ``h_max`` bracket contains :math:`h_u / s` and has the resolution of the bracket in
good units. The same for the loop under a dynamic controller (the gains filtered,
:math:`\dot x_c = 20 (K x - x_c)`, :math:`u = x_c`) with its states :math:`x_c' = S_c x_c`
in other units. Before: with the states in units ``1e-6`` and ``1e6`` the conditioning
transform (condition ``1e12``, nearly all of it the exact diagonal) was refused, the
loop's speed came out ``4.6e12`` (the 2-norms in the user's coordinates), and neither
certificate was found even ``1e-2`` below the crossing; the ``h_max`` scan started at
``2e-16`` and reported the loop "not stable at the smallest scanned period"; with
:math:`x_c` in units ``1e-3`` the conditioned loop's states were ``1e-3`` apart and the
bracket ``1e-2`` wide (``8e-4`` in good units) (``benchmarks/results/frame11.md``).
"""

from __future__ import annotations

import numpy as np
import pytest

from moved_loops import Units, moved

from ftc_verify.analysis.moments.sampled import H_MAX_RTOL, SampledLoop, crossing, sampled_analysis
from ftc_verify.analysis.moments.sampled_clock import clock_stable, time_unit
from ftc_verify.analysis.moments.sampled_conditioned import conditioned
from ftc_verify.analysis.moments.sampled_cubic import cubic_stable
from ftc_verify.analysis.moments.sampled_frame import LIMIT, essential_condition
from ftc_verify.controllers.controller import Controller
from ftc_verify.model.system import FTCSystem
from ftc_verify.testing.illconditioned import similarity
from ftc_verify.testing.sampled_cases import lqr_case

SPLIT = np.diag([1e-6, 1e6])

FRAMES = [
    Units("good units"),
    Units("states 1e-6", S=np.eye(2) * 1e-6),
    Units("states 1e6", S=np.eye(2) * 1e6),
    Units("states 1e-3 and 1e3", S=np.diag([1e-3, 1e3])),
    Units("states 1e-6 and 1e6", S=SPLIT),
    Units("states 1e-6 and 1e6, time 1e3", S=SPLIT, s=1e3),
    Units("states 1e-6 and 1e6, time 1e-3, inputs 1e6", S=SPLIT, s=1e-3, a=1e6),
    Units("inputs 1e-6", a=1e-6),
    Units("inputs 1e6", a=1e6),
    Units("time 1e-3 (all rates and flows)", s=1e-3),
    Units("time 1e3", s=1e3),
    Units("similarity of condition 1e4", S=similarity(np.random.default_rng(31), 2, 1.0, 1e4)),
    Units("similarity of condition 1e4 in units of condition 1e8",
          S=similarity(np.random.default_rng(31), 2, 1e8, 1e4)),
]


CONTROLLER_FRAMES = [np.eye(2), np.eye(2) * 1e-3, np.eye(2) * 1e6, np.diag([1e-6, 1e6])]


def filtered(system: FTCSystem, controller: Controller, Sc: np.ndarray) -> tuple[FTCSystem, Controller]:
    """``system`` under the state feedback ``controller`` filtered, its states in the units ``Sc``."""
    Si = np.linalg.inv(Sc)
    gains = controller.Dc
    return system, Controller(tuple(Sc @ (-20.0 * np.eye(2)) @ Si for _ in gains), tuple(Sc @ (20.0 * K) for K in gains),
                              tuple(Si for _ in gains), tuple(np.zeros_like(K) for K in gains), "state", "filtered")


@pytest.fixture(scope="module")
def case() -> tuple[FTCSystem, Controller]:
    return lqr_case(2, 2, np.random.default_rng(3))


@pytest.fixture(scope="module")
def h_u(case: tuple[FTCSystem, Controller]) -> float:
    """The crossing in good units (float64 bisection of the worst rate point, 1e-10)."""
    return crossing(SampledLoop.build(*case), 1e-3, 10.0, True, 1e-10)


def test_essential_condition_discounts_the_diagonal() -> None:
    """A diagonal of powers of two times a well-conditioned matrix: the condition of the
    well-conditioned factor (the diagonal's ``1e12`` moves no rounding); a non-diagonal
    similarity of condition 1e13 stays above :data:`LIMIT`."""
    M = similarity(np.random.default_rng(1), 3, 1.0, 10.0)
    D = np.diag(2.0 ** np.array([-20.0, 0.0, 20.0]))
    assert np.linalg.cond(D @ M) > LIMIT
    assert essential_condition(D @ M) <= 10.0 * 3
    assert essential_condition(similarity(np.random.default_rng(1), 3, 1.0, 1e13)) > LIMIT
    assert essential_condition(np.diag([1.0, 0.0])) == np.inf


@pytest.mark.parametrize("u", FRAMES, ids=[u.name for u in FRAMES])
def test_time_unit_follows_the_loop(case: tuple[FTCSystem, Controller], u: Units) -> None:
    """The clock programs' time unit is the good loop's over ``s`` (to the octaves of its
    rule): the speed no longer carries the units of the states."""
    good = time_unit(conditioned(SampledLoop.build(*case)))
    loop = conditioned(SampledLoop.build(*moved(*case, u)))
    assert abs(np.log2(time_unit(loop) * u.s / good)) <= 7, u.name
    assert 0.25 <= loop.speed / u.s / SampledLoop.build(*case).speed <= 4.0, u.name


@pytest.mark.parametrize("u", FRAMES, ids=[u.name for u in FRAMES])
def test_clock_certificates_in_every_frame(case: tuple[FTCSystem, Controller], h_u: float, u: Units) -> None:
    """Found and proved below the crossing as in good units; never proved above it."""
    system, controller = moved(*case, u)
    loop = SampledLoop.build(system, controller)
    clock = clock_stable(loop, 0.8 * h_u / u.s, 2, quadratic=True)
    assert clock is not None and clock.proved, u.name
    cubic = cubic_stable(loop, 0.99 * h_u / u.s, 4)
    assert cubic is not None and cubic.proved, u.name
    above = clock_stable(loop, 1.01 * h_u / u.s, 2, quadratic=True)
    assert above is None or not above.proved, u.name
    above_cubic = cubic_stable(loop, 1.01 * h_u / u.s, 4)
    assert above_cubic is None or not above_cubic.proved, u.name


@pytest.mark.parametrize("u", FRAMES, ids=[u.name for u in FRAMES])
def test_bracket_in_every_frame(case: tuple[FTCSystem, Controller], h_u: float, u: Units) -> None:
    """The proved ``h_max`` bracket contains the crossing ``h_u / s`` and has the
    bracket's resolution."""
    res = sampled_analysis(*moved(*case, u), 0.05 / u.s, max_seconds=60.0)
    assert res.verdict == "stable", res.proof
    assert res.h_max is not None and res.h_max_unstable is not None, res.h_max_note
    assert res.h_max <= h_u / u.s * (1 + 1e-9)
    assert res.h_max_unstable >= h_u / u.s * (1 - 1e-9)
    assert res.h_max_unstable / res.h_max - 1 <= H_MAX_RTOL


@pytest.mark.parametrize("Sc", CONTROLLER_FRAMES, ids=["x_c as written", "x_c 1e-3", "x_c 1e6", "x_c 1e-6 and 1e6"])
def test_controller_states_in_other_units(case: tuple[FTCSystem, Controller], Sc: np.ndarray) -> None:
    """The clock certificates and the bracket of the filtered loop as in good units."""
    good = filtered(*case, np.eye(2))
    h_u = crossing(SampledLoop.build(*good), 1e-3, 10.0, True, 1e-10)
    system, controller = filtered(*case, Sc)
    loop = SampledLoop.build(system, controller)
    clock = clock_stable(loop, 0.8 * h_u, 2, quadratic=True)
    assert clock is not None and clock.proved
    cubic = cubic_stable(loop, 0.99 * h_u, 4)
    assert cubic is not None and cubic.proved
    above = cubic_stable(loop, 1.01 * h_u, 4)
    assert above is None or not above.proved
    res = sampled_analysis(system, controller, 0.05, max_seconds=60.0)
    assert res.h_max is not None and res.h_max_unstable is not None, res.h_max_note
    assert res.h_max <= h_u * (1 + 1e-9) <= res.h_max_unstable * (1 + 2e-9)
    assert res.h_max_unstable / res.h_max - 1 <= H_MAX_RTOL
