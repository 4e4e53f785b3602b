r"""A performance certificate for the sampled loop: a proved bound on its L2 gain.

The loop of :mod:`ftc_verify.analysis.moments.sampled` (the controller reads
:math:`x(t_k)` and the FDI report at :math:`t_k = k h`, holds its output, faults and
detections happen between samples) with the disturbance :math:`w` and the output
:math:`z = C_\theta x` of the continuous analysis, observed *between* samples too.
Bounded here: the stochastic :math:`L_2` gain :math:`\sup E\|z\|^2 / \|w\|^2` (zero
initial state) over every rate of the box and, robust, every :math:`\|\Delta\| \le 1`
(eq. (13)), with the period as the float given.

**Model** (derived here). The augmented state :math:`\zeta = (x, u, x_c^+)` of
dimension :math:`d` (:class:`~ftc_verify.analysis.moments.sampled.SampledLoop`) flows
between samples by :math:`\dot\zeta = \bar A_i \zeta + \bar B_{w,i} w`,
:math:`\bar B_{w,i} = (D_i, 0, 0)`, :math:`z = \bar C_i \zeta`,
:math:`\bar C_i = (C_i, 0, 0)`, with :math:`i` the true mode of the joint chain
:math:`\theta`; the uncertainty enters as :math:`\bar E_1 \Delta_1 \bar F_1 \zeta`,
:math:`\bar E_1 = (A_{1}; 0; 0)`, :math:`\bar F_1 = (A_{2}, 0, 0)`, and
:math:`\bar E_2 \Delta_2 \bar F_2 \zeta`, :math:`\bar E_2 = (B_{1}; 0; 0)`,
:math:`\bar F_2 = (0, B_{2}, 0)` (the held input passes the uncertain :math:`B`).
At a sample in joint state :math:`s` the controller resets
:math:`\zeta^+ = J_s \zeta^-`, :math:`J_s = R_s P` (the reset and restriction of the
one-period map: :math:`u = C_{c,e} x_c + D_{c,e} M_i x`, :math:`x_c^+ = \Phi_c x_c +
\Gamma_c M_i x`). With the clock :math:`\tau = t - t_k \in [0, h)` the triple
:math:`(\zeta, \theta, \tau)` is a piecewise-deterministic Markov process.

**Clock-dependent storage** (derived here). Take :math:`V = \zeta^T P_\theta(\tau)
\zeta` with :math:`P_s` continuous and affine on each piece :math:`[\tau_k,
\tau_{k+1}]` of :math:`[0, h]` (:math:`\tau_k = k h / N`), nodes :math:`P_s^k`,
slope :math:`D_s^k = (P_s^{k+1} - P_s^k) N / h`. Between samples Dynkin's formula
(generator of the chain :math:`Q`, the clock advancing at rate 1) gives

.. math::

    \tfrac{d}{dt} E[V] = E\Bigl[\zeta^T\bigl(D^k_\theta + \bar A^T P_\theta + P_\theta
    \bar A + \textstyle\sum_{s'} q_{\theta s'} P_{s'}\bigr)\zeta + 2 \zeta^T P_\theta
    (\bar B_w w + \bar E \Delta \bar F \zeta)\Bigr],

so the block of :mod:`ftc_verify.analysis.lmi` (:func:`~ftc_verify.analysis.lmi.lyapunov_block`:
Theorem 3.2's bounded-real block, or Lemma 4.1's with the S-procedure multipliers
:math:`\lambda_{s}` for :math:`\Delta`) built on :math:`(\bar A, \bar B_w, \bar C,
\bar E, \bar F)` with :math:`P_s(\tau)`, plus :math:`D_s^k` in its leading block,
negative definite for every :math:`\tau` of every piece, gives
:math:`\frac{d}{dt} E[V] + E|z|^2 - \gamma^2 |w|^2 < 0` there. On a piece the block
is affine in :math:`\tau` (:math:`P_s(\tau)` and the multipliers, interpolated
between their node values, enter affinely; :math:`D_s^k` is constant), so it is
negative definite on the piece iff it is at both ends: :math:`2 N` instances per
block, each with the piece's slope. At the sample :math:`V` must not grow:

.. math::

    J_s^T P_s(0) J_s \prec P_s(h) \qquad \text{for every joint state } s

(the chain does not jump at the sample instant, probability 0). Summing over the
periods, :math:`E\!\int_0^T |z|^2 - \gamma^2 |w|^2 \le V(0) - E V(T) \le 0` from
:math:`\zeta(0) = 0`: the gain is at most :math:`\gamma`, and with :math:`w = 0`,
:math:`E V` decreases geometrically over periods (strict inequalities, compact
clock interval): mean-square stability. Each block is affine in the generator row
of its joint state, so imposing it at the vertices of the rates of that row
(:func:`~ftc_verify.analysis.lmi.block_specs`) covers the box; the jump condition
contains no rate. As :math:`h \to 0` with :math:`P_s(\tau)` constant in the
plant part the conditions approach the continuous Theorem 3.2 / Lemma 4.1 for the
loop :math:`A_i + B_i K_e`: the bound tends to the continuous gamma.

**Solved and proved.** ``min g`` (:math:`g = \gamma^2`) subject to every instance
:math:`\preceq -t I`, :math:`P_s^k \succeq t I`, :math:`\lambda \ge 0` with the margin
:math:`t` fixed (:data:`MARGIN_TAU`, raised a hundredfold when the proof fails), by
Clarabel on the conic program of :mod:`ftc_verify.analysis.conic` (the blocks are
evaluated on its affine variables). The answer is then **proved** in ball
arithmetic (:func:`~ftc_verify.analysis.rigorous.proven_positive_definite`, 128
bits): every instance, every jump condition and every :math:`P_s^k`, rebuilt with
:func:`~ftc_verify.analysis.lmi.lyapunov_block` on ball matrices -- the plant's
numbers as written (:func:`~ftc_verify.analysis.exact.written`), the rates as written
(:func:`~ftc_verify.analysis.exact.ball_generator`), a static gain as written, a dynamic
controller's :math:`(\Phi_c, \Gamma_c)` by Arb's rigorous exponential with its
matrices taken as the floats read (as :mod:`ftc_verify.analysis.moments.sampled_proof`
does), the period as the float given. Both in the coordinates of
:mod:`~ftc_verify.analysis.moments.sampled_frame` (from :class:`SampledLoop`'s balanced
ones; the transform built on balls).

**The pieces** (:data:`PIECES`, :func:`sampled_gamma`): affine on 4 pieces first; where
that fails or stays far above the lower bound, a storage *quadratic* in the clock on
each piece (:mod:`~ftc_verify.analysis.moments.sampled_quadratic`; loss second order in
the pieces' length: the reach towards ``h_max``), while the program has at most
:data:`MAX_ROWS` rows (:func:`~ftc_verify.analysis.moments.sampled_quadratic.program_rows`:
the dimensions decide, never the clock, so every machine proves the same gamma).

**Beside it, a proved lower bound** (:mod:`~ftc_verify.analysis.moments.sampled_lower`:
a held worst-case feedback disturbance, its exact energies proved in ball arithmetic);
when none is proved, the float64 estimate of
:func:`~ftc_verify.analysis.moments.sampled_energy.gain_lower_estimate`.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ...controllers.controller import Controller, check_period
from ...model.system import FTCSystem, Matrix
from ..closedloop import Channel, ClosedLoop
from ..conic import Affine, KeyedVariables, Rows, affine_bmat, svec_index
from ..lmi import BlockSpec, block_specs, lyapunov_block
from .sampled import SampledLoop
from .sampled_energy import OMEGAS, gain_lower_estimate
from .sampled_frame import Coordinates, float_frame, io_scales

__all__ = ["MARGIN_TAU", "PIECES", "clock_instance", "MAX_ROWS", "GAP_RTOL", "GAIN_RTOL", "OMEGAS", "augmented_loop",
           "io_scale", "sample_jumps", "SampledGamma", "SampledPerformance", "sampled_gamma", "gain_lower_estimate",
           "sampled_performance", "attach_performance"]

#: First margin of the program (every instance ``<= -t I``); raised 100x when the proof fails.
MARGIN_TAU = 1e-7
#: ``(degree, N)`` of the storage tried in turn: affine (1) on 4 pieces (cheap, tight
#: well below ``h_max``), then quadratic (2, :mod:`~ftc_verify.analysis.moments.sampled_quadratic`)
#: on 2, 4, 8 pieces (its error is second order in the pieces' length: the reach towards ``h_max``).
PIECES: tuple[tuple[int, int], ...] = ((1, 4), (2, 2), (2, 4), (2, 8))
#: No entry of :data:`PIECES` after the first is tried when its program has more rows
#: (:func:`~ftc_verify.analysis.moments.sampled_quadratic.program_rows`; the paper's robust N = 8: 13184).
MAX_ROWS = 16384
#: With a lower bound (``target``), a further ``N`` is tried while gamma exceeds it by more than this ...
GAP_RTOL = 0.1
#: ... and the last doubling of ``N`` tightened it by at least this fraction.
GAIN_RTOL = 0.01


def io_scale(aug: ClosedLoop) -> float:
    """:math:`s_w s_z` of :func:`~ftc_verify.analysis.moments.sampled_frame.io_scales`: the
    factor by which the gain of the loop the program is solved for is larger."""
    return math.prod(io_scales(aug))


def augmented_loop(loop: SampledLoop, system: FTCSystem, *, balls: bool = False,
                   w_scale: float = 1.0, z_scale: float = 1.0) -> ClosedLoop:
    """The flow between samples as a :class:`ClosedLoop` on ``zeta = (x, u, x_c)`` in the
    balanced coordinates of ``loop`` (module docstring): ``A`` the flow, ``Bw``, ``Cz`` and
    the channels padded with zeros. ``balls=True``: every matrix a ball of the numbers as
    written (call inside :func:`~ftc_verify.analysis.rigorous.precision`); the loop's
    ``source`` then carries the system for its written rates. ``w_scale`` and ``z_scale``
    (powers of two: exact) multiply ``Bw`` and ``Cz``: the gain is multiplied by both."""
    from ..exact import written
    from ..rigorous import ball

    n, nu, d = loop.n, loop.nu, loop.d
    lit = system.literals
    sc = loop.scale

    def pad(M: Matrix, row: int, col: int, rows: int, cols: int) -> Any:
        full = np.zeros((rows, cols))
        full[row:row + M.shape[0], col:col + M.shape[1]] = M
        if not balls:
            return full
        return written(full, lit)  # zeros stay exact zeros

    def left(M: Any) -> Any:  # S^-1 M
        return ball(np.diag(1.0 / sc)) @ M if balls else M / sc[:, None]

    def right(M: Any) -> Any:  # M S
        return M @ ball(np.diag(sc)) if balls else M * sc[None, :]

    def channel(E: Matrix, F: Matrix, col: int, name: str) -> Channel:
        """``(E r) Delta (F / r)``: the same uncertainty; ``r`` the power of two that makes the
        two norms (balanced coordinates) equal when their ratio is outside [2^-6, 2^6]."""
        e = float(np.linalg.norm(E / sc[:n, None], 2))
        f = float(np.linalg.norm(F * sc[None, col:col + F.shape[1]], 2))
        ok = e > 0 and f > 0 and math.isfinite(f / e) and not 2.0 ** -6 <= f / e <= 2.0 ** 6
        r = float(2.0 ** round(0.5 * math.log2(f / e))) if ok else 1.0
        return Channel(left(pad(E, 0, 0, d, E.shape[1])) * r, right(pad(F, 0, col, F.shape[0], d)) * (1.0 / r), name)

    A: list[Any] = []
    Bw: list[Any] = []
    Cz: list[Any] = []
    chans: list[tuple[Channel, ...]] = []
    for i, _ in system.chain.joint_modes:
        md = system.modes[i]
        flow = np.zeros((d, d))
        flow[:n, :n], flow[:n, n:n + nu] = md.A, md.B
        A.append(right(left(pad(flow, 0, 0, d, d))) if balls else loop.flow[len(A)])
        bw = left(pad(md.D, 0, 0, d, md.D.shape[1]))
        Bw.append(bw * w_scale if w_scale != 1.0 else bw)  # times a power of two: exact on balls too
        cz = right(pad(md.C, 0, 0, md.C.shape[0], d))
        Cz.append(cz * z_scale if z_scale != 1.0 else cz)
        c = [channel(E, F, col, name) for E, F, col, name in ((md.A1, md.A2, 0, "Delta1 (A)"),
                                                              (md.B1, md.B2, n, "Delta2 (B)"))
             if E is not None and F is not None]
        chans.append(tuple(c))
    return ClosedLoop(system.chain, tuple(A), tuple(Bw), tuple(Cz), tuple(chans), "sampled (x, u, x_c)",
                      None, system.names, (system, loop.controller) if balls else None)


def sample_jumps(loop: SampledLoop, h: float, *, balls: bool = False, literals: Any = None) -> list[Any]:
    """:math:`J_s = R_s P` per joint state (balanced coordinates); as balls, a static gain
    as written, a dynamic controller's discretisation by the rigorous exponential."""
    P = loop.restriction()
    if not balls:
        return [R @ P for R in loop.resets(h)]
    from ..exact import written
    from ..rigorous import ball, ball_bmat
    from .sampled_proof import ball_resets

    if loop.nc:
        return [R @ ball(P) for R in ball_resets(loop, h)]
    c = loop.controller
    out = []
    for M, e in zip(loop.measurement, loop.entry):
        R = ball_bmat([[np.eye(loop.n)], [written(c.Dc[e], c.literals) @ written(M, literals)]])
        R = ball(np.diag(1.0 / loop.scale)) @ R @ ball(np.diag(loop.scale_r))
        out.append(R @ ball(P))
    return out


