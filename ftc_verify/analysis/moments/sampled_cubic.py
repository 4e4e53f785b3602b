r"""A clock-dependent certificate of mean-square stability with *cubic* pieces in the
clock, on the whole rate box or on a sub-box of it: the tighter rung of the ``h_max``
refinement (:mod:`~ftc_verify.analysis.moments.sampled_refine`).

The functional is that of :mod:`~ftc_verify.analysis.moments.sampled_clock`,
:math:`V(\tau, Z) = \sum_s \langle Y_s(\tau), Z_s\rangle` with :math:`\tau` the time since
the last sample, continuous, and on piece :math:`k` (:math:`\tau = \tau_k + t\delta`,
:math:`t \in [0, 1]`, :math:`\delta = h / N`) the cubic

.. math::

    Y_s(t) = Y_s^k + t E_s + t (1 - t) C_s + t^2 (1 - t) W_s
           = Y_s^k + t (E_s + C_s) + t^2 (W_s - C_s) - t^3 W_s,

:math:`E = Y^{k+1} - Y^k` (nodes :math:`Y^k`, curvatures :math:`C^k`, cubic terms
:math:`W^k`). The flow condition of the clock module, :math:`F_s = dY_s/d\tau +
(\mathcal L^* Y)_s \preceq 0` (:math:`\mathcal L^*` the adjoint moment generator, affine
in row :math:`s` of the rates), is on the piece the cubic :math:`F(t) = F_0 + t F_1 + t^2
F_2 + t^3 F_3` with (:math:`dY/d\tau = (E + C + 2t(W - C) - 3t^2 W)/\delta`)

.. math::

    F_0 = (E_s + C_s)/\delta + \mathcal L^*(Y^k)_s,\quad
    F_1 = 2 (W_s - C_s)/\delta + \mathcal L^*(E + C)_s,\quad
    F_2 = -3 W_s/\delta + \mathcal L^*(W - C)_s,\quad
    F_3 = -\mathcal L^*(W)_s.

**Negativity on the piece** (Lukacs' form of a cubic non-negative on :math:`[0, 1]`, with
Gram matrices): :math:`P = -F = t\,\sigma_1(t) + (1 - t)\,\sigma_2(t)`,
:math:`\sigma_i(t) = [I;\ tI]^T M_i [I;\ tI]` with :math:`M_i = \bigl[\begin{smallmatrix}
A_i & B_i \\ B_i^T & C_i\end{smallmatrix}\bigr]`. Matching the coefficients of
:math:`t^0, \dots, t^3` (:math:`P_j = -F_j`): :math:`A_2 = P_0`, :math:`A_1 = P_1 + P_0 -
(B_2 + B_2^T)`, :math:`B_1 + B_1^T = P_2 - C_2 + B_2 + B_2^T`, :math:`C_1 = P_3 + C_2`; the
free parts are :math:`B_2` (any matrix), :math:`C_2` (symmetric) and the skew part
:math:`K` of :math:`B_1` (:math:`B_1 = (P_2 - C_2 + B_2 + B_2^T)/2 + K`). When
:math:`M_1, M_2 \succ 0` (proved in ball arithmetic, the identity holding by construction)
every :math:`\sigma_i(t) \succ 0` (:math:`[I; tI]` has full column rank) and so :math:`F(t)
\prec 0` on :math:`[0, 1]`. The rest is the clock module's: :math:`Y^k \succ 0`, the sample
:math:`J_s^T Y_s^0 J_s \prec Y_s^N`, the flow conditions at the vertices of each row's
rates in the (sub-)box (affine in them), so :math:`V` proves every one-period map of the
(sub-)box -- constant rates or rates varying in time inside it -- of spectral radius
below 1.

**Why cubic, why sub-boxes** (``benchmarks/results/h31r.md``). The quadratic pieces reach a
distance about ``0.04 / N`` below the crossing with ``N`` pieces (seed-1 ``n = 4, m = 3``
loop: 16 pieces for 2.5e-3, 43 CPU s); two cubic pieces reach it in 3 CPU s, four reach
1.5e-3. Below that a certificate common to the whole box fails at any ``N`` (at the worst
vertex alone four cubic pieces reach 5e-4): it holds for rates varying in time inside
the box, which are worse than constant ones there. On a sub-box that gap shrinks, and
sub-boxes covering the box prove every constant rate of it.
"""

from __future__ import annotations

import dataclasses
import itertools
from dataclasses import dataclass
from typing import Any

import numpy as np

