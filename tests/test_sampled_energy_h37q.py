"""The sampled loop's exact energy in the reduced moment form (issue 37, item 5, branch
h37q): :mod:`ftc_verify.analysis.moments.sampled_energy` carries the exosystem's state
*at the sample*, held (``z = (x, u, x_c^+, eta_k)``, the held disturbance ``c^T eta_k``
needing no state of its own), and moves it by ``e^{S h}`` between samples.

* its moment generator has size ``n_s d (d + 1) / 2`` with ``d = n + n_u + n_c + q``
  (the first form: ``d + 1``);
* on a loop whose modes are all the same (so the chain changes nothing and the loop is
  deterministic) its energy over a horizon that ends inside a period, from a nonzero
  ``x0``, equals an independent computation: the sampled loop stepped period by period,
  ``u_k = K x_k`` and ``w_k = e^{-0.1 t_k} sin t_k`` held, the period's integral of
  ``|C x|^2`` from the Van Loan exponential of the held-input system (1e-10 relative);
* its infinite-horizon energy is the limit of those sums.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg

from ftc_verify.analysis.moments.sampled_energy import sampled_energy
from ftc_verify.controllers import Controller
from ftc_verify.model.files import load_system

A = [[-1.0, 0.5], [-0.3, -0.4]]
B = [[0.0], [1.0]]
C = [[1.0, 0.5]]
D = [[0.3], [1.0]]
K = [[-0.8, -0.6]]


def _identical_modes(path: Path) -> Path:
    mode = f"[[mode]]\nA = {A}\nB = {B}\nC = {C}\nD = {D}\n"
    path.write_text("[chain]\nalpha = [[-1.0, 1.0], [2.0, -2.0]]\nbeta_min = [[0.0, 1.0], [1.0, 0.0]]\n"
                    "beta_max = [[0.0, 3.0], [3.0, 0.0]]\n" + mode + mode)
    return path


def _stepped(h: float, horizon: float, x0: np.ndarray) -> float:
    """int_0^horizon |C x|^2 of the deterministic sampled loop, period by period."""
    a, b, c, d, k = (np.array(M) for M in (A, B, C, D, K))
    n = a.shape[0]
    abar = np.zeros((n + 2, n + 2))
    abar[:n, :n], abar[:n, n:n + 1], abar[:n, n + 1:] = a, b, d
    cbar = np.zeros((1, n + 2))
    cbar[:, :n] = c

    def period(span: float) -> tuple[np.ndarray, np.ndarray]:
        """(e^{Abar span}, int_0^span e^{Abar' s} Cbar' Cbar e^{Abar s} ds) by Van Loan."""
        m = abar.shape[0]
        big = np.block([[-abar.T, cbar.T @ cbar], [np.zeros((m, m)), abar]]) * span
        E = scipy.linalg.expm(big)
        return E[m:, m:], E[m:, m:].T @ E[:m, m:]

    full, energy, x, t = period(h), 0.0, x0.astype(float), 0.0
    while t < horizon - 1e-12:
        span = min(h, horizon - t)
        Phi, Q = full if span == h else period(span)
        xi = np.concatenate([x, k @ x, [math.exp(-0.1 * t) * math.sin(t)]])
        energy += float(xi @ Q @ xi)
        x = (Phi @ xi)[:n]
        t += span
    return energy


@pytest.mark.parametrize(("h", "horizon"), [(0.3, 7.45), (0.05, 4.0)])
def test_energy_of_a_deterministic_loop_equals_the_loop_stepped_by_hand(tmp_path: Path, h: float,
                                                                         horizon: float) -> None:
    system = load_system(_identical_modes(tmp_path / "same.toml"))
    controller = Controller.state_feedback([np.array(K)] * 2)
    x0 = np.array([0.7, -1.2])
    for beta in (system.chain.beta_min, system.chain.beta_max):
        got = sampled_energy(system, controller, h, beta=beta, horizon=horizon, x0=x0, start=(1, 0)).y_energy
        assert got == pytest.approx(_stepped(h, horizon, x0), rel=1e-10)
    long = _stepped(h, 200.0, x0)
    assert sampled_energy(system, controller, h, beta=system.chain.beta_max, x0=x0).y_energy == \
        pytest.approx(long, rel=1e-9)


def test_moment_generator_has_the_reduced_size(tmp_path: Path) -> None:
    from ftc_verify.analysis.moments import sampled_energy as module

    system = load_system(_identical_modes(tmp_path / "same.toml"))
    controller = Controller.state_feedback([np.array(K)] * 2)
    aug = module._augmented(system, controller, 0.1, system.chain.beta_min, "paper", None, (0, 0))
    d = 2 + 1 + 0 + 2  # n + n_u + n_c + q (paper exosystem)
    assert aug.L.shape == (system.chain.n_states * d * (d + 1) // 2,) * 2