@dataclass(frozen=True)
class _Layout:
    """Columns of the program: ``svec`` of :math:`P_s^0` (key ``(0, s)``) and of the
    slopes :math:`D_s^j` (key ``(j + 1, s)``), the multipliers node by node, ``g``, ``t``.
    Nodes are :math:`P_s^k = P_s^0 + (h / N) \\sum_{j < k} D_s^j`: the slopes are
    variables of their own size (nodes differing by :math:`O(h)` would make the program
    ill-conditioned as :math:`h \\to 0`)."""

    d: int
    states: int
    nodes: int
    channels: tuple[int, ...]

    @property
    def pp(self) -> int:
        return self.d * (self.d + 1) // 2

    def p(self, k: int, s: int) -> int:
        return (k * self.states + s) * self.pp

    def lam(self, k: int, s: int) -> int:
        return self.nodes * self.states * self.pp + k * sum(self.channels) + sum(self.channels[:s])

    @property
    def g(self) -> int:
        return self.nodes * self.states * self.pp + self.nodes * sum(self.channels)

    @property
    def K(self) -> int:
        return self.g + 2


def clock_instance(aug: ClosedLoop, spec: BlockSpec, P: list[Any], D: Any, lam: Any, g: Any, bmat: Any) -> Any:
    """One instance: :func:`lyapunov_block` at a node plus the piece's slope ``D`` in
    the leading block."""
    M = lyapunov_block(aug, spec, P, lam, g, bmat)
    d = aug.n
    rest = M.shape[0] - d
    if rest == 0:
        return M + D
    return M + bmat([[D, np.zeros((d, rest))], [np.zeros((rest, d)), np.zeros((rest, rest))]])


