r"""A first-order stability proof of the sampled loop on a rate sub-box, with a
certificate that follows the rates.

:func:`ftc_verify.analysis.moments.sampled_proof.box_verdict` proves
:math:`\rho(T(r)) < 1` for every rate array :math:`r` of a sub-box by a stack
:math:`Y \succ 0` with :math:`Y - T(r) Y \succ 0` (the cone argument of that module).
A *fixed* :math:`Y` cannot do it near the period where the loop loses stability:
:math:`Y - T Y \succeq m Y` forces :math:`\rho(T) \le 1 - m`, so the relative margin of
any certificate is at most :math:`\epsilon = 1 - \rho`, while :math:`T(r) Y` moves
*first order* in :math:`r - r_0` in directions with both signs (a detection moves second
moments from mismatched to matched joint states): the sub-boxes would have to be about
:math:`\epsilon` wide. Here the certificate moves with the rates.

**Certificate** (derived here). At the sub-box's midpoint :math:`r_0`, with
:math:`T_0 = T(r_0)`, :math:`J_a = \partial T / \partial r_a` (the Frechet derivative of
the exponential, :meth:`~ftc_verify.analysis.moments.sampled_proof.MapParts.derivative`),
take :math:`Y_0 = (I - T_0)^{-1} I` and, for each free rate :math:`a`,

.. math::

    (I - T_0)\, y_a = J_a(r_0) Y_0 - c_a Y_0, \qquad
    c_a = \frac{\langle w, J_a(r_0) Y_0\rangle}{\langle w, Y_0 \rangle},

with :math:`w` the left Perron vector of :math:`T_0` (float64 choices: whatever they are,
the proof below checks the result). :math:`c_a \approx \partial\rho/\partial r_a` and the
right-hand side has no Perron component, so :math:`y_a` is of the size of :math:`Y_0`
(not :math:`1/\epsilon` times it): :math:`Y(r) = Y_0 + \sum_a \delta_a y_a`,
:math:`\delta = r - r_0`, follows the Perron vector to first order.

**Enclosure.** For :math:`r` in the sub-box and any vector :math:`v`,
:math:`T(r) v = T_0 v + \sum_b \delta_b \int_0^1 J_b(r_0 + t\delta) v\, dt
\in T_0 v + \sum_b \delta_b\, \mathbf J_b v` with :math:`\mathbf J_b` the ball of the
derivative over the sub-box (convex, containing every :math:`J_b(r_0 + t\delta)`). Hence

.. math::

    Y(r) - T(r) Y(r) \in \underbrace{(Y_0 - T_0 Y_0)}_{= I\ \text{(float)}}
    + \sum_a \delta_a \underbrace{(y_a - T_0 y_a - J_a(r_0) Y_0)}_{\approx -c_a Y_0}
    - \mathbf E,

.. math::

    \mathbf E = \sum_a [\delta_a] (\mathbf J_a - J_a(r_0)) Y_0
    + \sum_b [\delta_b]\, \mathbf J_b \Bigl(\sum_a [\delta_a] y_a\Bigr),

a ball quadratic in the sub-box's width. The part outside :math:`\mathbf E` is affine in
:math:`\delta`, so, as in the first-order form before, if it minus every element of
:math:`\mathbf E` is proved positive definite per joint state at every vertex of the
:math:`\delta` box (and :math:`Y(r)`, affine, at every vertex), then
:math:`Y(r) \succ 0` and :math:`Y(r) - T(r) Y(r) \succ 0` at every :math:`r` (convex
combinations): :math:`\rho(T(r)) < 1` on the whole sub-box. To first order the vertex
condition reads :math:`1 - \sum_a \delta_a c_a / \epsilon > 0`, i.e.
:math:`\rho(r_0) + \sum_a \delta_a \partial_a\rho < 1`: the proof is limited only by
the true margin and by :math:`\mathbf E`, and the sub-boxes need only be about
:math:`\sqrt{\epsilon}` wide where the margin is :math:`\epsilon`.

**Forms instead of balls** (:func:`affine_stable`, tried first). The derivative's ball
:math:`\mathbf J_b` over the sub-box is itself an entrywise ball of an exponential and
wraps: its width bounds a transfer of mass between joint states (a rise in one entry, a
fall in another) as independent spreads, about a hundred times the true second-order
term on the random loops of ``benchmarks/sampled.py``. :func:`affine_stable` instead
carries the sub-box's rates as symbols :math:`\delta_a \in [-1, 1]` through the
exponential (:func:`~ftc_verify.analysis.moments.fast_balls.aff_map`, and with their
products, :func:`~ftc_verify.analysis.moments.quad_balls.quad_map`, when
:func:`quadratic_forms`):
:math:`T(r) \in T_c + \sum_a \delta_a T_a + \sum_{a \le b} \delta_a \delta_b T_{ab}
+ E`, with :math:`T_a` in the role of :math:`J_a(r_0)` above (scaled by the half-width)
and only the terms of higher degree and the rounding in :math:`E`.

All the balls are formed at the data as written (the sub-box's ends enclosed as in
:func:`~ftc_verify.analysis.moments.sampled_balls.ball_generator`, the midpoint exact).
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ...model.system import Matrix
from ..exact import enclose
from ..rigorous import Ball, ball, midpoint, proven_positive_definite
from .sampled import SampledLoop
from .sampled_balls import ball_generator, generator_coefficients
from .stability import vech_order

__all__ = ["FIRST_ORDER_LIMIT", "AFFINE_RATES", "QUADRATIC_SIZE", "QUADRATIC_SIZE_SMALL", "QUADRATIC_ROWS", "quadratic_forms", "unvech_ball", "stack_pd", "identity_stack", "perron_first_order_stable", "affine_stable",
           "FormSpend", "CUBIC_GAIN", "float_pd", "resolvent_stack", "float_choices", "left_perron", "right_perron", "RHS_MIXES"]

#: Largest Van Loan block (rows, twice the moment generator's) the first-order form
#: exponentiates in ball arithmetic; above it only the direct ball is tried (cost).
FIRST_ORDER_LIMIT = 256

#: Most free rates the affine proof takes (it checks :math:`2^K` vertices).
AFFINE_RATES = 10

#: Largest ``K^2`` times the moment generator's rows for which the second-order forms of
#: :mod:`~ftc_verify.analysis.moments.quad_balls` are used on any loop (above it the
#: affine forms; :func:`quadratic_forms`).
QUADRATIC_SIZE = 1000
#: The same bound on loops of at most :data:`QUADRATIC_ROWS` rows: ``K = 6`` free rates
#: at 189 rows (random ``n = 4, m = 3`` loops), where a sub-box proof costs about 3 times
#: the affine one and proves sub-boxes 2-8 times wider per rate near the crossing
#: (``benchmarks/results/h31w.md``); not measured on larger generators, whose
#: :math:`K (K + 1) / 2` dense second-order terms grow as :math:`N^2` in memory.
QUADRATIC_SIZE_SMALL = 8000
#: Rows up to which :data:`QUADRATIC_SIZE_SMALL` applies.
QUADRATIC_ROWS = 256


#: :func:`affine_stable` computes the map's third-order form
#: (:func:`~ftc_verify.analysis.moments.cubic_balls.cubic_map`) only where the eigenpair
#: enclosure would prove the sub-box with the second-order form's remainder divided by
#: this (a float estimate; the third-order form's remainder came out 2.7 to 3.5 times
#: smaller near the worst vertex, ``benchmarks/results/split16.md``).
CUBIC_GAIN = 2.0


def quadratic_forms(K: int, N: int) -> bool:
    """Whether a sub-box with ``K`` free rates of a moment generator of ``N`` rows gets the
    second-order forms (:data:`QUADRATIC_SIZE`, :data:`QUADRATIC_SIZE_SMALL`); shared by
    the proof (:func:`affine_stable`) and its charge
    (:func:`~ftc_verify.analysis.moments.sampled_bracket.box_work`)."""
    return K * K * N <= (QUADRATIC_SIZE_SMALL if N <= QUADRATIC_ROWS else QUADRATIC_SIZE)


def _flint() -> Any:
    import flint

    return flint


def unvech_ball(col: Any, start: int, r: int) -> Ball:
    """The symmetric ``r x r`` ball matrix whose ``vech`` starts at ``col[start]``."""
    flint = _flint()
    rows, cols = vech_order(r)
    out = flint.arb_mat(r, r)
    for k, (i, j) in enumerate(zip(rows, cols)):
        out[int(i), int(j)] = col[start + k, 0]
        out[int(j), int(i)] = col[start + k, 0]
    return Ball(out)


def stack_pd(vec: Any, states: int, r: int) -> bool:
    """Every joint state's ``r x r`` block of the ball column ``vec`` proved positive
    definite (:func:`~ftc_verify.analysis.rigorous.proven_positive_definite`)."""
    v = r * (r + 1) // 2
    return all(proven_positive_definite(unvech_ball(vec, s * v, r)) for s in range(states))


def float_pd(vec: Matrix, states: int, r: int, *, margin: float = 0.0) -> bool:
    """Every joint state's block of the float column ``vec`` has a float64 smallest
    eigenvalue above ``margin`` times its largest modulus (with the default ``0``:
    positive): a necessary condition of :func:`stack_pd` on a ball around ``vec`` (the
    ball contains its midpoint), checked first because it is cheap -- skipping a proof
    only ever loses it, never claims one."""
    from .stability import unvech_stack

    for B in unvech_stack(np.asarray(vec, dtype=np.float64), states, r):
        w = np.linalg.eigvalsh(B)
        if not w[0] > margin * max(abs(w[-1]), 1e-300):
            return False
    return True


def resolvent_stack(T: Matrix, states: int, r: int, *, margin: float, residual: bool) -> Matrix | None:
    r"""The float64 cone test of a one-period map ``T`` (the stable argument of
    :mod:`~ftc_verify.analysis.moments.sampled_proof`): the stack
    :math:`Y = (I - T)^{-1} I` (:func:`identity_stack`) when it is finite and every joint
    state's block of :math:`Y` -- and, with ``residual``, of :math:`Y - T Y` -- passes
    :func:`float_pd` with relative ``margin``; else ``None``. :math:`Y \succ 0` and
    :math:`Y - T Y \succ 0` give :math:`\rho(T) < 1`; in exact arithmetic
    :math:`Y - T Y = I`, so ``residual`` checks the float solve. A float screen, never a
    proof: ``sampled_scan.octave_verdicts`` takes ``margin=0`` without the residual,
    the ball proofs' float pre-checks ``1e-9`` with it."""
    try:
        y = np.asarray(np.linalg.solve(np.eye(T.shape[0]) - T, identity_stack(states, r)), dtype=np.float64)
    except np.linalg.LinAlgError:
        return None
    if not (np.all(np.isfinite(y)) and float_pd(y, states, r, margin=margin)):
        return None
    if residual and not float_pd(np.asarray(y - T @ y, dtype=np.float64), states, r, margin=margin):
        return None
    return y


