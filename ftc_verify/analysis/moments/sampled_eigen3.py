r"""The eigenpair enclosure of :mod:`~ftc_verify.analysis.moments.sampled_eigen` on a
*third-order* form of the one-period map, with a preconditioner that moves with the rates.

**Why.** On held-out ``n = 4, m = 3`` loops 9e-4 below the crossing, the second-order
enclosure needs sub-boxes of an eighth to a sixteenth of every rate, also along rates the
spectral radius hardly depends on (``benchmarks/results/bulk18.md``, section 1). Three
losses dominate there: the second-order form's remainder (the map's terms of degree three
bounded by absolute values), the eigenvalue's own terms of degree three (held in the
enclosure's radius, not in the polynomial that is maximised), and the contraction
:math:`\Lambda` of the enclosure, which is of *first* order in the sub-box's widths (the
fixed preconditioner :math:`R` inverts the bordered matrix at the centre only). Here:

* the form is :func:`~ftc_verify.analysis.moments.cubic_balls.cubic_terms`'s,
  :math:`T(\delta) \in T_c + \sum_a \delta_a T_a + \sum_p \mu_p T_p + \sum_t \nu_t T_t +
  E`, :math:`\nu_t = \delta_a \delta_b \delta_e` over the triples :math:`t = (a, b, e)`,
  :math:`a \le b \le e`, :math:`|E| \le T_r`;
* the eigenvalue's model is :math:`\tilde\lambda(\delta) = \lambda_0 + \sum_a \delta_a
  \lambda_a + \sum_p \mu_p \lambda_p + \sum_t \nu_t \lambda_t`, the eigenvector's
  :math:`\tilde v(\delta)` of degree two, both from
  :func:`~ftc_verify.analysis.moments.sampled_eigen.expansion` and, for :math:`\lambda_t`,
  the last row of :math:`R\, g_t` below (any floats: the proof checks them);
* the preconditioner is :math:`S(\delta) = R - \sum_a \delta_a F_a R`, :math:`F_a` a
  float matrix near :math:`R M_a`, :math:`M_a = \begin{bmatrix} T_a - \lambda_a I & -v_a
  \\ 0 & 0 \end{bmatrix}` (the derivative of the bordered matrix along :math:`\delta_a`).

**The enclosure** (derived here; notation of
:mod:`~ftc_verify.analysis.moments.sampled_eigen`). Fix :math:`\delta` and a map
:math:`T` of the form's set; :math:`G(z) = ((T - \tilde\lambda - \mu)(\tilde v + y),
w_0^T y)`, :math:`z = (y, \mu)`, and :math:`\Phi(z) = z - S(\delta) G(z)`. Then
:math:`G(z) - G(0) = (M + \sum_a \delta_a M_a + B) z + (-\mu y, 0)` with :math:`B =
\begin{bmatrix} \sum_p \mu_p (T_p - \lambda_p) + \sum_t \nu_t (T_t - \lambda_t) + E &
-\sum_p \mu_p v_p \\ 0 & 0 \end{bmatrix}`, and

.. math::

    I - S (M + \textstyle\sum_a \delta_a M_a + B) = (I - RM)
    - \sum_a \delta_a \big((R M_a - F_a) + F_a (I - RM)\big) - R B
    + \sum_{a, b} \delta_a \delta_b F_a R M_b + \sum_a \delta_a F_a R B,

whose first-order terms are only the rounding of :math:`F_a` and :math:`I - RM`: the
Lipschitz matrix :math:`L` is of second order in the widths. So :math:`|\Phi(z)| \le
|S G(0)| + L |z| + |S_y| \zeta_\mu \zeta_y` and :math:`|\Phi(z) - \Phi(z')| \le (L +
[\zeta_\mu |S_y|, |S_y| \zeta_y]) |z - z'|` on the box :math:`|z| \le \zeta`, with
:math:`|S_y| \le |R_y| + \sum_a |F_a| |R_y|`, and the argument of
:mod:`~ftc_verify.analysis.moments.sampled_eigen` (a contraction of the box into itself,
the simple eigenvalue, the centre's eigenvector in the cone, continuity over the
connected box) gives :math:`\rho(T(\delta)) \le \max_\delta \tilde\lambda(\delta) +
\zeta_\mu` (the maximum by :func:`cubic_max`).

**The residual** :math:`G(0) = (T - \tilde\lambda) \tilde v`, by monomial: degrees 0 to
2 as in :mod:`~ftc_verify.analysis.moments.sampled_eigen`; degree 3 grouped, the
coefficient of :math:`\nu_t` being

.. math::

    g_t = (T_t - \lambda_t) v_0 + \sum_{i} \big((T_i - \lambda_i) v_{t \setminus i}
    + (T_{t \setminus i} - \lambda_{t \setminus i}) v_i\big)

(:math:`i` over the distinct indices of :math:`t`, :math:`t \setminus i` the pair left),
bounded after its product with :math:`R` (and with each :math:`F_a R`); :math:`\lambda_t`
is chosen to cancel the last entry of :math:`R g_t`. Degrees 4 and 5
(:math:`\mu_p \mu_q (T_p - \lambda_p) v_q`, :math:`\nu_t \delta_a (T_t - \lambda_t)
v_a`, :math:`\nu_t \mu_p (T_t - \lambda_t) v_p`) and :math:`E \tilde v` by absolute
values. Every float operation's rounding is bounded as in
:mod:`~ftc_verify.analysis.moments.fast_balls` and every bound rounded up.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from ...model.system import Matrix
from .cubic_balls import triples
from .fast_balls import up_bound as _up
from .quad_balls import pairs
from .sampled_eigen import Expansion, centre_in_cone, expansion, fixed_box, low_residual
from .sampled_second import box_maximum

__all__ = ["CubicBound", "cubic_max", "cubic_radius_bound"]

_U = 2.0 ** -53
_ETA = 2.0 ** -1022


@dataclass(frozen=True)
class CubicBound:
    """What :func:`cubic_radius_bound` found: ``top`` the proved upper bound of the
    spectral radius over the sub-box (``None``: no proof), ``reach`` the spectral radius
    of the enclosure's Lipschitz matrix (a float estimate, ``None`` when the expansion
    failed: the enclosure needs it below one)."""

    top: float | None
    reach: float | None


def cubic_max(lin: Matrix, quad: Matrix, cub: Matrix, max_boxes: int = 400, rtol: float = 1e-3) -> float:
    r"""An upper bound of :math:`\max_{\delta \in [-1, 1]^K} \varphi(\delta)`,
    :math:`\varphi = \sum_a l_a \delta_a + \sum_p q_p \mu_p + \sum_t c_t \nu_t` (``quad``
    over :func:`~ftc_verify.analysis.moments.quad_balls.pairs`, ``cub`` over
    :func:`~ftc_verify.analysis.moments.cubic_balls.triples`), by branch and bound: with
    the symmetric tensors :math:`Q`, :math:`C` of the degrees two and three, on a box
    with centre :math:`m` and half-widths :math:`h`, exactly :math:`\varphi(m + e) =
    \varphi(m) + g^T e + e^T H e + C(e, e, e)` with :math:`g = \nabla \varphi(m)`,
    :math:`H = Q + 3 C(m, \cdot, \cdot)`, so :math:`\varphi \le \varphi(m) + |g|^T h +
    \sum_{a \ne b} |H_{ab}| h_a h_b + \sum_a \max(H_{aa}, 0) h_a^2 + \sum_t |c_t| h_a h_b
    h_e`; the box of the largest bound is halved along its widest side until that bound
    is within ``rtol`` times :math:`\sum |l| + \sum |q| + \sum |c|` of the best centre
    value or ``max_boxes`` are split. Every bound is inflated by :math:`\max(10^{-12}, 16
    K^3 u)` times that sum (the float evaluation's rounding is at most :math:`8 K^3 u` of
    it)."""
    K = lin.shape[0]
    scale = float(np.abs(lin).sum() + np.abs(quad).sum() + np.abs(cub).sum())
    if scale == 0.0:
        return 0.0
    slack = max(1e-12, 16 * K ** 3 * _U) * scale
    Q = np.zeros((K, K))
    for k, (a, b) in enumerate(pairs(K)):
        Q[a, b] += 0.5 * quad[k]
        Q[b, a] += 0.5 * quad[k]
    C = np.zeros((K, K, K))
    for k, t in enumerate(triples(K)):
        perms = set(itertools.permutations(t))
        for p in perms:
            C[p] += cub[k] / len(perms)
    absC = np.abs(C)

    def bound(m: Matrix, h: Matrix) -> tuple[float, float]:
        Cm = np.einsum("abc,c->ab", C, m)
        value = float(lin @ m + m @ Q @ m + m @ Cm @ m)
        g = lin + 2.0 * Q @ m + 3.0 * Cm @ m
        H = Q + 3.0 * Cm
        off = np.abs(H - np.diag(np.diag(H)))
        cubic = float(np.einsum("abc,a,b,c->", absC, h, h, h))
        return value + float(np.abs(g) @ h + h @ off @ h + np.maximum(np.diag(H), 0.0) @ (h * h)) + cubic + slack, value

    return box_maximum(bound, K, max_boxes, rtol * scale)


def _cubic_residual(Tl: Matrix, Tq: Matrix, Tt: Matrix, e: Expansion, g: float) -> tuple[Matrix, Matrix, Matrix]:
    """``(lam_t, H, err)``: the eigenvalue's coefficients :math:`\\lambda_t`, the float
    products :math:`R g_t` (columns, ``N + 1`` rows) and a bound of their errors
    (summed over ``t``), module docstring."""
    N, K = Tl.shape[1], Tl.shape[0]
    v0, lam_l, Vl, lam_q, Vq = e.v0, e.lam_l, e.Vl, e.lam_q, e.Vq
    av0, aVl, aVq = np.abs(v0), np.abs(Vl), np.abs(Vq)
    Ry = e.R[:, :N]
    index = {p: k for k, p in enumerate(pairs(K))}
    cols, mags = [], np.zeros(N)
    for k, t in enumerate(triples(K)):
        c = Tt[k] @ v0
        m = np.abs(Tt[k]) @ av0
        for i in sorted(set(t)):
            rest = list(t)
            rest.remove(i)
            p = index[(rest[0], rest[1])]
            c = c + Tl[i] @ Vq[p] - lam_l[i] * Vq[p] + Tq[p] @ Vl[i] - lam_q[p] * Vl[i]
            m = m + np.abs(Tl[i]) @ aVq[p] + abs(lam_l[i]) * aVq[p] + np.abs(Tq[p]) @ aVl[i] + abs(lam_q[p]) * aVl[i]
        cols.append(c)
        mags = mags + m
    G = np.stack(cols, axis=1)
    first = Ry @ G
    lam_t = -first[N]  # cancels the last entry of R g_t (any float would do)
    G = G - np.outer(v0, lam_t)
    mags = mags + av0 * float(np.abs(lam_t).sum())
    H = Ry @ G
    err = g * (np.abs(Ry) @ (np.abs(G).sum(axis=1) + mags))
    return np.asarray(lam_t, dtype=np.float64), H, _up(err, 2 * N + 30)


def _parts(form: tuple[Matrix, ...], e: Expansion) -> tuple[Matrix, Matrix, Matrix, Matrix]:
    """``(lam_t, base, L, aS)``: the eigenvalue's third-order coefficients, upper bounds of
    :math:`|S G(0)|`, of the Lipschitz matrix's linear part and of :math:`|S_y|` over the
    sub-box and the form's set (module docstring)."""
    Tc, Tl, Tq, Tt, Tr = form
    N, K = Tc.shape[0], Tl.shape[0]
    P, T3 = len(pairs(K)), len(triples(K))
    u = _U
    g = 1.01 * (N + 8) * u + 12 * u
    Ry = e.R[:, :N]
    aRy = np.abs(Ry)
    lam_l, Vl, lam_q, Vq = e.lam_l, e.Vl, e.lam_q, e.Vq
    aVl, aVq = np.abs(Vl), np.abs(Vq)
    sVl, sVq = aVl.sum(axis=0), aVq.sum(axis=0)
    low = _up(low_residual(Tc, Tl, Tq, e, g), 2 * N + 30)
    lam_t, H, err3 = _cubic_residual(Tl, Tq, Tt, e, g)
    slt, sll, slq = float(np.abs(lam_t).sum()), float(np.abs(lam_l).sum()), float(np.abs(lam_q).sum())
    sTl, sTq, sTt = np.abs(Tl).sum(axis=0), np.abs(Tq).sum(axis=0), np.abs(Tt).sum(axis=0)
    RTq = [Ry @ Tq[k] - lam_q[k] * Ry for k in range(P)]
    RTt = [Ry @ Tt[k] for k in range(T3)]
    RVl, RVq = Ry @ Vl.T, Ry @ Vq.T
    # degrees 4 and 5, E v~, the lambda_t (v~ - v0) terms: by absolute values, with rounding
    high = sum(np.abs(x @ Vq.T).sum(axis=1) for x in RTq) + sum(np.abs(x @ Vl.T).sum(axis=1) + np.abs(x @ Vq.T).sum(axis=1) for x in RTt)
    high = high + slt * (np.abs(RVl).sum(axis=1) + np.abs(RVq).sum(axis=1) + g * (aRy @ (sVl + sVq)))
    high = high + 2 * g * (aRy @ ((sTq + sTt + slq * np.eye(N)) @ (sVl + sVq))) + aRy @ (Tr @ (np.abs(e.v0) + sVl + sVq))
    high = _up(high, 2 * N + P * P + 2 * T3 * P + 30) + (P + T3 + 4) * N * _ETA
    # the preconditioner's F_a and the bound of |R M_a - F_a|, summed over a
    F = np.empty((K, N + 1, N + 1))
    for a in range(K):
        F[a, :, :N] = Ry @ Tl[a] - lam_l[a] * Ry
        F[a, :, N] = -(Ry @ Vl[a])
    aF = np.abs(F)
    sF = aF.sum(axis=0)
    sE = np.zeros((N + 1, N + 1))
    sE[:, :N] = g * (aRy @ sTl + sll * aRy) + 2 * u * sF[:, :N]
    sE[:, N] = g * (aRy @ sVl)
    sE = _up(sE, 2 * N + 8) + N * _ETA
    # |S G(0)|: R G(0) and the F_a R G(0), the degree-3 part by product before the absolute value
    FH = np.abs(np.einsum("aij,jt->ait", F, H)).sum(axis=(0, 2))
    b3 = np.abs(H).sum(axis=1) + err3
    base = low + b3 + high + FH + g * (sF @ np.abs(H).sum(axis=1)) + sF @ (err3 + low + high)
    base = _up(base, 2 * N + K * T3 + 40) + (K + T3 + 4) * (N + 1) * _ETA
    # the linear part of the Lipschitz matrix
    aR = np.abs(e.R)
    C = _up(np.abs(np.eye(N + 1) - e.R @ e.M) + (1.01 * (N + 2) * u) * (aR @ np.abs(e.M) + np.eye(N + 1)), N + 6)
    Lq = np.zeros((N + 1, N + 1))
    Lq[:, :N] = sum(np.abs(x) for x in RTq) + sum(np.abs(x) for x in RTt) + slt * aRy + aRy @ Tr
    Lq[:, :N] += 2 * g * (aRy @ (sTq + sTt + slq * np.eye(N)))
    Lq[:, N] = np.abs(RVq).sum(axis=1) + g * (aRy @ sVq)
    Lq = _up(Lq, 2 * N + P + T3 + 12) + N * _ETA
    second = np.zeros((N + 1, N + 1))
    for a, b in pairs(K):
        second += np.abs(F[a] @ F[a]) if a == b else np.abs(F[a] @ F[b] + F[b] @ F[a])
    g1 = 1.01 * (N + 4) * u + 4 * u
    L = C + sE + sF @ C + Lq + second + g1 * (sF @ sF) + sF @ sE + sF @ Lq
    L = _up(L, 3 * N + 2 * P + 40) + (P + 8) * (N + 1) * _ETA
    aS = _up(aRy + sF @ aRy, N + 8) + N * _ETA
    return lam_t, base, L, aS


