r"""Third-order terms with their signs through the squarings of the second-order
exponential: a tighter remainder for the forms of
:mod:`~ftc_verify.analysis.moments.quad_balls`.

A second-order form bounds the terms of degree three of every product entrywise by
:math:`S_l S'_q + S_q S'_l` (sums of absolute values), and carries that bound through
the later products by absolute values. On held-out ``n = 4, m = 3`` loops near the
crossing the remainder :math:`T_r` of the one-period map came out three to four times
the sum of the absolute values of the map's true third-order coefficients
(``benchmarks/results/split16.md``), and near the worst vertex that remainder took most
of the eigenpair proof's margin. Here a matrix is kept, during the squarings and the products with the restriction and
the lift, as

.. math::

    c + \sum_a \delta_a l_a + \sum_{a \le b} \delta_a \delta_b q_{ab}
    + \sum_{a \le b \le e} \delta_a \delta_b \delta_e t_{abe} + E, \qquad |E| \le r,
    \quad \delta \in [-1, 1]^K,

(a *third-order form*, not to be confused with the cubic certificates of
:mod:`~ftc_verify.analysis.moments.sampled_cubic`, which are piecewise Lyapunov
functions). The product of two such forms (derived here): the coefficients of degree
up to two are those of :func:`~ftc_verify.analysis.moments.quad_balls.quad_mul`; the
coefficient of the monomial :math:`\delta_a \delta_b \delta_e` is

.. math::

    t_{abe} c' + c\, t'_{abe} + \sum_{i \in \{a, b, e\}} (l_i q'_{\{a, b, e\} \setminus i}
    + q_{\{a, b, e\} \setminus i}\, l'_i)

(the sum over the *distinct* values :math:`i` of the multiset, each removed once: every
pair :math:`(i, p)` of a linear and a quadratic term gives exactly one monomial); the
terms of degree four to six are bounded entrywise by :math:`S_l S'_t + S_q S'_q + S_t
S'_l + S_q S'_t + S_t S'_q + S_t S'_t` (:math:`|\delta|, |\mu|, |\nu| \le 1`) and the
radii by :math:`r (|c'| + S'_l + S'_q + S'_t + r') + (|c| + S_l + S_q + S_t) r'`. Every
coefficient is a sum of at most eight matrix products, each an inner product of length
:math:`k`: its rounding is at most :math:`\gamma_{k + 8}` times the sum of the products
of absolute values (Higham, as in :mod:`~ftc_verify.analysis.moments.fast_balls`: a
summation tree of depth at most :math:`k + 7` per entry), bounded by
:math:`1.01 (k + 8) u` times the product of the magnitudes; every bound is rounded up
(:func:`~ftc_verify.analysis.moments.fast_balls.up_bound`).

:func:`cubic_map` takes the scaled Taylor polynomial of the second-order exponential
and its first squarings in that arithmetic (their third-order terms in the radius: each
squaring multiplies them by about eight), the last :data:`CUBIC_SQUARINGS` squarings and
the products with the restriction and the lift in this one, and returns the second-order form whose radius is :math:`r + \sum_t |t|` (the third-order
coefficients bounded only once, after every cancellation between products). On the
held-out loop's sub-box of ``benchmarks/results/split16.md`` this takes the map's
remainder from 1.5e-3 to 5.2e-4, where the sum of the absolute values of the map's true
third-order coefficients (fitted to dense float maps) is 5.0e-4.
"""

from __future__ import annotations

import itertools
from typing import Any

import numpy as np
import scipy.sparse

from ...model.system import Matrix
from .fast_balls import TAYLOR_TERMS, MidRad, taylor_scaled
from .fast_balls import up_bound as _up
from .quad_balls import QUADRATIC, Quad, generator_form, pairs, quad_mul, sum_abs

__all__ = ["Cubic", "triples", "cubic_mul", "cubic_terms", "cubic_map", "CUBIC_SIZE", "CUBIC_SQUARINGS", "cubic_forms"]

