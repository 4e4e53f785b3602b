"""Stabilising gains of the plant's modes one by one (LQR and its dual): the designs the
hypothesis strategies of :mod:`ftc_verify.testing.strategies` draw controllers around,
usable on their own for property tests of a user's design."""

from __future__ import annotations

import warnings

import numpy as np
import scipy.linalg
from numpy.typing import NDArray

from ..model.system import FTCSystem

__all__ = ["GAIN_BOUND", "lqr_gains", "observer_gains"]

Matrix = NDArray[np.float64]

#: Largest accepted gain entry. Nearly uncontrollable draws (an unstable mode reached
#: through a 1e-8 coupling) give LQR gains ~1e8 and Lyapunov matrices with condition
#: ~1e17, which no certificate (``cond(P) <= 1e8``) can accept: not "well scaled".
GAIN_BOUND = 100.0


def _care(A: Matrix, B: Matrix, q: float, r: float) -> Matrix | None:
    """The stabilizing solution of the Riccati equation of ``(A, B)``, or ``None``."""
    try:
        # degenerate draws (rejected by the callers) make the solver overflow: silence it
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore")
            return scipy.linalg.solve_continuous_are(A, B, q * np.eye(A.shape[0]), r * np.eye(B.shape[1]))
    except (np.linalg.LinAlgError, ValueError):
        return None


def _acceptable(G: Matrix, closed: Matrix, max_gain: float) -> bool:
    """A gain is finite, bounded by ``max_gain`` and makes ``closed`` Hurwitz."""
    return bool(np.all(np.isfinite(G)) and np.max(np.abs(G)) <= max_gain
                and np.max(np.linalg.eigvals(closed).real) < 0)


def lqr_gains(system: FTCSystem, *, q: float = 1.0, r: float = 1.0,
              max_gain: float = GAIN_BOUND) -> tuple[Matrix, ...] | None:
    """Per FDI mode ``j`` the LQR gain ``K_j = -B_j' X_j / r`` of ``(A_j, B_j)``.

    Returns ``None`` when some pair is not stabilizable (the Riccati solver fails) or a
    gain is not finite, not stabilizing, or has an entry above ``max_gain``.

    Examples
    --------
    >>> from ftc_verify.model.system import FTCSystem
    >>> sys1 = FTCSystem.from_arrays(name="s", modes=[{"A": [[1.0]], "B": [[1.0]], "C": [[1.0]],
    ...     "D": [[1.0]]}] * 2, alpha=[[-1, 1], [1, -1]], beta_min=[[0, 1], [1, 0]], beta_max=[[0, 1], [1, 0]])
    >>> [round(float(K[0, 0]), 6) for K in lqr_gains(sys1)]
    [-2.414214, -2.414214]
    """
    gains = []
    for md in system.modes:
        X = _care(md.A, md.B, q, r)
        if X is None:
            return None
        K = -md.B.T @ X / r
        if not _acceptable(K, md.A + md.B @ K, max_gain):
            return None
        gains.append(K)
    return tuple(gains)


def observer_gains(system: FTCSystem, *, q: float = 1.0, r: float = 1.0,
                   max_gain: float = GAIN_BOUND) -> tuple[Matrix, ...] | None:
    """Per FDI mode ``j`` the observer gain ``L_j = X_j C_{y,j}' / r`` (dual LQR of
    ``(A_j, C_{y,j})``, measured output ``Cy``, default ``C``), or ``None`` when some pair
    is not detectable or a gain is not finite, not stabilizing or above ``max_gain``."""
    gains = []
    for md in system.modes:
        X = _care(md.A.T, md.measured.T, q, r)
        if X is None:
            return None
        L = X @ md.measured.T / r
        if not _acceptable(L, md.A - L @ md.measured, max_gain):
            return None
        gains.append(L)
    return tuple(gains)