def cubic_radius_bound(form: tuple[Matrix, ...], states: int, r: int) -> CubicBound:
    r"""An upper bound of :math:`\rho(T(\delta))` over every :math:`\delta \in [-1,
    1]^K` of the third-order form ``form`` (``(Tc, Tl, Tq, Tt, Tr)``,
    :func:`~ftc_verify.analysis.moments.cubic_balls.cubic_terms`), proved by the
    enclosure of the module docstring, with the enclosure's reach.

    Precondition (the proof's, not checked): as
    :func:`~ftc_verify.analysis.moments.sampled_eigen.eigen_radius_bound`'s, the form
    encloses a continuous map, positive on the cone of ``states`` stacked ``r x r``
    positive semidefinite blocks (``N = states r (r + 1) / 2`` rows, checked)."""
    Tc, Tl, Tq, _, Tr = form
    N = Tc.shape[0]
    if N != states * r * (r + 1) // 2:
        raise ValueError(f"a form of {N} rows is not a stack of {states} blocks of {r} x {r}")
    e = expansion(Tc, Tl, Tq)
    if e is None:
        return CubicBound(None, None)
    with np.errstate(over="ignore", invalid="ignore"):
        lam_t, base, L, aS = _parts(form, e)
    finite = bool(np.all(np.isfinite(L)) and np.all(np.isfinite(base)))
    reach = float(np.max(np.abs(np.linalg.eigvals(L)))) if finite else math.inf
    def step(z: Matrix, quad: float) -> Matrix:
        return _up(L @ z + quad * float(z[N]) * (aS @ z[:N]), 2 * N + 8)

    z = fixed_box(base, step) if finite else None
    if z is None or not centre_in_cone(Tc, Tr, e, z, states, r):
        return CubicBound(None, reach)
    top = e.lam0 + cubic_max(e.lam_l, e.lam_q, lam_t) + float(z[N])
    return CubicBound(top * (1 + 4 * _U) if math.isfinite(top) else None, reach)
