r"""A second-order stability certificate of the sampled loop on a rate sub-box: one
positive-definiteness check, limited by the curvature of :math:`\rho`, not of :math:`T`.

:func:`~ftc_verify.analysis.moments.sampled_taylor.affine_stable` encloses the one-period
map over a sub-box as a form in the sub-box's symbols :math:`\delta \in [-1, 1]^K`
(:math:`r = r_0 + \sum_a \delta_a w_a e_a`),

.. math::

    T(\delta) \in T_c + \sum_a \delta_a T_a + \sum_p \mu_p T_p + E, \qquad
    p = (a, b),\ a \le b,\ \mu_p = \delta_a \delta_b,\ |E| \le T_r

(``quad_map``; an affine form is the case :math:`T_p = 0`, its second-order terms in
:math:`T_r`). Its first-order certificate :math:`Y_0 + \sum_a \delta_a y_a` bounds the
terms :math:`\delta_a \delta_b T_a y_b` in absolute value, and checks the
:math:`2^K` vertices: where :math:`T` moves second moments between joint states (a
large second-order change of :math:`T` with a small one of :math:`\rho`) the sub-box
must be small. Here (derived):

**Certificate.** With :math:`(I - T_c) Y_0 = b` (:func:`~ftc_verify.analysis.moments.sampled_taylor.float_choices`:
``b`` the identity stack or the Perron-aligned one), :math:`(I - T_c) y_a = T_a Y_0 -
c_a Y_0` and

.. math::

    (I - T_c)\, y_p = g_p - c_p Y_0, \qquad g_p = T_p Y_0 + T_a y_b + [a \ne b]\, T_b y_a,
    \qquad c = \langle w, \cdot\rangle / \langle w, Y_0\rangle

(:math:`w` the left Perron vector of :math:`T_c`; float choices), take
:math:`Y(\delta) = Y_0 + \sum_a \delta_a y_a + \sum_p \mu_p y_p`. Expanding
:math:`T(\delta) Y(\delta)` and collecting powers of :math:`\delta`,

.. math::

    Y - T Y = b' - \varphi(\delta)\, Y_0 + \sum_a \delta_a r_a + \sum_p \mu_p r_p - C - E Y,
    \qquad \varphi(\delta) = \sum_a c_a \delta_a + \sum_p c_p \mu_p,

with :math:`b' = Y_0 - T_c Y_0`, :math:`r_a = L_a + c_a Y_0`, :math:`L_a = y_a - T_c y_a
- T_a Y_0`, :math:`r_p = L_p + c_p Y_0`, :math:`L_p = y_p - T_c y_p - g_p` (the
residuals of the float solves: :math:`c` is *any* float here, the identities are exact
by definition of :math:`r`), and :math:`C` the terms of degree three and four,
:math:`|C| \le S(T_a) S(y_p) + S(T_p) S(y_a) + S(T_p) S(y_p)` (:math:`S` the sum of
absolute values over the index; :math:`|\delta_a|, |\mu_p| \le 1`).

**Check.** :math:`\varphi` is a scalar quadratic; :func:`quadratic_max` bounds its
maximum over the box from above, :math:`\varphi \le \varphi_{hi}`. If :math:`Y_0`
and, at every vertex :math:`\delta \in \{-1, 1\}^K`, the ball :math:`Y_0 + \sum_a
\delta_a y_a \pm S(y_p)` are proved positive definite per joint state, then
:math:`Y(\delta) \succ 0` for every :math:`\delta` of the box (convex combinations)
and :math:`-\varphi(\delta) Y_0 \succeq -\varphi_{hi} Y_0`. So if the ball
:math:`b' - \varphi_{hi} Y_0 \pm (S(r_a) + S(r_p) + |C| + T_r |Y|)` (with the rounding
of every float operation, Higham's bound as in
:mod:`~ftc_verify.analysis.moments.fast_balls`) is proved positive definite per joint
state, :math:`Y(\delta) - T(\delta) Y(\delta) \succ 0` on the whole sub-box and
:math:`\rho(T(r)) < 1` for every rate of it (the cone argument of
:mod:`~ftc_verify.analysis.moments.sampled_proof`). Since :math:`b' \approx v + k I`
and :math:`Y_0 \approx (v + k I) / (1 - \rho_c)` along the Perron stack :math:`v`, the
condition reads :math:`\max_\delta (\rho_c + \sum_a \delta_a \partial_a\rho + \tfrac12
\delta^T \partial^2\rho\, \delta) < 1` up to the remainders: the maximum of
:math:`\rho`'s quadratic model over the sub-box, not a vertex bound of :math:`T`'s
second-order terms. The check of :math:`Y - T Y` is one positive-definiteness proof
instead of :math:`2^K`.

**Shifted certificate** (derived here; ``shifted=True``, tried last by
:func:`~ftc_verify.analysis.moments.sampled_taylor.affine_stable`, after the ``b`` of
:data:`~ftc_verify.analysis.moments.sampled_taylor.RHS_MIXES`). With the
Perron-aligned ``b`` the margin :math:`b' - \varphi_{hi} Y_0` is a fraction of
:math:`v + k I`, nearly singular where a Perron block is (and the identity part of
:math:`Y_0 = (I - T_c)^{-1}(v + k I)` is not aligned with :math:`v`: on held-out
``n = 4, m = 3`` loops it made :math:`b' - \varphi_{hi} Y_0` indefinite). Instead take
:math:`\sigma` with :math:`\rho(T_c) < \sigma < 1` and :math:`(I - T_c / \sigma) Y_0
= I`, i.e. :math:`Y_0 = \sum_k (T_c / \sigma)^k I \succ 0` when :math:`T_c` is a positive
map (the exact :math:`T` is; :math:`Y_0` is a float choice, proved positive below).
Then :math:`T_c Y_0 = \sigma (Y_0 - I)` and

.. math::

    b' - \varphi_{hi} Y_0 = Y_0 - T_c Y_0 - \varphi_{hi} Y_0
    = \sigma I + (1 - \sigma - \varphi_{hi})\, Y_0 \succeq \sigma I
    \quad \text{when } \sigma \le 1 - \varphi_{hi}:

the remainders are held against :math:`\sigma I`, the whole identity, in every joint
state. :math:`Y_0` (and with it the remainders, about :math:`|T_r| |Y|` and
:math:`S(T_a) S(y_p)`) grows like :math:`1 / (\sigma - \rho_c)`, so :math:`\sigma`
is taken near the largest value allowed, :math:`\sigma = 1 - \varphi_{hi} - k (1 -
\varphi_{hi} - \rho_c)` with :math:`k =` :data:`SHIFT_BACK`, :math:`\varphi_{hi}` from
the float :math:`c_a, c_p` of a first choice from the identity right-hand side (nearly independent of
:math:`Y_0`: :math:`c_a \approx \partial_a \rho`). All of these are float choices:
the check above proves whatever they give, with :math:`\varphi_{hi}` recomputed from
the final :math:`Y_0`. On held-out seed 13, 1 % below the crossing, it proves the
sub-box of a 16th of every width at the worst vertex where the Perron-aligned one
needs a 32nd (``benchmarks/results/h31w.md``).
"""