def identity_stack(states: int, r: int) -> Matrix:
    """``vech`` of the identity in every joint state."""
    rows, cols = vech_order(r)
    return np.tile((rows == cols).astype(float), states)


def left_perron(T: Matrix) -> Matrix | None:
    """The left Perron vector of ``T`` in float64 (``None`` when the dominant eigenvalue is not real)."""
    w, V = np.linalg.eig(T.T)
    k = int(np.argmax(np.abs(w)))
    if abs(w[k].imag) > 1e-9 * max(abs(w[k]), 1e-300):
        return None
    v = np.real(V[:, k])
    return v if np.all(np.isfinite(v)) else None


def right_perron(T: Matrix) -> Matrix | None:
    """The right Perron stack of ``T`` in float64, scaled to largest entry 1 with a
    positive sum (``None`` when the dominant eigenvalue is not real)."""
    w, V = np.linalg.eig(T)
    k = int(np.argmax(np.abs(w)))
    if abs(w[k].imag) > 1e-9 * max(abs(w[k]), 1e-300):
        return None
    v = np.real(V[:, k])
    v = -v if v.sum() < 0 else v
    v = v / np.max(np.abs(v))
    return v if np.all(np.isfinite(v)) else None


#: The right-hand side of :math:`(I - T_0) Y_0 = b` tried by the certificates: ``None``
#: for the identity stack, ``k`` for the float Perron stack plus ``k`` times it (a
#: float choice: the proof checks whatever it gives).
RHS_MIXES: tuple[float | None, ...] = (None, 0.05)


