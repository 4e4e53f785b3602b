r"""Exact zero-order-hold discretisation: one exponential, or many at once.

Over an interval of length :math:`h` with the input held, :math:`\dot x = A x + B u + D w`
gives :math:`x(h) = \Phi(h) x(0) + \Gamma(h) (B u + D w)` with

.. math::

    \Phi(h) = e^{A h}, \qquad \Gamma(h) = \int_0^h e^{A s}\, ds,

the blocks of :math:`\exp\bigl(\begin{smallmatrix} A & B & D \\ 0 & 0 & 0 \\ 0 & 0 & 0
\end{smallmatrix}\bigr) h` (Van Loan). The same formulas give the controller update
:math:`x_c(t + h) = \Phi_c x_c + \Gamma_c v` with :math:`\Phi_c = e^{A_c h}`,
:math:`\Gamma_c = \int_0^h e^{A_c s} ds\, B_c`.

* :func:`zoh_matrices` -- one triple :math:`(\Phi, \Gamma B, \Gamma D)` by
  :func:`scipy.linalg.expm` (the reference simulator);
* :func:`phi_gamma` -- :math:`\Phi(h), \Gamma(h)` for many ``(A, h)`` pairs by a Taylor
  polynomial with scaling and squaring, accurate to rounding like
  :func:`scipy.linalg.expm` (the vectorised energies and the continuous loop);
* :func:`controller_zoh` -- :math:`(\Phi_c, \Gamma_c)` of many ``(entry, h)`` pairs of a
  controller, through :func:`phi_gamma`.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike

from ..controllers.controller import Controller
from ..errors import ValidationError
from ..model.system import Matrix

__all__ = ["zoh_matrices", "phi_gamma", "controller_zoh", "taylor_series"]

#: Scaling target of :func:`phi_gamma`: the Taylor polynomial is evaluated at
#: ``||A h / 2^s||_1 <= _THETA``.
_THETA = 0.5
#: Truncation bound of the Taylor polynomial, relative (``theta^(q+1) / (q+1)! <= _TAYLOR_TOL``).
_TAYLOR_TOL = 1e-18
#: At most this many distinct matrices are handled group by group (one BLAS product per
#: group); beyond, per item (Horner with batched products). Read at call time, also by
#: ``ftc_verify.simulation._vectorised_maps``, so a test may lower it in this module.
_GROUP_LIMIT = 64


def zoh_matrices(A: ArrayLike, B: ArrayLike, D: ArrayLike, h: float) -> tuple[Matrix, Matrix, Matrix]:
    r"""Exact zero-order-hold matrices :math:`(\Phi, \Gamma B, \Gamma D)` over ``h``.

    They are the top blocks of :math:`\exp(M h)`, :math:`M = \bigl(\begin{smallmatrix}
    A & B & D \\ 0 & 0 & 0 \\ 0 & 0 & 0\end{smallmatrix}\bigr)` (:func:`scipy.linalg.expm`),
    so that :math:`x(h) = \Phi x(0) + \Gamma B u + \Gamma D w` for ``u, w`` held constant.
    """
    A, B, D = (np.asarray(v, dtype=float) for v in (A, B, D))
    n, nu, nw = A.shape[0], B.shape[1], D.shape[1]
    M = np.zeros((n + nu + nw, n + nu + nw))
    M[:n, :n], M[:n, n:n + nu], M[:n, n + nu:] = A, B, D
    E = scipy.linalg.expm(M * float(h))
    return E[:n, :n], E[:n, n:n + nu], E[:n, n + nu:]


def _taylor_degree(theta: float) -> int:
    """Smallest ``q`` with ``theta^(q+1) / (q+1)! <= _TAYLOR_TOL`` (at least 1)."""
    q, term = 0, 1.0
    while True:
        q += 1
        term *= theta / q
        if term * theta / (q + 1) <= _TAYLOR_TOL or q >= 40:
            return q


def taylor_series(A: np.ndarray, h: np.ndarray, norm: float) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
    r"""Taylor data of one matrix for many lengths (see :func:`phi_gamma`).

    Returns ``(s, powers, Rphi, Rgam)`` with ``powers[k] = (A tau)^k``,
    :math:`\tau = \max h / 2^s`, such that :math:`\Phi(h_i / 2^s) = \sum_k Rphi[i, k]\,
    powers[k]` and :math:`\Gamma(h_i / 2^s) = \sum_k Rgam[i, k]\, powers[k]`
    (:math:`Rphi = r^k / k!`, :math:`Rgam = (h/2^s)\, r^k/(k+1)!`, :math:`r = h_i / \max h`).
    ``norm`` is the induced 1-norm of ``A``.
    """
    n = A.shape[0]
    hmax = float(h.max()) if h.size else 0.0
    theta = norm * hmax
    if hmax == 0.0 or theta == 0.0:
        powers = np.eye(n)[None]
        return 0, powers, np.ones((h.size, 1)), h[:, None].copy()
    s = max(0, math.ceil(math.log2(theta / _THETA)))
    q = _taylor_degree(theta / 2.0 ** s)
    As = A * (hmax / 2.0 ** s)
    powers = np.empty((q + 1, n, n))
    powers[0] = np.eye(n)
    for k in range(1, q + 1):
        powers[k] = powers[k - 1] @ As
    r = h / hmax
    R = np.empty((h.size, q + 1))
    R[:, 0] = 1.0
    for k in range(1, q + 1):
        np.multiply(R[:, k - 1], r, out=R[:, k])
    inv_fact = 1.0 / np.array([math.factorial(k) for k in range(q + 2)], dtype=float)
    return s, powers, R * inv_fact[:q + 1], R * inv_fact[1:q + 2] * (h / 2.0 ** s)[:, None]


def one_norms(A: np.ndarray) -> np.ndarray:
    """Induced 1-norms (max column sums) of a stack ``(G, n, n)``."""
    return np.abs(A).sum(axis=1).max(axis=1)


def _check_args(A: ArrayLike, h: ArrayLike, groups: ArrayLike | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    A = np.asarray(A, dtype=float)
    h = np.asarray(h, dtype=float).reshape(-1)
    if A.ndim != 3 or A.shape[1] != A.shape[2]:
        raise ValidationError(f"phi_gamma: A must have shape (G, n, n), got {A.shape}")
    if np.any(~np.isfinite(h)) or np.any(h < 0):
        raise ValidationError(f"phi_gamma: h must be finite and >= 0, got {h[~(np.isfinite(h) & (h >= 0))][:5]}")
    G, N = A.shape[0], h.size
    gid = np.arange(N) if groups is None else np.asarray(groups, dtype=np.int64).reshape(-1)
    if gid.size != N or (N and (gid.min() < 0 or gid.max() >= G)):
        raise ValidationError(f"phi_gamma: groups must be {N} indices into {G} matrices")
    return A, h, gid


def _grouped(A: np.ndarray, h: np.ndarray, gid: np.ndarray, used: np.ndarray,
             norms: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Few distinct matrices: the powers once per matrix, one product per group."""
    N, n = h.size, A.shape[1]
    Phi = np.empty((N, n, n))
    Gam = np.empty((N, n, n))
    for g in used:
        idx = np.flatnonzero(gid == g) if used.size > 1 else slice(None)
        s, powers, Rphi, Rgam = taylor_series(A[g], h[idx], float(norms[g]))
        P = (Rphi @ powers.reshape(powers.shape[0], n * n)).reshape(-1, n, n)
        Gm = (Rgam @ powers.reshape(powers.shape[0], n * n)).reshape(-1, n, n)
        for _ in range(s):
            Gm = Gm + P @ Gm
            P = P @ P
        Phi[idx] = P
        Gam[idx] = Gm
    return Phi, Gam


