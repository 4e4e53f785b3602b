r"""Proofs about the sampled loop's one-period map in ball arithmetic, over the rate box.

The map :math:`T = \mathcal P e^{\mathcal L h} \mathcal R` of
:mod:`ftc_verify.analysis.moments.sampled` is formed in Arb's ball arithmetic
(:mod:`ftc_verify.analysis.rigorous`): the system's numbers as written (exact balls),
the rates of a sub-box of the rate box as balls covering it, the period as written,
:math:`e^{\mathcal L h}` by the float64 midpoint-radius ball exponential of
:mod:`ftc_verify.analysis.moments.fast_balls` (a ball containing the exponential of
every matrix in the ball, with its error analysis; the whole map
:math:`\mathcal P e^{\mathcal L h} \mathcal R` in that arithmetic, Arb's
``arb_mat.exp`` and products when a float overflows or at a working precision above
64 bits: the precise retries) and a dynamic controller's
:math:`(\Phi_c, \Gamma_c)` by Arb's rigorous matrix exponential. So one ball matrix
:math:`\mathbf T` contains the map of every rate in the sub-box.

**Stable** (derived here). :math:`T` maps the cone of positive semidefinite stacks to
itself. If a stack :math:`Y \succ 0` has :math:`Y - T(Y) \succ 0`, then
:math:`T(Y) \preceq c\,Y` for some :math:`c < 1` (both sides continuous, the set of
unit stacks compact), hence :math:`T^k(Y) \preceq c^k Y \to 0`; every positive
semidefinite :math:`X` lies below a multiple of :math:`Y`, so :math:`T^k(X) \to 0`,
and the cone spans all symmetric stacks: :math:`\rho(T) < 1`. :math:`Y` is the float
solution of :math:`Y - T_{mid}(Y) = I`; :math:`Y_s \succ 0` and
:math:`Y_s - \mathbf T(Y)_s \succ 0` are proved by
:func:`~ftc_verify.analysis.rigorous.proven_positive_definite` for every joint state,
with :math:`\mathbf T(Y)` in ball arithmetic -- for every rate of the sub-box at once.

**Unstable.** If :math:`X \succ 0` has :math:`T(X) - X \succ 0`, then
:math:`T(X) \succeq (1 + \epsilon) X` for some :math:`\epsilon > 0`, so
:math:`T^k(X) \succeq (1 + \epsilon)^k X` grows without bound: :math:`\rho(T) > 1`,
the loop is not mean-square stable at that rate. :math:`X` is the float Perron
eigenvector of :math:`T_{mid}` (a positive semidefinite stack), shifted by a small
multiple of :math:`I` when singular. When that fails (a singular Perron stack), a
sign change of :math:`\det(T - x I)` across the largest real eigenvalue, proved by
Arb's determinant, shows an eigenvalue above 1 (``_real_eigenvalue_above_one``).

**Upper envelope** (derived here). Split :math:`\mathcal L(r) = \mathcal D(r) +
\mathcal O(r)`: :math:`\mathcal D` acts on each joint state alone,
:math:`X_s \mapsto \bar A X_s + X_s \bar A^T + Q_{ss} X_s`, and :math:`\mathcal O`
moves mass between states, :math:`X \mapsto (\sum_{s' \ne s} Q_{s's} X_{s'})_s`.
:math:`e^{\mathcal D t}` and :math:`\mathcal O` are positive (they map positive
semidefinite stacks to positive semidefinite stacks), so every term of the Dyson
series of :math:`e^{(\mathcal D + \mathcal O) h}` is a product of positive maps, each
monotone in the rates: :math:`e^{\mathcal D(r) t}` decreases (the diagonal
:math:`Q_{ss}` falls as the rates grow), :math:`\mathcal O(r)` increases. Products of
positive maps are monotone, hence for every :math:`r` in :math:`[lo, hi]`,
:math:`T(r) \preceq T_{up} = \mathcal P e^{(\mathcal D(lo) + \mathcal O(hi)) h}
\mathcal R` in the order of positive maps, and :math:`Y - T(r)(Y) \succeq Y -
T_{up}(Y)` for :math:`Y \succeq 0`: one point computation, without the wrapping of
a ball over the box (:func:`envelope_generator`). Its price is the mass it creates,
about :math:`h` times the widths of the rates.

**Over the box** (:func:`box_verdict`): the float64 radius at the vertices and the
midpoint first; if some point has :math:`\rho \ge 1`, instability is proved there.
Otherwise the stable proof is tried on the whole box, and a sub-box where it fails is
halved along the rate the float64 radius depends on most there (:func:`split_rate`),
breadth first, until every sub-box is proved -- or a sub-box's midpoint is proved
unstable, or the budget of sub-boxes (or seconds) runs out: then the verdict is
``undecided`` and names the sub-box. On each sub-box (:func:`subbox_stable`) the upper envelope is tried first, then the enclosure of
:math:`T` as a polynomial in the sub-box's rates (second order where
:func:`~ftc_verify.analysis.moments.sampled_taylor.quadratic_forms` allows, six
rates at 189 rows included, :mod:`~ftc_verify.analysis.moments.quad_balls`; affine
above, :func:`~ftc_verify.analysis.moments.fast_balls.aff_expm`) with a certificate that moves
with the rates (:func:`~ftc_verify.analysis.moments.sampled_taylor.affine_stable`; the
shifted one of :mod:`~ftc_verify.analysis.moments.sampled_second` last): the
rates stay symbols through the exponential, so a transfer of mass between joint states
is not wrapped into independent entrywise balls, and the sub-boxes need only be about
:math:`\sqrt{\epsilon}` (second order: :math:`\epsilon^{1/3}`) wide where the margin is
:math:`\epsilon`. Only when that is not applicable (more than
:data:`~ftc_verify.analysis.moments.sampled_taylor.AFFINE_RATES` free rates, Arb
precision above 64 bits, overflow) the direct ball of :math:`T` and the first-order
expansion with the derivative's ball over the sub-box
(:func:`~ftc_verify.analysis.moments.sampled_taylor.perron_first_order_stable`) are
tried. A set of vertices is never called proved. The ball exponential of
:math:`\mathcal L` is the cost (a few tenths of a second at 189 rows in float64 balls,
seconds in Arb), so the envelope and the direct ball are attempted only when
their criterion holds in float64 first (``_float_stable``: the envelope's map;
``_float_vertices_hold``: :math:`Y - T(r) Y \succ 0` at the sub-box's vertices, which the
ball contains) -- a necessary condition checked with float exponentials; skipping an
attempt can leave a box undecided or split, never prove it.

**Data as written**: the flows, resets, generator and period are enclosed from the
files' decimal texts (:attr:`SampledLoop.literals`, :meth:`SampledLoop.period_ball`).
**Coordinates**: :func:`box_verdict` and :func:`prove_point_unstable` run on
:func:`~ftc_verify.analysis.moments.sampled_conditioned.conditioned` of the loop (a similar
loop, its data from the written balls and a ball inverse: :func:`~ftc_verify.analysis.moments.sampled_conditioned.written_data`).
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.linalg

from ...model.system import Matrix
from ..exact import enclose, written
from ..rigorous import PRECISION_BITS, Ball, ball, midpoint, precision
from .fast_balls import MidRad, arb_expm, from_arb, map_ball
from .sampled_conditioned import ConditionedLoop, conditioned, written_data
from .sampled_balls import ball_block_diag, ball_generator, ball_kron, envelope_generator
from .sampled import SampledLoop, assemble_map, one_period_map, rate_points, spectral_radius, worst_radius
from .sampled_taylor import (FIRST_ORDER_LIMIT, FormSpend, affine_stable, float_pd, identity_stack,
                             perron_first_order_stable, resolvent_stack, stack_pd)
from .stability import duplication_matrix

__all__ = ["FIRST_ORDER_LIMIT", "MapParts", "BoxVerdict", "ball_resets", "ball_one_period_map", "prove_stable", "prove_unstable",
           "prove_point_unstable", "box_verdict", "SPLIT_WIDTH_WEIGHT", "written_flow", "envelope_stable",
           "split_rate", "subbox_stable", "FLOAT_MARGIN"]

#: The relative margin of the float64 pre-checks of the stable proofs (``_float_stable``,
#: ``_float_vertices_hold``): a block counts as positive definite there when its smallest
#: eigenvalue exceeds this times its largest modulus.
FLOAT_MARGIN = 1e-9


def _flint() -> Any:
    import flint

    return flint


def _written_only(loop: SampledLoop) -> None:
    if isinstance(loop, ConditionedLoop):  # its floats are moved data, not the numbers written
        raise TypeError("the written balls of a conditioned loop come from written_data")


def written_flow(loop: SampledLoop, A: Matrix) -> Ball:
    """The ball of a balanced flow matrix :math:`\\bar A_i` with the user's numbers as
    written: entry :math:`(i, j)` is the written :math:`A_{ij}` (or :math:`B_{ij}`) times the
    power of two :math:`s_j / s_i` of the balancing (exact). Not for a
    :class:`~ftc_verify.analysis.moments.sampled_conditioned.ConditionedLoop` (its floats
    are not the numbers written: :func:`~ftc_verify.analysis.moments.sampled_conditioned.written_data`)."""
    _written_only(loop)
    flint = _flint()
    sc = loop.scale
    out = flint.arb_mat(A.shape[0], A.shape[1])
    for i, j in zip(*np.nonzero(A)):
        factor = float(sc[j] / sc[i])
        out[int(i), int(j)] = enclose(float(A[i, j]) / factor, loop.literals) * factor
    return Ball(out)


def ball_resets(loop: SampledLoop, h: float) -> list[Ball]:
    """:math:`R_s` as ball matrices; a dynamic controller's :math:`(\\Phi_c, \\Gamma_c)`
    from the rigorous exponential of :math:`[[A_c, B_c], [0, 0]] h` (Van Loan). Not for a
    :class:`~ftc_verify.analysis.moments.sampled_conditioned.ConditionedLoop`
    (:func:`~ftc_verify.analysis.moments.sampled_conditioned.written_data`)."""
    _written_only(loop)
    flint = _flint()
    n, nu, nc = loop.n, loop.nu, loop.nc
    c = loop.controller
    lit = loop.literals
    zoh: dict[int, tuple[Any, Any]] = {}
    out = []
    for M_float, e in zip(loop.measurement, loop.entry):
        M = written(M_float, lit)
        R = flint.arb_mat(loop.d, loop.r)
        for k in range(n):
            R[k, k] = 1
        DM = (written(c.Dc[e], lit) @ M).value
        for i in range(nu):
            for j in range(n):
                R[n + i, j] = DM[i, j]
        if nc:
            if e not in zoh:
                nv = c.n_v
                V = np.zeros((nc + nv, nc + nv))
                V[:nc, :nc], V[:nc, nc:] = c.Ac[e], c.Bc[e]
                E = _held_exponential(written(V, lit).value, loop.period_ball(h))
                zoh[e] = (E, None)
            E = zoh[e][0]  # [[Phi_c, Gamma_c], [0, I]]
            GM = (Ball(flint.arb_mat([[E[i, nc + j] for j in range(c.n_v)] for i in range(nc)])) @ M).value
            Cc = written(c.Cc[e], lit).value
            for i in range(nu):
                for j in range(nc):
                    R[n + i, n + j] = Cc[i, j]
            for i in range(nc):
                for j in range(n):
                    R[n + nu + i, j] = GM[i, j]
                for j in range(nc):
                    R[n + nu + i, n + j] = E[i, j]
        # the balanced coordinates: powers of two, exact
        out.append(ball(np.diag(1.0 / loop.scale)) @ Ball(R) @ ball(np.diag(loop.scale_r)))
    return out


def _held_exponential(V: Any, hb: Any) -> Any:
    """A ball containing :math:`e^{V t}` for every :math:`V` in the ball ``V`` and every
    :math:`t` in the ball ``hb``: :math:`e^{V h_0}\\, e^{V (t - h_0)}` with :math:`h_0` the
    ball's (exact) midpoint -- equal for each :math:`V` (:math:`V` commutes with itself).
    One exponential of :math:`V \\mathbf h` instead multiplies the period's radius by
    :math:`\\|V\\| h` at every squaring: the observer of ``examples/paper_observer.toml``
    at ``h = 1e4`` (the period as written: radius ``1.1e-12``) had radii ``8e15``."""
    flint = _flint()
    h0 = flint.arb(hb.mid())
    if hb.rad() == 0:
        return (V * h0).exp()
    return (V * h0).exp() * (V * (hb - h0)).exp()


@dataclass(frozen=True, eq=False)
class MapParts:
    """The rate-independent balls of :math:`T` at one period: the block diagonal of
    :math:`\\mathcal L`, :math:`\\mathcal P`, :math:`\\mathcal R`, the period."""

    modes: Any
    res: Any
    lift: Any
    h: Any
    vd: int
    states: int
    literals: Any = None
    floats: tuple[MidRad, ...] = ()  # (res, modes, lift, h) as float64 balls (fast_balls)

    @classmethod
    def build(cls, loop: SampledLoop, h: float) -> MapParts:
        Dd, Ld = duplication_matrix(loop.d)
        Dr, Lr = duplication_matrix(loop.r)
        eye = ball(np.eye(loop.d))
        flows, resets = written_data(loop, h)
        blocks = [ball(Ld) @ (ball_kron(eye, Ab) + ball_kron(Ab, eye)) @ ball(Dd) for Ab in flows]
        P = loop.restriction()
        restrict = ball(np.asarray(Lr @ np.kron(P, P) @ Dd, dtype=float))  # 0/1 products of 0/1 matrices: exact
        lift = ball_block_diag([ball(Ld) @ ball_kron(R, R) @ ball(Dr) for R in resets])
        modes, res, hb = ball_block_diag(blocks).value, ball_block_diag([restrict] * loop.states).value, loop.period_ball(h)
        floats = tuple(from_arb(x) for x in (res, modes, lift.value, _flint().arb_mat(1, 1, [hb])))
        return cls(modes, res, lift.value, hb, Dd.shape[1], loop.states, loop.literals, floats)

    def generator(self, Q: Any) -> Any:
        """:math:`\\mathcal L = ` blocks :math:`+ Q^T \\otimes I` for a ball generator ``Q``."""
        G = _flint().arb_mat(self.modes)
        vd = self.vd
        for s in range(self.states):
            for t in range(self.states):
                q = Q[t, s]
                for k in range(vd):
                    G[s * vd + k, t * vd + k] += q
        return G

    def map(self, Q: Any) -> Any:
        """:math:`T = \\mathcal P e^{\\mathcal L h} \\mathcal R` (ball): in float64
        midpoint-radius arithmetic (:func:`~ftc_verify.analysis.moments.fast_balls.map_ball`)
        at Arb's working precision up to 64 bits; in Arb when a number overflows there,
        and at a higher working precision (the proofs' precise retries)."""
        if _flint().ctx.prec <= 64:
            res, modes, lift, h = self.floats
            out = map_ball(res, modes, Q, h, lift)
            if out is not None:
                return out
        return self.res * arb_expm(self.generator(Q) * self.h) * self.lift

    def derivative(self, Q: Any, coef: Matrix) -> Any:
        """:math:`\\partial T / \\partial r` along a rate whose generator coefficient is
        ``coef`` (:math:`\\partial Q / \\partial r`): the top-right block of
        :math:`\\exp\\bigl(\\bigl[\\begin{smallmatrix} \\mathcal L & E \\\\ 0 & \\mathcal L
        \\end{smallmatrix}\\bigr] h\\bigr)` with :math:`E = coef^T \\otimes I` (Van Loan:
        the Frechet derivative of the exponential), between :math:`\\mathcal P` and
        :math:`\\mathcal R`."""
        flint = _flint()
        G = self.generator(Q)
        N, vd = G.nrows(), self.vd
        V = flint.arb_mat(2 * N, 2 * N)
        for i in range(N):
            for j in range(N):
                g = G[i, j]
                V[i, j] = g
                V[N + i, N + j] = g
        for s in range(self.states):
            for t in range(self.states):
                c = float(coef[t, s])
                if c:
                    for k in range(vd):
                        V[s * vd + k, N + t * vd + k] = c
        E = arb_expm(V * self.h)
        D = flint.arb_mat(N, N)
        for i in range(N):
            for j in range(N):
                D[i, j] = E[i, N + j]
        return self.res * D * self.lift


def ball_one_period_map(loop: SampledLoop, h: float, lo: Matrix, hi: Matrix) -> Ball:
    """A ball matrix containing :math:`T` (:mod:`ftc_verify.analysis.moments.sampled`) at period
    ``h`` for every rate array in ``[lo, hi]``, in the balanced coordinates of
    :attr:`SampledLoop.scale` (``one_period_map(..., scaled=True)``; same spectrum)."""
    return Ball(MapParts.build(loop, h).map(ball_generator(loop.chain, lo, hi, loop.literals).value))


def prove_stable(T: Ball, T_mid: Matrix, states: int, r: int) -> bool:
    """``True`` only if :math:`\\rho(T) < 1` for every map in the ball ``T`` (module
    docstring); ``T_mid`` is a float map inside (or near) it."""
    N = T_mid.shape[0]
    try:
        y = np.linalg.solve(np.eye(N) - T_mid, identity_stack(states, r))
    except np.linalg.LinAlgError:
        return False
    if not np.all(np.isfinite(y)):
        return False
    Y = ball(np.asarray(y[:, None], dtype=float))
    if not stack_pd(Y.value, states, r):
        return False
    return stack_pd((Y - T @ Y).value, states, r)


def envelope_stable(loop: SampledLoop, parts: MapParts, lo: Matrix, hi: Matrix) -> bool:
    """The stable proof on a sub-box by the upper envelope (module docstring):
    :math:`T(r) \\preceq T_{up}` for every rate of the sub-box, so :math:`Y \\succ 0`,
    :math:`Y - T_{up}(Y) \\succ 0` proves :math:`\\rho(T(r)) < 1` for all of them."""
    Q_up = envelope_generator(loop.chain, lo, hi, loop.literals)
    if not _float_stable(loop, midpoint(Q_up), float(parts.h.mid())):
        return False  # the float64 criterion fails: the ball one would too (its exponential is the cost)
    T_up = Ball(parts.map(Q_up.value))
    return prove_stable(T_up, midpoint(T_up), loop.states, loop.r)


def _float_vertices_hold(loop: SampledLoop, h: float, lo: Matrix, hi: Matrix, T_mid: Matrix,
                         limit: int = 16) -> bool:
    """A float64 necessary condition of the direct ball proof on ``[lo, hi]``: with
    :math:`Y = (I - T_{mid})^{-1} I`, :math:`Y - T(r) Y \\succ 0` at every vertex
    :math:`r` of the sub-box (the ball contains every :math:`T(r)`). ``True`` (do the ball
    proof) when the sub-box has more than ``limit`` vertices."""
    free = [idx for idx in loop.chain.rate_indices if hi[idx] > lo[idx]]
    if 2 ** len(free) > limit:
        return True
    y = resolvent_stack(T_mid, loop.states, loop.r, margin=FLOAT_MARGIN, residual=False)
    if y is None:
        return False
    for corner in itertools.product((0, 1), repeat=len(free)):
        r = np.array(lo, dtype=float)
        for k, idx in zip(corner, free):
            r[idx] = hi[idx] if k else lo[idx]
        T = one_period_map(loop, h, r, scaled=True)
        if not float_pd(y - T @ y, loop.states, loop.r, margin=FLOAT_MARGIN):
            return False
    return True


def _float_stable(loop: SampledLoop, Q: Matrix, h: float) -> bool:
    """The criterion of :func:`prove_stable` in float64 on the map of the generator ``Q``
    (:func:`~ftc_verify.analysis.moments.sampled_taylor.resolvent_stack` with the residual,
    margin :data:`FLOAT_MARGIN`): a necessary condition of the ball proof, checked
    first because it costs one float exponential instead of a ball one. Skipping a proof
    only ever leaves a box undecided (or split), never proves anything."""
    vd = loop.d * (loop.d + 1) // 2
    F = scipy.linalg.expm((loop.modes_part + np.kron(Q.T, np.eye(vd))) * h)
    T = assemble_map(loop, F, h)
    return resolvent_stack(T, loop.states, loop.r, margin=FLOAT_MARGIN, residual=True) is not None


def prove_unstable(T: Ball, T_mid: Matrix, states: int, r: int) -> bool:
    """``True`` only if :math:`\\rho(T) > 1` for every map in the ball ``T`` (module
    docstring)."""
    w, V = np.linalg.eig(T_mid)
    k = int(np.argmax(np.abs(w)))
    if abs(w[k].imag) > 1e-9 * abs(w[k]) or w[k].real <= 1.0:
        return False
    v = V[:, k].real
    if v.sum() < 0:  # the trace-like sum of a PSD stack is positive
        v = -v
    v = v / np.max(np.abs(v))
    eye = identity_stack(states, r)
    for eps in (0.0, 1e-9, 1e-6, 1e-4, 1e-2):
        x = v + eps * eye
        X = ball(x[:, None])
        if stack_pd(X.value, states, r) and stack_pd((T @ X - X).value, states, r):
            return True
    return _real_eigenvalue_above_one(T, w)


def _real_eigenvalue_above_one(T: Ball, w: Matrix) -> bool:
    """``True`` only if every map in the ball ``T`` has a real eigenvalue above 1 (so
    :math:`\\rho > 1`), when the Perron stack is singular and the cone proof cannot be
    used: :math:`p(x) = \\det(T - x I)` is real and continuous in :math:`x`, and if
    :math:`p(a)\\, p(b) < 0` (both signs proved by Arb's determinant) for some
    :math:`1 < a < b`, :math:`p` has a root in :math:`(a, b)`. ``w`` are the float
    eigenvalues; :math:`(a, b)` is placed around the largest real one, away from the
    other real ones (complex pairs do not change the sign of :math:`p`)."""
    flint = _flint()
    real = np.sort(np.real(w[np.abs(np.imag(w)) <= 1e-12 * np.maximum(1.0, np.abs(w))]))
    if real.size == 0 or real[-1] <= 1.0:
        return False
    lam = float(real[-1])
    below = real[real < lam]
    a = max(1.0 + 0.5 * (lam - 1.0), 0.5 * (lam + float(below[-1])) if below.size else -np.inf)
    b = lam + 0.5 * (lam - a)
    if not 1.0 < a < lam < b:
        return False
    N = T.shape[0]
    eye = flint.arb_mat(N, N)
    for i in range(N):
        eye[i, i] = 1
    pa = (T.value - eye * flint.arb(a)).det()
    pb = (T.value - eye * flint.arb(b)).det()
    return bool((pa > 0 and pb < 0) or (pa < 0 and pb > 0))


def prove_point_unstable(loop: SampledLoop, h: float, rates: Matrix) -> bool:
    """``True`` only if the sampled loop at period ``h`` is proved not mean-square stable
    at the rate array ``rates`` (of the box)."""
    rates = np.asarray(rates, dtype=float)
    for frame in _frames(loop):  # the conditioned coordinates first, then the loop as written
        T_mid = one_period_map(frame, h, rates, scaled=True)
        for bits in (64, PRECISION_BITS):  # the cheap precision first
            with precision(bits):
                if prove_unstable(ball_one_period_map(frame, h, rates, rates), T_mid, frame.states, frame.r):
                    return True
    return False


def _frames(loop: SampledLoop) -> list[SampledLoop]:
    """:func:`~ftc_verify.analysis.moments.sampled_conditioned.conditioned` of ``loop``, then
    the loop as written when that is another one."""
    first = conditioned(loop)
    base = first.base if isinstance(first, ConditionedLoop) and first.base is not None else loop
    return [first] if base is first else [first, base]


@dataclass(frozen=True, eq=False)
class BoxVerdict:
    """The verdict of :func:`box_verdict` and how it was reached.

    ``verdict`` is ``"stable"`` (proved for every rate of the box), ``"not stable"``
    (proved at the rate array ``where``) or ``"undecided"`` (``where`` is the sub-box
    ``(lo, hi)`` or point left); ``boxes`` counts the sub-boxes evaluated."""

    verdict: str
    detail: str
    boxes: int
    where: Any = None


#: Weight of a rate's relative width against its change of :math:`\rho` in
#: :func:`split_rate`: at 1 a full-width rate counts as much as the largest change (random
#: ``n = 4, m = 3`` loop: 37 sub-boxes at 3 % below the crossing instead of 73 with 0.1;
#: ``n = 2, m = 2`` seed 2: 105 at ``2.5e-4`` instead of 231).
SPLIT_WIDTH_WEIGHT = 1.0


def split_rate(loop: SampledLoop, h: float, lo: Matrix, hi: Matrix) -> tuple[int, ...] | None:
    r"""The rate along which a sub-box is halved: the largest score
    :math:`s_a + c\, m\, w_a / W_a` with :math:`s_a = \max_\pm |\rho(r_0 \pm w_a e_a)
    - \rho(r_0)|` (float64 radii at the midpoint and at the sub-box's ends
    along the rate: slope and curvature), :math:`m` the largest such change,
    :math:`w_a / W_a` the relative width (weight :data:`SPLIT_WIDTH_WEIGHT`). A
    heuristic: only where the proofs look next depends on it."""
    chain = loop.chain
    full = chain.rate_max - chain.rate_min
    mid = 0.5 * (lo + hi)
    rho0 = spectral_radius(loop, h, mid)
    rel, change = {}, {}
    for idx in chain.rate_indices:
        if full[idx] > 0 and hi[idx] > lo[idx]:
            rel[idx] = (hi[idx] - lo[idx]) / full[idx]
            up, down = mid.copy(), mid.copy()
            up[idx], down[idx] = hi[idx], lo[idx]
            d = max(abs(spectral_radius(loop, h, up) - rho0), abs(spectral_radius(loop, h, down) - rho0))
            change[idx] = d if math.isfinite(d) else 0.0
    if not rel:
        return None
    m = max(change.values())
    return max(rel, key=lambda idx: (change[idx] + SPLIT_WIDTH_WEIGHT * m * rel[idx], rel[idx]))


def subbox_stable(loop: SampledLoop, h: float, parts: MapParts, lo: Matrix, hi: Matrix,
                  deadline: float = math.inf, spend: FormSpend | None = None) -> bool:
    r"""``True`` when :math:`\rho(T(r)) < 1` is proved in ball arithmetic for every rate
    array ``r`` in ``[lo, hi]`` at period ``h`` (``parts``: :meth:`MapParts.build` at
    ``h``): one sub-box of :func:`box_verdict` (module docstring, "Over the box"; the
    first-order expansion not after ``deadline``, ``time.perf_counter()``); ``spend``:
    what the map's polynomial forms may cost
    (:class:`~ftc_verify.analysis.moments.sampled_taylor.FormSpend`; where it declines the
    second-order form, only the envelope is tried)."""
    T_mid = one_period_map(loop, h, 0.5 * (lo + hi), scaled=True)
    with precision(64):
        proved = envelope_stable(loop, parts, lo, hi)
        affine = None if proved else affine_stable(loop, parts, lo, hi, spend)  # None: not applicable
        proved = proved or bool(affine)
        if not proved and affine is None and _float_vertices_hold(loop, h, lo, hi, T_mid):
            T = Ball(parts.map(ball_generator(loop.chain, lo, hi, loop.literals).value))
            proved = prove_stable(T, T_mid, loop.states, loop.r)
        if not proved and affine is None and not np.array_equal(lo, hi):
            proved = perron_first_order_stable(loop, parts, lo, hi, T_mid, deadline)
    if not proved and np.array_equal(lo, hi):
        with precision(PRECISION_BITS):
            proved = prove_stable(ball_one_period_map(loop, h, lo, hi), T_mid, loop.states, loop.r)
    return proved


def box_verdict(loop: SampledLoop, h: float, *, max_boxes: int = 64, max_seconds: float = 20.0,
                clock: Callable[[], float] = time.perf_counter, stable_only: bool = False) -> BoxVerdict:
    """Mean-square stability of the sampled loop at period ``h`` over the whole rate box
    (module docstring); at most ``max_boxes`` sub-boxes and about ``max_seconds`` seconds
    of ``clock`` (wall time; ``time.process_time``: a budget that does not shrink with
    the load) before the verdict is ``undecided``. ``stable_only``: the caller needs only
    a ``stable`` verdict (the ``h_max`` bracket), so the search stops, ``undecided``, as
    soon as the sub-boxes left exceed the budget left (``stable`` can no longer be
    reached; a ``not stable`` sub-box midpoint it might still have met is not looked for). On
    :func:`~ftc_verify.analysis.moments.sampled_conditioned.conditioned` of the loop; when
    that leaves it ``undecided`` (not ``stable_only``), the loop as written gets the budget left."""
    frames, t0 = _frames(loop), clock()
    out = _box_verdict(frames[0], h, max_boxes, max_seconds, clock, stable_only)
    if len(frames) == 1 or out.verdict != "undecided" or stable_only or out.boxes >= max_boxes:
        return out
    second = _box_verdict(frames[1], h, max_boxes - out.boxes, max_seconds - (clock() - t0), clock, stable_only)
    return out if second.verdict == "undecided" else second


def _box_verdict(loop: SampledLoop, h: float, max_boxes: int, max_seconds: float, clock: Callable[[], float],
                 stable_only: bool) -> BoxVerdict:
    chain = loop.chain
    rho, where = worst_radius(loop, h, rate_points(chain))
    text = chain.rate_text
    if not np.isfinite(rho) or rho >= 1.0:
        if np.isfinite(rho) and prove_point_unstable(loop, h, where):
            return BoxVerdict("not stable", f"spectral radius {rho:.6g} > 1 proved at {text(where)} "
                              "(ball arithmetic)", 1, where)
        return BoxVerdict("undecided", f"float64 spectral radius {rho:.6g} >= 1 at {text(where)}, but "
                          "instability not proved there", 1, where)
    queue = [(np.array(chain.rate_min, dtype=float), np.array(chain.rate_max, dtype=float))]
    done, t0, wall = 0, clock(), time.perf_counter()
    with precision(64):
        parts = MapParts.build(loop, h)
    while queue:
        lo, hi = queue.pop(0)
        if done >= max_boxes or clock() - t0 > max_seconds or (stable_only and done + 1 + len(queue) > max_boxes):
            spent = "spent" if done >= max_boxes or clock() - t0 > max_seconds else f"short of {1 + len(queue)} sub-boxes"
            return BoxVerdict("undecided", f"budget ({max_boxes} sub-boxes, {max_seconds:g} s) {spent} after {done} "
                              f"sub-boxes; not proved on [{text(lo)}] .. [{text(hi)}]", done, (lo, hi))
        done += 1
        mid = 0.5 * (lo + hi)
        if subbox_stable(loop, h, parts, lo, hi, wall + max_seconds):
            continue
        if spectral_radius(loop, h, mid) >= 1.0:
            if prove_point_unstable(loop, h, mid):
                return BoxVerdict("not stable", f"spectral radius > 1 proved at {text(mid)} (ball arithmetic)",
                                  done, mid)
            return BoxVerdict("undecided", f"float64 spectral radius >= 1 at {text(mid)}, not proved", done, mid)
        idx = split_rate(loop, h, lo, hi)
        if idx is None:
            return BoxVerdict("undecided", f"stability not proved at the rate point {text(lo)}", done, lo)
        left_hi, right_lo = hi.copy(), lo.copy()
        left_hi[idx] = right_lo[idx] = mid[idx]
        queue += [(lo, left_hi), (right_lo, hi)]
    word = "the rate box" if done == 1 else f"{done} sub-boxes covering the rate box"
    return BoxVerdict("stable", f"spectral radius < 1 proved on {word} (ball arithmetic)", done)