def float_choices(T0: Matrix, J0: list[Matrix], states: int, r: int, mix: float | None = None,
                  sigma: float | None = None) -> tuple[Matrix, list[Matrix]] | None:
    r"""``(Y_0, [y_a])`` of the module docstring in float64 (``None`` when a solve fails),
    with :math:`(I - T_0) Y_0 = b`: ``b`` the identity stack (``mix`` ``None``) or the
    right Perron stack :math:`v` of :math:`T_0` plus ``mix`` times the identity stack --
    then :math:`Y_0 - T_0 Y_0 \approx v + k I` is aligned with :math:`Y_0 \approx v /
    (1 - \rho)`, and the vertex condition :math:`b - s Y_0 \succ 0` holds up to
    :math:`s \approx 1 - \rho` (with the identity, only up to :math:`1 / \lambda_{max}`
    of :math:`Y_0`'s blocks, far less when a Perron block is anisotropic). With ``sigma``
    (:math:`\rho(T_0) < \sigma < 1`; ``mix`` is then ignored) instead
    :math:`(I - T_0 / \sigma) Y_0 = I`: :math:`Y_0 = \sum_k (T_0/\sigma)^k I \succ 0`
    and :math:`Y_0 - T_0 Y_0 - s Y_0 = \sigma I + (1 - \sigma - s) Y_0`, positive
    definite for every :math:`s \le 1 - \sigma`
    (:func:`~ftc_verify.analysis.moments.sampled_second.certify_second_order` takes
    :math:`\sigma` just below :math:`1 - s` for the :math:`s` it needs)."""
    N = T0.shape[0]
    A = np.eye(N) - T0
    rhs, lhs = identity_stack(states, r), A
    if sigma is not None:
        lhs = np.eye(N) - T0 / sigma
    elif mix is not None:
        v = right_perron(T0)
        if v is None:
            return None
        rhs = v + mix * rhs
    try:
        y0 = np.linalg.solve(lhs, rhs)
    except np.linalg.LinAlgError:
        return None
    w = left_perron(T0)
    if w is None or not np.all(np.isfinite(y0)) or w @ y0 == 0:
        return None
    ys = []
    for J in J0:
        g = J @ y0
        rhs = g - (w @ g) / (w @ y0) * y0
        try:
            ya = np.linalg.solve(A, rhs)
        except np.linalg.LinAlgError:
            return None
        if not np.all(np.isfinite(ya)):
            return None
        ys.append(ya)
    return np.asarray(y0, dtype=np.float64), [np.asarray(y, dtype=np.float64) for y in ys]


