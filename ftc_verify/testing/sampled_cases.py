"""Random sampled-data test loops: a plant per mode with an LQR gain per FDI mode.

The one generator of the random loops that ``benchmarks/sampled.py`` and the ``h_max``
bracket's tests (``tests/test_sampled_h31b.py``, ``tests/test_bracket_h31x.py``) draw:
:func:`lqr_case`.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg

from ..controllers.controller import Controller
from ..model.system import FTCSystem

__all__ = ["lqr_case"]


def lqr_case(n: int, m: int, rng: np.random.Generator) -> tuple[FTCSystem, Controller]:
    """A random plant per mode, :math:`A_i = 0.6\\, G_i - 0.5 I` and :math:`B_i` with
    standard normal entries (``n`` states, two inputs, ``C = 1^T``, ``D = 0.3 \\cdot 1``),
    the gain of FDI mode ``i`` the LQR gain :math:`K_i = -B_i^T P_i` of that mode's plant
    (:math:`Q = I`, :math:`R = I`, :math:`P_i` the stabilising solution of the continuous
    algebraic Riccati equation); fault rates ``0.3`` between every pair of modes and
    detection rates in ``[2, 4]``. Every number comes from ``rng`` in a fixed order
    (mode by mode: ``A`` then ``B``), so a seed names the loop."""
    modes, gains = [], []
    for _ in range(m):
        A = rng.standard_normal((n, n)) * 0.6 - 0.5 * np.eye(n)
        B = rng.standard_normal((n, 2))
        modes.append({"A": A, "B": B, "C": np.ones((1, n)), "D": np.ones((n, 1)) * 0.3})
        P = scipy.linalg.solve_continuous_are(A, B, np.eye(n), np.eye(2))
        gains.append(-B.T @ P)
    alpha = np.full((m, m), 0.3)
    np.fill_diagonal(alpha, -0.3 * (m - 1))
    off = 1 - np.eye(m)
    system = FTCSystem.from_arrays(name=f"random n={n} m={m}", modes=modes, alpha=alpha, beta_min=2 * off,
                                   beta_max=4 * off)
    return system, Controller.state_feedback(gains)