class _Local(KeyedVariables):
    """The variables one constraint uses, on its own columns, keyed ``(j, s)`` as in :class:`_Layout`."""

    def node(self, e: int, t: int, delta: float) -> Affine:
        """:math:`P_t^e = P_t^0 + \\delta \\sum_{j < e} D_t^j`."""
        out = self.var[(0, t)]
        for j in range(e):
            out = out + self.var[(j + 1, t)] * delta
        return out


def _node_keys(e: int, t: int) -> list[tuple[int, int]]:
    return [(j, t) for j in range(e + 1)]


def _rows(aug: ClosedLoop, jumps: list[Matrix], lay: _Layout, h: float, robust: bool) -> Rows:
    """Every instance, jump condition (divided by ``h``: its slack is :math:`O(h)`) and
    ``P_s^k >= t I`` as conic rows (``+ t I <= 0``)."""
    rows = Rows(lay.K)
    N = lay.nodes - 1
    delta = h / N
    specs = block_specs(aug)
    for k in range(N):
        for e in (k, k + 1):
            for spec in specs:
                s = spec.s
                coupled = [s] + [t for t, q in enumerate(spec.q_row) if q != 0.0 and t != s]
                nl = lay.channels[s] if robust else 0
                keys = [key for t in coupled for key in _node_keys(e, t)] + [(k + 1, s)]
                loc = _Local(lay.d, lay.p, keys, list(range(lay.lam(e, s), lay.lam(e, s) + nl)) + [lay.g, lay.g + 1])
                P: list[Any] = [None] * lay.states
                for t in coupled:
                    P[t] = loc.node(e, t, delta)
                lam = [loc.scalar(c) for c in range(nl)] if robust else None
                M = clock_instance(aug, spec, P, loc.var[(k + 1, s)], lam, loc.scalar(nl), affine_bmat)
                rows.lmi(M + loc.scalar(nl + 1) * np.eye(M.shape[0]), loc.columns)
    for s, J in enumerate(jumps):
        loc = _Local(lay.d, lay.p, _node_keys(N, s), [lay.g + 1])
        rows.lmi((J.T @ loc.node(0, s, delta) @ J - loc.node(N, s, delta)) * (1.0 / h)
                 + loc.scalar(0) * np.eye(lay.d), loc.columns)
    for k in range(lay.nodes):
        for s in range(lay.states):
            loc = _Local(lay.d, lay.p, _node_keys(k, s), [lay.g + 1])
            rows.lmi(loc.scalar(0) * np.eye(lay.d) - loc.node(k, s, delta), loc.columns)
    nl = lay.g - lay.lam(0, 0)
    if nl:
        A = np.zeros((nl, lay.K))
        A[np.arange(nl), lay.lam(0, 0) + np.arange(nl)] = -1.0
        rows.nonneg(A, np.zeros(nl))
    return rows