def perron_first_order_stable(loop: SampledLoop, parts: Any, lo: Matrix, hi: Matrix, T_mid: Matrix,
                              deadline: float = math.inf) -> bool:
    """``True`` only if :math:`\\rho(T(r)) < 1` is proved for every rate array ``r`` of
    ``[lo, hi]`` by the moving certificate of the module docstring. ``parts`` is the
    sampled proof's :class:`~ftc_verify.analysis.moments.sampled_proof.MapParts` at the
    period; ``T_mid`` the float map at the midpoint. ``False`` also when the Van Loan
    block exceeds :data:`FIRST_ORDER_LIMIT`, no rate is free or ``deadline``
    (``time.perf_counter()``) passes."""
    flint = _flint()
    if 2 * parts.modes.nrows() > FIRST_ORDER_LIMIT:
        return False
    chain, lit, S, r = loop.chain, loop.literals, loop.states, loop.r
    free = [(idx, coef) for idx, coef in generator_coefficients(chain)[1] if hi[idx] > lo[idx]]
    if not free:
        return False
    mid = 0.5 * (lo + hi)
    Q0 = ball_generator(chain, mid, mid, lit).value
    Qb = ball_generator(chain, lo, hi, lit).value
    J0, Jb = [], []
    for _, coef in free:
        if time.perf_counter() > deadline:
            return False
        J0.append(parts.derivative(Q0, coef))
        Jb.append(parts.derivative(Qb, coef))
    choice = float_choices(T_mid, [midpoint(Ball(J)) for J in J0], S, r)
    if choice is None:
        return False
    y0f, ysf = choice
    Y0 = ball(np.asarray(y0f[:, None], dtype=float)).value
    ys = [ball(np.asarray(y[:, None], dtype=float)).value for y in ysf]
    T0 = parts.map(Q0)
    base = Y0 - T0 * Y0
    ends, lin = [], []
    spread = flint.arb_mat(Y0.nrows(), 1)  # sum_a [delta_a] y_a
    rem = flint.arb_mat(Y0.nrows(), 1)
    for (idx, _), J, JB, y in zip(free, J0, Jb, ys):
        e = (enclose(float(lo[idx]), lit, computed_exact=True) - flint.arb(float(mid[idx])),
             enclose(float(hi[idx]), lit, computed_exact=True) - flint.arb(float(mid[idx])))
        ends.append(e)
        lin.append(y - T0 * y - J * Y0)
        spread += e[0].union(e[1]) * y
        rem += e[0].union(e[1]) * ((JB - J) * Y0)
    for e, JB in zip(ends, Jb):
        rem += e[0].union(e[1]) * (JB * spread)
    for corner in itertools.product((0, 1), repeat=len(free)):
        vec, Y = base - rem, flint.arb_mat(Y0)
        for k, e, L, y in zip(corner, ends, lin, ys):
            vec += e[k] * L
            Y += e[k] * y
        if not (stack_pd(Y, S, r) and stack_pd(vec, S, r)):
            return False
    return True