from __future__ import annotations

import heapq
import itertools
import math
from collections.abc import Callable
from typing import Any

import numpy as np

from ...model.system import Matrix
from .fast_balls import up_bound as _up
from .quad_balls import pairs
from .sampled import SampledLoop
from .sampled_taylor import float_choices, float_pd, left_perron, stack_pd

__all__ = ["quadratic_max", "box_maximum", "second_order_choices", "certify_second_order", "SHIFT_BACK"]

_U = 2.0 ** -53
_ETA = 2.0 ** -1022


def _flint() -> Any:
    import flint

    return flint


def quadratic_max(lin: Matrix, quad: Matrix, max_boxes: int = 400, rtol: float = 1e-3) -> float:
    r"""An upper bound of :math:`\max_{\delta \in [-1, 1]^K} \varphi(\delta)`,
    :math:`\varphi = \sum_a l_a \delta_a + \sum_{p = (a, b)} q_p \delta_a \delta_b`
    (``quad`` over :func:`~ftc_verify.analysis.moments.quad_balls.pairs`), by branch and
    bound: on a box with centre :math:`m` and half-widths :math:`h`,
    :math:`\varphi(m + e) = \varphi(m) + \sum_a g_a e_a + \sum_p q_p e_a e_b` exactly
    (:math:`g = \nabla\varphi(m)`), so :math:`\varphi \le \varphi(m) + \sum_a |g_a| h_a +
    \sum_{a < b} |q_p| h_a h_b + \sum_a \max(q_{aa}, 0) h_a^2`; the box with the largest
    bound is halved along its widest side until that bound is within ``rtol`` times
    :math:`\sum |l| + \sum |q|` of the best centre value or ``max_boxes`` boxes are
    split. Every bound is inflated by :math:`10^{-12}` times that sum (the float
    evaluation's rounding, at most :math:`4 K^2 u` of it, :math:`K \le 40`; the proofs take at most
    :data:`~ftc_verify.analysis.moments.sampled_taylor.AFFINE_RATES`)."""
    K = lin.shape[0]
    prs = pairs(K)
    scale = float(np.abs(lin).sum() + np.abs(quad).sum())
    if scale == 0.0:
        return 0.0
    slack = 1e-12 * scale
    Q = np.zeros((K, K))  # phi = l.d + d^T Q d with Q symmetric
    for k, (a, b) in enumerate(prs):
        if a == b:
            Q[a, a] += quad[k]
        else:
            Q[a, b] += 0.5 * quad[k]
            Q[b, a] += 0.5 * quad[k]
    absQ = np.abs(Q - np.diag(np.diag(Q)))
    diag_pos = np.maximum(np.diag(Q), 0.0)

    def bound(m: Matrix, h: Matrix) -> tuple[float, float]:
        value = float(lin @ m + m @ Q @ m)
        g = lin + 2.0 * Q @ m
        return value + float(np.abs(g) @ h + h @ absQ @ h + diag_pos @ (h * h)) + slack, value

    return box_maximum(bound, K, max_boxes, rtol * scale)