def _values(x: Matrix, lay: _Layout, h: float) -> tuple[list[list[Matrix]], list[list[list[float]]]]:
    """The nodes ``P[k][s]`` and ``lam[k][s]`` from a solution ``x``."""
    r, c, w = svec_index(lay.d)
    delta = h / (lay.nodes - 1)

    def unsvec(k: int, s: int) -> Matrix:
        M = np.zeros((lay.d, lay.d))
        v = x[lay.p(k, s):lay.p(k, s) + lay.pp] / w
        M[r, c] = v
        M[c, r] = v
        return M

    P = [[unsvec(0, s) for s in range(lay.states)]]
    for k in range(1, lay.nodes):
        P.append([P[-1][s] + delta * unsvec(k, s) for s in range(lay.states)])
    lam = [[list(x[lay.lam(k, s):lay.lam(k, s) + lay.channels[s]]) for s in range(lay.states)]
           for k in range(lay.nodes)]
    return P, lam


def _prove(loop: SampledLoop, system: FTCSystem, h: float, P: list[list[Matrix]], lam: list[list[list[float]]],
           g: float, robust: bool, coords: Coordinates | None = None) -> bool:
    """Every instance, jump condition and ``P_s^k`` proved definite in ball arithmetic
    (module docstring), from the numbers as written."""
    import flint

    from ..rigorous import ball_bmat, precision, proven_positive_definite
    from .sampled_quadratic import proved_nodes

    N = len(P) - 1
    with precision():
        nodes = proved_nodes(loop, system, h, P, robust, coords)
        if nodes is None:
            return False
        aug, Pb = nodes
        slope = flint.arb(N) / flint.arb(float(h))
        for k in range(N):
            for e in (k, k + 1):
                for spec in block_specs(aug):
                    lam_s = [float(v) for v in lam[e][spec.s]] if robust else None
                    D = (Pb[k + 1][spec.s] - Pb[k][spec.s]) * slope
                    M = clock_instance(aug, spec, Pb[e], D, lam_s, g, ball_bmat)
                    if not proven_positive_definite(-M):
                        return False
    return True


