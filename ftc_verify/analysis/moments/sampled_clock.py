r"""Mean-square stability of the sampled loop over the whole rate box, without sub-boxes:
a clock-dependent Lyapunov certificate of the second moments.

The loop of :mod:`ftc_verify.analysis.moments.sampled`: between samples the joint
second moments :math:`Z_s(t) = E[\zeta\zeta^T 1\{\theta_t = s\}]` of the augmented
state :math:`\zeta = (x, u, x_c)` obey :math:`\dot Z_s = \bar A_s Z_s + Z_s \bar A_s^T +
\sum_t q_{ts} Z_t` (the moment generator :math:`\mathcal L(\beta)`, affine in the rates
:math:`\beta` of the box); at a sample the controller resets them,
:math:`Z_s^+ = J_s Z_s^- J_s^T` with :math:`J_s = R_s P` (the reset and restriction of
the one-period map).

**Certificate** (derived here). Take the linear functional :math:`V(\tau, Z) = \sum_s
\langle Y_s(\tau), Z_s\rangle` of the moments, :math:`\tau = t - t_k \in [0, h)` the
time since the last sample, with :math:`Y_s` continuous and affine on each piece
:math:`[\tau_k, \tau_{k+1}]`, :math:`\tau_k = k h / N` (nodes :math:`Y_s^k`, slope
:math:`D_s^k = (Y_s^{k+1} - Y_s^k) N / h`). Between samples

.. math::

    \tfrac{d}{dt} V = \sum_s \bigl\langle D_s^k + \bar A_s^T Y_s + Y_s \bar A_s +
    \textstyle\sum_{t} q_{st} Y_t,\; Z_s \bigr\rangle,

(the adjoint :math:`\mathcal L^*` of the moment generator: the same operator as the
Lyapunov block of :mod:`ftc_verify.analysis.lmi` without disturbance). It is
:math:`\le 0` for every positive semidefinite stack :math:`Z` iff every
:math:`F_s^k(\tau) = D_s^k + \bar A_s^T Y_s(\tau) + Y_s(\tau) \bar A_s + \sum_{t \ne s}
q_{st} (Y_t(\tau) - Y_s(\tau)) \preceq 0`. On a piece :math:`F_s^k` is affine in
:math:`\tau` (so negative semidefinite on it iff at both ends) and affine in row
:math:`s` of the generator (so on the whole box iff at the vertices of the rates of
that row, :meth:`~ftc_verify.model.chain.JointChain.row_rate_points`). At the sample

.. math::

    V(0, Z^+) = \sum_s \langle J_s^T Y_s(0) J_s, Z_s^-\rangle
    < \sum_s \langle Y_s(h), Z_s^- \rangle = V(h^-, Z^-)
    \quad\Longleftarrow\quad J_s^T Y_s^0 J_s \prec Y_s^N

for every nonzero :math:`Z^- \succeq 0`. With :math:`Y_s^0 \succ 0`, the post-reset
moments :math:`Z_k^+` then obey :math:`\langle Y^0, Z_{k+1}^+\rangle \le c \langle Y^0,
Z_k^+ \rangle` with :math:`c < 1` (the flow over a period maps a nonzero stack to a
nonzero one, the compact set :math:`\{Z \succeq 0, \langle Y^0, Z\rangle = 1\}`), for
*every* rate path inside the box: the post-reset map :math:`\mathcal R \mathcal P e^{\mathcal L h}`,
hence :math:`T` of :mod:`~ftc_verify.analysis.moments.sampled` (same non-zero spectrum),
has spectral radius below 1 at every rate of the box -- the loop is mean-square
stable over the box at period :math:`h`. (It is the storage of
:mod:`~ftc_verify.analysis.moments.sampled_gamma` with no disturbance; the same
functional in the quadratic form :math:`E[\zeta^T Y_\theta(\tau) \zeta]`.)

**What it costs and what it gives up.** One semidefinite program over the vertices
(no sub-boxes), then every block proved negative definite and every node and jump
condition positive definite in ball arithmetic on the numbers as written
(:func:`prove_clock`). A certificate common to the box holds for rates that vary in
time inside the box, so it can fail below the crossing of the worst constant rate (the
experiment: ``benchmarks/sampled_clock.py``, ``benchmarks/results/h31c.md``).
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.linalg

from ...model.system import Matrix
from ..conic import Rows, affine_bmat, sym_variable
from ..solvers import solve_conic
from .sampled import SampledLoop, rate_points
from .sampled_proof import BoxVerdict, box_verdict, prove_point_unstable

__all__ = ["ClockCertificate", "adjoint", "clock_program", "clock_certificate", "prove_clock", "clock_stable", "clock_size", "clock_verdict", "period_verdict",
           "TIME_OCTAVES", "time_unit", "frame_scale", "node_jump_rows", "unpack_sym", "proof_start"]


@dataclass(frozen=True, eq=False)
class ClockCertificate:
    """The nodes :math:`Y_s^k` (``nodes[k][s]``, in the balanced coordinates of the loop it was found for:
    :func:`clock_stable`'s conditioned loop), the
    curvatures :math:`C_s^k` (``curvatures[k][s]``, empty for affine pieces) and the
    multipliers :math:`G` (``multipliers[k][i]``, one per piece and vertex instance, of the
    flow conditions in the frame of :func:`time_unit`) found at period ``h`` with ``pieces`` pieces, and whether they were proved (ball
    arithmetic) to certify stability over the whole rate box."""

    h: float
    pieces: int
    nodes: tuple[tuple[Matrix, ...], ...]
    proved: bool
    curvatures: tuple[tuple[Matrix, ...], ...] = ()
    multipliers: tuple[tuple[Matrix, ...], ...] = ()


def _specs(loop: SampledLoop) -> list[tuple[int, Matrix, Matrix]]:
    """``(s, beta, q_row)`` at every vertex of the rates of row ``s`` (every joint state)."""
    chain = loop.chain
    return [(s, point, chain.row_generator(s, point)) for s in range(loop.states)
            for point in chain.row_rate_points(s)]


def adjoint(A: Any, Ys: list[Any], s: int, q_row: Any) -> Any:
    r"""Block ``s`` of :math:`\mathcal L^* Y`: :math:`A^T Y_s + Y_s A + \sum_{t \ne s}
    q_{st} (Y_t - Y_s)` (a generator row sums to zero)."""
    out = A.T @ Ys[s] + Ys[s] @ A
    for t, q in enumerate(q_row):
        if t != s and not (isinstance(q, float) and q == 0.0):
            out = out + (Ys[t] - Ys[s]) * q
    return out


def _piece_parts(A: Any, Y0: list[Any], Y1: list[Any], C: list[Any] | None, s: int, q_row: Any,
                 rate: Any) -> tuple[Any, Any, Any]:
    r"""The coefficients :math:`F_0, F_1, F_2` of :math:`F(t) = F_0 + t F_1 + t^2 F_2`,
    :math:`F = dY_s/d\tau + (\mathcal L^* Y)_s` on a piece, :math:`\tau = \tau_k + t
    \delta`, ``rate`` :math:`= 1/\delta`, :math:`Y(t) = (1 - t) Y^k + t Y^{k+1} + t (1 - t)
    C^k` (``C`` ``None``: affine, :math:`F_2 = 0`). With :math:`E = Y^{k+1} - Y^k`:
    :math:`dY/d\tau = (E + (1 - 2t) C) / \delta`, so :math:`F_0 = (E_s + C_s)/\delta +
    \mathcal L^*(Y^k)`, :math:`F_1 = -2 C_s / \delta + \mathcal L^*(E + C)`,
    :math:`F_2 = -\mathcal L^*(C)`."""
    E = [b - a for a, b in zip(Y0, Y1)]
    if C is None:
        return (E[s] * rate + adjoint(A, Y0, s, q_row), adjoint(A, E, s, q_row), None)
    EC = [e + c for e, c in zip(E, C)]
    F0 = EC[s] * rate + adjoint(A, Y0, s, q_row)
    F1 = C[s] * (-2.0 * rate) + adjoint(A, EC, s, q_row)
    F2 = -adjoint(A, C, s, q_row)
    return F0, F1, F2


#: Octaves of :attr:`SampledLoop.speed` around 1 in which the program is solved in the
#: loop's own time unit (:func:`time_unit`).
TIME_OCTAVES = 6


def time_unit(loop: SampledLoop) -> float:
    r"""The time unit :math:`c` of the program (:math:`t = c\,t'`): the power of two nearest
    :math:`1 / \text{speed}` (:attr:`SampledLoop.speed`, the loop's largest rate) when that
    is more than :data:`TIME_OCTAVES` octaves from 1, else 1 (the loop as written). In the
    frame :math:`t'` the flows and rates are :math:`c \bar A_s, c\,Q` and the period
    :math:`h / c`; every flow condition is :math:`c F` (definiteness unchanged, :math:`c > 0`),
    the nodes and jumps are the same. Without it the flow conditions' margin :math:`-I`
    against data :math:`10^{-6}` times smaller (a plant in microseconds of a slow process)
    left the solver without a solution (``benchmarks/results/h31r.md``). The speed is
    measured in the coordinates of
    :func:`~ftc_verify.analysis.moments.sampled_frame.loop_similarity`, so the units of
    the states do not move it: with states in units ``1e-6`` and ``1e6`` it was ``4.6e12``
    (the transform refused for its condition ``1e12``, the exact diagonal's), this unit
    ``2^-42`` and no certificate found 1e-2 below the crossing
    (``benchmarks/results/frame11.md``)."""
    e = round(-math.log2(loop.speed)) if math.isfinite(loop.speed) and loop.speed > 0 else 0
    return 1.0 if abs(e) <= TIME_OCTAVES else float(2.0 ** e)


def frame_scale(loop: SampledLoop, h: float) -> Matrix:
    """Powers of two :math:`D` (``z = diag(D) z'``) balancing the program's data in the frame
    of :func:`time_unit` (the pattern of :math:`c |\\bar A_s|` and :math:`|J_s|`): the
    loop's own balancing (:attr:`SampledLoop.scale`) weighs the flows in its time unit, so a
    plant in time units of ``1e6`` had its held input scaled for flows ``1e6`` larger and
    no certificate was found in the normalised frame. Ones when the unit is 1 (the program
    as before)."""
    unit = time_unit(loop)
    if unit == 1.0:
        return np.ones(loop.d)
    P = loop.restriction()
    pattern = np.eye(loop.d) + sum(np.abs(F) * unit for F in loop.flow) + sum(np.abs(R @ P) for R in loop.resets(h))
    if not np.all(np.isfinite(pattern)):
        return np.ones(loop.d)
    _, (found, _) = scipy.linalg.matrix_balance(pattern, permute=False, separate=True)
    return np.asarray(found, dtype=float)


def _layout(loop: SampledLoop, pieces: int, quadratic: bool) -> tuple[int, int, int]:
    """``(m, first curvature, first multiplier)`` offsets: ``svec`` of every node, node
    by node and state by state, then (quadratic) every curvature, then every multiplier."""
    m = loop.d * (loop.d + 1) // 2
    curv = (pieces + 1) * loop.states * m
    mult = curv + (pieces * loop.states * m if quadratic else 0)
    return m, curv, mult


def clock_size(loop: SampledLoop, pieces: int, quadratic: bool) -> int:
    """The number of scalar variables of :func:`clock_program`."""
    m, _, mult = _layout(loop, pieces, quadratic)
    return mult + (pieces * len(_specs(loop)) * m if quadratic else 0)


def clock_program(loop: SampledLoop, h: float, pieces: int, quadratic: bool = False) -> tuple[Rows, int]:
    r"""The rows of the certificate's program at period ``h`` (module docstring): nodes
    :math:`Y_s^k \succeq I`, on every piece at every vertex of its row the flow
    condition :math:`F \preceq -I` (affine pieces: at both ends; quadratic ones: the
    bordered matrix :math:`\bigl[\begin{smallmatrix} F_0 & (F_1 + G)/2 \\ (F_1 + G)/2 &
    F_2 - G\end{smallmatrix}\bigr] \preceq -I`, :math:`G \succeq I`, which gives
    :math:`F(t) + t (1 - t) G \preceq -(1 + t^2) I` on :math:`[0, 1]`), and
    :math:`J_s^T Y_s^0 J_s - Y_s^N \preceq -I` (margins of 1: the program is homogeneous).
    Returns the rows and the number of variables (:func:`clock_size`)."""
    d, S = loop.d, loop.states
    m, curv, mult = _layout(loop, pieces, quadratic)
    specs = _specs(loop)
    K = clock_size(loop, pieces, quadratic)
    Y = [[sym_variable(d, (k * S + s) * m, K) for s in range(S)] for k in range(pieces + 1)]
    C = [[sym_variable(d, curv + (k * S + s) * m, K) for s in range(S)] for k in range(pieces)] if quadratic else []
    cols: Any = np.arange(K)
    rows = Rows(K)
    eye = np.eye(d)
    unit = time_unit(loop)  # t = unit t': the flows and rates times unit, the period over it
    D = frame_scale(loop, h)  # z = diag(D) z' (powers of two)
    node_jump_rows(loop, h, rows, Y, D)
    for k in range(pieces):
        for i, (s, _, q_row) in enumerate(specs):
            q = [float(v) * unit for v in q_row]
            F0, F1, F2 = _piece_parts(loop.flow[s] * unit / D[:, None] * D[None, :], Y[k], Y[k + 1], C[k] if quadratic else None, s, q,
                                      pieces * unit / h)
            if not quadratic:
                rows.lmi(F0 + eye, cols)
                rows.lmi(F0 + F1 + eye, cols)
                continue
            G = sym_variable(d, mult + (k * len(specs) + i) * m, K)
            rows.lmi(eye - G, cols)
            half = (F1 + G) * 0.5
            rows.lmi(affine_bmat([[F0, half], [half, F2 - G]]) + np.eye(2 * d), cols)
    return rows, K


def node_jump_rows(loop: SampledLoop, h: float, rows: Rows, Y: list[list[Any]], D: Matrix) -> None:
    r"""Add to ``rows`` the rows shared by the clock programs (this module's and
    :mod:`~ftc_verify.analysis.moments.sampled_cubic`'s): every node :math:`Y_s^k \succeq
    I` and the sample :math:`J_s^T Y_s^0 J_s - Y_s^N \preceq -I`, in the frame
    :math:`D` of :func:`frame_scale` (:math:`J' = D^{-1} J D`); ``Y[k][s]`` the nodes'
    variables (the last row: :math:`Y^N`)."""
    eye = np.eye(loop.d)
    cols: Any = np.arange(rows.K)
    for row in Y:
        for y in row:
            rows.lmi(eye - y, cols)
    P = loop.restriction()
    for s, R in enumerate(loop.resets(h)):
        J = R @ P / D[:, None] * D[None, :]
        rows.lmi(J.T @ Y[0][s] @ J - Y[-1][s] + eye, cols)


def unpack_sym(x: Matrix, d: int, first: int, count: int, K: int) -> list[Matrix]:
    """``count`` symmetric ``d x d`` matrices of the solution ``x`` (``K`` variables), the
    ``svec`` of the first from variable ``first`` on (:func:`~ftc_verify.analysis.conic.sym_variable`)."""
    m = d * (d + 1) // 2
    out = []
    for j in range(count):
        v = np.einsum("ijk,k->ij", sym_variable(d, first + j * m, K).lin, x)
        out.append(0.5 * (v + v.T))
    return out


def clock_certificate(loop: SampledLoop, h: float, pieces: int = 4,
                      quadratic: bool = False) -> ClockCertificate | None:
    """The certificate found by the solver (float64; ``proved`` is ``False``: nothing
    proved yet), or ``None``. The objective: the smallest total trace of the last nodes
    (the program is homogeneous; this keeps the point bounded)."""
    rows, K = clock_program(loop, h, pieces, quadratic)
    d, S = loop.d, loop.states
    m, curv, mult = _layout(loop, pieces, quadratic)
    c = np.zeros(K)
    r, cl = np.tril_indices(d)
    diag = np.flatnonzero(r == cl)
    for s in range(S):
        c[(pieces * S + s) * m + diag] = 1.0
    outcome, x = solve_conic(rows.problem(c), "clarabel")
    if x is None or not outcome.solved:
        return None
    w = 1.0 / frame_scale(loop, h)  # back to the loop's coordinates: Y = D^-1 Y' D^-1 (exact)
    flat = [Y * w[:, None] * w[None, :] for Y in unpack_sym(x, d, 0, (pieces + 1) * S, K)]
    nodes = tuple(tuple(flat[k * S:(k + 1) * S]) for k in range(pieces + 1))
    if not quadratic:
        return ClockCertificate(float(h), pieces, nodes, False)
    flat = [Y * w[:, None] * w[None, :] for Y in unpack_sym(x, d, curv, pieces * S, K)]
    curvs = tuple(tuple(flat[k * S:(k + 1) * S]) for k in range(pieces))
    n_spec = len(_specs(loop))
    flat = [Y * w[:, None] * w[None, :] for Y in unpack_sym(x, d, mult, pieces * n_spec, K)]
    mults = tuple(tuple(flat[k * n_spec:(k + 1) * n_spec]) for k in range(pieces))
    return ClockCertificate(float(h), pieces, nodes, False, curvs, mults)


def prove_clock(loop: SampledLoop, cert: ClockCertificate) -> bool:
    """``True`` only if ``cert`` certifies mean-square stability over the whole rate box
    at its period (module docstring), every condition proved in ball arithmetic on the
    numbers as written: the flows by :func:`~ftc_verify.analysis.moments.sampled_proof.written_flow`, the gains
    by :func:`~ftc_verify.analysis.moments.sampled_gamma.sample_jumps`, the rates of each
    vertex by :func:`~ftc_verify.analysis.exact.ball_generator`, the period by
    :meth:`~ftc_verify.analysis.moments.sampled.SampledLoop.period_ball`."""
    from ..exact import ball_generator
    from ..rigorous import ball, ball_bmat, precision, proven_positive_definite

    h, pieces, quadratic = cert.h, cert.pieces, bool(cert.curvatures)
    with precision():
        start = proof_start(loop, h, cert.nodes, None)
        if start is None:
            return False
        flows, Yb = start
        Cb = [[ball(c) for c in row] for row in cert.curvatures]
        unit = time_unit(loop)
        rate = pieces * unit / loop.period_ball(h)
        for i, (s, beta, _) in enumerate(_specs(loop)):
            row = [q * unit for q in ball_generator(loop.chain, beta, loop.literals)[s]]
            for k in range(pieces):
                F0, F1, F2 = _piece_parts(flows[s], Yb[k], Yb[k + 1], Cb[k] if quadratic else None, s, row, rate)
                if not quadratic:
                    if not (proven_positive_definite(-F0) and proven_positive_definite(-(F0 + F1))):
                        return False
                    continue
                G = ball(cert.multipliers[k][i])
                half = (F1 + G) * 0.5
                if not (proven_positive_definite(G) and proven_positive_definite(-ball_bmat([[F0, half], [half, F2 - G]]))):
                    return False
    return True


def proof_start(loop: SampledLoop, h: float, nodes: tuple[tuple[Matrix, ...], ...],
                D: Matrix | None) -> tuple[list[Any], list[list[Any]]] | None:
    r"""The start shared by the clock proofs (:func:`prove_clock`,
    :func:`~ftc_verify.analysis.moments.sampled_cubic.prove_cubic`; call it inside
    :func:`~ftc_verify.analysis.rigorous.precision`): the flows as written
    (:func:`~ftc_verify.analysis.moments.sampled_proof.written_flow`, or the moved ones of a
    :class:`~ftc_verify.analysis.moments.sampled_conditioned.ConditionedLoop`) and the
    jumps :math:`J_s = R_s P` of the gains as written
    (:func:`~ftc_verify.analysis.moments.sampled_gamma.sample_jumps`), as balls; then the
    nodes :math:`Y^k_s \succ 0` and the sample :math:`Y_s^N - J_s^T Y_s^0 J_s \succ 0`
    proved. With ``D`` (:func:`frame_scale`, powers of two: exact) it is done in the
    program's frame (:math:`Y' = D Y D`, :math:`J' = D^{-1} J D`); ``None``: the loop's
    coordinates. Returns the flows times :func:`time_unit` (:math:`D^{-1} A D` with ``D``)
    and the nodes as balls, or ``None`` when a condition is not proved."""
    from ..rigorous import ball, proven_positive_definite
    from .sampled_conditioned import ConditionedLoop, written_data
    from .sampled_gamma import sample_jumps
    from .sampled_proof import written_flow

    if isinstance(loop, ConditionedLoop):  # the moved data from the written balls
        flows, resets = written_data(loop, h)
        jumps = [R @ ball(loop.restriction()) for R in resets]
    else:
        flows = [written_flow(loop, A) for A in loop.flow]
        jumps = sample_jumps(loop, h, balls=True, literals=loop.literals)
    unit = time_unit(loop)  # a power of two: the program's frame, scaled exactly
    if D is None:
        Yb = [[ball(y) for y in row] for row in nodes]
        flows = [F * unit for F in flows]
    else:
        Yb = [[ball(y * D[:, None] * D[None, :]) for y in row] for row in nodes]
        Db, Dinv = ball(np.diag(D)), ball(np.diag(1.0 / D))
        jumps = [Dinv @ J @ Db for J in jumps]
        flows = [Dinv @ (F * unit) @ Db for F in flows]
    if not all(proven_positive_definite(y) for row in Yb for y in row):
        return None
    for s, J in enumerate(jumps):
        if not proven_positive_definite(Yb[-1][s] - J.T @ Yb[0][s] @ J):
            return None
    return flows, Yb


def clock_stable(loop: SampledLoop, h: float, pieces: int = 4, quadratic: bool = False) -> ClockCertificate | None:
    """A certificate found at period ``h`` (:func:`clock_certificate`) with ``proved`` set
    by :func:`prove_clock`, or ``None`` when the solver found none; found and proved for
    :func:`~ftc_verify.analysis.moments.sampled_conditioned.conditioned` of ``loop`` (its
    nodes in those coordinates: the loop itself unless its coordinates are badly
    conditioned -- the paper loop moved by a similarity of condition 1e3 had none)."""
    from .sampled_conditioned import conditioned

    loop = conditioned(loop)
    cert = clock_certificate(loop, h, pieces, quadratic)
    if cert is None:
        return None
    return dataclasses.replace(cert, proved=prove_clock(loop, cert))


def period_verdict(loop: SampledLoop, h: float, rho: float, *, max_boxes: int, max_seconds: float,
                   where: Matrix | None = None) -> BoxVerdict:
    """Mean-square stability of the sampled loop at period ``h`` over the whole rate box
    (``rho``: the largest float64 spectral radius of the one-period map found, at the rate
    array ``where``: :func:`~ftc_verify.analysis.moments.sampled_bracket.period_worst`). In
    order, the first that decides: ``rho > 1`` proved at ``where``
    (:func:`~ftc_verify.analysis.moments.sampled_proof.prove_point_unstable`); the sub-box proofs
    (:func:`~ftc_verify.analysis.moments.sampled_proof.box_verdict`) on the whole box
    alone; when ``rho < 1``, one clock-dependent certificate of the whole box
    (:func:`clock_verdict`); the sub-box proofs with up to ``max_boxes`` sub-boxes. ``max_seconds`` of
    wall time from the start is a safety valve for the sub-box proofs (they start no
    sub-box after it); the clock certificate's one program has no time budget.

    The box alone decides the easy loops at the price of one proof (the paper's loop at
    0.05 s: 0.07 CPU s against 0.15 s for the clock certificate); the clock certificate
    decides at once the loops whose sub-box proofs would need many sub-boxes (wide rate
    boxes at long periods, where the map is far from affine in the rates even when its
    radius is far below 1: a random ``n = 4, m = 3`` loop at 40 % of its ``h_max``, radius
    0.85, undecided after 17 sub-boxes and 20 s, proved by the clock in 0.9 CPU s), and
    its verdict does not depend on the machine's speed."""
    t0 = time.perf_counter()
    if (where is not None and math.isfinite(rho) and rho > 1  # an inner vertex (box_verdict tries rate_points)
            and not any(np.array_equal(where, p) for p in rate_points(loop.chain)) and prove_point_unstable(loop, h, where)):
        return BoxVerdict("not stable", f"spectral radius {rho:.6g} > 1 proved at {loop.chain.rate_text(where)} "
                          "(ball arithmetic)", 1, where)
    first = box_verdict(loop, h, max_boxes=1, max_seconds=max_seconds)
    if first.verdict != "undecided":
        return first
    if rho < 1:
        clock = clock_verdict(loop, h, first)
        if clock.verdict != "undecided":
            return clock
    if max_boxes <= 1:
        return first
    return box_verdict(loop, h, max_boxes=max_boxes, max_seconds=max(0.0, max_seconds - (time.perf_counter() - t0)))


def clock_verdict(loop: SampledLoop, h: float, undecided: BoxVerdict) -> BoxVerdict:
    """The verdict at period ``h`` when the sub-box proofs
    (:func:`~ftc_verify.analysis.moments.sampled_proof.box_verdict`) left it ``undecided``:
    ``"stable"`` when one clock-dependent certificate is found and proved over the whole
    rate box (:func:`clock_stable`; module docstring: it holds for every rate of the box,
    constant or not), else ``undecided`` unchanged. The certificate is the ``h_max``
    bracket's (:data:`~ftc_verify.analysis.moments.sampled_bracket.CLOCK_PIECES` quadratic
    pieces, not tried when its program has more than
    :data:`~ftc_verify.analysis.moments.sampled_bracket.CLOCK_SIZE` scalar variables).

    Deterministic (no time budget): where the sub-box proofs ran out of their budget --
    wide rate boxes at long periods, where the one-period map is far from affine in the
    rates even though its radius is far below 1 -- the verdict no longer depends on how
    fast the machine was."""
    from .sampled_bracket import CLOCK_PIECES, CLOCK_SIZE

    if undecided.verdict != "undecided" or clock_size(loop, CLOCK_PIECES, True) > CLOCK_SIZE:
        return undecided
    cert = clock_stable(loop, h, CLOCK_PIECES, quadratic=True)
    if cert is None or not cert.proved:
        return undecided
    return BoxVerdict("stable", f"spectral radius < 1 on the whole rate box by one clock-dependent Lyapunov "
                      f"certificate ({CLOCK_PIECES} quadratic pieces, ball arithmetic)", undecided.boxes)