_U = 2.0 ** -53
_ETA = 2.0 ** -1022

#: A third-order form ``(c, l, q, t, r)``: ``t`` is ``(T, n, m)`` over :func:`triples`.
Cubic = tuple[Matrix, Matrix, Matrix, Matrix, Matrix]

#: Largest :math:`K M N^2` (``K`` free rates, ``M = K (K + 1) / 2``, ``N`` the moment
#: generator's rows) for which :func:`cubic_map` is used (:func:`cubic_forms`): the
#: products :math:`l_i q'_p` of a squaring are held at once, :math:`8 K M N^2` bytes:
#: 36 MB at ``K = 6``, ``N = 189``, at most 48 MB.
CUBIC_SIZE = 6_000_000


#: How many of the last squarings :func:`cubic_map` takes in this arithmetic (the
#: earlier ones, and the Taylor polynomial, in the second-order one: their third-order
#: terms are a power of two smaller per squaring). On the sub-box of
#: ``benchmarks/results/split16.md``: the map's remainder 1.07e-3 with one, 5.97e-4 with
#: two, 5.24e-4 with three, 5.23e-4 with all five.
CUBIC_SQUARINGS = 3


def cubic_forms(K: int, N: int) -> bool:
    """Whether :func:`cubic_map` may be used on ``K`` free rates and ``N`` generator rows
    (:data:`CUBIC_SIZE`, the memory of one squaring's products)."""
    return K * (K * (K + 1) // 2) * N * N <= CUBIC_SIZE


def triples(K: int) -> tuple[tuple[int, int, int], ...]:
    """The triples ``(a, b, e)``, ``a <= b <= e < K``, in the order of a form's ``t``."""
    return tuple(itertools.combinations_with_replacement(range(K), 3))


def _monomials(K: int) -> tuple[Any, Any]:
    """0/1 sparse matrices that add every product of a linear and a quadratic term into
    its monomial: ``(T, K M)`` for the products :math:`l_i q'_p` (row major over
    ``(i, p)``, :func:`pairs`) and ``(T, M K)`` for :math:`q_p l'_i`; each row has at
    most three ones (the distinct values of its triple)."""
    where: dict[tuple[int, ...], int] = {t: k for k, t in enumerate(triples(K))}
    prs = pairs(K)
    T, KM = len(where), K * len(prs)
    lq = [where[tuple(sorted((i,) + p))] for i in range(K) for p in prs]
    ql = [where[tuple(sorted((i,) + p))] for p in prs for i in range(K)]
    return tuple(scipy.sparse.csr_matrix((np.ones(KM), (rows, np.arange(KM))), shape=(T, KM)) for rows in (lq, ql))


def _cross(a: Matrix, b: Matrix) -> Matrix:
    """Every product ``a[i] @ b[j]`` as a ``(I J, n, m)`` stack (row major); exact
    zeros without products when either stack is zero (a restriction or a lift)."""
    if not (a.any() and b.any()):
        return np.zeros((a.shape[0] * b.shape[0], a.shape[1], b.shape[2]))
    p = np.matmul(a[:, None], b[None, :])
    return p.reshape((a.shape[0] * b.shape[0],) + p.shape[2:])


def cubic_mul(x: Cubic, y: Cubic) -> Cubic:
    """The product of two third-order forms over the same symbols (module docstring)."""
    (ac, al, aq, at, ar), (bc, bl, bq, bt, br) = x, y
    k, K = ac.shape[1], al.shape[0]
    prs = pairs(K)
    cc = ac @ bc
    cl = np.matmul(al, bc) + np.matmul(ac, bl)
    cq = np.matmul(aq, bc) + np.matmul(ac, bq)
    ll = _cross(al, bl).reshape(K, K, ac.shape[0], bc.shape[1])
    cq = cq + np.stack([ll[a, b] + ll[b, a] if a != b else ll[a, a] for a, b in prs])
    ct = (np.matmul(at, bc) if at.any() else np.zeros(at.shape[:2] + bc.shape[1:])) + (np.matmul(ac, bt) if bt.any() else 0.0)
    lq, ql = _monomials(K)
    shape = ct.shape
    ct = ct + np.asarray(lq @ _cross(al, bq).reshape(lq.shape[1], -1) + ql @ _cross(aq, bl).reshape(ql.shape[1], -1)).reshape(shape)
    sl, sq, st = sum_abs(al), sum_abs(aq), sum_abs(at)
    tl, tq, tt = sum_abs(bl), sum_abs(bq), sum_abs(bt)
    abs_ac, abs_bc = np.abs(ac), np.abs(bc)
    g = 1.01 * (k + 8) * _U
    mag_b = abs_bc + tl + tq + tt + br
    r = (abs_ac @ (g * (abs_bc + tl + tq + tt) + br)
         + sl @ (g * (abs_bc + tl + tq) + tt + br)
         + sq @ (g * (abs_bc + tl) + tq + tt + br)
         + st @ (g * abs_bc + tl + tq + tt + br)
         + ar @ mag_b)
    n_terms = 1 + K + len(prs) + ct.shape[0]
    return cc, cl, cq, ct, _up(r, k + 4 * n_terms + 16) + (4 * n_terms * n_terms + 4) * k * _ETA


def _thin(b: MidRad, K: int, M: int, T: int) -> Cubic:
    z = np.zeros(b[0].shape)
    return b[0], np.stack([z] * K), np.stack([z] * M), np.stack([z] * T), b[1]


def cubic_terms(res: MidRad, modes: MidRad, q: MidRad, dirs: Matrix, h: MidRad, lift: MidRad,
                terms: int = TAYLOR_TERMS) -> Cubic | None:
    """:math:`\\mathcal P e^{(M + Q(\\delta)^T \\otimes I) h} \\mathcal R` as a
    third-order form ``(c, l, q, t, r)`` over :math:`\\delta \\in [-1, 1]^K` (the
    arguments as in :func:`~ftc_verify.analysis.moments.quad_balls.quad_map`): the
    Taylor polynomial and the first squarings in the second-order arithmetic, the last
    :data:`CUBIC_SQUARINGS` and the products with the restriction and the lift in this
    one (module docstring); ``None`` when a number overflows."""
    K = dirs.shape[0]
    M, T = len(pairs(K)), len(triples(K))
    with np.errstate(over="ignore", invalid="ignore"):
        scaled = taylor_scaled(generator_form(modes, q, dirs, h), QUADRATIC, terms)
        if scaled is None:
            return None
        e, squarings = scaled
        for _ in range(max(0, squarings - CUBIC_SQUARINGS)):
            e = quad_mul(e, e)
        p: Cubic = (e[0], e[1], e[2], np.zeros((T,) + e[0].shape), e[3])
        for _ in range(min(squarings, CUBIC_SQUARINGS)):
            p = cubic_mul(p, p)
        out = cubic_mul(cubic_mul(_thin(res, K, M, T), p), _thin(lift, K, M, T))
    return out if all(np.all(np.isfinite(v)) for v in out) else None


def cubic_map(res: MidRad, modes: MidRad, q: MidRad, dirs: Matrix, h: MidRad, lift: MidRad,
              terms: int = TAYLOR_TERMS) -> Quad | None:
    """:func:`cubic_terms`' form as a second-order one: the third-order coefficients go
    to the radius, :math:`r + \\sum_t |t|` (module docstring); ``None`` when a number
    overflows."""
    form = cubic_terms(res, modes, q, dirs, h, lift, terms)
    if form is None:
        return None
    tc, tl, tq, tt, tr = form
    with np.errstate(over="ignore", invalid="ignore"):
        rad = _up(tr + sum_abs(tt), 2)
    out = (tc, tl, tq, rad)
    return out if np.all(np.isfinite(rad)) else None
