"""Verdicts at periods where the one-period map overflows float64 (issue 31, item 6 / a).

The reference is independent of the proof: at a long period the moments grow like
:math:`e^{\\lambda h}`, :math:`\\lambda` the spectral abscissa of the held-input moment
generator :math:`\\mathcal L` (float64 eigenvalues of the generator the loop is built
from, no exponential), so :math:`\\log \\rho(T) / h \\to \\lambda`; the proved exponent
:math:`e` (:math:`\\rho(T) > 2^e`) must be within a constant of :math:`\\lambda h / \\ln 2`.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from ftc_verify.analysis.moments.sampled import SampledLoop, sampled_analysis, spectral_radius
from ftc_verify.analysis.moments.sampled_overflow import prove_overflow_unstable
from ftc_verify.cli.main import main
from ftc_verify.controllers.controller import Controller
from ftc_verify.controllers.files import load_controller
from ftc_verify.model.files import load_system
from ftc_verify.model.system import FTCSystem

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def paper_loop() -> SampledLoop:
    system = load_system(ROOT / "examples" / "paper.toml")
    return SampledLoop.build(system, load_controller(ROOT / "examples" / "paper_gains.toml"))


def _abscissa(loop: SampledLoop, rates: np.ndarray) -> float:
    vd = loop.d * (loop.d + 1) // 2
    L = loop.modes_part + np.kron(loop.chain.generator(rates).T, np.eye(vd))
    return float(np.max(np.linalg.eigvals(L).real))


@pytest.mark.parametrize("h", [1e3, 1e4, 1e6])
def test_proved_exponent_matches_the_growth_rate(paper_loop: SampledLoop, h: float) -> None:
    """The float map is ``inf``; the Arb proof gives ``rho(T) > 2^e`` with ``e ln 2``
    within 8 of ``lambda h`` (``lambda`` the generator's abscissa) at every vertex, and
    below the float estimate of ``ln rho(T)``."""
    for rates in paper_loop.chain.vertices():
        rates = np.asarray(rates, dtype=float)
        assert spectral_radius(paper_loop, h, rates) == math.inf
        proof = prove_overflow_unstable(paper_loop, h, rates)
        assert proof is not None
        lam = _abscissa(paper_loop, rates)
        assert lam > 0
        # rho(T) = C e^{lambda h} (1 + o(1)) with a constant C of the resets and the
        # Perron vectors (log C about 4 here): both within 8 of lambda h in natural log
        assert abs(proof.exponent * math.log(2.0) - lam * h) < 8.0
        assert abs(proof.log10_radius * math.log(10.0) - lam * h) < 8.0
        assert proof.exponent * math.log(2.0) <= proof.log10_radius * math.log(10.0)


def test_no_overflow_proof_at_an_ordinary_period(paper_loop: SampledLoop) -> None:
    """At h = 0.1 (radius 1.91, finite) the overflow route declines: the ordinary proofs apply."""
    rates = np.asarray(paper_loop.chain.midpoint(), dtype=float)
    assert 1.0 < spectral_radius(paper_loop, 0.1, rates) < 2.0
    assert prove_overflow_unstable(paper_loop, 0.1, rates) is None


def _stable_plant() -> tuple[FTCSystem, Controller]:
    """A stable plant under small gains: the sampled loop is stable at every period
    (radius about 0.03 at long periods)."""
    modes = [{"A": -np.array([[1.0, 0.2], [0.0, 0.8]]), "B": np.array([[0.0, 1.0], [-0.25, 0.25]]),
              "C": np.array([[1.0, 2.0]]), "D": np.array([[0.5], [0.5]])},
             {"A": -np.array([[1.0, 0.0], [0.3, 0.8]]), "B": np.array([[0.0, 0.2], [-0.25, 0.05]]),
              "C": np.array([[1.0, 2.0]]), "D": np.array([[0.5], [1.0]])}]
    system = FTCSystem.from_arrays(name="stable plant", modes=modes, alpha=[[-0.5, 0.5], [1.0, -1.0]],
                                   beta_min=[[0.0, 2.0], [2.5, 0.0]], beta_max=[[0.0, 3.0], [3.5, 0.0]])
    ctrl = Controller.state_feedback([np.array([[0.1, 0.2], [-0.3, 0.1]]), np.array([[0.2, 0.1], [-0.1, 0.3]])])
    return system, ctrl


def test_stable_loop_at_a_huge_period_is_never_called_unstable() -> None:
    """h = 1e8 on a stable plant: the float radius is finite and below 1 at every vertex,
    the overflow route proves nothing there, and the verdict is stable or undecided --
    never "not stable" (no wrong claim)."""
    system, ctrl = _stable_plant()
    loop = SampledLoop.build(system, ctrl)
    for rates in loop.chain.vertices():
        rates = np.asarray(rates, dtype=float)
        assert spectral_radius(loop, 1e8, rates) < 0.05
        assert prove_overflow_unstable(loop, 1e8, rates) is None
    res = sampled_analysis(system, ctrl, 1e8, h_max=False, max_seconds=6.0)
    assert res.verdict in ("stable", "undecided"), res.proof


def test_analyze_at_an_overflowing_period_proves_instability(capsys: pytest.CaptureFixture[str]) -> None:
    """``analyze --period 1e4`` on the paper's gains: exit 1 (the claim does not hold),
    the proof in Arb named, strict JSON with ``spectral_radius`` null."""
    args = ["analyze", str(ROOT / "examples" / "paper.toml"), "--gains", str(ROOT / "examples" / "paper_gains.toml"),
            "--period", "1e4"]
    code = main(args + ["--json"])
    out, err = capsys.readouterr()
    assert code == 1, (out, err)
    sampled = json.loads(out)["sampled"]
    assert sampled["verdict"] == "not stable"
    assert sampled["spectral_radius"] is None
    assert "overflows float64" in sampled["proof"] and "2^28860" in sampled["proof"]
    assert sampled["h_max"] is not None and sampled["h_max"] < 0.1


def test_two_sided_monte_carlo_skipped_on_a_loop_proved_unstable() -> None:
    """``verify``'s sampled Monte Carlo has no finite expectation to compare with on a loop
    proved NOT stable: its check fails at once, without drawing paths (at ``--step 1e4``
    its 1000 paths over 1e5 time units were 1e8 jumps of the chain and the run 7 GB). With
    the period 1 and horizon 10 a regression would simulate (and report divergence)."""
    from ftc_verify.verification.sampled_stage import sampled_mc_stage

    system = load_system(ROOT / "examples" / "paper.toml")
    controller = load_controller(ROOT / "examples" / "paper_gains.toml")
    res = sampled_analysis(system, controller, 1.0, h_max=False, max_seconds=6.0)
    assert res.verdict == "not stable", res.proof
    found, check = sampled_mc_stage(system, controller, 1.0, 10.0, 10, 1, res)
    assert found is None and not check.ok
    assert "proved NOT mean-square stable" in check.detail
