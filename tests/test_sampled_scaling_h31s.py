r"""The sampled gain certificate on rescaled and ill-conditioned loops (issue 31, item 6).

The paper loop moved to other units and coordinates: states :math:`x' = T x` (diagonal
units 1e-6..1e6, or a non-orthogonal similarity of condition 1e3 with units of
condition 1e4: :func:`ftc_verify.testing.illconditioned.similarity`), inputs
:math:`u = a u'`, disturbance :math:`w = b w'`, output :math:`z' = c z`, uncertainty
channels :math:`A_1 r`, :math:`A_2 / r`. In exact arithmetic its sampled gain is
:math:`b c` times the paper loop's, for every period. The certificate is solved on the
loop with the disturbance input scaled by a power of two
(:func:`~ftc_verify.analysis.moments.sampled_gamma.io_scale`) and the bound divided back.
Asserted per case: the proved bracket holds (lower <= upper), the upper bound divided by
:math:`b c` is within :data:`RTOL` of the paper loop's and never below its proved lower
bound; at :math:`h = 10^{-3}` within 1 % of the continuous-time gamma (an independent
LMI, :func:`~ftc_verify.analysis.lmi_analysis.hinf_gamma`, on the unscaled loop), and
above the exact expected-energy ratio of the sampled loop for the paper's disturbance
(:func:`~ftc_verify.analysis.moments.sampled_energy.sampled_energy`, another independent
computation), which itself scales by :math:`(b c)^2` to 1e-6.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from ftc_verify.analysis.closedloop import closed_loop
from ftc_verify.analysis.lmi_analysis import hinf_gamma
from ftc_verify.analysis.moments.sampled_energy import sampled_energy
from ftc_verify.analysis.moments.sampled_gains import sampled_gains
from ftc_verify.analysis.moments.sampled_gamma import SampledPerformance, sampled_gamma
from ftc_verify.controllers.controller import Controller
from ftc_verify.controllers.files import load_controller
from ftc_verify.model.files import load_system
from ftc_verify.model.system import FTCSystem
from ftc_verify.testing.illconditioned import similarity

ROOT = Path(__file__).resolve().parents[1]
#: The rescaled loop's upper bound over ``b c`` against the paper loop's (relative).
RTOL = 0.02


@dataclass(frozen=True)
class Scaling:
    """``x' = T x``, ``u = a u'``, ``w = b w'``, ``z' = c z``, channels ``A1 r``, ``A2 / r``;
    ``lower_rtol``: the proved lower bound over ``b c`` against the paper loop's."""

    name: str
    T: np.ndarray
    a: float = 1.0
    b: float = 1.0
    c: float = 1.0
    r: float = 1.0
    lower_rtol: float = 0.02


CASES = [
    Scaling("states 1e-6 and 1e6", np.diag([1e-6, 1e6])),
    Scaling("inputs 1e6, disturbance 1e6, output 1e-6", np.eye(2), a=1e6, b=1e6, c=1e-6),
    Scaling("inputs 1e-6, disturbance 1e-6, output 1e6", np.eye(2), a=1e-6, b=1e-6, c=1e6),
    Scaling("tiny gain: disturbance 1e-6, output 1e-6, states 1e3", np.diag([1e3, 1e3]), b=1e-6, c=1e-6),
    Scaling("huge gain: disturbance 1e6, output 1e6, inputs 1e-3", np.eye(2), a=1e-3, b=1e6, c=1e6),
    Scaling("ill-conditioned similarity (1e3) in units of condition 1e4",
            similarity(np.random.default_rng(31), 2, 1e4, 1e3)),
    Scaling("ill-conditioned similarity (1e4) in units of condition 1e6",
            similarity(np.random.default_rng(31), 2, 1e6, 1e4)),
    Scaling("channels A1 1e3, A2 1e-3, states 1e-4 and 1e2", np.diag([1e-4, 1e2]), r=1e3),
]


def rescaled(system: FTCSystem, controller: Controller, s: Scaling) -> tuple[FTCSystem, Controller]:
    """The loop of the module docstring (same chain)."""
    Ti = np.linalg.inv(s.T)
    modes = []
    for md in system.modes:
        assert md.A1 is not None and md.A2 is not None and md.B1 is not None and md.B2 is not None
        modes.append({"A": s.T @ md.A @ Ti, "B": s.T @ md.B * s.a, "C": s.c * md.C @ Ti, "D": s.T @ md.D * s.b,
                      "A1": s.T @ md.A1 * s.r, "A2": md.A2 @ Ti / s.r, "B1": s.T @ md.B1, "B2": md.B2 * s.a})
    ch = system.chain
    moved = FTCSystem.from_arrays(name=s.name, modes=modes, alpha=ch.alpha, beta_min=ch.beta_min, beta_max=ch.beta_max)
    return moved, Controller.state_feedback([K @ Ti / s.a for K in controller.Dc])


