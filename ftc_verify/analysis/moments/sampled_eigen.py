r"""A stability proof of the sampled loop on a rate sub-box by an enclosure of the
one-period map's Perron eigenpair.

The certificates of :mod:`~ftc_verify.analysis.moments.sampled_taylor` and
:mod:`~ftc_verify.analysis.moments.sampled_second` prove :math:`Y(\delta) - T(\delta)
Y(\delta) \succ 0`: every remainder of the enclosure of :math:`T` is held, entry by
entry, against a margin of about :math:`(1 - \rho)` times the smallest eigenvalue of a
joint state's block of the certificate. Near the period where the loop loses stability
the Perron stack's blocks are far from isotropic, and the sub-boxes must be tiny.
Here the remainders meet the margin mainly through a weighted sum (the left Perron
vector; the rest of the eigenvector's enclosure enters scaled by the inverse spectral
gap), and the eigenvector is needed inside the cone at the sub-box's centre only.

**The form.** :func:`~ftc_verify.analysis.moments.quad_balls.quad_map` encloses the
map over the sub-box, :math:`\delta \in [-1, 1]^K` its scaled rates,
:math:`\mu_p = \delta_a \delta_b` (:math:`p = (a, b)`, :math:`a \le b`):

.. math::

    T(\delta) \in T_c + \sum_a \delta_a T_a + \sum_p \mu_p T_p + E, \qquad |E| \le T_r.

**Float choices.** :math:`\lambda_0, v_0, w_0`: the Perron eigenvalue and right and left
vectors of :math:`T_c`; :math:`R \approx M^{-1}` with the bordered matrix
:math:`M = \begin{bmatrix} T_c - \lambda_0 I & -v_0 \\ w_0^T & 0 \end{bmatrix}`; the
perturbation expansion :math:`\tilde\lambda(\delta) = \lambda_0 + \sum_a \delta_a
\lambda_a + \sum_p \mu_p \lambda_p`, :math:`\tilde v(\delta) = v_0 + \sum_a \delta_a v_a
+ \sum_p \mu_p v_p` from :math:`(v_a, \lambda_a) = R (-T_a v_0, 0)`, :math:`(v_p,
\lambda_p) = R (-g_p, 0)`, :math:`g_p = T_p v_0 + T_a v_b + T_b v_a - \lambda_a v_b -
\lambda_b v_a` (:math:`a \ne b`; :math:`T_p v_0 + T_a v_a - \lambda_a v_a` when
:math:`a = b`): the coefficients of :math:`\delta_a` and :math:`\mu_p` in :math:`T v =
\lambda v`. Whatever these floats are, the proof below checks them.

**Enclosure** (derived here). Fix :math:`\delta` and any :math:`T` of the form's set
(the exact map at :math:`\delta` is one). Write an eigenpair as :math:`(\tilde\lambda +
\mu, \tilde v + y)` with :math:`w_0^T y = 0`: with :math:`z = (y, \mu)`,

.. math::

    G(z) = \begin{bmatrix} (T - \tilde\lambda - \mu)(\tilde v + y) \\ w_0^T y
    \end{bmatrix} = G(0) + M z + \begin{bmatrix} (T - T_c - (\tilde\lambda - \lambda_0))
    y - \mu (\tilde v - v_0) - \mu y \\ 0 \end{bmatrix},

and :math:`\Phi(z) = z - R G(z)` satisfies, for :math:`|y| \le \zeta_y`,
:math:`|\mu| \le \zeta_\mu`,

.. math::

    |\Phi(z)| \le b + |I - R M| \zeta + \Lambda \zeta_y + \zeta_\mu m
    + \zeta_\mu |R_y| \zeta_y,

with :math:`b \ge |R\, G(0)|`, :math:`\Lambda = \sum_a |R_y (T_a - \lambda_a I)| +
\sum_p |R_y (T_p - \lambda_p I)| + |R_y| T_r` and :math:`m = \sum_a |R_y v_a| + \sum_p
|R_y v_p|` (:math:`R_y` the first :math:`N` columns of :math:`R`; :math:`T - T_c -
(\tilde\lambda - \lambda_0) = \sum_a \delta_a (T_a - \lambda_a) + \sum_p \mu_p (T_p -
\lambda_p) + E`; the products with :math:`R` are formed before the absolute values, so
that a transfer of mass between joint states cancels in them). :math:`G(0) = (T -
\tilde\lambda)\tilde v` is the float solves' residuals at degrees 0, 1, 2 (computed, with
their rounding), the terms of degree 3 and 4 (:math:`\delta_a \mu_p ((T_a - \lambda_a)
v_p + (T_p - \lambda_p) v_a)`, :math:`\mu_p \mu_q (T_p - \lambda_p) v_q`, each bounded
after its product with :math:`R`) and :math:`E \tilde v`. Likewise :math:`|\Phi(z) -
\Phi(z')| \le L |z - z'|` entrywise with the nonnegative matrix

.. math::

    L = |I - R M| + \begin{bmatrix} \Lambda + \zeta_\mu |R_y| & m + |R_y| \zeta_y
    \end{bmatrix}, \qquad L \zeta = |I - RM| \zeta + \Lambda \zeta_y + \zeta_\mu m
    + 2 \zeta_\mu |R_y| \zeta_y

(columns of :math:`y` and of :math:`\mu`; from :math:`\mu y - \mu' y' = \mu (y - y') +
(\mu - \mu') y'`); :math:`L \ge |I - R\, DG(z)|` on the box, :math:`DG` the Jacobian of
:math:`G`. If the first bound is below :math:`\zeta` and :math:`L\zeta < \zeta` in every
entry (:math:`\zeta > 0`), then :math:`\rho(L) < 1` (Collatz-Wielandt), :math:`\Phi` maps
the box :math:`|z| \le \zeta` into itself and is a contraction there (in the norm
:math:`\max_i |z_i| / \zeta_i`): one fixed point. :math:`R\, DG(z)` is nonsingular, so
:math:`R` is, the fixed point solves :math:`G = 0`, and the bordered Jacobian
:math:`DG = \begin{bmatrix} T - \lambda & -v \\ w_0^T & 0 \end{bmatrix}` is nonsingular
there, which makes :math:`\lambda` an algebraically simple eigenvalue (a second
eigenvector, or a Jordan chain, would give a null vector of :math:`DG`). So every map of
the set has exactly one eigenpair :math:`(\lambda(\delta), v(\delta))` in the box, with
:math:`|\lambda(\delta) - \tilde\lambda(\delta)| \le \zeta_\mu`.

**Stable** (derived here). :math:`T(\delta)` is a positive map, so its spectral radius
:math:`\rho(\delta)` is an eigenvalue (with an eigenvector in the cone), continuous in
:math:`\delta`, as is :math:`\lambda(\delta)` (the unique fixed point of a contraction
that depends continuously on :math:`\delta`). The set of :math:`\delta` where
:math:`\rho(\delta) = \lambda(\delta)` is closed, and open: near such a
:math:`\delta_0` the simple eigenvalue :math:`\lambda(\delta_0)` is the only eigenvalue
of :math:`T(\delta)` near :math:`\rho(\delta_0)`, so the eigenvalue :math:`\rho(\delta)`
is :math:`\lambda(\delta)`. At :math:`\delta = 0` it holds: the same enclosure without the
rates' terms gives :math:`\zeta^0 \le \zeta` (so the same eigenpair) and every stack
:math:`v_0 + y`, :math:`|y| \le \zeta^0_y`, positive definite in every joint state (the
ball proof of :func:`~ftc_verify.analysis.moments.sampled_taylor.stack_pd`, for every
symmetric matrix of the ball): an eigenvector inside the
cone, whose eigenvalue is the spectral radius (every stack lies below a multiple of it).
The box being connected, :math:`\rho(\delta) = \lambda(\delta) \le \lambda_0 +
\max_\delta (\sum_a \delta_a \lambda_a + \sum_p \mu_p \lambda_p) + \zeta_\mu` for every
:math:`\delta` (:func:`~ftc_verify.analysis.moments.sampled_second.quadratic_max`); below
one, the loop is mean-square stable at every rate array of the sub-box.

Every float operation's rounding is bounded as in
:mod:`~ftc_verify.analysis.moments.fast_balls` (Higham: :math:`1.01\, k u` per inner
product of length :math:`k`) and every bound rounded up.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any

import numpy as np

from ...model.system import Matrix
from .fast_balls import up_bound as _up
from .quad_balls import pairs
from .sampled import SampledLoop
from .sampled_second import quadratic_max
from .sampled_taylor import float_pd, stack_pd

__all__ = ["Expansion", "expansion", "eigen_stable", "eigen_radius_bound", "enclosure_reach", "centre_in_cone", "fixed_box", "low_residual", "EIGEN_ITERATIONS"]

_U = 2.0 ** -53
_ETA = 2.0 ** -1022

#: Most rounds of the iteration that looks for the enclosure's radius :math:`\zeta`.
EIGEN_ITERATIONS = 40


def _perron(Tc: Matrix) -> tuple[float, Matrix, Matrix] | None:
    """``(lambda_0, v_0, w_0)`` of the module docstring (float64), ``w_0 . v_0 = 1``;
    ``None`` when the dominant eigenvalue is not real and positive."""
    try:
        ev, V = np.linalg.eig(Tc)
        ew, W = np.linalg.eig(Tc.T)
    except np.linalg.LinAlgError:
        return None
    k = int(np.argmax(np.abs(ev)))
    if not (abs(ev[k].imag) <= 1e-9 * abs(ev[k]) and ev[k].real > 0):
        return None
    lam = float(ev[k].real)
    v = np.real(V[:, k])
    v = v / (v[np.argmax(np.abs(v))])
    j = int(np.argmin(np.abs(ew - lam)))
    w = np.real(W[:, j])
    s = float(w @ v)
    if not (np.all(np.isfinite(v)) and np.all(np.isfinite(w)) and s != 0.0):
        return None
    return lam, np.asarray(v, dtype=np.float64), np.asarray(w / s, dtype=np.float64)


@dataclasses.dataclass(frozen=True, eq=False)
class Expansion:
    r"""The float choices of the module docstring: the Perron triple ``lam0, v0, w0`` of
    :math:`T_c`, the bordered matrix ``M`` (as computed) and ``R``, the coefficients
    ``lam_l`` (``K``), ``Vl`` (``K x N``) of :math:`\delta_a` and ``lam_q``, ``Vq`` of
    :math:`\mu_p`."""

    lam0: float
    v0: Matrix
    w0: Matrix
    M: Matrix
    R: Matrix
    lam_l: Matrix
    Vl: Matrix
    lam_q: Matrix
    Vq: Matrix

    def centre(self) -> Expansion:
        """The same choices without the rates' terms (the sub-box's centre alone)."""
        N = self.v0.shape[0]
        return dataclasses.replace(self, lam_l=np.zeros(0), Vl=np.zeros((0, N)), lam_q=np.zeros(0),
                                   Vq=np.zeros((0, N)))


def expansion(Tc: Matrix, Tl: Matrix, Tq: Matrix) -> Expansion | None:
    """The float choices of the module docstring (``None`` when a step fails)."""
    found = _perron(Tc)
    if found is None:
        return None
    lam0, v0, w0 = found
    N, K = Tc.shape[0], Tl.shape[0]
    M = np.zeros((N + 1, N + 1))
    M[:N, :N] = Tc - lam0 * np.eye(N)
    M[:N, N] = -v0
    M[N, :N] = w0
    try:
        R = np.linalg.inv(M)
    except np.linalg.LinAlgError:
        return None
    sol = R[:, :N] @ (-np.einsum("aij,j->ia", Tl, v0))
    Vl, lam_l = sol[:N].T.copy(), sol[N].copy()
    rhs = []
    for k, (a, b) in enumerate(pairs(K)):
        g = Tq[k] @ v0 if Tq.shape[0] else np.zeros(N)
        if a == b:
            g = g + Tl[a] @ Vl[a] - lam_l[a] * Vl[a]
        else:
            g = g + Tl[a] @ Vl[b] + Tl[b] @ Vl[a] - lam_l[a] * Vl[b] - lam_l[b] * Vl[a]
        rhs.append(-g)
    sol = R[:, :N] @ np.stack(rhs, axis=1) if rhs else np.zeros((N + 1, 0))
    Vq, lam_q = sol[:N].T.copy(), sol[N].copy()
    out = Expansion(lam0, v0, w0, M, R, lam_l, Vl, lam_q, Vq)
    return out if all(np.all(np.isfinite(x)) for x in dataclasses.astuple(out)) else None


def low_residual(Tc: Matrix, Tl: Matrix, Tq: Matrix, e: Expansion, g: float) -> Matrix:
    r"""An upper bound (before rounding up) of :math:`|R_y r|` summed over the
    coefficients :math:`r` of :math:`G(0)` of degrees 0, 1 and 2 (module docstring): the
    float residuals' products with :math:`R_y`, plus ``g`` (a rounding factor covering
    inner products of length ``N``) times their magnitudes; ``Tq`` may be empty."""
    N, K = Tc.shape[0], Tl.shape[0]
    lam0, v0, lam_l, Vl, lam_q, Vq = e.lam0, e.v0, e.lam_l, e.Vl, e.lam_q, e.Vq
    aTc, av0, aVl, aVq = np.abs(Tc), np.abs(v0), np.abs(Vl), np.abs(Vq)
    res = [Tc @ v0 - lam0 * v0]
    mag = aTc @ av0 + abs(lam0) * av0
    for a in range(K):
        res.append(Tc @ Vl[a] + Tl[a] @ v0 - lam0 * Vl[a] - lam_l[a] * v0)
        mag = mag + aTc @ aVl[a] + np.abs(Tl[a]) @ av0 + abs(lam0) * aVl[a] + abs(lam_l[a]) * av0
    for k, (a, b) in enumerate(pairs(K)):
        q = Tc @ Vq[k] - lam0 * Vq[k] - lam_q[k] * v0
        m = aTc @ aVq[k] + abs(lam0) * aVq[k] + abs(lam_q[k]) * av0
        if Tq.shape[0]:
            q = q + Tq[k] @ v0
            m = m + np.abs(Tq[k]) @ av0
        for x, y in (((a, b), (b, a)) if a != b else ((a, a),)):
            q = q + Tl[x] @ Vl[y] - lam_l[x] * Vl[y]
            m = m + np.abs(Tl[x]) @ aVl[y] + abs(lam_l[x]) * aVl[y]
        res.append(q)
        mag = mag + m
    Ry = e.R[:, :N]
    stack = np.stack(res, axis=1)
    return np.abs(Ry @ stack).sum(axis=1) + g * (np.abs(Ry) @ (np.abs(stack).sum(axis=1) + mag))


def _parts(Tc: Matrix, Tl: Matrix, Tq: Matrix, Tr: Matrix, e: Expansion) -> tuple[Matrix, Matrix, Matrix]:
    r"""``(base, lin, mu)``: upper bounds of :math:`|R\, (G(0), 0)|`, of the matrix
    :math:`\sum_a |R_y (T_a - \lambda_a I)| + \sum_p |R_y (T_p - \lambda_p I)| + |R_y| T_r`
    (which bounds :math:`|R_y (T - T_c - (\tilde\lambda - \lambda_0)) y|` by its product
    with :math:`|y|`) and of :math:`\sum_a |R_y v_a| + \sum_p |R_y v_p|`
    (:math:`R_y` the first ``N`` columns of :math:`R`), over the sub-box and the form's
    set (module docstring). The products with :math:`R` are formed before the absolute
    values (a transfer of mass between joint states cancels in them), each with its
    rounding."""
    u, N, K = _U, Tc.shape[0], Tl.shape[0]
    prs = pairs(K)
    P = len(prs)
    v0, lam_l, Vl, lam_q, Vq = e.v0, e.lam_l, e.Vl, e.lam_q, e.Vq
    Ry = e.R[:, :N]
    aRy = np.abs(Ry)
    av0, aVl, aVq = np.abs(v0), np.abs(Vl), np.abs(Vq)
    g = 1.01 * N * u + 12 * u
    RT = [Ry @ Tl[a] - lam_l[a] * Ry for a in range(K)]
    RT += [(Ry @ Tq[k] if Tq.shape[0] else 0.0) - lam_q[k] * Ry for k in range(P)]
    base = low_residual(Tc, Tl, Tq, e, g)
    # the degrees 3 and 4: delta_a mu_p (T_a - lam_a) v_p + (T_p - lam_p) v_a, mu_p mu_q (T_p - lam_p) v_q
    hi = np.zeros(N + 1)
    for a in range(K):
        hi += np.abs(RT[a] @ Vq.T).sum(axis=1)
    for k in range(P):
        hi += np.abs(RT[K + k] @ Vl.T).sum(axis=1) + np.abs(RT[K + k] @ Vq.T).sum(axis=1)
    sTl = np.abs(Tl).sum(axis=0)
    sTq = np.abs(Tq).sum(axis=0) if Tq.shape[0] else np.zeros_like(Tc)
    sll, slq = float(np.abs(lam_l).sum()), float(np.abs(lam_q).sum())
    sVl, sVq = aVl.sum(axis=0), aVq.sum(axis=0)
    mags = aRy @ ((sTl + sTq + (sll + slq) * np.eye(N)) @ (sVl + sVq))
    base = base + hi + 2 * g * mags + aRy @ (Tr @ (av0 + sVl + sVq))
    base = _up(base, 2 * N + K * P + P * P + 30) + (K + P + 4) * N * _ETA
    lin = sum(np.abs(x) for x in RT) + aRy @ Tr
    lin = lin + 2 * g * aRy @ (sTl + sTq + (sll + slq) * np.eye(N))
    lin = _up(lin, 2 * N + K + P + 8) + N * _ETA
    mu = np.abs(Ry @ Vl.T).sum(axis=1) + np.abs(Ry @ Vq.T).sum(axis=1) + 2 * g * aRy @ (sVl + sVq)
    return base, lin, _up(mu, 2 * N + K + P + 8) + N * _ETA


def _enclosure(Tc: Matrix, Tl: Matrix, Tq: Matrix, Tr: Matrix, e: Expansion) -> Matrix | None:
    r""":math:`\zeta` of the module docstring (``N + 1`` entries, the last one
    :math:`\zeta_\mu`) with :math:`\Phi` mapping the box :math:`|z| \le \zeta` into
    itself and contracting on it, for every :math:`\delta` and every map of the form's
    set; ``None`` when none is found in :data:`EIGEN_ITERATIONS` rounds."""
    u, N = _U, Tc.shape[0]
    R, Mf = e.R, e.M
    aR = np.abs(R)
    C = _up(np.abs(np.eye(N + 1) - R @ Mf) + (1.01 * (N + 2) * u) * (aR @ np.abs(Mf) + np.eye(N + 1)), N + 6)
    base, lin, mu = _parts(Tc, Tl, Tq, Tr, e)
    aRy = aR[:, :N]

    def step(z: Matrix, quad: float) -> Matrix:
        zy, zm = z[:N], float(z[N])
        return _up(C @ z + lin @ zy + zm * mu + quad * zm * (aRy @ zy), 2 * N + 8)

    return fixed_box(base, step)


def fixed_box(base: Matrix, step: Callable[[Matrix, float], Matrix]) -> Matrix | None:
    r"""The enclosure's radius :math:`\zeta` by iteration from ``base`` (an upper bound of
    :math:`|\Phi(0)|`): on the box :math:`|z| \le` ``z``, ``step(z, 1)`` bounds
    :math:`|\Phi(z) - \Phi(0)|` and ``step(z, 2)`` bounds :math:`L z`, :math:`L` a
    Lipschitz matrix of :math:`\Phi`; returned once ``base + step(z, 1)
    < z`` (into itself) and ``step(z, 2) < z`` (Lipschitz with a matrix of radius below
    one) in every entry, each round inflating ``z`` by 5 %; ``None`` after
    :data:`EIGEN_ITERATIONS` rounds or an overflow."""
    z = base + 1e-300
    with np.errstate(over="ignore", invalid="ignore"):
        for _ in range(EIGEN_ITERATIONS):
            nz = _up(base + step(z, 1.0), 1)
            if np.all(nz < z) and np.all(step(z, 2.0) < z):
                return z
            z = np.maximum(nz, z) * 1.05 + 1e-300
            if not np.all(np.isfinite(z)):
                return None
    return None


def eigen_radius_bound(form: tuple[Matrix, ...], states: int, r: int) -> float | None:
    r"""An upper bound of :math:`\rho(T(\delta))` over every :math:`\delta \in [-1,
    1]^K` of the form ``form`` (``(Tc, Tl, Tq, Tr)``,
    :func:`~ftc_verify.analysis.moments.quad_balls.quad_map`; an affine ``(Tc, Tl, Tr)``
    too), proved by the eigenpair enclosure of the module docstring, or ``None``.

    Precondition (the proof's, not checked): the form encloses, at each :math:`\delta`, a
    map :math:`T(\delta)` that is continuous in :math:`\delta` and positive on the cone
    of ``states`` stacked ``r x r`` positive semidefinite blocks (``vech``, ``N = states
    r (r + 1) / 2`` rows, checked) -- as the one-period map of a sampled loop is; for
    other maps the number returned bounds nothing."""
    if len(form) == 3:
        Tc, Tl, Tr = form
        Tq = np.zeros((0,) + Tc.shape)
    else:
        Tc, Tl, Tq, Tr = form
    N = Tc.shape[0]
    if N != states * r * (r + 1) // 2:
        raise ValueError(f"a form of {N} rows is not a stack of {states} blocks of {r} x {r}")
    e = expansion(Tc, Tl, Tq)
    if e is None:
        return None
    z = _enclosure(Tc, Tl, Tq, Tr, e)
    if z is None or not centre_in_cone(Tc, Tr, e, z, states, r):
        return None
    phi = quadratic_max(e.lam_l, e.lam_q)
    top = e.lam0 + phi + float(z[N])
    return top * (1 + 4 * _U) if math.isfinite(top) else None


def centre_in_cone(Tc: Matrix, Tr: Matrix, e: Expansion, z: Matrix, states: int, r: int) -> bool:
    r"""The enclosure's step at the sub-box's centre (module docstring, "Stable"): the
    same choices without the rates give :math:`\zeta^0 \le \zeta` (``z``) for the maps
    :math:`T_c + E`, :math:`|E| \le T_r`, and every stack :math:`v_0 + y`, :math:`|y| \le
    \zeta^0_y`, is positive definite in every joint state (proved in ball arithmetic)."""
    N = Tc.shape[0]
    empty = np.zeros((0, N, N))
    z0 = _enclosure(Tc, empty, empty, Tr, e.centre())
    if z0 is None or not np.all(z0 <= z):
        return False
    flint = _flint()
    arb = flint.arb
    yrad = _up(z0[:N], 1)
    return bool(float_pd(e.v0, states, r)
                and stack_pd(flint.arb_mat(N, 1, [arb(float(x), float(q)) for x, q in zip(e.v0, yrad)]), states, r))


def enclosure_reach(form: tuple[Matrix, ...]) -> float | None:
    r"""A float estimate (not a bound) of how far the enclosure of
    :func:`eigen_radius_bound` is from succeeding on ``form`` (``(Tc, Tl, Tq, Tr)``):
    the spectral radius of the linear part of its Lipschitz matrix :math:`L` (the
    enclosure needs :math:`\rho(L) < 1`, whatever the margin); ``None`` when the
    expansion fails. It shrinks as the sub-box does, by 0.6-0.9 per halving on the
    sub-boxes of held-out seed 31 (``benchmarks/results/split16.md``), where no sub-box
    with a parent above 0.56 was proved by the second-order form; on seed 13's box, away
    from the worst vertex, it stays above 1 for 13 halvings and no form proves a sub-box
    there. The ``h_max`` cover uses it to decide where to compute a form at all
    (:func:`~ftc_verify.analysis.moments.sampled_cover.cover_box`)."""
    Tc, Tl, Tq, Tr = form
    e = expansion(Tc, Tl, Tq)
    if e is None:
        return None
    N = Tc.shape[0]
    _, lin, mu = _parts(Tc, Tl, Tq, Tr, e)
    L = np.abs(np.eye(N + 1) - e.R @ e.M)
    L[:, :N] += lin
    L[:, N] += mu
    return float(np.max(np.abs(np.linalg.eigvals(L)))) if np.all(np.isfinite(L)) else None


def eigen_stable(loop: SampledLoop, form: tuple[Matrix, ...]) -> bool:
    r"""``True`` only if :math:`\rho(T(\delta)) < 1` is proved for every
    :math:`\delta \in [-1, 1]^K` of the form ``form`` (:func:`eigen_radius_bound`)."""
    top = eigen_radius_bound(form, loop.states, loop.r)
    return top is not None and top < 1.0


def _flint() -> Any:
    import flint

    return flint
