"""Lemma 4.1 (gains fixed) by the augmented loop's coupled Riccati equations
(analysis.robust_riccati): a candidate proved like the SDP's answer, at most a little
above it."""

from __future__ import annotations

from pathlib import Path

import pytest

from ftc_verify.analysis.closedloop import closed_loop
from ftc_verify.analysis.lmi import check_certificate
from ftc_verify.analysis.lmi_analysis import hinf_gamma
from ftc_verify.controllers.files import load_controller
from ftc_verify.model.files import load_system

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def uncertain_loop():
    loop = closed_loop(load_system(ROOT / "examples/paper.toml"), load_controller(ROOT / "examples/paper_gains.toml"))
    assert loop.uncertain
    return loop


def test_riccati_route_certifies_lemma_4_1_near_the_sdp(uncertain_loop) -> None:
    sdp = hinf_gamma(uncertain_loop, robust=True, route="sdp")
    riccati = hinf_gamma(uncertain_loop, robust=True, route="riccati")
    assert sdp.certified and riccati.certified and riccati.solver == "riccati"
    assert riccati.multipliers is not None and all(v > 0 for row in riccati.multipliers for v in row)
    # the SDP's certified gamma is within 1e-3 of its minimum; the Riccati one is a level of the same LMI
    assert sdp.gamma * (1 - 1e-3) <= riccati.gamma <= sdp.gamma * 1.05
    nominal = hinf_gamma(uncertain_loop, robust=False, route="sdp")
    assert riccati.gamma >= nominal.gamma * (1 - 1e-3)  # Lemma 4.1's blocks contain Theorem 3.2's


def test_its_certificate_is_proved_again_and_fails_below(uncertain_loop) -> None:
    riccati = hinf_gamma(uncertain_loop, robust=True, route="riccati")
    P = riccati.P_conditioned
    assert P is not None and riccati.gamma is not None
    again = check_certificate(uncertain_loop, "lemma-4.1", P, riccati.multipliers, riccati.gamma ** 2,
                              similarity=riccati.similarity)
    assert again.ok
    lower = check_certificate(uncertain_loop, "lemma-4.1", P, riccati.multipliers, 0.8 * riccati.gamma ** 2,
                              similarity=riccati.similarity)
    assert not lower.ok
