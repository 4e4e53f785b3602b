"""Exact expected energy and worst-case disturbance against hand solutions and an
independent ODE integration of the moment equations."""

from __future__ import annotations

import math
from pathlib import Path

import control
import numpy as np
import pytest
import scipy.integrate

from ftc_verify.analysis.closedloop import state_feedback_loop
from ftc_verify.errors import ValidationError
from ftc_verify.analysis.lmi_analysis import hinf_gamma
from ftc_verify.model.system import FTCSystem
from ftc_verify.analysis.moments.energy import exact_energy, worst_case_disturbance
from ftc_verify.model.files import load_system
from ftc_verify.controllers.files import load_controller, load_gains

ROOT = Path(__file__).resolve().parents[1]
PAPER = load_system(ROOT / "examples" / "paper.toml")
PAPER_LOOP = state_feedback_loop(PAPER, load_gains(ROOT / "examples" / "paper_gains.toml")).nominal()


def scalar_two_mode(alpha: float, beta: float) -> FTCSystem:
    """Plant modes a = -1, -2 (B = C = D = 1); mode 2 absorbing; FDI catches up at beta."""
    m1 = {"A": [[-1.0]], "B": [[1.0]], "C": [[1.0]], "D": [[1.0]]}
    m2 = {"A": [[-2.0]], "B": [[1.0]], "C": [[1.0]], "D": [[1.0]]}
    return FTCSystem.from_arrays(name="hand", modes=[m1, m2], alpha=[[-alpha, alpha], [0.0, 0.0]],
                                 beta_min=[[0.0, beta], [beta, 0.0]], beta_max=[[0.0, beta], [beta, 0.0]])


def test_scalar_two_mode_energy_by_hand() -> None:
    """From (1,1) with x0 = 1, w = 0: closed-loop rates a00 = -1.5, a10 = -2.5, a11 = -3.5.
    X00 = e^{-k0 t}, X10 solves X' = -k1 X + alpha X00, X11' = -k2 X11 + beta X10, so
    E int x^2 = 1/k0 + alpha/(k0 k1) + alpha beta/(k0 k1 k2), k0 = alpha - 2a00, k1 = beta - 2a10, k2 = -2a11."""
    alpha, beta = 0.7, 2.5
    system = scalar_two_mode(alpha, beta)
    loop = state_feedback_loop(system, [np.array([[-0.5]]), np.array([[-1.5]])])
    k0, k1, k2 = alpha + 3.0, beta + 5.0, 7.0
    expected = 1 / k0 + alpha / (k0 * k1) + alpha * beta / (k0 * k1 * k2)
    got = exact_energy(loop, beta=system.chain.midpoint(), disturbance="zero", x0=np.array([1.0]))
    assert got.y_energy == pytest.approx(expected, rel=1e-12)
    # finite horizon: the same ODE integrated numerically
    T = 1.3
    fin = exact_energy(loop, beta=system.chain.midpoint(), disturbance="zero", x0=np.array([1.0]), horizon=T)

    def rhs(t: float, z: np.ndarray) -> list[float]:
        x00, x10, x11, _ = z
        return [-k0 * x00, -k1 * x10 + alpha * x00, -k2 * x11 + beta * x10, x00 + x10 + x11]

    sol = scipy.integrate.solve_ivp(rhs, (0, T), [1.0, 0.0, 0.0, 0.0], rtol=1e-12, atol=1e-14)
    assert fin.y_energy == pytest.approx(sol.y[3, -1], rel=1e-9)


def test_paper_disturbance_energy() -> None:
    """int_0^inf e^{-0.2t} sin^2 t dt = (1/2)(1/0.2 - 0.2/(0.04 + 4)) = 2.4752...; ||w||_2 = 1.5733."""
    e = exact_energy(PAPER_LOOP, beta=PAPER.chain.midpoint())
    assert e.w_energy == pytest.approx(0.5 * (5.0 - 0.2 / 4.04), rel=1e-12)
    assert math.sqrt(e.w_energy) == pytest.approx(1.5733, abs=5e-5)


