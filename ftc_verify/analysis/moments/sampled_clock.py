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

from dataclasses import dataclass
from typing import Any

import numpy as np

from ...model.system import Matrix
from ..conic import Rows, sym_variable
from ..solvers import solve_conic
from .sampled import SampledLoop

__all__ = ["ClockCertificate", "clock_program", "clock_certificate", "prove_clock", "clock_stable"]


@dataclass(frozen=True, eq=False)
class ClockCertificate:
    """The nodes :math:`Y_s^k` (``nodes[k][s]``, balanced coordinates of the loop) found
    at period ``h`` with ``pieces`` pieces, and whether they were proved (ball
    arithmetic) to certify stability over the whole rate box."""

    h: float
    pieces: int
    nodes: tuple[tuple[Matrix, ...], ...]
    proved: bool


def _specs(loop: SampledLoop) -> list[tuple[int, Matrix, Matrix]]:
    """``(s, beta, q_row)`` at every vertex of the rates of row ``s`` (every joint state)."""
    chain = loop.chain
    return [(s, point, chain.row_generator(s, point)) for s in range(loop.states)
            for point in chain.row_rate_points(s)]


def _flow_block(A: Any, Ys: list[Any], s: int, q_row: Any, D: Any) -> Any:
    """:math:`D + A^T Y_s + Y_s A + \\sum_{t \\ne s} q_{st} (Y_t - Y_s)`."""
    out = D + A.T @ Ys[s] + Ys[s] @ A
    for t, q in enumerate(q_row):
        if t != s and not (isinstance(q, float) and q == 0.0):
            out = out + (Ys[t] - Ys[s]) * q
    return out


def clock_program(loop: SampledLoop, h: float, pieces: int) -> tuple[Rows, int]:
    """The rows of the certificate's program at period ``h`` (module docstring): nodes
    :math:`Y_s^k \\succeq I`, every block :math:`F_s^k \\preceq -I` at both ends of its
    piece at every vertex of its row, :math:`J_s^T Y_s^0 J_s - Y_s^N \\preceq -I` (margins
    of 1: the program is homogeneous in :math:`Y`). Returns the rows and the number of
    variables (the ``svec`` of every node, node by node, state by state)."""
    d, S = loop.d, loop.states
    m = d * (d + 1) // 2
    K = (pieces + 1) * S * m
    Y = [[sym_variable(d, (k * S + s) * m, K) for s in range(S)] for k in range(pieces + 1)]
    cols: Any = np.arange(K)
    rows = Rows(K)
    eye = np.eye(d)
    for row in Y:
        for y in row:
            rows.lmi(eye - y, cols)
    specs = _specs(loop)
    for k in range(pieces):
        for s, _, q_row in specs:
            D = (Y[k + 1][s] - Y[k][s]) * (pieces / h)
            for e in (k, k + 1):
                rows.lmi(_flow_block(loop.flow[s], Y[e], s, [float(q) for q in q_row], D) + eye, cols)
    P = loop.restriction()
    for s, R in enumerate(loop.resets(h)):
        J = R @ P
        rows.lmi(J.T @ Y[0][s] @ J - Y[pieces][s] + eye, cols)
    return rows, K


def clock_certificate(loop: SampledLoop, h: float, pieces: int = 4) -> tuple[tuple[Matrix, ...], ...] | None:
    """The nodes of a certificate found by the solver (float64; nothing proved yet), or
    ``None``. The objective: the smallest total trace of the last nodes (the program is
    homogeneous; this keeps the point bounded)."""
    rows, K = clock_program(loop, h, pieces)
    d, S = loop.d, loop.states
    m = d * (d + 1) // 2
    c = np.zeros(K)
    r, cl = np.tril_indices(d)
    diag = np.flatnonzero(r == cl)
    for s in range(S):
        c[(pieces * S + s) * m + diag] = 1.0
    outcome, x = solve_conic(rows.problem(c), "clarabel")
    if x is None or not outcome.solved:
        return None
    out = []
    for k in range(pieces + 1):
        row = []
        for s in range(S):
            y = sym_variable(d, (k * S + s) * m, K)
            v = np.einsum("ijk,k->ij", y.lin, x)
            row.append(0.5 * (v + v.T))
        out.append(tuple(row))
    return tuple(out)


def prove_clock(loop: SampledLoop, h: float, nodes: tuple[tuple[Matrix, ...], ...]) -> bool:
    """``True`` only if the nodes certify mean-square stability over the whole rate box
    at period ``h`` (module docstring), every condition proved in ball arithmetic on the
    numbers as written: the flows and gains by :func:`~ftc_verify.analysis.exact.written`,
    the rates of each vertex by :func:`~ftc_verify.analysis.exact.ball_generator`, the
    period by :meth:`~ftc_verify.analysis.moments.sampled.SampledLoop.period_ball`."""
    from ..exact import ball_generator, enclose
    from ..rigorous import ball, precision, proven_positive_definite
    from .sampled_gamma import sample_jumps

    import flint

    pieces = len(nodes) - 1
    with precision():
        flows = []
        sc = loop.scale
        for A in loop.flow:
            B = flint.arb_mat(A.shape[0], A.shape[1])
            for i, j in zip(*np.nonzero(A)):
                factor = float(sc[j] / sc[i])  # a power of two: exact
                B[int(i), int(j)] = enclose(float(A[i, j]) / factor, loop.literals) * factor
            flows.append(_as_ball(B))
        Yb = [[ball(y) for y in row] for row in nodes]
        if not all(proven_positive_definite(y) for row in Yb for y in row):
            return False
        for s, J in enumerate(sample_jumps(loop, h, balls=True, literals=loop.literals)):
            if not proven_positive_definite(Yb[pieces][s] - J.T @ Yb[0][s] @ J):
                return False
        hb = loop.period_ball(h)
        step = _as_ball(flint.arb_mat(1, 1, [pieces / hb]))
        for s, beta, _ in _specs(loop):
            row = ball_generator(loop.chain, beta, loop.literals)[s]
            for k in range(pieces):
                D = (Yb[k + 1][s] - Yb[k][s]) * step.value[0, 0]
                for e in (k, k + 1):
                    if not proven_positive_definite(-_flow_block(flows[s], Yb[e], s, row, D)):
                        return False
    return True


def _as_ball(M: Any) -> Any:
    from ..rigorous import Ball

    return Ball(M)


def clock_stable(loop: SampledLoop, h: float, pieces: int = 4) -> ClockCertificate | None:
    """A certificate found and proved at period ``h`` (:func:`clock_certificate`,
    :func:`prove_clock`), or ``None``."""
    nodes = clock_certificate(loop, h, pieces)
    if nodes is None:
        return None
    return ClockCertificate(float(h), pieces, nodes, prove_clock(loop, h, nodes))