from ...model.system import Matrix
from ..conic import Affine, Rows, affine_bmat, sym_variable
from ..solvers import solve_conic
from .sampled import SampledLoop
from .sampled_clock import adjoint, frame_scale, node_jump_rows, proof_start, time_unit, unpack_sym

__all__ = ["CubicCertificate", "box_specs", "cubic_parts", "piece_blocks", "cubic_size", "cubic_program", "cubic_certificate",
           "prove_cubic", "cubic_stable"]


@dataclass(frozen=True, eq=False)
class CubicCertificate:
    """The nodes :math:`Y^k_s` (``nodes[k][s]``), curvatures :math:`C^k_s`, cubic terms
    :math:`W^k_s` (in the balanced coordinates of the loop it was found for) and, per piece
    and row vertex, the free Gram parts ``(B_2, C_2, K)`` (module docstring; in the frame of
    :func:`~ftc_verify.analysis.moments.sampled_clock.time_unit` and
    :func:`~ftc_verify.analysis.moments.sampled_clock.frame_scale`), found at period ``h``
    with ``pieces`` pieces for the rates in ``[lo, hi]``; ``proved``: every condition proved
    in ball arithmetic."""

    h: float
    pieces: int
    lo: Matrix
    hi: Matrix
    nodes: tuple[tuple[Matrix, ...], ...]
    curvatures: tuple[tuple[Matrix, ...], ...]
    cubics: tuple[tuple[Matrix, ...], ...]
    grams: tuple[tuple[tuple[Matrix, Matrix, Matrix], ...], ...]
    proved: bool


def box_specs(loop: SampledLoop, lo: Matrix, hi: Matrix) -> list[tuple[int, Matrix]]:
    """``(s, point)`` at every vertex of the rates of row ``s`` in ``[lo, hi]`` (the other
    rates at the sub-box's midpoint; row ``s`` of the generator depends on its own only),
    for every joint state: :meth:`~ftc_verify.model.chain.JointChain.row_rate_points` of a
    sub-box; a rate with ``lo = hi`` gives one point, not two)."""
    chain = loop.chain
    mid = 0.5 * (np.asarray(lo, dtype=float) + np.asarray(hi, dtype=float))
    out = []
    for s in range(loop.states):
        indices = chain.row_rates(s)
        for combo in itertools.product(*[sorted({float(lo[r]), float(hi[r])}) for r in indices]):
            point = mid.copy()
            for r, v in zip(indices, combo):
                point[r] = v
            out.append((s, point))
    return out


def cubic_parts(A: Any, Yk: list[Any], Yk1: list[Any], C: list[Any], W: list[Any], s: int, q_row: Any,
                rate: Any) -> tuple[Any, Any, Any, Any]:
    r""":math:`F_0, \dots, F_3` of the module docstring (``rate`` :math:`= 1/\delta`),
    for float, :class:`~ftc_verify.analysis.conic.Affine` or ball matrices."""
    E = [b - a for a, b in zip(Yk, Yk1)]
    EC = [e + c for e, c in zip(E, C)]
    WC = [w - c for c, w in zip(C, W)]
    F0 = EC[s] * rate + adjoint(A, Yk, s, q_row)
    F1 = (W[s] - C[s]) * (2.0 * rate) + adjoint(A, EC, s, q_row)
    F2 = W[s] * (-3.0 * rate) + adjoint(A, WC, s, q_row)
    F3 = -adjoint(A, W, s, q_row)
    return F0, F1, F2, F3


def _grams(P: tuple[Any, Any, Any, Any], B2: Any, C2: Any, K: Any) -> tuple[list[list[Any]], list[list[Any]]]:
    """The blocks of :math:`M_2` and :math:`M_1` (module docstring) for :math:`P = -F`."""
    P0, P1, P2, P3 = P
    B2s = B2 + B2.T
    B1 = (P2 - C2 + B2s) * 0.5 + K
    return [[P0, B2], [B2.T, C2]], [[P1 + P0 - B2s, B1], [B1.T, P3 + C2]]


def piece_blocks(A: Any, Yk: list[Any], Yk1: list[Any], C: list[Any], W: list[Any], s: int, q_row: Any, rate: Any,
                 gram: tuple[Any, Any, Any]) -> tuple[list[list[Any]], list[list[Any]]]:
    r"""The blocks of :math:`M_2` and :math:`M_1` (module docstring) of row ``s`` on a
    piece, from :math:`P = -F` (:func:`cubic_parts`) and the free parts ``gram`` :math:`=
    (B_2, C_2, K)`: the one assembly of the program (:class:`~ftc_verify.analysis.conic.Affine`)
    and of the proof (balls); in float it lets a test check :math:`-F(t) = t\sigma_1(t) +
    (1 - t)\sigma_2(t)` against :math:`F` written out from its definition."""
    F = cubic_parts(A, Yk, Yk1, C, W, s, q_row, rate)
    return _grams((-F[0], -F[1], -F[2], -F[3]), *gram)