def test_paper_energy_against_integrated_moment_odes() -> None:
    """The moment ODEs (p, m_s, X_s, energy) integrated by scipy on [0, 8] with w = e^{-0.1t} sin t."""
    loop, beta, T = PAPER_LOOP, PAPER.chain.midpoint(), 8.0
    Q = loop.chain.generator(beta)
    S, n = len(loop.A), loop.n

    def rhs(t: float, z: np.ndarray) -> np.ndarray:
        w = math.exp(-0.1 * t) * math.sin(t)
        p = z[:S]
        ms = z[S:S + S * n].reshape(S, n)
        X = z[S + S * n:-1].reshape(S, n, n)
        dp = Q.T @ p
        dm = np.array([loop.A[s] @ ms[s] + loop.Bw[s][:, 0] * w * p[s] for s in range(S)]) + np.einsum("ts,tn->sn", Q, ms)
        dX = np.array([loop.A[s] @ X[s] + X[s] @ loop.A[s].T + w * (np.outer(loop.Bw[s][:, 0], ms[s]) + np.outer(ms[s], loop.Bw[s][:, 0]))
                       for s in range(S)]) + np.einsum("ts,tij->sij", Q, X)
        de = sum(np.trace(loop.Cz[s] @ X[s] @ loop.Cz[s].T) for s in range(S))
        return np.concatenate([dp, dm.ravel(), dX.ravel(), [de]])

    z0 = np.zeros(S + S * n + S * n * n + 1)
    z0[0] = 1.0
    sol = scipy.integrate.solve_ivp(rhs, (0, T), z0, method="DOP853", rtol=1e-11, atol=1e-13)
    got = exact_energy(loop, beta=beta, horizon=T)
    assert got.y_energy == pytest.approx(sol.y[-1, -1], rel=1e-7)


def test_worst_case_below_certified_gamma_and_above_paper_ratio() -> None:
    beta = PAPER.chain.midpoint()
    wc = worst_case_disturbance(PAPER_LOOP, beta=beta, horizon=30.0, pieces=40)
    gamma = hinf_gamma(PAPER_LOOP, robust=False).gamma
    assert gamma is not None and wc.gain <= gamma
    # the paper's own w is one disturbance; the worst over a finer class is at least near it
    paper_ratio = exact_energy(PAPER_LOOP, beta=beta, horizon=30.0).ratio
    assert wc.ratio >= 0.95 * paper_ratio
    assert wc.w.shape == (40, 1) and wc.t.shape == (41,)


def test_worst_case_matches_hinf_norm_for_identical_modes() -> None:
    """All modes equal: the chain is irrelevant and the gain is the H-infinity norm (within 2 %)."""
    md = {"A": [[-1.0, 2.0], [-2.0, -1.0]], "B": [[0.0], [0.0]], "C": [[1.0, 0.0]], "D": [[0.0], [1.0]]}
    system = FTCSystem.from_arrays(name="lti", modes=[md, md], alpha=[[-1.0, 1.0], [1.0, -1.0]],
                                   beta_min=[[0.0, 2.0], [2.0, 0.0]], beta_max=[[0.0, 2.0], [2.0, 0.0]])
    loop = state_feedback_loop(system, [np.zeros((1, 2))] * 2)
    norm = control.norm(control.ss(md["A"], md["D"], md["C"], [[0.0]]), "inf", method="scipy")
    wc = worst_case_disturbance(loop, beta=system.chain.midpoint(), horizon=40.0, pieces=120)
    assert wc.gain <= norm * (1 + 1e-6)
    assert wc.gain >= 0.98 * norm


def test_bad_arguments() -> None:
    with pytest.raises(ValidationError, match="pulse"):
        exact_energy(PAPER_LOOP, beta=PAPER.chain.midpoint(), disturbance="pulse")
    with pytest.raises(ValidationError, match="horizon"):
        exact_energy(PAPER_LOOP, beta=PAPER.chain.midpoint(), disturbance="step")  # infinite energy
    with pytest.raises(ValidationError, match="pieces"):
        worst_case_disturbance(PAPER_LOOP, beta=PAPER.chain.midpoint(), pieces=0)


