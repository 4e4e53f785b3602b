r"""Second-order forms: the rates kept as symbols, with their products, through the
exponential (float64 midpoint-radius arithmetic).

The affine forms of :mod:`ftc_verify.analysis.moments.fast_balls` (``aff_expm``) carry
the first-order dependence on the rates with its sign and bound the second-order part
entrywise -- where it wraps as the first-order part did in plain balls. Here a matrix is
kept as

.. math::

    c + \sum_a \delta_a l_a + \sum_{a \le b} \delta_a \delta_b q_{ab} + E, \qquad
    |E| \le r, \quad \delta \in [-1, 1]^K,

and the product of two such forms (derived here) is
:math:`c c' + \sum_a \delta_a (l_a c' + c l'_a) + \sum_{a \le b} \delta_a \delta_b
(q_{ab} c' + c q'_{ab} + l_a l'_b + [a \ne b]\, l_b l'_a)` plus the terms of degree three
and four, bounded entrywise by :math:`S_l S'_q + S_q S'_l + S_q S'_q` (:math:`S_l = \sum_a
|l_a|`, :math:`S_q = \sum_{a \le b} |q_{ab}|`), plus
:math:`r (|c'| + S'_l + S'_q + r') + (|c| + S_l + S_q) r'`. The rounding of every float
product (Higham's bound :math:`1.01\, k u` on each inner product of length :math:`k`, as
in :mod:`~ftc_verify.analysis.moments.fast_balls`) and of every sum goes to the radius,
which is rounded up by ``_up`` (same lemma). The exponential is that module's one
:func:`~ftc_verify.analysis.moments.fast_balls.taylor_expm` in this arithmetic
(:data:`QUADRATIC`): scaling by a power of two so that the norm bound :math:`\nu` of
every matrix of the set is at most :math:`2^{s - 1}`, Horner's rule with the entrywise
tail bound, :math:`s` squarings. The Horner steps multiply by the scaled generator,
which has no second-order part and few nonzeros (a sixth at 189 rows): their products
are formed sparsely (:func:`~ftc_verify.analysis.moments.fast_balls.sparse_left`, the
same rounding bound), so a step costs a few dense products (the radius) instead of
:math:`1 + 2K + 2M + K^2` (``M`` the pairs): 0.77 to 0.42 CPU s for ``quad_map`` at
``K = 6``, 189 rows.
"""

from __future__ import annotations

import numpy as np

from ...model.system import Matrix
from .fast_balls import TAYLOR_TERMS, FormArithmetic, MidRad, sparse_enough, sparse_left, taylor_expm, unwide, wide

__all__ = ["Quad", "QUADRATIC", "pairs", "sum_abs", "quad_mul", "quad_expm", "generator_form", "quad_map"]

_U = 2.0 ** -53
_ETA = 2.0 ** -1022

#: A second-order form ``(c, l, q, r)``: ``l`` is ``(K, n, m)``, ``q`` is ``(M, n, m)``
#: over :func:`pairs` ``(a, b)``, ``a <= b``.
Quad = tuple[Matrix, Matrix, Matrix, Matrix]


def _up(v: Matrix | float, k: int) -> Matrix:
    """An upper bound of a nonnegative expression computed with at most ``k`` roundings
    on every path (:mod:`~ftc_verify.analysis.moments.fast_balls`)."""
    return np.asarray(v * (1.0 + 2.0 * (k + 1) * _U) + (k + 1) * _ETA)


def pairs(K: int) -> tuple[tuple[int, int], ...]:
    """The pairs ``(a, b)``, ``a <= b < K``, in the order of a form's ``q``."""
    return tuple((a, b) for a in range(K) for b in range(a, K))


def sum_abs(x: Matrix) -> Matrix:
    """An upper bound of :math:`\\sum_a |x_a|` over a form's stacked coefficients (the
    zero matrix of their shape when there are none)."""
    return _up(np.abs(x).sum(axis=0), x.shape[0] + 1) if x.shape[0] else np.zeros(x.shape[1:])


def _products(ac: Matrix, al: Matrix, aq: Matrix, bc: Matrix, bl: Matrix,
              bq: Matrix) -> tuple[Matrix, Matrix, Matrix, Matrix]:
    """The float products of :func:`quad_mul`: ``c c'``, ``l_a c' + c l'_a``,
    ``q_p c' + c q'_p`` and the cross products ``l_a l'_b`` as a ``(K, K, n, m)`` array;
    sparsely (:func:`~ftc_verify.analysis.moments.fast_balls.sparse_left`, same rounding
    bound) when the left factor has no second-order part and a sparse midpoint (the
    scaled generator of the Taylor polynomial's Horner steps, the restriction
    :math:`\\mathcal P`): about ten times fewer operations in a Horner step."""
    if aq.any() or not sparse_enough(ac):
        return (ac @ bc, np.matmul(al, bc) + np.matmul(ac, bl), np.matmul(aq, bc) + np.matmul(ac, bq),
                np.matmul(al[:, None], bl[None, :]))
    K = al.shape[0]
    cc, cl, C, L = sparse_left(ac, al, bc, bl)
    cross = np.asarray(L @ wide(bl)).reshape(K, ac.shape[0], K, bc.shape[1]).transpose(0, 2, 1, 3)
    return cc, cl, unwide(C @ wide(bq), bq.shape[0]), cross