def box_maximum(bound: Callable[[Matrix, Matrix], tuple[float, float]], K: int, max_boxes: int, tol: float) -> float:
    """Branch and bound over :math:`[-1, 1]^K`: ``bound(m, h)`` gives an upper bound of a
    function on the box of centre ``m`` and half-widths ``h`` and its value at ``m``; the
    box of the largest bound is halved along its widest side until that bound is within
    ``tol`` of the best centre value or ``max_boxes`` boxes are split. Returns the largest
    bound left (an upper bound of the maximum whenever ``bound`` is one)."""
    m0, h0 = np.zeros(K), np.ones(K)
    ub, best = bound(m0, h0)
    heap = [(-ub, 0, m0, h0)]
    count = 1
    for _ in range(max_boxes):
        neg, _, m, h = heap[0]
        if -neg - best <= tol:
            break
        heapq.heappop(heap)
        a = int(np.argmax(h))
        for sign in (-0.5, 0.5):
            mc, hc = m.copy(), h.copy()
            hc[a] = 0.5 * h[a]
            mc[a] = m[a] + sign * h[a]
            u, v = bound(mc, hc)
            best = max(best, v)
            heapq.heappush(heap, (-u, count, mc, hc))
            count += 1
    return -heap[0][0]


def second_order_choices(Tc: Matrix, Tl: Matrix, Tq: Matrix, Y0: Matrix, Yl: Matrix,
                         w: Matrix) -> tuple[Matrix, Matrix] | None:
    r"""``(Yq, cq)``: the certificate's :math:`y_p` and :math:`c_p` (module docstring;
    ``Tq`` may be empty, an affine form), float64; ``None`` when a solve fails."""
    K = Tl.shape[0]
    A = np.eye(Tc.shape[0]) - Tc
    rhs, cs = [], []
    for k, (a, b) in enumerate(pairs(K)):
        g = Tl[a] @ Yl[b] + (Tl[b] @ Yl[a] if a != b else 0.0)
        if Tq.shape[0]:
            g = g + Tq[k] @ Y0
        c = float(w @ g / (w @ Y0))
        rhs.append(g - c * Y0)
        cs.append(c)
    try:
        ys = np.linalg.solve(A, np.stack(rhs, axis=1)).T
    except np.linalg.LinAlgError:
        return None
    if not (np.all(np.isfinite(ys)) and all(math.isfinite(c) for c in cs)):
        return None
    return np.asarray(ys, dtype=np.float64), np.asarray(cs, dtype=np.float64)


