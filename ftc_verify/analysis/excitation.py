r"""The excitation of the lower bounds: the frequency and direction of :math:`v(t) = e\cos\omega t`.

For the disturbance :math:`w = F_{\theta_t}\xi + e\cos\omega t` of
:mod:`~ftc_verify.analysis.lower_bound` (its module docstring derives the moments), the
stationary energy rates :math:`N(e)` (output) and :math:`D(e)` (input) are quadratic forms
in :math:`e` at a fixed :math:`\omega`: :math:`N(e) = e^T H_N e`, :math:`D(e) = e^T H_D e`,
each entry from the float solves of the first-moment equation
:math:`(i\omega - \tilde{\mathcal A}) M = (\pi_s B_{w,s} e)_s` and of the averaged
second-moment equation :math:`\tilde{\mathcal L}(\bar X)_s = -c\,(B_{w,s} e\, M_{r,s}^T +
M_{r,s} e^T B_{w,s}^T)` (one LU factorisation of each per frequency, the second-moment one
shared by all frequencies). The best direction at :math:`\omega` is the top generalised
eigenvector of :math:`(H_N, H_D)`, its ratio the top generalised eigenvalue. Floats only:
the lower bound proves the ratio of what is chosen here
(:func:`~ftc_verify.analysis.lower_bound.gain_lower_bound`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import scipy.linalg

from ..model.system import Matrix
from .moments.stability import second_moment_matrix, unvech_stack, vech_order

__all__ = ["energy_forms", "best_excitation"]


def energy_forms(At: Sequence[Matrix], Bw: Sequence[Matrix], Cz: Sequence[Matrix], F: Sequence[Matrix], Q: Matrix,
           pi: Matrix, omega: float, lu_second: Any) -> tuple[Matrix, Matrix]:
    """The quadratic forms ``N(e) = e' HN e`` and ``D(e) = e' HD e`` (module docstring),
    float; ``lu_second`` the LU factors of the second-moment generator (any frequency)."""
    n, S, nw = At[0].shape[0], len(At), Bw[0].shape[1]
    first = scipy.linalg.block_diag(*At) + np.kron(Q.T, np.eye(n))
    c = 1.0 if omega == 0.0 else 0.5
    lu_first = scipy.linalg.lu_factor(1j * omega * np.eye(S * n) - first)
    rows, cols = vech_order(n)

    def rates(e: Matrix) -> tuple[float, float]:
        M = scipy.linalg.lu_solve(lu_first, np.concatenate([pi[s] * Bw[s] @ e for s in range(S)])).reshape(S, n)
        Mr = M.real
        G = [c * (np.outer(Bw[s] @ e, Mr[s]) + np.outer(Mr[s], Bw[s] @ e)) for s in range(S)]
        X = unvech_stack(scipy.linalg.lu_solve(lu_second, -np.concatenate([g[rows, cols] for g in G])), S, n)
        N = sum(float(np.trace(Cz[s] @ X[s] @ Cz[s].T)) for s in range(S))
        D = sum(float(np.trace(F[s] @ X[s] @ F[s].T)) + 2 * c * float(e @ F[s] @ Mr[s]) for s in range(S))
        return N, D + c * float(e @ e)

    HN, HD = np.zeros((nw, nw)), np.zeros((nw, nw))
    eye = np.eye(nw)
    for i in range(nw):
        HN[i, i], HD[i, i] = rates(eye[i])
    for i in range(nw):
        for j in range(i + 1, nw):
            N, D = rates(eye[i] + eye[j])
            HN[i, j] = HN[j, i] = 0.5 * (N - HN[i, i] - HN[j, j])
            HD[i, j] = HD[j, i] = 0.5 * (D - HD[i, i] - HD[j, j])
    return HN, HD


def best_excitation(At: Sequence[Matrix], Bw: Sequence[Matrix], Cz: Sequence[Matrix], F: Sequence[Matrix],
                     Q: Matrix, pi: Matrix) -> tuple[float, float, Matrix]:
    """``(ratio, omega, e)``: the best frequency of the candidates and its best direction."""
    n = At[0].shape[0]
    first = scipy.linalg.block_diag(*At) + np.kron(Q.T, np.eye(n))
    ev = np.linalg.eigvals(first)
    order = np.argsort(-ev.real)[:6]
    omegas = sorted({0.0, *(abs(float(ev[k].imag)) for k in order)})
    best = (-math.inf, 0.0, np.zeros(Bw[0].shape[1]))
    try:
        lu_second = scipy.linalg.lu_factor(second_moment_matrix(At, Q))
    except (ValueError, np.linalg.LinAlgError, scipy.linalg.LinAlgError):
        return best
    for omega in omegas:
        try:
            HN, HD = energy_forms(At, Bw, Cz, F, Q, pi, omega, lu_second)
            w, V = scipy.linalg.eigh(0.5 * (HN + HN.T), 0.5 * (HD + HD.T))
        except (ValueError, np.linalg.LinAlgError, scipy.linalg.LinAlgError):
            continue
        if np.isfinite(w[-1]) and w[-1] > best[0]:
            e = V[:, -1] / np.abs(V[:, -1]).max()
            best = (float(w[-1]), omega, e)
    return best