def _rates_affine(loop: SampledLoop, lo: Matrix, hi: Matrix) -> tuple[Any, Matrix] | None:
    """``(q, dirs)``: the generator over ``[lo, hi]`` (ends as written) as
    :math:`Q(\\delta) = Q(r_0) + \\sum_a \\delta_a\\, w_a C_a`, :math:`\\delta \\in [-1, 1]^K`
    over the free rates (:math:`r_0` the midpoint, :math:`w_a` an upper bound of the
    distance from it to either written end, :math:`C_a` the exact coefficient): ``q`` the
    ``(mid, rad)`` ball of :math:`Q(r_0)` with the rounding of ``dirs`` = fl(:math:`w_a C_a`)
    added to its radius."""
    from .fast_balls import from_arb

    flint = _flint()
    chain, lit = loop.chain, loop.literals
    mid = 0.5 * (lo + hi)
    dirs = []
    for idx, coef in generator_coefficients(chain)[1]:
        if hi[idx] <= lo[idx]:
            continue
        m = flint.arb(float(mid[idx]))
        ends = [enclose(float(x), lit, computed_exact=True) - m for x in (lo[idx], hi[idx])]
        w = max(float(abs(e).upper()) for e in ends) * (1 + 2 ** -50)
        dirs.append(w * coef)
    if not dirs:
        return None
    qc, qr = from_arb(ball_generator(chain, mid, mid, lit).value)
    D = np.stack(dirs)
    return (qc, (qr + 2.0 ** -52 * np.abs(D).sum(axis=0)) * (1 + 2 ** -40)), D


@dataclass(frozen=True)
class FormSpend:
    """What a caller of :func:`affine_stable` pays for and learns (the ``h_max`` cover,
    :func:`~ftc_verify.analysis.moments.sampled_cover.cover_box`): ``second`` is asked
    before the map's polynomial form is computed, ``third`` before its third-order form
    (each computed only on ``True``, the caller's budget charged there; ``third`` None:
    never, and nothing is estimated for it), and ``reach`` is
    told :func:`~ftc_verify.analysis.moments.sampled_eigen.enclosure_reach` of the
    second-order form when every proof of it failed (when estimated). With ``cubic``, the
    form ``second`` is asked for is the third-order one with its signed terms
    (:func:`~ftc_verify.analysis.moments.cubic_balls.cubic_terms`, where
    :func:`~ftc_verify.analysis.moments.cubic_balls.cubic_forms` allows it), proved by
    :func:`~ftc_verify.analysis.moments.sampled_eigen3.cubic_radius_bound` alone, and
    ``reach`` is told that enclosure's reach when it proves nothing.
    Without one the form is always computed and the third-order form never."""

    second: Callable[[], bool]
    third: Callable[[], bool] | None
    reach: Callable[[float], None]
    cubic: bool = False