#: Where the shifted certificate puts :math:`\sigma` (:func:`certify_second_order`):
#: :math:`\sigma = 1 - \varphi_{hi} - k (1 - \varphi_{hi} - \rho_c)`, this ``k``.
SHIFT_BACK = 0.05


def _certificate(Tc: Matrix, Tl: Matrix, Tq: Matrix, S: int, r: int, mix: float | None,
                 sigma: float | None) -> tuple[Matrix, Matrix, Matrix, Matrix, Matrix] | None:
    """``(Y0, Yl, Yq, cq, w)``: the float choices of the module docstring
    (:func:`~ftc_verify.analysis.moments.sampled_taylor.float_choices` with ``mix`` or
    ``sigma``, :func:`second_order_choices`); ``None`` when a solve fails."""
    choice = float_choices(Tc, list(Tl), S, r, mix, sigma)
    w = left_perron(Tc)
    if choice is None or w is None:
        return None
    Y0, ys = choice
    Yl = np.stack(ys)
    second = second_order_choices(Tc, Tl, Tq, Y0, Yl, w)
    return None if second is None else (Y0, Yl, second[0], second[1], w)


def _shift(Tc: Matrix, Tl: Matrix, Y0: Matrix, cq: Matrix, w: Matrix) -> float | None:
    r""":math:`\sigma` of the shifted certificate (:func:`certify_second_order`) from a
    first float certificate: :math:`\varphi_{hi}` of its :math:`c_a \approx \langle w,
    T_a Y_0\rangle / \langle w, Y_0\rangle` and :math:`c_p` (both float estimates, nearly
    independent of :math:`Y_0`), :math:`\rho_c` the float spectral radius of
    :math:`T_c`; ``None`` when :math:`\rho_c + \varphi_{hi} \ge 1` (the quadratic
    model of :math:`\rho` reaches 1: no certificate)."""
    ca = (Tl @ Y0) @ w / float(w @ Y0)
    phi = quadratic_max(ca, cq)
    rho = float(np.max(np.abs(np.linalg.eigvals(Tc))))
    gap = 1.0 - phi - rho
    return 1.0 - phi - SHIFT_BACK * gap if gap > 0 and math.isfinite(gap) else None


