"""The nonsmooth descent on the exact stability test (issue 21, first part): its gradient,
and controllers it finds that the core analysis proves stable."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from ftc_verify.analysis.closedloop import closed_loop
from ftc_verify.analysis.stability import mean_square_stability
from ftc_verify.model.files import load_system
from ftc_verify.model.system import FTCSystem, JointChain
from ftc_verify.synthesis.descent import Parametrisation, stabilise, worst_abscissa

ROOT = Path(__file__).resolve().parents[1]


def _paper(doubled: bool = False) -> FTCSystem:
    system = load_system(ROOT / "examples" / "paper.toml")
    if not doubled:
        return system
    chain = JointChain(system.chain.alpha, np.array([[0.0, 4.0], [5.0, 0.0]]), np.array([[0.0, 6.0], [7.0, 0.0]]))
    return replace(system, chain=chain)


@pytest.mark.parametrize("order", [0, 1, 2])
def test_abscissa_gradient_matches_central_differences(order: int) -> None:
    system = _paper()
    par = Parametrisation.build(system, order)
    rng = np.random.default_rng(order)
    for _ in range(3):
        theta = rng.standard_normal(par.size)
        f, g = worst_abscissa(par, system.chain, theta)
        h = 1e-6 * max(1.0, float(np.linalg.norm(theta)))
        num = np.array([(worst_abscissa(par, system.chain, theta + h * e)[0]
                         - worst_abscissa(par, system.chain, theta - h * e)[0]) / (2 * h) for e in np.eye(theta.size)])
        assert np.linalg.norm(num - g) <= 1e-5 * np.linalg.norm(g), (order, f)


def test_descent_stabilises_the_paper_plant_with_doubled_detection_rates() -> None:
    system = _paper(doubled=True)
    best = stabilise(system, 2, seed=0)[0]
    assert best.stabilised and best.abscissa < -1e-2
    par = Parametrisation.build(system, 2)
    mss = mean_square_stability(closed_loop(system, par.controller(best.theta, "descent")))
    assert mss.verdict == "stable"  # proved by the core, not by the descent
    assert [k for k, _ in best.history] == [8.0, 4.0, 2.0, 1.4, 1.0]


def test_static_output_feedback_found_where_one_exists_and_gain_bound_kept() -> None:
    """A plant built around a known stabilising static output feedback ``u = K0 y``."""
    rng = np.random.default_rng(7)
    n, m = 3, 2
    B, C = rng.standard_normal((n, 1)), rng.standard_normal((1, n))
    K0 = np.array([[-2.0]])
    modes = []
    for _ in range(m):
        stable = rng.standard_normal((n, n))
        stable -= (np.max(np.linalg.eigvals(stable).real) + 0.5) * np.eye(n)
        modes.append(dict(A=stable - B @ K0 @ C, B=B, C=C, D=np.ones((n, 1))))  # A + B K0 C is Hurwitz
    system = FTCSystem.from_arrays(name="sof", modes=modes, alpha=[[-1.0, 1.0], [1.0, -1.0]],
                                   beta_min=[[0.0, 2.0], [2.0, 0.0]], beta_max=[[0.0, 3.0], [3.0, 0.0]])
    results = stabilise(system, 0, seed=1, k_max=5.0)
    best = results[0]
    assert best.stabilised
    assert all(r.gain_norm <= 5.0 * (1 + 1e-12) for r in results)
    par = Parametrisation.build(system, 0)
    assert mean_square_stability(closed_loop(system, par.controller(best.theta, "sof"))).verdict == "stable"