def affine_stable(loop: SampledLoop, parts: Any, lo: Matrix, hi: Matrix,
                  spend: FormSpend | None = None) -> bool | None:
    """``True`` only if :math:`\\rho(T(r)) < 1` is proved for every rate array of
    ``[lo, hi]`` from the affine enclosure :math:`T(r) \\in T_c + \\sum_a \\delta_a T_a + E`
    (:func:`~ftc_verify.analysis.moments.fast_balls.aff_map`) and the moving certificate
    of the module docstring, :math:`Y(\\delta) = Y_0 + \\sum_a \\delta_a y_a` with
    :math:`T_a` in place of :math:`J_a(r_0)` (the same first-order term, scaled by the
    half-width): :math:`Y(\\delta) - T Y(\\delta)` is its affine part
    :math:`Y_0 - T_c Y_0 + \\sum_a \\delta_a (y_a - T_c y_a - T_a Y_0)` plus
    :math:`-\\sum_{a,b} \\delta_a \\delta_b T_a y_b - E\\, Y(\\delta)`, bounded entrywise
    by :math:`\\sum_a |T_a| \\sum_b |y_b| + |E| (|Y_0| + \\sum_b |y_b|)`; the affine part
    is evaluated at every vertex :math:`\\delta \\in \\{-1, 1\\}^K` in floating point with
    its rounding bounded as in :mod:`~ftc_verify.analysis.moments.fast_balls`, and every
    joint state's block is proved positive definite there, with :math:`Y(\\delta)`'s
    (convex combinations, as above). ``None`` (not applicable) when no rate is free, more
    than :data:`AFFINE_RATES` are, Arb's precision is above 64 bits or a number overflows.

    Last, where every proof of the second-order form failed and the eigenpair enclosure
    would prove the sub-box with that form's remainder divided by :data:`CUBIC_GAIN` (a
    float estimate), the third-order form
    (:func:`~ftc_verify.analysis.moments.cubic_balls.cubic_map`: the same coefficients, a
    smaller remainder) is computed and the enclosure tried on it -- only with ``spend``
    (:class:`FormSpend`), which also decides whether anything is tried here at all
    (``False`` when it declines: neither the form nor, in
    :func:`~ftc_verify.analysis.moments.sampled_proof.subbox_stable`, the proofs tried
    where no form applies). Where ``spend.cubic`` says so (and
    :func:`~ftc_verify.analysis.moments.cubic_balls.cubic_forms` allows), the form is
    instead the third-order one with its signed terms, proved by
    :func:`~ftc_verify.analysis.moments.sampled_eigen3.cubic_radius_bound` alone."""
    from .cubic_balls import cubic_forms, cubic_map, cubic_terms
    from .fast_balls import aff_map
    from .quad_balls import pairs, quad_map

    if spend is not None and not spend.second():  # declined: no form, nor the proofs after it
        return False
    if parts.floats == () or _flint().ctx.prec > 64:
        return None
    found = _rates_affine(loop, lo, hi)
    if found is None or len(found[1]) > AFFINE_RATES:
        return None
    res, modes, lift, h = parts.floats
    K = len(found[1])
    if spend is not None and spend.cubic and cubic_forms(K, modes[0].shape[0]):
        from .sampled_eigen3 import cubic_radius_bound

        terms = cubic_terms(res, modes, found[0], found[1], h, lift)
        bound = None if terms is None else cubic_radius_bound(terms, loop.states, loop.r)
        if bound is not None and bound.top is not None and bound.top < 1.0:
            return True
        if bound is not None and bound.reach is not None:
            spend.reach(bound.reach)
        return False
    second = quadratic_forms(K, modes[0].shape[0])
    form = quad_map(res, modes, found[0], found[1], h, lift) if second else None
    if form is None:
        aff = aff_map(res, modes, found[0], found[1], h, lift)
        if aff is None:
            return None
        form = (aff[0], aff[1], np.zeros((0,) + aff[0].shape), aff[2])
    from .sampled_eigen import eigen_radius_bound, eigen_stable, enclosure_reach
    from .sampled_second import certify_second_order

    if eigen_stable(loop, form):
        return True
    for mix in RHS_MIXES:
        if certify_second_order(loop, form, mix):
            return True
        if _certify(loop, form, pairs(K) if form[2].shape[0] else (), mix):
            return True
    if certify_second_order(loop, form, shifted=True):
        return True
    if spend is None or not (second and form[2].shape[0]):
        return False
    estimate = enclosure_reach(form)
    if estimate is not None:
        spend.reach(estimate)
    # the remainder-limited case: the third-order terms with their signs (cubic_balls)
    if spend.third is None or not cubic_forms(K, modes[0].shape[0]):
        return False
    est = eigen_radius_bound(form[:3] + (form[3] / CUBIC_GAIN,), loop.states, loop.r)
    if est is None or est >= 1.0 or not spend.third():
        return False
    tight = cubic_map(res, modes, found[0], found[1], h, lift)
    return tight is not None and eigen_stable(loop, tight)