def certify_second_order(loop: SampledLoop, form: tuple[Matrix, ...], mix: float | None = None,
                         shifted: bool = False) -> bool:
    r"""``True`` only if :math:`\rho(T(\delta)) < 1` is proved for every
    :math:`\delta \in [-1, 1]^K` of the form ``form`` (``(Tc, Tl, Tq, Tr)`` with ``Tq``
    over :func:`~ftc_verify.analysis.moments.quad_balls.pairs`, or an affine
    ``(Tc, Tl, Tr)``) by the certificate and check of the module docstring; ``mix``
    chooses the right-hand side ``b``
    (:func:`~ftc_verify.analysis.moments.sampled_taylor.float_choices`); ``shifted``:
    :math:`Y_0` from :math:`(I - T_c / \sigma) Y_0 = I` instead, :math:`\sigma` just
    below :math:`1 - \varphi_{hi}` (module docstring, *Shifted certificate*)."""
    if len(form) == 3:
        Tc, Tl, Tr = form
        Tq = np.zeros((0,) + Tc.shape)
    else:
        Tc, Tl, Tq, Tr = form
    S, r, N, K = loop.states, loop.r, Tc.shape[0], Tl.shape[0]
    prs = pairs(K)
    M = len(prs)
    cert = _certificate(Tc, Tl, Tq, S, r, mix, None)
    if cert is not None and shifted:
        sigma = _shift(Tc, Tl, cert[0], cert[3], cert[4])
        cert = None if sigma is None else _certificate(Tc, Tl, Tq, S, r, None, sigma)
    if cert is None:
        return False
    Y0, Yl, Yq, cq, w = cert
    u = _U
    aTc, aY0, aYl, aYq = np.abs(Tc), np.abs(Y0), np.abs(Yl), np.abs(Yq)
    sTl, sYl, sYq = (_up(np.abs(x).sum(axis=0), x.shape[0] + 1) for x in (Tl, Yl, Yq))
    sTq = _up(np.abs(Tq).sum(axis=0), M + 1) if Tq.shape[0] else np.zeros(N)
    wY0 = float(w @ Y0)
    base = Y0 - Tc @ Y0
    # first order: r_a = L_a + c_a Y0, with every rounding in err (Higham: 1.01 N u per product)
    lin = Yl - Yl @ Tc.T - np.einsum("aij,j->ai", Tl, Y0)
    ca = -(lin @ w) / wY0
    ra = lin + ca[:, None] * Y0[None, :]
    err = (1.01 * N * u + 6 * u) * (aYl + aYl @ aTc.T + np.abs(Tl) @ aY0 + np.abs(ca)[:, None] * aY0).sum(axis=0)
    # second order: r_p = y_p - Tc y_p - g_p + c_p Y0
    rp = Yq - Yq @ Tc.T + cq[:, None] * Y0[None, :]
    mags = aYq + aYq @ aTc.T + np.abs(cq)[:, None] * aY0
    for k, (a, b) in enumerate(prs):
        rp[k] -= Tl[a] @ Yl[b] + (Tl[b] @ Yl[a] if a != b else 0.0)
        mags[k] += np.abs(Tl[a]) @ aYl[b] + (np.abs(Tl[b]) @ aYl[a] if a != b else 0.0)
        if Tq.shape[0]:
            rp[k] -= Tq[k] @ Y0
            mags[k] += np.abs(Tq[k]) @ aY0
    err = err + (1.01 * N * u + 8 * u) * mags.sum(axis=0)
    phi = quadratic_max(ca, cq)
    rad = np.abs(ra).sum(axis=0) + np.abs(rp).sum(axis=0) + err
    rad = rad + sTl @ sYq + sTq @ sYl + sTq @ sYq + Tr @ (aY0 + sYl + sYq)
    rad = rad + (1.01 * N * u + 3 * u) * (aTc @ aY0) + 4 * u * (np.abs(base) + abs(phi) * aY0)
    rad = _up(rad, N + K + M + 16) + (2 * K + 2 * M + 6) * N * _ETA
    yrad = _up(sYq + (K + 2) * u * (aY0 + sYl), K + M + 4)
    flint = _flint()
    arb = flint.arb
    v = base - phi * Y0
    if not (float_pd(v, S, r) and float_pd(Y0, S, r)):
        return False
    vec = flint.arb_mat(N, 1, [arb(float(x), float(e)) for x, e in zip(v, rad)])
    if not (stack_pd(flint.arb_mat(N, 1, [arb(float(x)) for x in Y0]), S, r) and stack_pd(vec, S, r)):
        return False
    for corner in itertools.product((-1.0, 1.0), repeat=K):
        Y = Y0 + np.array(corner) @ Yl
        if not (float_pd(Y, S, r) and stack_pd(flint.arb_mat(N, 1, [arb(float(x), float(e)) for x, e in zip(Y, yrad)]), S, r)):
            return False
    return True