@dataclass(frozen=True)
class SampledGamma:
    """One certificate of :func:`sampled_gamma`.

    ``gamma`` is the proved bound (``None`` when none was found: ``note`` says why),
    ``pieces`` the :math:`N` of the storage matrix, ``degree`` its degree in the clock on
    each piece (1 affine, 2 quadratic), ``margin`` the program's ``t``, ``seconds`` CPU
    seconds (reported, never deciding anything), ``rows`` the rows of its program."""

    robust: bool
    gamma: float | None
    pieces: int
    margin: float
    note: str
    seconds: float
    degree: int = 1
    rows: int = 0


def _attempt(loop: SampledLoop, system: FTCSystem, aug: ClosedLoop, jumps: list[Matrix], h: float,
             piece: tuple[int, int], robust: bool,
             coords: Coordinates | None = None) -> tuple[float | None, float, str]:
    """``(gamma, margin, why)`` of the program with storage of degree ``piece[0]`` (1:
    affine, this module; 2: quadratic, :mod:`~ftc_verify.analysis.moments.sampled_quadratic`)
    on ``piece[1]`` pieces: solved with the margins ``MARGIN_TAU * 100**j``, ``j < 3``,
    until one answer is proved (``gamma`` ``None``: ``why`` says what failed)."""
    from ..solvers import solve_conic_dual
    from .sampled_quadratic import quadratic_check, quadratic_program

    degree, N = piece
    name = f"N = {N} ({'affine' if degree == 1 else 'quadratic'})"
    if degree == 1:
        lay = _Layout(loop.d, loop.states, N + 1, tuple(len(c) if robust else 0 for c in aug.channels))
        objective = np.zeros(lay.K)
        objective[lay.g] = 1.0
        problem, gi = _rows(aug, jumps, lay, h, robust).problem(objective), lay.g
    else:
        problem, quad = quadratic_program(aug, jumps, h, N, robust)
        gi = quad.g
    tau = MARGIN_TAU
    why = "no certificate"
    for _ in range(3):
        out, x, _z = solve_conic_dual(problem.fix(gi + 1, tau))
        if x is None:
            return None, tau, f"{name}: the solver found no point ({out.status}{': ' + out.message if out.message else ''})"
        g = float(x[gi]) * (1 + 1e-9) + 1e-300
        if degree == 1:
            P, lam = _values(x, lay, h)
            proved = _prove(loop, system, h, P, lam, g, robust, coords)
        else:
            proved = quadratic_check(loop, system, h, x, quad, g, robust, coords)
        if proved:
            factor = 1.0 if coords is None else coords.gain_factor  # a power of two: exact
            return math.nextafter(math.sqrt(g) / factor, math.inf), tau, ""
        why = f"{name}: the solver's answer was not proved in ball arithmetic"
        tau *= 100.0
    return None, tau, why