def _certify(loop: SampledLoop, form: tuple[Matrix, Matrix, Matrix, Matrix], prs: Sequence[tuple[int, int]],
             mix: float | None = None) -> bool:
    r"""The vertex checks of :func:`affine_stable` on :math:`T(\delta) \in T_c +
    \sum_a \delta_a T_a + \sum_{(a, b) \in prs} \delta_a \delta_b T_{ab} + E`."""
    flint = _flint()
    Tc, Tl, Tq, Tr = form
    S, r, N, K = loop.states, loop.r, Tc.shape[0], Tl.shape[0]
    choice = float_choices(Tc, list(Tl), S, r, mix)
    if choice is None:
        return False
    Y0, ys = choice
    Yl = np.stack(ys)
    u, eta = 2.0 ** -53, 2.0 ** -1022

    def up(v: Matrix, k: int) -> Matrix:
        return np.asarray(v * (1.0 + 2.0 * (k + 1) * u) + (k + 1) * eta)

    def sum_abs(x: Matrix) -> Matrix:
        return up(np.abs(x).sum(axis=0), x.shape[0] + 1) if x.shape[0] else np.zeros(x.shape[1:])

    base = Y0 - Tc @ Y0
    lin = Yl - Yl @ Tc.T - np.einsum("aij,j->ai", Tl, Y0)
    aTc, aTl, aY0, aYl, aTq = np.abs(Tc), sum_abs(Tl), np.abs(Y0), sum_abs(Yl), sum_abs(Tq)
    # the terms of degree two (with their signs, then bounded), three and the radius
    quad = [Tq[k] @ Y0 + Tl[a] @ Yl[b] + (Tl[b] @ Yl[a] if a != b else 0.0) for k, (a, b) in enumerate(prs)]
    rad = (sum_abs(np.stack(quad)) if quad else aTl @ aYl) + aTq @ aYl + Tr @ (aY0 + aYl)
    rad += (1.01 * N * u + 3 * u) * (aTc @ (aY0 + aYl) + aTl @ (aY0 + aYl) + aTq @ aY0)
    rad += (K + 4) * u * (np.abs(base) + sum_abs(lin))
    rad = up(rad, N + K + len(prs) + 12) + (3 * K + 4) * N * eta
    yrad = up((K + 2) * u * (aY0 + aYl), K + 4)
    arb = flint.arb
    for corner in itertools.product((-1.0, 1.0), repeat=K):
        sg = np.array(corner)
        v = base + sg @ lin
        Y = Y0 + sg @ Yl
        if not (float_pd(Y, S, r) and float_pd(v, S, r)):
            return False
        vec = flint.arb_mat(N, 1, [arb(float(x), float(e)) for x, e in zip(v, rad)])
        Yb = flint.arb_mat(N, 1, [arb(float(x), float(e)) for x, e in zip(Y, yrad)])
        if not (stack_pd(Yb, S, r) and stack_pd(vec, S, r)):
            return False
    return True