@pytest.mark.slow(14)  # seconds measured on 2 busy cores: scheduled first
def test_exact_energy_against_20k_path_monte_carlo() -> None:
    """Paper example, paper's gains, Delta = 0, beta fixed at the midpoint, horizon 15.

    The simulator holds u over each step, a first-order bias (0.2-0.4 % at h = 0.01,
    measured); Richardson extrapolation 2 E(h/2) - E(h) on common paths cancels it, leaving
    O(h^2). The steps are h = 0.02 and 0.01 (were 0.01 and 0.005: 2.7 s of the
    simulation's CPU, now 2.0 s): on these paths the two extrapolations differ by 0.015 % of the exact
    value, 0.04 standard errors of the sample (measured), so the coarser pair moves the
    interval by nothing that matters. The exact value must lie in the two-sided Student-t
    interval at alpha = 1e-6 per side (with a residual bias of up to
    0.05 standard errors, above the 0.04 measured, the false-failure probability is at most
    about 2.1e-6 under the CLT; fixed seed).

    20,000 paths (was 100,000: 5x the cost for an interval sqrt(5) narrower). The
    sample's relative standard error is 0.36 % (measured), so the interval (+-4.9 standard
    errors) is about 3.5 % of the exact value wide; it must be under 7 % (twice that: the
    same margin the 100,000-path test had with 1.5 % against 3 %), so it is informative."""
    from ftc_verify.verification.montecarlo import estimate
    from ftc_verify.simulation.paths import sample_paths
    from ftc_verify.simulation.reference import energies_reference

    gains = load_controller(ROOT / "examples" / "paper_gains.toml")
    beta, T = PAPER.chain.midpoint(), 15.0
    exact = exact_energy(PAPER_LOOP, beta=beta, horizon=T)
    paths = sample_paths(PAPER.chain, T, 20_000, 20261122, beta=beta)
    y_coarse, w = energies_reference(PAPER, gains, paths, step=0.02)
    y_fine, _ = energies_reference(PAPER, gains, paths, step=0.01)
    est = estimate(2.0 * y_fine - y_coarse, w, alpha=1e-6, seed=20261122)
    lo, hi = est.lower_bound * est.w_energy, est.upper_bound * est.w_energy
    assert lo <= exact.y_energy <= hi
    assert (hi - lo) / exact.y_energy < 0.07  # the interval is informative, not vacuous


def _exact_in_monte_carlo_interval(system, controller, *, horizon, paths, step, seed) -> tuple[float, float, float]:
    """Exact expected energy and the Richardson-corrected Monte Carlo interval (alpha = 1e-6
    per side) on common paths at ``step`` and ``step / 2``, beta at the box centre."""
    from ftc_verify.analysis.closedloop import closed_loop
    from ftc_verify.simulation.paths import sample_paths
    from ftc_verify.simulation.reference import energies_reference
    from ftc_verify.verification.montecarlo import estimate

    beta = system.chain.midpoint()
    exact = exact_energy(closed_loop(system, controller).nominal(), beta=beta, horizon=horizon)
    drawn = sample_paths(system.chain, horizon, paths, seed, beta=beta)
    y_coarse, w = energies_reference(system, controller, drawn, step=step)
    y_fine, _ = energies_reference(system, controller, drawn, step=step / 2)
    est = estimate(2.0 * y_fine - y_coarse, w, alpha=1e-6, seed=seed)
    return exact.y_energy, est.lower_bound * est.w_energy, est.upper_bound * est.w_energy


def test_exact_energy_of_a_dynamic_controller_against_monte_carlo() -> None:
    """A mean-square stable dynamic controller on ``y_m = x``: the paper's gains behind a
    first-order lag (``Ac = -20 I, Bc = 20 K_l, Cc = I, Dc = 0``), horizon 8, 20,000 paths.
    The exact energy of the augmented loop lies in the Monte Carlo interval (false-failure
    probability about 2e-6 under the CLT; fixed seed), and the interval is informative."""
    from ftc_verify.controllers import Controller
    from ftc_verify.analysis.moments.stability import mean_square_stability
    from ftc_verify.analysis.closedloop import closed_loop

    gains = load_controller(ROOT / "examples" / "paper_gains.toml").gains
    system = PAPER.with_measured_output(np.eye(2))
    lagged = Controller.dynamic([-20.0 * np.eye(2)] * 2, [20.0 * K for K in gains], [np.eye(2)] * 2,
                                [np.zeros((2, 2))] * 2, name="lagged paper gains")
    assert mean_square_stability(closed_loop(system, lagged)).stable
    exact, lo, hi = _exact_in_monte_carlo_interval(system, lagged, horizon=8.0, paths=20_000, step=0.01,
                                                   seed=20261123)
    assert lo <= exact <= hi
    assert (hi - lo) / exact < 0.06


def test_exact_energy_of_the_observer_example_against_monte_carlo() -> None:
    """The observer-based controller of ``examples/paper_observer.toml`` on ``y_m = x1 + 2 x2``
    is not mean-square stable (joint mode (2, 1) has a pole near +63), so the comparison runs
    over a short horizon (0.3) where the energy is finite and the tails are still moderate:
    20,000 paths, Richardson on h = 0.002 / 0.001. Fixed seed; the CLT-based false-failure
    probability (2e-6) is only approximate for these heavier tails."""
    from ftc_verify.controllers import Controller

    observer = load_controller(ROOT / "examples" / "paper_observer.toml")
    assert isinstance(observer, Controller) and observer.n_c == 2
    system = PAPER.with_measured_output([[1.0, 2.0]])
    exact, lo, hi = _exact_in_monte_carlo_interval(system, observer, horizon=0.3, paths=20_000, step=0.002,
                                                   seed=20261123)
    assert lo <= exact <= hi
    assert (hi - lo) / exact < 1.0