@pytest.fixture(scope="module")
def paper() -> tuple[FTCSystem, Controller]:
    return load_system(ROOT / "examples" / "paper.toml"), load_controller(ROOT / "examples" / "paper_gains.toml")


@pytest.fixture(scope="module")
def reference(paper: tuple[FTCSystem, Controller]) -> SampledPerformance:
    """The paper loop's certificates and proved lower bounds at h = 0.05."""
    return sampled_gains(*paper, 0.05)


def test_rescaling_keeps_the_closed_loop(paper: tuple[FTCSystem, Controller]) -> None:
    """The helper is right: every case's continuous closed loop is the paper's moved by
    ``T`` (``A_cl' = T A_cl T^-1``), its disturbance input ``T D b``, output ``c C T^-1``."""
    base = closed_loop(*paper)
    for s in CASES:
        loop = closed_loop(*rescaled(*paper, s))
        Ti = np.linalg.inv(s.T)
        for A0, A1, B0, B1, C0, C1 in zip(base.A, loop.A, base.Bw, loop.Bw, base.Cz, loop.Cz):
            assert np.allclose(Ti @ A1 @ s.T, A0, rtol=1e-7, atol=1e-7), s.name
            assert np.allclose(Ti @ B1 / s.b, B0, rtol=1e-9), s.name
            assert np.allclose(C1 @ s.T / s.c, C0, rtol=1e-9), s.name


@pytest.mark.parametrize("case", CASES, ids=[s.name for s in CASES])
def test_bracket_of_a_rescaled_loop(paper: tuple[FTCSystem, Controller], reference: SampledPerformance,
                                    case: Scaling) -> None:
    """h = 0.05: both brackets hold (lower <= upper), each upper bound over ``b c`` is
    within :data:`RTOL` of the paper loop's and at least its proved lower bound, and the
    lower bound (proved) over ``b c`` at most the paper loop's upper bound and within
    ``lower_rtol`` of its lower bound. Before the coordinates of
    :mod:`~ftc_verify.analysis.moments.sampled_frame` the upper bound was up to 400 times
    the paper loop's (similarity) or not found (gain 1e12; similarity of condition 1e4), and
    the lower bound 0.18 of the paper loop's after 2 minutes (similarity of condition 1e3)
    or not found (1e4)."""
    system, controller = rescaled(*paper, case)
    perf = sampled_gains(system, controller, 0.05)
    k = case.b * case.c
    for got, lower, kind, ref, ref_lower in (
            (perf.nominal, perf.nominal_lower, perf.nominal_lower_kind, reference.nominal, reference.nominal_lower),
            (perf.robust, perf.robust_lower, perf.robust_lower_kind, reference.robust, reference.robust_lower)):
        assert got is not None and got.gamma is not None, (case.name, got)
        assert ref is not None and ref.gamma is not None and ref_lower is not None
        assert got.gamma / k == pytest.approx(ref.gamma, rel=RTOL), (case.name, got.note)
        assert got.gamma / k >= ref_lower * (1 - 1e-9), case.name
        assert kind == "proved" and lower is not None, (case.name, kind)
        assert lower <= got.gamma, (case.name, lower, got.gamma)
        assert lower / k <= ref.gamma * (1 + 1e-9), case.name
        assert lower / k == pytest.approx(ref_lower, rel=case.lower_rtol), case.name


@pytest.mark.parametrize("case", CASES[:7:2] + CASES[5:7:1], ids=[s.name for s in CASES[:7:2] + CASES[5:7]])
def test_rescaled_loop_tends_to_the_continuous_gamma(paper: tuple[FTCSystem, Controller], case: Scaling) -> None:
    """h = 1e-3, nominal, affine storage on 4 pieces: the rescaled loop's gamma over
    ``b c`` within 1 % of the continuous gamma of the unscaled loop, and its square above
    the exact expected-energy ratio of the sampled loop (paper disturbance, one rate
    vertex), whose value over ``(b c)^2`` equals the unscaled loop's to 1e-6."""
    system, controller = rescaled(*paper, case)
    k = case.b * case.c
    continuous = hinf_gamma(closed_loop(*paper), robust=False).gamma
    cert = sampled_gamma(system, controller, 1e-3, robust=False, pieces=((1, 4),))
    assert cert.gamma is not None, cert.note
    assert cert.gamma / k == pytest.approx(continuous, rel=0.01)
    beta = paper[0].chain.beta_max
    e = sampled_energy(system, controller, 1e-3, beta=beta)
    e0 = sampled_energy(*paper, 1e-3, beta=beta)
    assert e.ratio / k**2 == pytest.approx(e0.ratio, rel=1e-6)
    assert e.ratio <= cert.gamma ** 2