def quad_mul(x: Quad, y: Quad) -> Quad:
    """The product of two second-order forms over the same symbols (module docstring)."""
    (ac, al, aq, ar), (bc, bl, bq, br) = x, y
    k, K = ac.shape[1], al.shape[0]
    cc, cl, cq, cross = _products(ac, al, aq, bc, bl, bq)
    terms = [cross[a, b] + cross[b, a] if a != b else cross[a, a] for a, b in pairs(K)]
    if terms:
        cq = cq + np.stack(terms)
    sl, sq, tl, tq = sum_abs(al), sum_abs(aq), sum_abs(bl), sum_abs(bq)
    abs_ac, abs_bc = np.abs(ac), np.abs(bc)
    g = 1.01 * k * _U + 2.0 * _U  # the products' rounding and that of the sums of two or four
    mag_b = abs_bc + tl + tq + br
    r = (abs_ac @ (g * (abs_bc + tl + tq) + br) + sl @ (g * (abs_bc + tl) + tq + br)
         + sq @ (g * abs_bc + tl + tq + br) + ar @ mag_b
         + 2.0 * _U * (sum_abs(cl) + sum_abs(cq)))
    return cc, cl, cq, _up(r, k + 2 * K * K + 16) + (4 * K * K + 4) * k * _ETA


def _scale(x: Quad, cm: float, cr: float) -> Quad:
    """``x`` times the scalar ball ``<cm, cr>``."""
    ac, al, aq, ar = x
    cc, cl, cq = ac * cm, al * cm, aq * cm
    mag = np.abs(ac) + sum_abs(al) + sum_abs(aq)
    r = mag * cr + ar * (abs(cm) + cr) + _U * (np.abs(cc) + sum_abs(cl) + sum_abs(cq))
    return cc, cl, cq, _up(r, al.shape[0] + aq.shape[0] + 8) + _ETA


def _add_identity(x: Quad) -> Quad:
    ac, al, aq, ar = x
    cc = ac + np.eye(ac.shape[0])
    return cc, al, aq, _up(ar + _U * np.abs(cc), 2)


#: :func:`~ftc_verify.analysis.moments.fast_balls.taylor_expm` in this module's arithmetic.
QUADRATIC: FormArithmetic[Quad] = FormArithmetic(lambda x: np.abs(x[0]) + sum_abs(x[1]) + sum_abs(x[2]) + x[3],
                                                 quad_mul, _scale, _add_identity,
                                                 lambda x, t: (x[0], x[1], x[2], _up(x[3] + t, 1)))


def quad_expm(x: Quad, terms: int = TAYLOR_TERMS) -> Quad | None:
    """A second-order form containing :math:`e^{X}` for every :math:`X` of ``x`` at the
    same :math:`\\delta` (module docstring); ``None`` when a number overflows."""
    return taylor_expm(x, QUADRATIC, terms)


def generator_form(modes: MidRad, q: MidRad, dirs: Matrix, h: MidRad) -> Quad:
    """:math:`(M + Q(\\delta)^T \\otimes I) h` as a second-order form (no second-order
    part), the arguments as in :func:`quad_map`."""
    qc, qr = q
    K = dirs.shape[0]
    M = len(pairs(K))
    eye = np.eye(modes[0].shape[0] // qc.shape[0])
    with np.errstate(over="ignore", invalid="ignore"):
        gc = modes[0] + np.kron(qc.T, eye)
        gl = np.stack([np.kron(d.T, eye) for d in dirs])
        gr = _up(modes[1] + np.kron(qr.T, eye) + _U * np.abs(gc), 3)
        return _scale((gc, gl, np.zeros((M,) + gc.shape), gr), float(h[0][0, 0]), float(h[1][0, 0]))


def quad_map(res: MidRad, modes: MidRad, q: MidRad, dirs: Matrix, h: MidRad, lift: MidRad) -> Quad | None:
    """:math:`\\mathcal P e^{(M + Q(\\delta)^T \\otimes I) h} \\mathcal R` as a
    second-order form over :math:`\\delta \\in [-1, 1]^K`, the arguments as in
    :func:`~ftc_verify.analysis.moments.fast_balls.aff_map`."""
    K = dirs.shape[0]
    M = len(pairs(K))
    with np.errstate(over="ignore", invalid="ignore"):
        e = quad_expm(generator_form(modes, q, dirs, h))
        if e is None:
            return None

        def thin(b: MidRad) -> Quad:
            z = np.zeros(b[0].shape)
            return b[0], np.stack([z] * K), np.stack([z] * M), b[1]

        t = quad_mul(quad_mul(thin(res), e), thin(lift))
    return t if all(np.all(np.isfinite(v)) for v in t) else None