def sampled_gamma(system: FTCSystem, controller: Controller, period: float, *, robust: bool,
                  pieces: tuple[int | tuple[int, int], ...] = PIECES, loop: SampledLoop | None = None,
                  max_rows: int = MAX_ROWS, target: float | None = None) -> SampledGamma:
    """The gamma proved by the clock-dependent certificate of the module docstring at
    ``period``, over the rate box (and ``Delta`` when ``robust``): each ``N`` of
    ``pieces`` in turn (the cost grows with ``N``, the reach towards ``h_max`` and the
    tightness too) until one is proved -- with a ``target`` (a lower bound of the gain),
    until one is proved within :data:`GAP_RTOL` of it or a doubling of ``N`` tightens it
    by less than :data:`GAIN_RTOL`, the smallest proved gamma kept -- and no entry after
    the first tried when its program would have more than ``max_rows`` rows
    (:func:`~ftc_verify.analysis.moments.sampled_quadratic.program_rows`, from the
    dimensions: the result does not depend on the machine's speed or load; ``seconds``
    is CPU time, reported only)."""
    from .sampled_quadratic import program_rows

    h = check_period(period, "period")
    t0 = time.process_time()
    loop = SampledLoop.of(system, controller, loop)
    coords = (frame := float_frame(loop, system, h)).coords  # shared with the lower bound (sampled_lower)
    aug = coords.loop(augmented_loop(loop, system, w_scale=coords.w_scale, z_scale=coords.z_scale))
    robust = robust and aug.uncertain
    if not robust:
        aug = aug.nominal()
    jumps = coords.jumps(list(frame.jumps))
    whys: list[str] = []
    best: tuple[float, tuple[int, int], float] | None = None
    for item in pieces:
        piece = (1, item) if isinstance(item, int) else item
        rows = program_rows(aug, piece, robust)
        if (whys or best) and rows > max_rows:
            whys.append(f"N = {piece[1]} not tried (its program would have {rows} rows, above {max_rows})")
            break
        gamma, tau, why = _attempt(loop, system, aug, jumps, h, piece, robust, coords)
        if gamma is None:
            whys.append(why)
            continue
        if best is not None and gamma > best[0] * (1.0 - GAIN_RTOL):
            best = min(best, (gamma, piece, tau))
            break  # diminishing returns: more pieces would not tighten it much further
        best = (gamma, piece, tau) if best is None or gamma < best[0] else best
        if target is None or gamma <= target * (1.0 + GAP_RTOL):
            break
    seconds = time.process_time() - t0
    if best is None:
        return SampledGamma(robust, None, 0, 0.0, "; ".join(whys) or "no certificate", seconds)
    (degree, N), how = best[1], ("affine", "every instance at both ends of each piece")
    if degree == 2:
        how = ("quadratic", "every instance on each whole piece (S-procedure in the clock)")
    return SampledGamma(robust, best[0], N, best[2],
                        f"proved in 128-bit ball arithmetic: storage {how[0]} on {N} piece(s) of [0, h], "
                        f"{how[1]}, the jump at the sample, every node P_s", seconds, degree,
                        program_rows(aug, best[1], robust))