def _per_item(A: np.ndarray, h: np.ndarray, gid: np.ndarray, norms: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Many distinct matrices: Horner with batched products, squarings per item."""
    N, n = h.size, A.shape[1]
    eye = np.eye(n)
    theta = norms[gid] * h
    s = np.zeros(N, dtype=np.int64)
    pos = theta > _THETA
    s[pos] = np.ceil(np.log2(theta[pos] / _THETA)).astype(np.int64)
    tau = h / 2.0 ** s
    As = A[gid] * tau[:, None, None]
    q = _taylor_degree(float(np.max(theta / 2.0 ** s)) if N else 0.0)
    T = np.broadcast_to(eye / math.factorial(q + 1), (N, n, n)).copy()
    for k in range(q - 1, -1, -1):
        T = As @ T
        T += eye / math.factorial(k + 1)
    P = eye + As @ T
    Gm = T * tau[:, None, None]
    for level in range(int(s.max())):
        sel = np.flatnonzero(s > level)
        Gm[sel] = Gm[sel] + P[sel] @ Gm[sel]
        P[sel] = P[sel] @ P[sel]
    return P, Gm


def phi_gamma(A: ArrayLike, h: ArrayLike, groups: ArrayLike | None = None) -> tuple[np.ndarray, np.ndarray]:
    r"""Batched :math:`\Phi(h) = e^{A h}` and :math:`\Gamma(h) = \int_0^h e^{A s} ds`.

    Parameters
    ----------
    A : (G, n, n) array
        Distinct state matrices.
    h : (N,) array
        Non-negative interval lengths.
    groups : (N,) int array, optional
        Which matrix each interval uses (default ``arange(N)``, then ``G == N``).

    Returns
    -------
    Phi, Gamma : (N, n, n) arrays

    Notes
    -----
    Scaling and squaring with a Taylor polynomial: with ``s`` such that
    :math:`\theta = \|A h\|_1 / 2^s \le 1/2` and :math:`\tau = h / 2^s`,

    .. math::

        \Phi(\tau) = \sum_{k=0}^{q} \frac{(A\tau)^k}{k!}, \qquad
        \Gamma(\tau) = \tau \sum_{k=0}^{q} \frac{(A\tau)^k}{(k+1)!},

    ``q`` the smallest degree with :math:`\theta^{q+1}/(q+1)! \le 10^{-18}` (no
    cancellation at :math:`\theta \le 1/2`), then ``s`` times
    :math:`\Gamma(2\tau) = \Gamma(\tau) + \Phi(\tau)\Gamma(\tau)`,
    :math:`\Phi(2\tau) = \Phi(\tau)^2`. For few distinct matrices the powers
    :math:`A^k` are formed once per matrix and the polynomials of all its intervals are
    one matrix product (``(N_g, q+1) @ (q+1, n^2)``); otherwise the polynomial is
    evaluated per interval by Horner's rule with batched products.
    """
    A, h, gid = _check_args(A, h, groups)
    n = A.shape[1]
    if h.size == 0:
        return np.empty((0, n, n)), np.empty((0, n, n))
    norms = one_norms(A)
    used = np.unique(gid)
    if used.size <= _GROUP_LIMIT:
        return _grouped(A, h, gid, used, norms)
    return _per_item(A, h, gid, norms)


def controller_zoh(controller: Controller, entries: ArrayLike, h: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    r"""Batched exact controller updates :math:`(\Phi_c, \Gamma_c)` of many intervals.

    For interval ``k`` with entry :math:`e_k` and length :math:`h_k`:
    :math:`\Phi_c = e^{A_{c,e} h}`, :math:`\Gamma_c = \int_0^h e^{A_{c,e} s}\, ds\,
    B_{c,e}` (the same as :meth:`Controller.discretise`, by :func:`phi_gamma`).

    Returns
    -------
    Phi_c : (N, n_c, n_c) array
    Gamma_c : (N, n_c, n_v) array
    """
    e = np.asarray(entries, dtype=np.int64).reshape(-1)
    Phi, Gam = phi_gamma(np.stack(controller.Ac), h, e)
    return Phi, Gam @ np.stack(controller.Bc)[e]
