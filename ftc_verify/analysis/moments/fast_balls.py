r"""A rigorous ball matrix exponential in float64 midpoint-radius arithmetic (numpy/BLAS).

:func:`ball_expm` returns a ball matrix containing :math:`e^{A}` for *every* matrix
:math:`A` of a ball matrix :math:`\langle A_c, A_r\rangle = \{A : |A - A_c| \le A_r\}`
(entrywise), like Arb's ``arb_mat.exp`` -- but with float64 BLAS products instead of
Arb's multiprecision ones: about a hundred times faster at 189 rows, at the price of
radii near :math:`10^{-14}` relative instead of :math:`10^{-18}` (64-bit Arb). The
sampled loop's proofs (:mod:`ftc_verify.analysis.moments.sampled_proof`) use it for
:math:`e^{\mathcal L h}`.

**Error analysis** (derived here; :math:`u = 2^{-53}` the unit roundoff of rounding to
nearest, :math:`\eta = 2^{-1022}` the smallest normal number, which bounds every
underflow error below). Every operation below returns a ball containing the exact
result for every element of its argument balls; the radii are computed in rounding to
nearest and then inflated so that they bound the exact radius formula.

* *Nonnegative expressions.* A sum or product of nonnegative floats, evaluated with
  :math:`k` roundings to nearest on any path (any summation order, FMA or not), is at
  least the exact value divided by :math:`(1 + u)^k`, up to an absolute
  :math:`k \eta` for underflow; so ``_up(v, k)``
  :math:`= v (1 + 2(k + 1) u) + (k + 1) \eta` bounds the exact value from above while
  :math:`k u < 10^{-3}` (:math:`(1+u)^{k} \le 1 + 2 k u`).
* *Products* (Rump, "Fast and parallel interval arithmetic", BIT 39 (1999), the
  midpoint-radius product). For :math:`\tilde A \in \langle A_c, A_r\rangle`,
  :math:`\tilde B \in \langle B_c, B_r\rangle` (inner dimension :math:`k`) and
  :math:`C_c = fl(A_c B_c)` in any order,
  :math:`|C_c - A_c B_c| \le \gamma_k |A_c||B_c| + k\eta` with
  :math:`\gamma_k = k u / (1 - k u) \le 1.01\, k u` (Higham, *Accuracy and Stability*,
  Lemma 3.1 and section 3.5; also for a sparse product that skips exact zeros,
  :func:`sparse_left`: fewer terms, fewer roundings), and
  :math:`|\tilde A \tilde B - A_c B_c| \le |A_c| B_r + A_r (|B_c| + B_r)`, so
  :math:`C_r = |A_c| (1.01 k u |B_c| + B_r) + A_r (|B_c| + B_r)`, evaluated with at most
  :math:`k + 4` roundings on each path and bounded by ``_up`` (plus :math:`k\eta`).
* *Sums* :math:`fl(a + b)` err by at most :math:`u |fl(a + b)|`; *scalar multiples* by a
  ball :math:`\langle c_m, c_r\rangle` (:math:`1/k` enclosed as
  :math:`\langle fl(1/k), u\, fl(1/k)\rangle`) by :math:`|A_c| c_r + A_r (|c_m| + c_r)`
  plus :math:`u` times the computed product (and :math:`\eta`).
* *Taylor series with remainder.* With :math:`\nu \ge \| |A_c| + A_r \|_\infty`
  (rounded up) and :math:`s` such that :math:`\nu 2^{-s} \le 1/2`, the matrix
  :math:`B = A / 2^s` (exact: a power of two; underflow covered by :math:`\eta`) has
  :math:`\|\tilde B^j\|_\infty \le (\nu 2^{-s})^j`, hence every entry of
  :math:`e^{\tilde B} - \sum_{j \le K} \tilde B^j / j!` is at most
  :math:`\mu^{K+1} / (K+1)! \cdot 1 / (1 - \mu / (K + 2))` with :math:`\mu = \nu 2^{-s}`
  (the tail of the exponential series, each term bounded by the previous one times
  :math:`\mu / (K + 2)`); the polynomial is evaluated in ball arithmetic by Horner's rule
  (:math:`I + \tilde B (I + \tilde B/2 (\dots))`), which contains its value at every
  :math:`\tilde B`, and the remainder is added to every radius.
* *Squaring.* :math:`e^{\tilde A} = (e^{\tilde B})^{2^s}`; the ball product contains
  the product of any elements, so :math:`s` ball squarings contain :math:`e^{\tilde A}`.

The input ball is read from Arb exactly enough: each Arb midpoint is rounded to the
nearest float (error at most :math:`u` times its magnitude, added to the radius with
the radius rounded up), and the result is handed back to Arb as balls whose midpoints
are floats (exact) and whose radii Arb rounds up. If any number overflows (or the
series cannot be bounded) :func:`ball_expm` returns ``None`` and the caller uses Arb's
exponential; no result is ever returned without its bound.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

import numpy as np
import scipy.sparse

from ...model.system import Matrix

__all__ = ["up_bound", "MidRad", "Affine", "ball_expm", "arb_expm", "map_ball", "from_arb", "to_arb", "TAYLOR_TERMS", "aff_mul",
           "aff_expm", "aff_map", "FormArithmetic", "taylor_scaled", "taylor_expm", "BALLS", "AFFINE", "SPARSE_SHARE", "SPARSE_ROWS", "sparse_enough", "sparse_left",
           "wide", "unwide"]

_U = 2.0 ** -53
_ETA = 2.0 ** -1022

#: Terms of the Taylor polynomial (the scaled argument has norm at most 1/2:
#: the remainder is below ``3e-20`` per entry before squaring).
TAYLOR_TERMS = 16

MidRad = tuple[Matrix, Matrix]


def _flint() -> Any:
    import flint

    return flint


def up_bound(v: Matrix | float, k: int) -> Any:
    """An upper bound of the exact value of a nonnegative expression computed as ``v``
    with at most ``k`` roundings to nearest on every path (module docstring)."""
    return v * (1.0 + 2.0 * (k + 1) * _U) + (k + 1) * _ETA


_up = up_bound


def _mul(a: MidRad, b: MidRad) -> MidRad:
    """The midpoint-radius product of two ball matrices (module docstring)."""
    (ac, ar), (bc, br) = a, b
    k = ac.shape[1]
    cc = ac @ bc
    abs_ac, abs_bc = np.abs(ac), np.abs(bc)
    cr = abs_ac @ (1.01 * k * _U * abs_bc + br) + ar @ (abs_bc + br)
    return cc, _up(cr, k + 4) + k * _ETA


def _add_identity(a: MidRad) -> MidRad:
    ac, ar = a
    cc = ac + np.eye(ac.shape[0])
    return cc, _up(ar + _U * np.abs(cc), 2)


def _scale(a: MidRad, cm: float, cr: float) -> MidRad:
    """``a`` times the scalar ball ``<cm, cr>``."""
    ac, ar = a
    cc = ac * cm
    return cc, _up(np.abs(ac) * cr + ar * (abs(cm) + cr) + _U * np.abs(cc), 4)


def ball_expm(a: MidRad, terms: int = TAYLOR_TERMS) -> MidRad | None:
    """A ball ``(mid, rad)`` containing :math:`e^{A}` for every :math:`A` with
    ``|A - mid| <= rad`` (entrywise), or ``None`` when a number overflows (module
    docstring: Taylor polynomial with remainder, scaling and squaring)."""
    with np.errstate(over="ignore", invalid="ignore"):
        return _ball_expm(a, terms)


def _ball_expm(a: MidRad, terms: int) -> MidRad | None:
    ac, ar = (np.asarray(x, dtype=np.float64) for x in a)
    if not (np.all(np.isfinite(ac)) and np.all(np.isfinite(ar)) and np.all(ar >= 0)):
        return None
    return taylor_expm((ac, ar), BALLS, terms)


#: An enclosure of one of the arithmetics of :func:`taylor_expm` (a tuple of float arrays).
F = TypeVar("F", bound=tuple[Any, ...])


@dataclass(frozen=True)
class FormArithmetic(Generic[F]):
    r"""The operations :func:`taylor_expm` needs on one kind of enclosure ``F`` (a tuple
    of float arrays: a ball ``(mid, rad)``, an affine form ``(c, lin, r)``, a
    second-order form ``(c, l, q, r)``); each returns an enclosure of the exact result
    for every element of its arguments (at the same symbols).

    ``magnitude(x)``: an entrywise upper bound of :math:`|X|` over the set (rounded
    to within the two roundings :func:`taylor_expm` adds); ``mul``, ``scale(x, cm, cr)``
    (times the scalar ball :math:`\langle cm, cr\rangle`), ``add_identity``;
    ``widen(x, t)``: ``x`` with ``t >= 0`` added to every radius (``t`` exact)."""

    magnitude: Callable[[F], Matrix]
    mul: Callable[[F, F], F]
    scale: Callable[[F, float, float], F]
    add_identity: Callable[[F], F]
    widen: Callable[[F, float], F]


def taylor_scaled(x: F, arith: FormArithmetic[F], terms: int = TAYLOR_TERMS) -> tuple[F, int] | None:
    r"""``(p, s)``: an enclosure ``p`` of :math:`e^{X / 2^s}` for every :math:`X` of the
    enclosure ``x`` (at the same symbols), in the arithmetic ``arith``, and the number
    ``s`` of squarings that make it :math:`e^X`; ``None`` when a number overflows.

    The scaled Taylor polynomial of :func:`taylor_expm` (module docstring, *Taylor series
    with remainder*): :math:`\nu \ge \| \mathrm{magnitude}(x) \|_\infty` rounded up,
    :math:`s` with :math:`\mu = \nu 2^{-s} \le 1/2`, Horner's rule on :math:`X / 2^s`
    (the scaling by a power of two exact up to underflow), the tail
    :math:`\mu^{K+1} / (K+1)! / (1 - \mu / (K + 2))` added to every radius."""
    with np.errstate(over="ignore", invalid="ignore"):
        mag = arith.magnitude(x)
        nu = float(np.max(_up(np.sum(mag, axis=1), mag.shape[1] + 2))) if mag.size else 0.0
        if not math.isfinite(nu):
            return None
        s = max(0, math.ceil(math.log2(nu)) + 1) if nu > 0 else 0
        b = arith.scale(x, 2.0 ** -s, 0.0)
        mu = float(_up(nu * 2.0 ** -s, 2))  # <= 1/2 up to rounding
        if mu >= 1.0:  # pragma: no cover - s is chosen so that mu <= 1/2
            return None
        p = arith.add_identity(arith.scale(b, 1.0 / terms, _U / terms))
        for j in range(terms - 1, 0, -1):
            inv = 1.0 / j
            p = arith.add_identity(arith.scale(arith.mul(b, p), inv, _U * inv))
        tail = mu ** (terms + 1) / math.factorial(terms + 1) / (1.0 - mu / (terms + 2))
        return arith.widen(p, float(_up(tail, terms + 8))), s


def taylor_expm(x: F, arith: FormArithmetic[F], terms: int = TAYLOR_TERMS) -> F | None:
    r"""An enclosure of :math:`e^{X}` for every :math:`X` of the enclosure ``x`` (at the
    same symbols), in the arithmetic ``arith``; ``None`` when a number overflows.

    The one scaling-and-squaring routine of the ball, affine and second-order
    exponentials (module docstring, *Taylor series with remainder* and *Squaring*):
    :func:`taylor_scaled`, then its ``s`` squarings."""
    scaled = taylor_scaled(x, arith, terms)
    if scaled is None:
        return None
    p, s = scaled
    with np.errstate(over="ignore", invalid="ignore"):
        for _ in range(s):
            p = arith.mul(p, p)
        if not all(np.all(np.isfinite(v)) for v in p):
            return None
        return p


def from_arb(m: Any) -> MidRad:
    """An Arb ball matrix as ``(mid, rad)`` float arrays whose ball contains it: the
    midpoints rounded to nearest, the rounding added to the radii (rounded up)."""
    rows, cols = m.nrows(), m.ncols()
    entries = m.entries()
    mid = np.array([float(x.mid()) for x in entries], dtype=np.float64).reshape(rows, cols)
    rad = np.array([float(x.rad()) for x in entries], dtype=np.float64).reshape(rows, cols)
    return mid, _up(rad + 2.0 * _U * np.abs(mid), 3)


def to_arb(a: MidRad) -> Any:
    """``(mid, rad)`` as an Arb ball matrix (float midpoints exact, radii rounded up by Arb)."""
    flint = _flint()
    mid, rad = a
    arb = flint.arb
    vals = [arb(m, r) for m, r in zip(mid.ravel().tolist(), rad.ravel().tolist())]
    return flint.arb_mat(mid.shape[0], mid.shape[1], vals)


def arb_expm(m: Any) -> Any:
    """:math:`e^{M}` for an Arb ball matrix ``m`` as an Arb ball matrix containing the
    exponential of every matrix in ``m``: :func:`ball_expm` when its numbers stay
    finite and Arb's working precision is at most 64 bits, Arb's ``arb_mat.exp``
    otherwise (a caller that raised the precision wants Arb's narrower balls)."""
    if _flint().ctx.prec > 64:
        return m.exp()
    out = ball_expm(from_arb(m))
    return m.exp() if out is None else to_arb(out)


def _add(a: MidRad, b: MidRad) -> MidRad:
    (ac, ar), (bc, br) = a, b
    cc = ac + bc
    return cc, _up(ar + br + _U * np.abs(cc), 3)


def map_ball(res: MidRad, modes: MidRad, q: Any, h: MidRad, lift: MidRad) -> Any:
    """:math:`\\mathcal P e^{(M + Q^T \\otimes I) h} \\mathcal R` as an Arb ball matrix,
    with ``res`` :math:`= \\mathcal P`, ``modes`` :math:`= M`, ``lift``
    :math:`= \\mathcal R`, ``h`` a ``1 x 1`` ball and ``q`` an Arb ball generator
    :math:`Q`: every operation in midpoint-radius arithmetic (module docstring), one
    conversion to Arb at the end; ``None`` when a number overflows (the caller then
    uses Arb). The identity's size is ``modes``'s rows over ``q``'s."""
    qc, qr = from_arb(q)
    eye = np.eye(modes[0].shape[0] // qc.shape[0])
    with np.errstate(over="ignore", invalid="ignore"):
        # the Kronecker product with the identity places entries (exact)
        g = _add(modes, (np.asarray(np.kron(qc.T, eye), dtype=np.float64), np.asarray(np.kron(qr.T, eye), dtype=np.float64)))
        e = _ball_expm(_scale(g, float(h[0][0, 0]), float(h[1][0, 0])), TAYLOR_TERMS)
        if e is None:
            return None
        t = _mul(_mul(res, e), lift)
    if not (np.all(np.isfinite(t[0])) and np.all(np.isfinite(t[1]))):
        return None
    return to_arb(t)


# --- Affine forms: the rates kept as symbols through the exponential -----------------

#: An affine ball matrix ``(c, lin, r)``: the set of :math:`c + \sum_a \delta_a\, lin_a + E`,
#: :math:`|E| \le r`, one matrix per :math:`\delta \in [-1, 1]^K` (``lin`` is ``(K, n, m)``).
Affine = tuple[Matrix, Matrix, Matrix]


def _lin_abs(lin: Matrix) -> Matrix:
    """An upper bound of :math:`\\sum_a |lin_a|` (``K`` roundings)."""
    return np.asarray(_up(np.abs(lin).sum(axis=0), lin.shape[0] + 1))


#: Largest share of nonzero entries of a left factor's midpoint for which :func:`aff_mul`
#: (and :func:`~ftc_verify.analysis.moments.quad_balls.quad_mul`) form its products
#: sparsely (:func:`sparse_left`): the scaled generator of the Taylor polynomial's Horner
#: steps (a sixth nonzero at 189 rows) and the restriction :math:`\mathcal P`.
SPARSE_SHARE = 0.25

#: Fewest rows of a left factor formed sparsely (below, the sparse products' overhead
#: exceeds the dense products: the ``n = 2, m = 2`` loops' 40 rows).
SPARSE_ROWS = 100


def sparse_enough(ac: Matrix) -> bool:
    """A left factor's midpoint for :func:`sparse_left`: at least :data:`SPARSE_ROWS`
    rows and at most :data:`SPARSE_SHARE` of its entries nonzero."""
    return bool(ac.shape[0] >= SPARSE_ROWS and np.count_nonzero(ac) <= SPARSE_SHARE * ac.size)


def wide(z: Matrix) -> Matrix:
    r"""A stack ``(S, k, m)`` side by side, ``(k, S m)``: :math:`[z_1 \dots z_S]`."""
    return z.transpose(1, 0, 2).reshape(z.shape[1], z.shape[0] * z.shape[2])


def unwide(p: Any, S: int) -> Matrix:
    """The inverse of :func:`wide` on a product: ``(n, S m)`` as the stack ``(S, n, m)``."""
    p = np.asarray(p)
    return p.reshape(p.shape[0], S, p.shape[1] // max(S, 1)).transpose(1, 0, 2)


def sparse_left(ac: Matrix, al: Matrix, bc: Matrix, bl: Matrix) -> tuple[Matrix, Matrix, Any, Any]:
    r"""``(c c', l_a c' + c l'_a, C, L)`` for a left factor ``(c, l)`` with few
    nonzeros (:data:`SPARSE_SHARE`), by sparse products over its nonzeros only; ``C`` and
    ``L`` (the ``l_a`` stacked, ``(K n, k)``) its CSR matrices for further products. The
    terms skipped are exactly zero (the zeros of ``c`` and ``l`` are exact) and each inner
    product has at most ``k`` terms, so the rounding bound of the dense products
    (Higham's, any order of summation; module docstring) holds unchanged."""
    n, k = ac.shape
    K = al.shape[0]
    C = scipy.sparse.csr_matrix(ac)
    L = scipy.sparse.csr_matrix(al.reshape(K * n, k))
    cl = np.asarray(L @ bc).reshape(K, n, bc.shape[1]) + unwide(C @ wide(bl), K)
    return np.asarray(C @ bc), cl, C, L


def aff_mul(a: Affine, b: Affine) -> Affine:
    """The product of two affine ball matrices over the same symbols (module docstring
    of ``aff_expm`` below: the linear terms exact in the symbols, the quadratic ones and
    every rounding in the radius); sparsely (:func:`sparse_left`) when ``a``'s midpoint
    is."""
    (ac, al, ar), (bc, bl, br) = a, b
    k, K = ac.shape[1], al.shape[0]
    if sparse_enough(ac):
        cc, cl = sparse_left(ac, al, bc, bl)[:2]
    else:
        cc = ac @ bc
        cl = np.matmul(al, bc) + np.matmul(ac, bl)
    sa, sb = _lin_abs(al), _lin_abs(bl)
    abs_ac, abs_bc = np.abs(ac), np.abs(bc)
    g = 1.01 * k * _U
    r = (abs_ac @ (g * (abs_bc + sb) + br) + sa @ (g * abs_bc + sb + br) + ar @ (abs_bc + sb + br)
         + _U * _lin_abs(cl))
    return cc, cl, _up(r, k + K + 12) + (2 * K + 2) * k * _ETA


def _aff_scale(a: Affine, cm: float, cr: float) -> Affine:
    """``a`` times the scalar ball ``<cm, cr>``."""
    ac, al, ar = a
    cc, cl = ac * cm, al * cm
    mag = np.abs(ac) + _lin_abs(al)
    r = mag * cr + ar * (abs(cm) + cr) + _U * (np.abs(cc) + _lin_abs(cl))
    return cc, cl, _up(r, al.shape[0] + 8) + _ETA


def _aff_add_identity(a: Affine) -> Affine:
    ac, al, ar = a
    cc = ac + np.eye(ac.shape[0])
    return cc, al, _up(ar + _U * np.abs(cc), 2)


def _widen(x: Any, t: float) -> Any:
    """``x`` with ``t`` added to its radius (the last array), rounded up."""
    return (*x[:-1], _up(x[-1] + t, 1))


#: :func:`taylor_expm` in the ball arithmetic of :func:`ball_expm`.
BALLS: FormArithmetic[MidRad] = FormArithmetic(lambda a: np.abs(a[0]) + a[1], _mul, _scale, _add_identity, _widen)
#: :func:`taylor_expm` in the affine arithmetic of :func:`aff_expm`.
AFFINE: FormArithmetic[Affine] = FormArithmetic(lambda a: np.abs(a[0]) + _lin_abs(a[1]) + a[2], aff_mul,
                                                 lambda a, cm, cr: _aff_scale(a, cm, cr), _aff_add_identity, _widen)


def aff_expm(a: Affine, terms: int = TAYLOR_TERMS) -> Affine | None:
    r"""An affine ball containing :math:`e^{X}` for every :math:`X` of the affine ball
    ``a``, at the same :math:`\delta` (``None`` when a number overflows).

    **Affine arithmetic** (derived here; first-order Taylor models). A matrix depending
    on symbols :math:`\delta \in [-1, 1]^K` is kept as :math:`c + \sum_a \delta_a l_a + E`,
    :math:`|E| \le r`. The product of two is
    :math:`c c' + \sum_a \delta_a (l_a c' + c\, l'_a) + \sum_{a,b} \delta_a \delta_b l_a
    l'_b + E (c' + \sum \delta l' + E') + (c + \sum \delta l) E'`: the first two parts are
    formed in floating point (their rounding, Higham's bound as in :func:`ball_expm`'s
    products, goes to the radius), the rest is bounded entrywise by
    :math:`S_a S_b + r(|c'| + S_b + r') + (|c| + S_a) r'` with :math:`S = \sum_a |l_a|`.
    So the dependence on each rate is carried *with its sign* through the Taylor
    polynomial and the squarings -- a transfer of mass between joint states, a rise in
    one entry and a fall in another, stays one term -- and only second-order terms are
    bounded in absolute value; the plain ball arithmetic of :func:`ball_expm` bounds the
    first-order spread entrywise at every product, which wraps (about a hundred times the
    true spread on the random loops of ``benchmarks/sampled.py``). The exponential is
    :func:`taylor_expm` (:data:`AFFINE`; scaling, Horner's rule with the same remainder bound for
    every matrix of the set: :math:`\nu` bounds :math:`\| |c| + S + r \|_\infty`,
    squaring) in this arithmetic."""
    return taylor_expm(a, AFFINE, terms)


def aff_map(res: MidRad, modes: MidRad, q: MidRad, dirs: Matrix, h: MidRad, lift: MidRad) -> Affine | None:
    """:math:`\\mathcal P e^{(M + Q(\\delta)^T \\otimes I) h} \\mathcal R` as an affine
    ball over :math:`\\delta \\in [-1, 1]^K`, with :math:`Q(\\delta) = Q + \\sum_a \\delta_a
    D_a`: ``res``, ``modes``, ``lift``, ``h`` and ``q`` balls as in :func:`map_ball`
    (``q`` as ``(mid, rad)``), ``dirs`` the ``(K, S, S)`` float directions :math:`D_a`
    (rounding of their Kronecker products is exact: entries are placed, not computed)."""
    qc, qr = q
    K = dirs.shape[0]
    eye = np.eye(modes[0].shape[0] // qc.shape[0])
    with np.errstate(over="ignore", invalid="ignore"):
        gc = modes[0] + np.kron(qc.T, eye)
        gl = np.stack([np.kron(d.T, eye) for d in dirs]) if K else np.zeros((0,) + gc.shape)
        gr = _up(modes[1] + np.kron(qr.T, eye) + _U * np.abs(gc), 3)
        g = _aff_scale((gc, gl, gr), float(h[0][0, 0]), float(h[1][0, 0]))
        e = aff_expm(g)
        if e is None:
            return None
        zero = np.zeros((K,) + res[0].shape), np.zeros((K,) + lift[0].shape)
        t = aff_mul(aff_mul((res[0], zero[0], res[1]), e), (lift[0], zero[1], lift[1]))
    return t if all(np.all(np.isfinite(x)) for x in t) else None
