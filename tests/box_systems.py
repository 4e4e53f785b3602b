"""Loops for the box verdicts and the gamma bracket (tests only): whose worst constant
rate lies inside the rate box, and an independent coupled-Riccati gain."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import scipy.linalg

from ftc_verify.analysis.closedloop import ClosedLoop, closed_loop, state_feedback_loop
from ftc_verify.controllers.files import load_controller
from ftc_verify.model.files import load_system
from ftc_verify.model.system import FTCSystem

#: Two modes, B = I, a second FDI-mode gain: stable at the four vertices of the box
#: beta in [0.1, 10]^2 but not for the constant rates near beta = (2.2, 6.6).
INTERIOR = """name = "interior-instability"
[chain]
alpha = [[-1.6, 1.6], [1.6, -1.6]]
beta_min = [[0.0, 0.1], [0.1, 0.0]]
beta_max = [[0.0, 10.0], [10.0, 0.0]]
{extra}
[[mode]]
A = [[{a0}, 2.0], [-5.0, {a0}]]
B = [[1.0, 0.0], [0.0, 1.0]]
C = [[1.0, 0.0], [0.0, 1.0]]
D = [[1.0, 0.0], [0.0, 1.0]]
[[mode]]
A = [[{a0}, 9.0], [-1.1, {a0}]]
B = [[1.0, 0.0], [0.0, 1.0]]
C = [[1.0, 0.0], [0.0, 1.0]]
D = [[1.0, 0.0], [0.0, 1.0]]
"""
INTERIOR_GAINS = """[[gain]]
K = [[0.0, 0.0], [0.0, 0.0]]
[[gain]]
K = [[-2.6, 0.06], [-2.45, 1.37]]
"""


def interior_files(path: Path, *, shift: float = 0.0, extra: str = "") -> tuple[Path, Path]:
    """The system and gain files of :data:`INTERIOR`, every mode's ``A`` moved by
    ``-shift I`` (the second-moment abscissa by ``-2 shift``, the diagonal written as a
    decimal), ``extra`` lines added to ``[chain]``."""
    system = path / f"interior{shift:g}.toml"
    system.write_text(INTERIOR.format(a0=repr(-0.1 - shift), extra=extra))
    gains = path / "interior_gains.toml"
    gains.write_text(INTERIOR_GAINS)
    return system, gains


def interior_loop(path: Path, *, shift: float = 0.0, extra: str = "") -> ClosedLoop:
    system, gains = interior_files(path, shift=shift, extra=extra)
    return closed_loop(load_system(system), load_controller(gains))


def coupled_riccati_gain(loop: ClosedLoop, rates: np.ndarray, *, rtol: float = 1e-9) -> float:
    r"""The worst-case gain of the nominal ``loop`` at the constant ``rates``, independently of
    the package: bisection on the existence of a stabilising solution of the coupled
    bounded-real Riccati equations, each solved by a Gauss-Seidel sweep of single-mode
    H-infinity AREs (``scipy.linalg.solve_continuous_are`` with ``R = -gamma^2 I``):
    :math:`(A_s + q_{ss}/2)^T P_s + P_s (A_s + q_{ss}/2) + \gamma^{-2} P_s B_s B_s^T P_s
    + C_s^T C_s + \sum_{t \ne s} q_{st} P_t = 0`."""
    Q = loop.chain.generator(rates)
    S, n = len(loop.A), loop.n

    def feasible(gamma: float) -> bool:
        P = np.zeros((S, n, n))
        for _ in range(400):
            old = P.copy()
            for s in range(S):
                a = loop.A[s] + 0.5 * Q[s, s] * np.eye(n)
                rhs = loop.Cz[s].T @ loop.Cz[s] + sum(Q[s, t] * P[t] for t in range(S) if t != s)
                b = loop.Bw[s]
                try:
                    X = scipy.linalg.solve_continuous_are(a, b, rhs, -gamma ** 2 * np.eye(b.shape[1]))
                except (np.linalg.LinAlgError, ValueError):
                    return False
                if not np.all(np.isfinite(X)) or np.linalg.eigvalsh(0.5 * (X + X.T))[0] < -1e-9 * max(1, abs(X).max()):
                    return False
                closed = a + b @ b.T @ X / gamma ** 2
                if np.max(np.linalg.eigvals(closed).real) >= 0:
                    return False
                P[s] = 0.5 * (X + X.T)
            if np.abs(P - old).max() <= 1e-13 * max(1.0, np.abs(P).max()):
                return True
        return False

    lo, hi = 0.0, 1.0
    while not feasible(hi):
        lo, hi = hi, 2 * hi
    while hi - lo > rtol * hi:
        mid = 0.5 * (lo + hi)
        if feasible(mid):
            hi = mid
        else:
            lo = mid
    return hi


def shifted(loop: ClosedLoop, shift: float) -> ClosedLoop:
    """``loop`` with every state matrix moved by ``-shift I`` (a loop without a source)."""
    return replace(loop, A=tuple(a - shift * np.eye(loop.n) for a in loop.A), source=None)


def three_mode_loop(seed: int = 7) -> ClosedLoop:
    """A random stable plant with three fault modes, n = 5, zero gains: 9 joint states, a
    second-moment generator of 135 rows (above the pruning threshold of the spectral
    stage), 6 uncertain rates (64 vertices). The one loop of ``tests/test_conic.py``'s
    pruned vertex search and ``tests/test_matrix_free_h37L.py``'s matrix-free stage."""
    rng = np.random.default_rng(seed)
    n, m = 5, 3
    modes = [{"A": rng.normal(size=(n, n)) / 2 - 1.5 * np.eye(n), "B": rng.normal(size=(n, 1)),
              "C": rng.normal(size=(1, n)), "D": rng.normal(size=(n, 1))} for _ in range(m)]
    alpha = rng.uniform(0.2, 1.0, (m, m))
    np.fill_diagonal(alpha, 0.0)
    np.fill_diagonal(alpha, -alpha.sum(axis=1))
    bmin = rng.uniform(0.5, 2.0, (m, m))
    np.fill_diagonal(bmin, 0.0)
    system = FTCSystem.from_arrays(name="three-mode", modes=modes, alpha=alpha, beta_min=bmin, beta_max=bmin + 2.0)
    return state_feedback_loop(system, [np.zeros((1, n))] * m)