@dataclass(frozen=True)
class SampledPerformance:
    """The sampled loop's gains at ``period`` (JSON: :meth:`to_dict`, merged into ``sampled``)."""

    period: float
    nominal: SampledGamma
    robust: SampledGamma | None
    nominal_lower: float | None
    nominal_lower_where: str
    robust_lower: float | None
    robust_lower_where: str
    nominal_lower_kind: str = "estimate"
    robust_lower_kind: str = "estimate"

    def to_dict(self) -> dict[str, Any]:
        """``nominal_gamma``, ``robust_gamma`` (proved, ``None`` if not), their lower
        estimates and notes."""
        rob = self.robust
        return {
            "nominal_gamma": self.nominal.gamma,
            "nominal_gamma_note": self.nominal.note,
            "nominal_gamma_pieces": self.nominal.pieces,
            "nominal_gamma_storage_degree": self.nominal.degree,
            "nominal_gamma_program_rows": self.nominal.rows,
            "robust_gamma_pieces": None if rob is None else rob.pieces,
            "robust_gamma_program_rows": None if rob is None else rob.rows,
            "gamma_max_program_rows": MAX_ROWS,
            "robust_gamma": None if rob is None else rob.gamma,
            "robust_gamma_note": "no uncertainty channels" if rob is None else rob.note,
            "robust_gamma_storage_degree": None if rob is None else rob.degree,
            "nominal_gamma_lower": self.nominal_lower,
            "nominal_gamma_lower_where": self.nominal_lower_where,
            "robust_gamma_lower": self.robust_lower,
            "robust_gamma_lower_where": self.robust_lower_where,
            "nominal_gamma_lower_kind": self.nominal_lower_kind,
            "robust_gamma_lower_kind": self.robust_lower_kind,
            "gamma_lower_kind": ("proved" if {self.nominal_lower_kind, self.robust_lower_kind} == {"proved"}
                                 else "estimate (float64 exact-energy ratio; not proved)"),
        }


def sampled_performance(system: FTCSystem, controller: Controller, period: float, *,
                        loop: SampledLoop | None = None) -> SampledPerformance:
    """Both certificates and their lower bounds: :func:`~ftc_verify.analysis.moments.sampled_gains.sampled_gains`
    (``loop``: :meth:`SampledLoop.build` of ``system, controller`` when the caller has it)."""
    from .sampled_gains import sampled_gains

    return sampled_gains(system, controller, period, loop=loop)


def attach_performance(result: Any, system: FTCSystem, controller: Controller, *,
                       loop: SampledLoop | None = None) -> Any:
    """``result`` (a :class:`~ftc_verify.analysis.moments.sampled.SampledResult`) with its
    ``performance`` at ``result.period``; none is sought (the notes say why) when the loop is
    proved not mean-square stable there or its float64 radius is not below 1 (or overflows).
    ``loop``: as for :func:`sampled_performance`."""
    h, rho = result.period, result.spectral_radius
    if result.verdict == "not stable" or not rho < 1.0:
        why = "no certificate: " + ("the sampled loop is proved NOT mean-square stable at this period (infinite gain)"
                                    if result.verdict == "not stable" else f"float64 one-period radius {rho:.6g} >= 1")
        rob = SampledGamma(True, None, 0, 0.0, why, 0.0) if system.uncertain else None
        perf = SampledPerformance(h, SampledGamma(False, None, 0, 0.0, why, 0.0), rob, None, why, None, why)
    else:
        perf = sampled_performance(system, controller, h, loop=loop)
    return replace(result, performance=perf)