def _layout(loop: SampledLoop, pieces: int, n_specs: int) -> tuple[int, int, int, int]:
    """``(m, first curvature, first cubic term, first Gram part)``; each Gram part has
    ``d^2 + m + d (d - 1) / 2`` variables (``B_2``, ``C_2``, ``K``)."""
    m = loop.d * (loop.d + 1) // 2
    curv = (pieces + 1) * loop.states * m
    cub = curv + pieces * loop.states * m
    return m, curv, cub, cub + pieces * loop.states * m


def cubic_size(loop: SampledLoop, pieces: int, lo: Matrix | None = None, hi: Matrix | None = None) -> int:
    """The number of scalar variables of :func:`cubic_program`."""
    lo = loop.chain.rate_min if lo is None else lo
    hi = loop.chain.rate_max if hi is None else hi
    n = len(box_specs(loop, lo, hi))
    d = loop.d
    _, _, _, gram = _layout(loop, pieces, n)
    return gram + pieces * n * (d * d + d * (d + 1) // 2 + d * (d - 1) // 2)


def _full(d: int, first: int, K: int) -> Affine:
    lin = np.zeros((d, d, K))
    i, j = np.divmod(np.arange(d * d), d)
    lin[i, j, first + np.arange(d * d)] = 1.0
    return Affine(np.zeros((d, d)), lin)


def _skew(d: int, first: int, K: int) -> Affine:
    lin = np.zeros((d, d, K))
    i, j = np.tril_indices(d, -1)
    k = first + np.arange(len(i))
    lin[i, j, k] = 1.0
    lin[j, i, k] = -1.0
    return Affine(np.zeros((d, d)), lin)


def _gram_vars(d: int, first: int, K: int) -> tuple[Affine, Affine, Affine]:
    m = d * (d + 1) // 2
    return _full(d, first, K), sym_variable(d, first + d * d, K), _skew(d, first + d * d + m, K)


def cubic_program(loop: SampledLoop, h: float, pieces: int, lo: Matrix, hi: Matrix) -> tuple[Rows, int, Matrix]:
    """The rows, the number of variables and the objective (the total trace of the last
    nodes: the program is homogeneous, margins of 1) of the certificate's program at
    period ``h`` for the rates in ``[lo, hi]``: :math:`Y^k \\succeq I`, :math:`M_1, M_2
    \\succeq I` per piece and row vertex, :math:`J_s^T Y_s^0 J_s - Y_s^N \\preceq -I`."""
    d, S = loop.d, loop.states
    specs = box_specs(loop, lo, hi)
    m, curv, cub, gram = _layout(loop, pieces, len(specs))
    per = d * d + m + d * (d - 1) // 2
    K = gram + pieces * len(specs) * per
    Y = [[sym_variable(d, (k * S + s) * m, K) for s in range(S)] for k in range(pieces + 1)]
    C = [[sym_variable(d, curv + (k * S + s) * m, K) for s in range(S)] for k in range(pieces)]
    W = [[sym_variable(d, cub + (k * S + s) * m, K) for s in range(S)] for k in range(pieces)]
    cols: Any = np.arange(K)
    rows = Rows(K)
    eye2 = np.eye(2 * d)
    unit = time_unit(loop)
    D = frame_scale(loop, h)
    node_jump_rows(loop, h, rows, Y, D)
    flows = [F * unit / D[:, None] * D[None, :] for F in loop.flow]
    for k in range(pieces):
        for i, (s, point) in enumerate(specs):
            q = [float(v) * unit for v in loop.chain.row_generator(s, point)]
            M2, M1 = piece_blocks(flows[s], Y[k], Y[k + 1], C[k], W[k], s, q, pieces * unit / h,
                                  _gram_vars(d, gram + (k * len(specs) + i) * per, K))
            rows.lmi(eye2 - affine_bmat(M2), cols)
            rows.lmi(eye2 - affine_bmat(M1), cols)
    c = np.zeros(K)
    r, cl = np.tril_indices(d)
    diag = np.flatnonzero(r == cl)
    for s in range(S):
        c[(pieces * S + s) * m + diag] = 1.0
    return rows, K, c


def cubic_certificate(loop: SampledLoop, h: float, pieces: int, lo: Matrix, hi: Matrix) -> CubicCertificate | None:
    """The certificate the solver found (float64, ``proved`` ``False``), or ``None``. The
    nodes, curvatures and cubic terms are returned in the loop's coordinates (``Y = D^{-1}
    Y' D^{-1}``, exact: powers of two), the Gram parts in the program's frame."""
    rows, K, c = cubic_program(loop, h, pieces, lo, hi)
    outcome, x = solve_conic(rows.problem(c), "clarabel")
    if x is None or not outcome.solved:
        return None
    d, S = loop.d, loop.states
    specs = box_specs(loop, lo, hi)
    m, curv, cub, gram = _layout(loop, pieces, len(specs))
    w = 1.0 / frame_scale(loop, h)

    def split(first: int, count: int) -> tuple[tuple[Matrix, ...], ...]:
        flat = [Y * w[:, None] * w[None, :] for Y in unpack_sym(x, d, first, count * S, K)]
        return tuple(tuple(flat[k * S:(k + 1) * S]) for k in range(count))

    per = d * d + m + d * (d - 1) // 2
    grams = []
    for k in range(pieces):
        row = []
        for i in range(len(specs)):
            o = gram + (k * len(specs) + i) * per
            B2, C2, Ks = (np.einsum("ijk,k->ij", v.lin, x) for v in _gram_vars(d, o, K))
            row.append((B2, 0.5 * (C2 + C2.T), 0.5 * (Ks - Ks.T)))
        grams.append(tuple(row))
    return CubicCertificate(float(h), pieces, np.array(lo, dtype=float), np.array(hi, dtype=float), split(0, pieces + 1),
                            split(curv, pieces), split(cub, pieces), tuple(grams), False)


def prove_cubic(loop: SampledLoop, cert: CubicCertificate) -> bool:
    """``True`` only if ``cert`` certifies mean-square stability for every rate array in
    ``[cert.lo, cert.hi]`` at its period (module docstring), every condition proved in ball
    arithmetic on the numbers as written (the flows, the gains, the rates of each vertex
    and the period as in :func:`~ftc_verify.analysis.moments.sampled_clock.prove_clock`).
    The Gram parts are taken as the exact numbers stored; the blocks of :math:`M_1, M_2`
    computed from them and the balls of :math:`F` (so :math:`-F = t\\sigma_1 + (1 -
    t)\\sigma_2` holds for every element of the balls)."""
    from ..exact import ball_generator
    from ..rigorous import ball, ball_bmat, precision, proven_positive_definite

    h, pieces = cert.h, cert.pieces
    with precision():
        D = frame_scale(loop, h)  # powers of two: exact
        start = proof_start(loop, h, cert.nodes, D)
        if start is None:
            return False
        flows, Yb = start
        Cb = [[ball(y * D[:, None] * D[None, :]) for y in row] for row in cert.curvatures]
        Wb = [[ball(y * D[:, None] * D[None, :]) for y in row] for row in cert.cubics]
        unit = time_unit(loop)
        rate = pieces * unit / loop.period_ball(h)
        for i, (s, beta) in enumerate(box_specs(loop, cert.lo, cert.hi)):
            row = [q * unit for q in ball_generator(loop.chain, beta, loop.literals)[s]]
            for k in range(pieces):
                B2, C2, Ks = (ball(v) for v in cert.grams[k][i])
                for M in piece_blocks(flows[s], Yb[k], Yb[k + 1], Cb[k], Wb[k], s, row, rate, (B2, C2, Ks)):
                    if not proven_positive_definite(ball_bmat(M)):
                        return False
    return True


def cubic_stable(loop: SampledLoop, h: float, pieces: int = 4, lo: Matrix | None = None,
                 hi: Matrix | None = None) -> CubicCertificate | None:
    """A certificate found at period ``h`` for the rates in ``[lo, hi]`` (default: the
    whole box) with ``proved`` set by :func:`prove_cubic`, or ``None`` when the solver found
    none; for :func:`~ftc_verify.analysis.moments.sampled_conditioned.conditioned` of
    ``loop``, as :func:`~ftc_verify.analysis.moments.sampled_clock.clock_stable`."""
    from .sampled_conditioned import conditioned

    loop = conditioned(loop)
    lo = loop.chain.rate_min if lo is None else np.asarray(lo, dtype=float)
    hi = loop.chain.rate_max if hi is None else np.asarray(hi, dtype=float)
    cert = cubic_certificate(loop, h, pieces, lo, hi)
    if cert is None:
        return None
    return dataclasses.replace(cert, proved=prove_cubic(loop, cert))
