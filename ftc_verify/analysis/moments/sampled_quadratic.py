r"""The sampled gain certificate with a storage *quadratic* in the clock on each piece.

The certificate of :mod:`ftc_verify.analysis.moments.sampled_gamma` takes
:math:`P_s(\tau)` affine on each of :math:`N` pieces of :math:`[0, h]`: its slope is
constant on a piece while the derivative the flow asks for changes along it, so the
slack it loses is first order in the piece's length :math:`\delta = h / N`. Close to
``h_max`` that loss exceeds the loop's stability margin unless :math:`N` is large (the
paper's example at :math:`h = 0.075`: no certificate below 16 pieces). Here, derived:

**Storage.** On piece :math:`k` with :math:`\sigma = \tau - \tau_k = s\,\delta`,
:math:`s \in [0, 1]`,

.. math::

    P_t(\tau) = P_t^k + s\,\delta D_t^k + s^2 (P_t^{k+1} - P_t^k - \delta D_t^k),
    \qquad \dot P_t(\tau) = D_t^k + 2 s\,(P_t^{k+1} - P_t^k - \delta D_t^k) / \delta,

continuous (it takes the node values :math:`P_t^k` at both ends), with the node
values, the initial slopes :math:`D_t^k` and the multipliers :math:`\lambda` (one set
per piece: they are not part of the storage and need not be continuous) free. (The program's variables are :math:`P^0_t`, :math:`D^k_t` and
:math:`\tilde E^k_t = (P^{k+1}_t - P^k_t)/\delta - D^k_t`, all :math:`O(1)` as
:math:`h \to 0`.)

**Flow condition on a piece.** The instance of the affine certificate (the block of
:func:`~ftc_verify.analysis.lmi.lyapunov_block` at :math:`P(\tau)`, :math:`\lambda(\tau)`
plus :math:`\dot P_s(\tau)` in its leading block) is now a quadratic polynomial
:math:`M(s) = M_0 + s M_1 + s^2 M_2` in :math:`s` (every term is affine in
:math:`(P, \dot P)`, each at most quadratic in :math:`s`; :math:`\lambda` is constant), so its coefficients
follow exactly from its values at :math:`s = 0, \tfrac12, 1`:
:math:`M_0 = M(0)`, :math:`M_2 = 2M(1) - 4M(\tfrac12) + 2M(0)`,
:math:`M_1 = M(1) - M(0) - M_2`. With a multiplier :math:`G \succeq 0` per instance,

.. math::

    \begin{bmatrix} M_0 & \tfrac12 (M_1 + G) \\ \tfrac12 (M_1 + G) & M_2 - G
    \end{bmatrix} \prec 0
    \;\Longrightarrow\; M(s) \prec 0 \text{ for every } s \in [0, 1]:

with :math:`v = (x, s x)`, :math:`v^T(\cdot)v = x^T M(s) x + s(1 - s)\,x^T G x`, and
:math:`s(1-s) \ge 0` on :math:`[0, 1]`. One condition per piece and block (instead of
one at each end), twice the size.

**Sample and positivity.** The jump condition :math:`J_s^T P_s(0) J_s \prec P_s(h)` of
the affine certificate, and :math:`P_s^k \succ 0` at every node. :math:`P_s(\tau)` need
not be positive between nodes: the gain argument sums
:math:`\tfrac{d}{dt}E[V] + E|z|^2 - \gamma^2|w|^2 < 0` over whole periods,
:math:`E\int_0^{t_K}(|z|^2 - \gamma^2|w|^2) \le V(0) - E V(t_K^+) \le 0` (the node
:math:`P_s^0` at the sample instants), and the gain is the limit over :math:`K`; with
:math:`w = 0`, :math:`E V(t_k^+)` decreases geometrically and the flow over one
period is bounded: mean-square stability.

**Proof.** In ball arithmetic (:func:`~ftc_verify.analysis.rigorous.proven_positive_definite`,
128 bits) from the float nodes :math:`P^k`, slopes :math:`D^k`, multipliers and
:math:`G` taken as exact, the loop's numbers as written (as the affine certificate):
:math:`M(0), M(\tfrac12), M(1)` evaluated on balls, the polynomial identity above
exact, every block, every :math:`G`, every node and every jump condition proved.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ...model.system import FTCSystem, Matrix
from ..closedloop import ClosedLoop
from ..conic import Affine, ConicProblem, KeyedVariables, Rows, affine_bmat, svec_index
from ..lmi import BlockSpec, block_specs
from .sampled import SampledLoop
from .sampled_frame import Coordinates

__all__ = ["QuadraticLayout", "quadratic_rows", "quadratic_values", "proved_nodes", "prove_quadratic",
           "quadratic_program", "quadratic_check", "instance_sizes", "program_rows"]


class QuadraticLayout:
    """Columns of the program: ``svec`` of :math:`P_s^0`, then per piece :math:`k` of
    :math:`D_s^k` and :math:`\\tilde E_s^k`; the multipliers piece by piece; one
    :math:`G` per piece and block spec; ``g``; ``t``."""

    def __init__(self, d: int, states: int, pieces: int, channels: tuple[int, ...], sizes: list[int]) -> None:
        self.d, self.states, self.pieces, self.channels, self.sizes = d, states, pieces, channels, sizes
        self.pp = d * (d + 1) // 2
        self.lam0 = (1 + 2 * pieces) * states * self.pp
        self.g0 = self.lam0 + pieces * sum(channels)
        self.gsz = [m * (m + 1) // 2 for m in sizes]
        self.g = self.g0 + pieces * sum(self.gsz)
        self.K = self.g + 2

    def p(self, kind: int, k: int, s: int) -> int:
        """First column of :math:`P^0_s` (``kind`` 0), :math:`D^k_s` (1), :math:`\\tilde E^k_s` (2)."""
        if kind == 0:
            return s * self.pp
        return ((1 + 2 * k + kind - 1) * self.states + s) * self.pp

    def lam(self, k: int, s: int) -> int:
        return self.lam0 + k * sum(self.channels) + sum(self.channels[:s])

    def G(self, k: int, j: int) -> int:
        return self.g0 + k * sum(self.gsz) + sum(self.gsz[:j])


class _Vars(KeyedVariables):
    """The variables one constraint uses, on its own columns, keyed ``(kind, k, s)`` as in
    :meth:`QuadraticLayout.p`."""

    def node(self, k: int, t: int, delta: float) -> Affine:
        """:math:`P^k_t = P^0_t + \\delta \\sum_{j<k} (D^j_t + \\tilde E^j_t)`."""
        out = self.var[(0, 0, t)]
        for j in range(k):
            out = out + (self.var[(1, j, t)] + self.var[(2, j, t)]) * delta
        return out


def _keys(k: int, t: int) -> list[tuple[int, int, int]]:
    return [(0, 0, t)] + [(kind, j, t) for j in range(k) for kind in (1, 2)]


def _poly(instance: Any, P0: list[Any], D: list[Any], E: list[Any], lam: Any, delta: Any) -> tuple[Any, Any, Any]:
    """``(M0, M1, M2)`` from ``instance(P, Pdot, lam)`` at ``s = 0, 1/2, 1`` (module
    docstring); ``E[t]`` is :math:`P^{k+1}_t - P^k_t - \\delta D^k_t`."""
    vals = []
    for s in (0.0, 0.5, 1.0):
        P = [None if p is None else p + D[t] * (delta * s) + E[t] * (s * s) for t, p in enumerate(P0)]
        Pdot = [None if p is None else D[t] + E[t] * (2.0 * s / delta) for t, p in enumerate(P0)]
        vals.append(instance(P, Pdot, lam))
    m0, mh, m1 = vals
    M2 = m1 * 2.0 - mh * 4.0 + m0 * 2.0
    return m0, m1 - m0 - M2, M2


def _bordered(M0: Any, M1: Any, M2: Any, G: Any, bmat: Any) -> Any:
    half = (M1 + G) * 0.5  # symmetric: M(s) and G are
    return bmat([[M0, half], [half, M2 - G]])


def quadratic_rows(aug: ClosedLoop, jumps: list[Matrix], lay: QuadraticLayout, h: float, robust: bool) -> Rows:
    """Every piece's bordered condition, ``G >= t I``, the jump conditions (divided by
    ``h``) and ``P^k_s >= t I`` as conic rows (the instance is the affine certificate's
    :func:`~ftc_verify.analysis.moments.sampled_gamma.clock_instance`)."""
    from .sampled_gamma import clock_instance as instance

    rows = Rows(lay.K)
    N = lay.pieces
    delta = h / N
    specs = block_specs(aug)
    for k in range(N):
        for j, spec in enumerate(specs):
            s = spec.s
            coupled = [s] + [t for t, q in enumerate(spec.q_row) if q != 0.0 and t != s]
            nl = lay.channels[s] if robust else 0
            m = lay.sizes[j]
            keys = [key for t in coupled for key in _keys(k, t) + [(1, k, t), (2, k, t)]]
            extra = (list(range(lay.lam(k, s), lay.lam(k, s) + nl)) + list(range(lay.G(k, j), lay.G(k, j) + lay.gsz[j]))
                     + [lay.g, lay.g + 1])
            v = _Vars(lay.d, lay.p, keys, extra)
            P0: list[Any] = [None] * lay.states
            D: list[Any] = [None] * lay.states
            E: list[Any] = [None] * lay.states
            for t in coupled:
                P0[t] = v.node(k, t, delta)
                D[t] = v.var[(1, k, t)]
                E[t] = v.var[(2, k, t)] * delta
            lam = [v.scalar(c) for c in range(nl)] if robust else None
            g = v.scalar(nl + lay.gsz[j])

            def inst(P: list[Any], Pdot: list[Any], lam: Any, spec: BlockSpec = spec, g: Any = g) -> Any:
                return instance(aug, spec, P, Pdot[spec.s], lam, g, affine_bmat)

            M0, M1, M2 = _poly(inst, P0, D, E, lam, delta)
            G = v.sym(nl, m)
            B = _bordered(M0, M1, M2, G, affine_bmat)
            t_ = v.scalar(nl + lay.gsz[j] + 1)
            rows.lmi(B + t_ * np.eye(2 * m), v.columns)
            rows.lmi(t_ * np.eye(m) - G, v.columns)
    for s, J in enumerate(jumps):
        v = _Vars(lay.d, lay.p, _keys(N, s), [lay.g + 1])
        rows.lmi((J.T @ v.node(0, s, delta) @ J - v.node(N, s, delta)) * (1.0 / h) + v.scalar(0) * np.eye(lay.d),
                 v.columns)
    for k in range(N + 1):
        for s in range(lay.states):
            v = _Vars(lay.d, lay.p, _keys(k, s), [lay.g + 1])
            rows.lmi(v.scalar(0) * np.eye(lay.d) - v.node(k, s, delta), v.columns)
    nl = lay.g0 - lay.lam0
    if nl:
        A = np.zeros((nl, lay.K))
        A[np.arange(nl), lay.lam0 + np.arange(nl)] = -1.0
        rows.nonneg(A, np.zeros(nl))
    return rows


def _unsvec(x: Matrix, first: int, m: int) -> Matrix:
    r, c, w = svec_index(m)
    M = np.zeros((m, m))
    v = x[first:first + len(r)] / w
    M[r, c] = v
    M[c, r] = v
    return M


def quadratic_values(x: Matrix, lay: QuadraticLayout, h: float) -> dict[str, Any]:
    """The nodes ``P[k][s]``, slopes ``D[k][s]``, multipliers ``lam[k][s]`` and
    ``G[k][j]`` of a solution ``x``."""
    delta = h / lay.pieces
    P = [[_unsvec(x, lay.p(0, 0, s), lay.d) for s in range(lay.states)]]
    D = [[_unsvec(x, lay.p(1, k, s), lay.d) for s in range(lay.states)] for k in range(lay.pieces)]
    for k in range(lay.pieces):
        P.append([P[-1][s] + delta * (D[k][s] + _unsvec(x, lay.p(2, k, s), lay.d)) for s in range(lay.states)])
    lam = [[list(x[lay.lam(k, s):lay.lam(k, s) + lay.channels[s]]) for s in range(lay.states)]
           for k in range(lay.pieces)]
    G = [[_unsvec(x, lay.G(k, j), m) for j, m in enumerate(lay.sizes)] for k in range(lay.pieces)]
    return {"P": P, "D": D, "lam": lam, "G": G}


def proved_nodes(loop: SampledLoop, system: FTCSystem, h: float, P: list[list[Matrix]], robust: bool,
                 coords: Coordinates | None = None) -> tuple[ClosedLoop, list[list[Any]]] | None:
    """What the affine and the quadratic storage prove alike: the ball loop of
    :func:`~ftc_verify.analysis.moments.sampled_gamma.augmented_loop` (nominal unless
    ``robust``) and the nodes ``P_s^k`` as symmetric balls, returned when every node is
    proved positive definite and every jump condition ``P_s^N - J_s^T P_s^0 J_s`` too
    (``J_s`` of :func:`~ftc_verify.analysis.moments.sampled_gamma.sample_jumps`, from the
    numbers as written), both in the coordinates ``coords``
    (:class:`~ftc_verify.analysis.moments.sampled_frame.Coordinates`, built on the balls);
    ``None`` otherwise. Call it inside :func:`~ftc_verify.analysis.rigorous.precision`."""
    from ..rigorous import ball, proven_positive_definite
    from .sampled_gamma import augmented_loop, sample_jumps

    N = len(P) - 1
    coords = Coordinates() if coords is None else coords
    try:  # Arb proves the transform invertible, or nothing is proved
        aug = coords.loop(augmented_loop(loop, system, balls=True, w_scale=coords.w_scale, z_scale=coords.z_scale),
                          balls=True)
        jumps = coords.jumps(sample_jumps(loop, h, balls=True, literals=system.literals), balls=True)
    except ZeroDivisionError:
        return None
    if not robust:
        aug = aug.nominal()
    Pb = [[ball(0.5 * (p + p.T)) for p in row] for row in P]
    if not all(proven_positive_definite(p) for row in Pb for p in row):
        return None
    for s, J in enumerate(jumps):
        if not proven_positive_definite(Pb[N][s] - J.T @ Pb[0][s] @ J):
            return None
    return aug, Pb


def prove_quadratic(loop: SampledLoop, system: FTCSystem, h: float, values: dict[str, Any], g: float,
                    robust: bool, coords: Coordinates | None = None) -> bool:
    """Every bordered condition, ``G``, node and jump condition proved definite in ball
    arithmetic (module docstring), on the ball loop and jumps of
    :func:`~ftc_verify.analysis.moments.sampled_gamma.augmented_loop` and
    :func:`~ftc_verify.analysis.moments.sampled_gamma.sample_jumps`."""
    import flint

    from ..rigorous import ball, ball_bmat, precision, proven_positive_definite
    from .sampled_gamma import clock_instance as instance

    P, D, lam, G = values["P"], values["D"], values["lam"], values["G"]
    N = len(P) - 1
    with precision():
        nodes = proved_nodes(loop, system, h, P, robust, coords)
        if nodes is None:
            return False
        aug, Pb = nodes
        delta = flint.arb(float(h)) / N
        for k in range(N):
            Db = [ball(0.5 * (m + m.T)) for m in D[k]]
            Eb = [Pb[k + 1][t] - Pb[k][t] - Db[t] * delta for t in range(len(Db))]
            for j, spec in enumerate(block_specs(aug)):
                Gb = ball(0.5 * (G[k][j] + G[k][j].T))
                if not proven_positive_definite(Gb):
                    return False
                la = [float(v) for v in lam[k][spec.s]] if robust else None

                def inst(Pn: list[Any], Pdot: list[Any], la: Any, spec: BlockSpec = spec) -> Any:
                    return instance(aug, spec, Pn, Pdot[spec.s], la, g, ball_bmat)

                M0, M1, M2 = _poly(inst, list(Pb[k]), Db, Eb, la, delta)
                if not proven_positive_definite(-_bordered(M0, M1, M2, Gb, ball_bmat)):
                    return False
    return math.isfinite(g)


def quadratic_program(aug: ClosedLoop, jumps: list[Matrix], h: float, N: int,
                      robust: bool) -> tuple[ConicProblem, QuadraticLayout]:
    """``min g`` subject to :func:`quadratic_rows` on ``N`` pieces, and its layout
    (``g`` is column ``layout.g``, the margin ``t`` the next one)."""
    sizes = instance_sizes(aug, robust)
    lay = QuadraticLayout(aug.n, len(aug.A), N, tuple(len(c) if robust else 0 for c in aug.channels), sizes)
    objective = np.zeros(lay.K)
    objective[lay.g] = 1.0
    return quadratic_rows(aug, jumps, lay, h, robust).problem(objective), lay


def quadratic_check(loop: SampledLoop, system: FTCSystem, h: float, x: Matrix, lay: QuadraticLayout, g: float,
                    robust: bool, coords: Coordinates | None = None) -> bool:
    """:func:`prove_quadratic` of the solution ``x`` with the bound ``g`` (gamma squared of
    the loop in the coordinates ``coords``)."""
    return prove_quadratic(loop, system, h, quadratic_values(x, lay, h), g, robust, coords)


def instance_sizes(aug: ClosedLoop, robust: bool) -> list[int]:
    """The size of the instance of every block spec of ``aug`` (:func:`block_specs` order):
    ``d`` plus the disturbance and output sizes (and, ``robust``, the channels')."""
    from .sampled_gamma import clock_instance

    zero = [np.zeros((aug.n, aug.n))] * len(aug.A)
    return [clock_instance(aug, spec, zero, zero[0], [0.0] * len(aug.channels[spec.s]) if robust else None, 1.0,
                           np.block).shape[0] for spec in block_specs(aug)]


def program_rows(aug: ClosedLoop, piece: tuple[int, int], robust: bool) -> int:
    r"""The rows of the conic program of the storage of degree ``piece[0]`` on
    ``piece[1]`` pieces (the dimension of its cone), from the dimensions alone: with
    :math:`N` pieces, block specs of instance sizes :math:`m_j`, :math:`S` joint states,
    :math:`d` the augmented state's size and :math:`t(m) = m (m + 1) / 2`,

    .. math::

        \text{affine: } 2N \textstyle\sum_j t(m_j), \qquad
        \text{quadratic: } N \textstyle\sum_j \bigl(t(2 m_j) + t(m_j)\bigr)

    (every instance at both ends of each piece; one bordered block and its :math:`G` per
    piece), plus :math:`S\,t(d)` jump and :math:`(N + 1) S\,t(d)` node rows and, robust,
    one nonnegative row per multiplier (per node, affine; per piece, quadratic). The
    solver's work and memory per iteration grow with it:
    :func:`~ftc_verify.analysis.moments.sampled_gamma.sampled_gamma` tries no program
    above :data:`~ftc_verify.analysis.moments.sampled_gamma.MAX_ROWS` rows."""
    degree, N = piece

    def t(m: int) -> int:
        return m * (m + 1) // 2

    sizes = instance_sizes(aug, robust)
    flow = 2 * N * sum(t(m) for m in sizes) if degree == 1 else N * sum(t(2 * m) + t(m) for m in sizes)
    multipliers = (N + 1 if degree == 1 else N) * sum(len(c) for c in aug.channels) if robust else 0
    return flow + (N + 2) * len(aug.A) * t(aug.n) + multipliers
