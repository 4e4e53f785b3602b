r"""A proved lower bound of the sampled loop's L2 gain: one admissible disturbance, exactly.

The sampled loop of :mod:`ftc_verify.analysis.moments.sampled_gamma` (state
:math:`\zeta = (x, u, x_c^+)` between samples, sampled state :math:`\xi = (x, x_c)`,
reset :math:`\zeta = R_s \xi` at the sample :math:`t_k = k h` in joint state :math:`s`)
has the stochastic gain :math:`\gamma_h = \sup_w (E\|z\|^2 / E\|w\|^2)^{1/2}` over
adapted disturbances (zero initial state). Any one admissible disturbance, one rate
array :math:`\rho` of the box and (robust) one :math:`\|\Delta\| \le 1` give
:math:`\gamma_h \ge (E\|z\|^2 / E\|w\|^2)^{1/2}`. Derived here:

**The disturbance** -- a *held feedback of the sampled state*, switched off after
:math:`K` periods:

.. math::

    w(t) = e \ (k = 0), \qquad w(t) = F_{\theta(t_k)}\,\xi(t_k) \ (1 \le k < K), \qquad
    w(t) = 0 \ (k \ge K), \qquad t \in [t_k, t_{k+1}),

with :math:`e` a fixed unit vector. It uses only what is known at :math:`t_k` (adapted),
is bounded on a finite horizon (in :math:`L_2`), and is what the simulator's
sample-and-hold would apply. Augment the flow with the held value :math:`w_h`:
:math:`\bar z = (\zeta, w_h)`, :math:`\dot{\bar z} = \hat A_i \bar z`,
:math:`\hat A_i = \bigl[\begin{smallmatrix}\bar A_i + \bar E\Delta\bar F & \bar B_{w,i}
\\ 0 & 0\end{smallmatrix}\bigr]`, reset :math:`\bar z = \hat R_s \xi`,
:math:`\hat R_s = (R_s; F_s)`. Per joint state, the second moments
:math:`\bar X_s = E[\bar z\bar z^T 1\{\theta = s\}]` obey :math:`\dot{\bar X} =
\mathcal L(\bar X)` inside a period (the moment generator at :math:`\rho`, jumps of the
chain included); with the Van Loan blocks :math:`\mathcal F = e^{\mathcal L h}`,
:math:`\mathcal G = \int_0^h e^{\mathcal L \tau} d\tau` (only :math:`\ell^T\mathcal G`
is needed: with :math:`\mathcal F` it is a block of one exponential of size :math:`N + 1`,
:math:`e^{[[0, \ell^T], [0, \mathcal L]]\,h} = [[1, \ell^T\mathcal G], [0, \mathcal F]]`) and :math:`\mathcal P` the restriction to
:math:`\xi`, the sampled moments :math:`v_k` (``vech`` per joint state) satisfy
:math:`v_1 = \mathcal P\mathcal F m_0`, :math:`v_{k+1} = T v_k`,
:math:`T = \mathcal P\mathcal F\hat{\mathcal R}` (:math:`m_0` the moments of
:math:`\bar z(0) = (0, e)` in the initial joint state :math:`s_0`), and

.. math::

    E\!\int_0^{Kh}|z|^2 = \ell^T\mathcal G m_0 + \ell^T\mathcal G\hat{\mathcal R}\,S, \qquad
    E\!\int_0^{\infty}|w|^2 = h|e|^2 + h\,f^T S, \qquad S = \sum_{j=0}^{K-2} T^j v_1,

:math:`\ell` the weights of :math:`\operatorname{tr}(\bar C_i^T\bar C_i\,\cdot)`,
:math:`f` those of :math:`\operatorname{tr}(F_s^T F_s\,\cdot)`. The output energy after
:math:`Kh` is dropped (:math:`\ge 0`): the bound is :math:`\gamma_h \ge
\sqrt{\text{numerator}/\text{denominator}}`. No stability is needed (finite horizon),
so :math:`F` may even destabilise the loop. With :math:`K = 2^p`, :math:`S` is computed
by doubling (:math:`S_{2m} = S_m + T^m S_m`, :math:`T^{2m} = (T^m)^2`).

**The choice** (float64 search, then proved). :math:`F_s` is the continuous loop's
worst-case feedback :func:`~ftc_verify.analysis.lower_bound.float_gain` (coupled
bounded-real Riccati equations at the box's centre, the smallest feasible gamma; refined
below by Nelder-Mead over its entries at the best rate array) on the plant
state, times a scale :math:`\alpha` from :data:`SCALES`: as :math:`\alpha F` makes the loop
nearly marginal, the ratio tends to the ratio of :math:`\ell` and :math:`h f` on the
dominant eigenvector of :math:`T`, which at the Riccati equality is the gain. The
best ratio in float64 over :math:`\alpha`, the rate arrays of
:func:`~ftc_verify.analysis.moments.sampled.rate_points` and (robust)
:math:`\Delta \in \{0, +I, -I\}` (norm 1) is then proved.

**The proof.** :math:`F`, :math:`e` and :math:`\rho` are floats taken as exact (the rate
array a vertex or the centre of the box, as the user wrote it:
:func:`~ftc_verify.analysis.moments.sampled_balls.ball_generator`); the flow, the
disturbance and output matrices, the uncertainty channels and the resets are balls of
the numbers as written (:func:`~ftc_verify.analysis.moments.sampled_gamma.augmented_loop`,
the resets of a dynamic controller by Arb's rigorous exponential), the period is the
float given; :math:`\mathcal F`, :math:`\mathcal G` by a rigorous ball exponential
(:func:`~ftc_verify.analysis.moments.fast_balls.arb_expm`: float64 midpoint-radius
arithmetic with its error analysis, Arb's exponential when a number overflows) of the
Van Loan matrix with its output row scaled by a power of two (exact; it set the norm, so
the squarings: :mod:`~ftc_verify.analysis.moments.sampled_lower_ops`), the doubling in
64-bit Arb ball arithmetic (:data:`PROOF_BITS`), both as written and in the float
eigenbasis of :math:`T` (:func:`~ftc_verify.analysis.moments.sampled_lower_ops.eigen_sums`:
no wrapping), every level a bound of its own; when the enclosure still loses more than
:data:`PROOF_RTOL` below the float64 value, everything again at 128 bits with Arb's
exponential. The bound is the lower end of the
enclosure of the ratio (rounded down): a **proved** lower bound of the sampled loop's nominal (robust)
gain at this period.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ...controllers.controller import Controller, check_period
from ...model.system import FTCSystem, Matrix
from ..closedloop import ClosedLoop, closed_loop
from ..lower_bound import float_gain
from .sampled import SampledLoop, rate_points
from .sampled_energy import DECAY, OMEGAS, gain_lower_estimate
from .sampled_lower_ops import MomentOps, row_exponent, trace_weights
from .stability import duplication_matrix, vech_order

__all__ = ["SCALES", "HORIZON", "SPAN_TIMES", "PROOF_BITS", "PROOF_RTOL", "SampledLowerBound", "sampled_lower_bound",
           "sampled_lower_bounds", "OMEGAS", "DECAY",
           "gain_lower_estimate"]

#: Scales ``alpha`` of the worst-case feedback tried in float64 (the best ratio is proved).
SCALES = (0.0, 0.8, 0.95, 1.0, 1.02, 1.05, 1.1, 1.3)
#: Time span (time units) the disturbance acts over: ``K = 2^p`` periods, ``K h >= HORIZON``.
HORIZON = 200.0
#: ... or this many time constants of the continuous loop's slowest second moment when longer.
SPAN_TIMES = 200.0
#: Relative tolerance of the float bisection for the worst-case feedback (the scales absorb it).
FEEDBACK_RTOL = 1e-3
#: Most float64 ratios the Nelder-Mead refinement of the feedback evaluates.
REFINE_EVALUATIONS = 400
#: Largest ``p`` of ``K = 2^p``.
MAX_DOUBLINGS = 20
#: Arb's working precision of the proof: 64 bits lets the Van Loan exponential run in
#: float64 midpoint-radius arithmetic (:func:`~ftc_verify.analysis.moments.fast_balls.arb_expm`,
#: seven times faster than Arb's at 128 bits); the bound usually loses about ``1e-9``
#: relative, and the proof is redone at 128 bits when it loses more than ``PROOF_RTOL``.
PROOF_BITS = 64
#: The 64-bit bound is redone at 128 bits when it lies more than this fraction below the float value.
PROOF_RTOL = 1e-6


@dataclass(frozen=True)
class SampledLowerBound:
    """One lower bound of :func:`sampled_lower_bound`: ``value`` (``None`` when none was
    proved), ``kind`` (``"proved"``), ``where`` the disturbance, rate array and ``Delta``."""

    value: float | None
    kind: str
    where: str
    float_value: float | None


_weights = trace_weights
_Ops = MomentOps


@dataclass(frozen=True, eq=False)
class _Blocks:
    r"""The feedback-independent parts at one rate array and ``Delta``: the blocks
    :math:`\mathcal F` and :math:`\ell^T\mathcal G` (the output weights times the integral),
    the restriction :math:`\mathcal P`, :math:`m_0` (module docstring)."""

    Fm: Any
    lg: Any  # the row ell^T G
    restrict: Any
    m0: Matrix
    Dr: Matrix
    Ld: Matrix


def _blocks(ops: _Ops, aug: ClosedLoop, restriction: Matrix, Q: Any, h: Any, delta: float, nw: int) -> _Blocks:
    """:class:`_Blocks` (float or ball) for the loop ``aug`` with ``Delta = delta I``."""
    d, r = aug.n, restriction.shape[0]
    dd = d + nw
    Dd, Ld = duplication_matrix(dd)
    Dr, Lr = duplication_matrix(r)
    vd = Dd.shape[1]
    states = len(aug.A)
    eye = ops.mat(np.eye(dd))
    blocks, ell = [], []
    for s in range(states):
        A = aug.A[s]
        for ch in aug.channels[s]:
            A = A + ch.E @ ops.mat(delta * np.eye(ch.E.shape[1], ch.F.shape[0])) @ ch.F
        Ah = ops.bmat([[A, aug.Bw[s]], [np.zeros((nw, d)), np.zeros((nw, nw))]])
        blocks.append(ops.mat(Ld) @ (ops.kron(eye, Ah) + ops.kron(Ah, eye)) @ ops.mat(Dd))
        Ch = ops.bmat([[aug.Cz[s], np.zeros((aug.Cz[s].shape[0], nw))]])
        ell.append(ops.weights(Ch.T @ Ch))
    N = states * vd
    V = ops.diag(blocks)
    if ops.balls:
        for s in range(states):
            for t in range(states):
                for k in range(vd):
                    V.value[s * vd + k, t * vd + k] += Q[t, s]
    else:
        V = V + np.kron(np.asarray(Q).T, np.eye(vd))
    # exp([[0, ell], [0, V]] h) = [[1, ell G], [0, F]]: size N + 1, not the 2N of [[V, I], [0, 0]];
    # with the row ell scaled by 2^-k (exact: sampled_lower_ops' module docstring)
    lrow = ops.bmat([ell])
    hm = abs(float(h.mid() if hasattr(h, "mid") else h))
    if ops.balls:
        from .fast_balls import from_arb

        row_mid, V_mid = from_arb(lrow.value)[0], from_arb(V.value)[0]
    else:
        row_mid, V_mid = np.asarray(lrow), np.asarray(V)
    k = row_exponent(float(np.abs(row_mid).sum()) * hm, float(np.max(np.abs(V_mid).sum(axis=1))) * hm)
    E = ops.expm(ops.bmat([[np.zeros((1, 1)), lrow * 2.0 ** -k if k else lrow], [np.zeros((N, 1)), V]]), h)
    Pz = np.zeros((r, dd))
    Pz[:, :d] = restriction
    rows_d, cols_d = vech_order(dd)
    z0 = np.zeros(dd)
    z0[d] = 1.0
    m0 = np.zeros((N, 1))
    m0[:vd, 0] = np.outer(z0, z0)[rows_d, cols_d]  # the initial joint state 0
    lg = ops.block(E, 0, 1, 1, N + 1)
    return _Blocks(ops.block(E, 1, N + 1, 1, N + 1), lg * 2.0 ** k if k else lg,
                   ops.mat(np.kron(np.eye(states), Lr @ np.kron(Pz, Pz) @ Dd)), m0, Dr, Ld)


def _ratio(ops: _Ops, b: _Blocks, resets: Sequence[Any], F: Sequence[Matrix], h: Any,
           doublings: int) -> tuple[Any, Any]:
    """``(numerator, denominator)`` of the module docstring (float or ball, 1 x 1) with
    :math:`K = 2^p + 1` periods, :math:`p` = ``doublings``, :math:`e` the first unit vector."""
    return _ratios(ops, b, resets, F, h, doublings)[-1]


def _ratios(ops: _Ops, b: _Blocks, resets: Sequence[Any], F: Sequence[Matrix], h: Any,
            doublings: int, terms: tuple[Any, Any, Any, Any] | None = None) -> list[tuple[Any, Any]]:
    """:func:`_ratio` at every :math:`p' \\le p` (``out[p']``, :math:`K = 2^{p'} + 1`), from
    the one pass of doublings: each is a lower bound of its own. ``terms``: :func:`_terms`
    when already computed."""
    lift, f, T, Sm = _terms(ops, b, resets, F) if terms is None else terms
    Pw = T
    num0 = b.lg @ b.m0
    out = []
    for k in range(doublings + 1):  # S_{2m} = S_m + T^m S_m, T^{2m} = (T^m)^2
        if k:
            Sm = Sm + Pw @ Sm
            Pw = Pw @ Pw if k < doublings else Pw
        out.append((num0 + b.lg @ (lift @ Sm), (f @ Sm + 1.0) * h))
    return out


def _lift(ops: _Ops, b: _Blocks, resets: Sequence[Any], F: Sequence[Matrix]) -> tuple[Any, Any]:
    r"""The reset of the moments :math:`\hat{\mathcal R}` and the row :math:`f`."""
    lifts = []
    for R, Fs in zip(resets, F):
        Rh = ops.bmat([[R], [Fs]])
        lifts.append(ops.mat(b.Ld) @ ops.kron(Rh, Rh) @ ops.mat(b.Dr))
    return ops.diag(lifts), ops.mat(np.concatenate([_weights(Fs.T @ Fs) for Fs in F])[None, :])


def _terms(ops: _Ops, b: _Blocks, resets: Sequence[Any], F: Sequence[Matrix]) -> tuple[Any, Any, Any, Any]:
    r"""``(lift, f, T, v_1)``: :func:`_lift`, the one-period map :math:`T` and :math:`v_1`."""
    lift, f = _lift(ops, b, resets, F)
    return lift, f, b.restrict @ b.Fm @ lift, b.restrict @ (b.Fm @ b.m0)


def _eigen_levels(b: _Blocks, terms: tuple[Any, Any, Any, Any], h: Any,
                  doublings: int) -> list[tuple[Any, Any]]:
    """:func:`_ratios` on balls (Arb numbers) with the doublings in the eigenbasis of
    :math:`T` (:func:`~ftc_verify.analysis.moments.sampled_lower_ops.eigen_sums`; ``[]`` when
    unusable); ``terms`` from :func:`_terms`."""
    from .sampled_lower_ops import eigen_sums

    lift, f, T, v1 = terms
    found = eigen_sums(T.value, v1.value, (b.lg @ lift).value, f.value, doublings)
    num0 = (b.lg @ b.m0).value[0, 0]
    return [(num0 + gS, (fS + 1) * h) for gS, fS in found]


class _FloatRatio:
    r""":func:`_ratio` in float64 with every feedback-independent product of ``b``
    precomputed (:math:`\mathcal P\mathcal F`, :math:`\ell\mathcal G`, :math:`v_1`,
    :math:`\ell\mathcal G m_0`): the same formulas, a few times faster; what the float
    search and the Nelder-Mead refinement evaluate (the proof uses :func:`_ratio` on balls)."""

    def __init__(self, b: _Blocks, r: int) -> None:
        self.RF = b.restrict @ b.Fm
        self.lg = b.lg
        self.v1 = b.restrict @ (b.Fm @ b.m0)
        self.num0 = float((self.lg @ b.m0)[0, 0])
        self.Ld, self.Dr = b.Ld, b.Dr
        self.vd, self.vr = b.Ld.shape[0], b.Dr.shape[1]
        rows, cols = vech_order(r)
        self.index = (rows, cols, np.where(rows == cols, 1.0, 2.0))

    def __call__(self, resets: Sequence[Matrix], F: Sequence[Matrix], h: float, doublings: int) -> float:
        """The ratio numerator / denominator (``nan`` or ``inf`` when it overflows)."""
        states = len(resets)
        vd, vr = self.vd, self.vr
        lift = np.zeros((states * vd, states * vr))
        rows, cols, w = self.index
        f = np.empty(states * vr)
        for s, (R, Fs) in enumerate(zip(resets, F)):
            Rh = np.vstack([R, Fs])
            lift[s * vd:(s + 1) * vd, s * vr:(s + 1) * vr] = self.Ld @ np.kron(Rh, Rh) @ self.Dr
            f[s * vr:(s + 1) * vr] = w * (Fs.T @ Fs)[rows, cols]
        T = self.RF @ lift
        Sm, Pw = self.v1, T
        for _ in range(doublings):
            Sm = Sm + Pw @ Sm
            Pw = Pw @ Pw
        num = self.num0 + float((self.lg @ (lift @ Sm))[0, 0])
        return num / ((float(f @ Sm[:, 0]) + 1.0) * h)


def _feedbacks(system: FTCSystem, controller: Controller, loop: SampledLoop, rates: Matrix,
               delta: float) -> list[Matrix] | None:
    """The continuous loop's worst-case feedback at ``rates`` (``Delta = delta I``) on the
    plant state, in the sampled loop's balanced coordinates, one per joint state; searched
    in the coordinates :math:`x = T\tilde x` of
    :func:`~ftc_verify.analysis.conditioning.conditioning_transform` (when its condition is
    above 100; the feedback :math:`\tilde F T^{-1}` mapped back in float: any feedback is
    admissible): in units of condition 1e6 the search in the loop's own coordinates found
    a feedback 7 times below the gain."""
    from ..conditioning import conditioning_transform

    cl = closed_loop(system, controller)
    deltas = ({ch.name: delta * np.eye(ch.E.shape[1], ch.F.shape[0]) for chans in cl.channels for ch in chans}
              if delta else {})
    A = cl.perturbed(deltas) if deltas else cl.A
    T, T_inv = np.eye(cl.n), np.eye(cl.n)
    try:
        sim = conditioning_transform(cl)
        if 100.0 < sim.condition < 1e12:
            T, T_inv = np.asarray(sim.T, dtype=float), np.asarray(sim.T_inv, dtype=float)
    except (np.linalg.LinAlgError, ValueError):
        pass
    found = float_gain([T_inv @ a @ T for a in A], [T_inv @ b for b in cl.Bw], [c @ T for c in cl.Cz],
                       cl.chain.generator(rates), rtol=FEEDBACK_RTOL)
    if found is None:
        return None
    sc = loop.scale_r
    out = []
    for Ft in found[1]:
        Fs = Ft @ T_inv
        Fb = np.zeros((Fs.shape[0], loop.r))
        Fb[:, :loop.n] = Fs[:, :loop.n] * sc[None, :loop.n]
        out.append(Fb)
    return out


def _moved(loop: SampledLoop, system: FTCSystem, h: float, balls: bool) -> tuple[ClosedLoop, list[Any], Matrix]:
    r"""``(aug, resets, T_r)``: the augmented loop and the resets (sampled state to
    :math:`\zeta`) in the coordinates :math:`\zeta = T\tilde\zeta` of
    :func:`~ftc_verify.analysis.moments.sampled_frame.coordinates` (its similarity only; the
    identity for a well-conditioned loop), and :math:`T_r`, its block on the sampled state
    (:math:`T` leaves the held input apart, so the restriction is unchanged): a feedback
    :math:`\tilde F` there is :math:`\tilde F T_r^{-1}` on the loop's own state -- as
    admissible as any. On balls (call inside :func:`~ftc_verify.analysis.rigorous.precision`)
    from the numbers as written with the ball of the exact :math:`T^{-1}`: the energies are
    those of the written loop. In a similarity of condition 1e3 the proof in the loop's own
    coordinates kept 0.18 of the float64 value."""
    from .sampled_frame import Coordinates, float_frame
    from .sampled_gamma import augmented_loop, sample_jumps

    shared = float_frame(loop, system, h)  # shared with the gain certificate (sampled_gamma)
    P = loop.restriction()
    if balls:
        aug = augmented_loop(loop, system, balls=True)
        jumps = sample_jumps(loop, h, balls=True, literals=system.literals)
    else:
        aug, jumps = shared.aug, list(shared.jumps)
    found = shared.coords
    if found.T is None:
        return aug, [J @ P.T for J in jumps], np.eye(loop.r)
    frame = Coordinates(1.0, 1.0, found.T, found.T_inv)
    idx = np.r_[0:loop.n, loop.n + loop.nu:loop.d]
    Tr = np.asarray(found.T)[np.ix_(idx, idx)]
    return frame.loop(aug, balls), [J @ P.T for J in frame.jumps(jumps, balls)], Tr


def _refine(fast: _FloatRatio, resets: Sequence[Any], h: float, nw: int, p: int, F: list[Matrix],
            value: float, evaluations: int = 0) -> tuple[float, list[Matrix]]:
    """The float64 ratio maximised over the entries of ``F`` on the plant state by
    Nelder-Mead from ``F`` (at most ``evaluations`` ratios, :data:`REFINE_EVALUATIONS`
    by default); ``(value, F)`` unchanged when it finds nothing better."""
    import scipy.optimize

    shape = (len(F), nw, resets[0].shape[1])
    x0 = np.stack(F).reshape(-1)

    def negative(x: Matrix) -> float:
        with np.errstate(all="ignore"):
            v = fast(resets, list(x.reshape(shape)), h, p)
        return -v if math.isfinite(v) else 0.0

    found = scipy.optimize.minimize(negative, x0, method="Nelder-Mead",
                                    options={"maxfev": evaluations or REFINE_EVALUATIONS, "xatol": 1e-6,
                                             "fatol": 1e-9})
    if -found.fun > value:
        return float(-found.fun), list(np.asarray(found.x).reshape(shape))
    return value, F


def _doublings(h: float, span: float = HORIZON) -> int:
    return max(1, min(MAX_DOUBLINGS, math.ceil(math.log2(max(span / h, 2.0)))))


def _span(system: FTCSystem, controller: Controller) -> float:
    """The time the disturbance acts over: :data:`HORIZON`, or :data:`SPAN_TIMES` time
    constants :math:`1/|\\alpha|` of the continuous loop's slowest second moment
    (:func:`~ftc_verify.analysis.moments.stability.spectral_abscissa` at the box's midpoint)
    when longer -- a slow loop's energy ratio converges only over many of them."""
    from .stability import spectral_abscissa

    alpha = spectral_abscissa(closed_loop(system, controller), system.chain.midpoint())
    return max(HORIZON, SPAN_TIMES / -alpha) if alpha < 0 else HORIZON


#: One float64 candidate of the search: ``(ratio, rates, delta, F, alpha, evaluator)``.
_Candidate = tuple[float, Matrix, float, list[Matrix], float, _FloatRatio, int]


def _search(system: FTCSystem, controller: Controller, loop: SampledLoop, h: float, deltas: Sequence[float],
            scales: Sequence[float]) -> dict[float, _Candidate]:
    """The best float64 candidate per ``Delta = delta I`` over the feedback scales and
    the rate arrays (module docstring); a ``delta`` without a worst-case feedback is absent."""
    aug, resets, Tr = _moved(loop, system, h, False)
    P = loop.restriction()
    p = _doublings(h, _span(system, controller))
    ops = _Ops(False)
    nw = system.dims[3]
    out: dict[float, _Candidate] = {}
    for delta in deltas:
        F0 = _feedbacks(system, controller, loop, system.chain.midpoint(), delta)
        if F0 is None:
            continue
        F0 = [f @ Tr for f in F0]  # on the moved sampled state
        for rates in rate_points(system.chain):
            fast = _FloatRatio(_blocks(ops, aug, P, system.chain.generator(rates), h, delta, nw), loop.r)
            for a in scales:
                F = [a * f for f in F0]
                with np.errstate(all="ignore"):
                    value = fast(resets, F, h, p)
                if math.isfinite(value) and (delta not in out or value > out[delta][0]):
                    out[delta] = (value, rates, delta, F, a, fast, p)
    return out


def _finish(system: FTCSystem, loop: SampledLoop, h: float, best: _Candidate | None,
            robust: bool) -> SampledLowerBound:
    """Refine the candidate ``best`` (:func:`_refine`) and prove it (:func:`_prove`)."""
    if best is None:
        return SampledLowerBound(None, "proved", "no float64 candidate (the continuous loop is not stable)", None)
    value, rates, delta, F, a, fast, _ = best
    resets = _moved(loop, system, h, False)[1]
    p = best[6]
    start = value
    value, F = _refine(fast, resets, h, system.dims[3], p, F, value)
    proved, level = _prove(system, loop, h, rates, delta, F, p, math.sqrt(max(value, 0.0)))
    how = "refined by Nelder-Mead from " if value > start else ""
    where = (f"held feedback {how}{a:g} x the continuous worst case over {2 ** level + 1} periods, "

             f"{system.chain.rate_text(rates)}" + (f", Delta = {delta:+g} I" if robust else ""))
    return SampledLowerBound(proved, "proved", where if proved is not None else "not proved: " + where,
                             math.sqrt(max(value, 0.0)))


def sampled_lower_bound(system: FTCSystem, controller: Controller, period: float, *, robust: bool,
                        loop: SampledLoop | None = None, scales: Sequence[float] = SCALES) -> SampledLowerBound:
    """A proved lower bound of the sampled loop's nominal (``robust``: robust) gain at
    ``period`` (module docstring): the best float64 ratio over the feedback scales, rate
    arrays, initial joint state 0 and (robust) ``Delta``, proved in ball arithmetic."""
    h = check_period(period, "period")
    loop = SampledLoop.of(system, controller, loop)
    robust = robust and system.uncertain
    found = _search(system, controller, loop, h, (0.0, 1.0, -1.0) if robust else (0.0,), scales)
    return _finish(system, loop, h, max(found.values(), key=lambda c: c[0], default=None), robust)


def sampled_lower_bounds(system: FTCSystem, controller: Controller, period: float, *,
                         loop: SampledLoop | None = None,
                         scales: Sequence[float] = SCALES) -> tuple[SampledLowerBound, SampledLowerBound | None]:
    """``(nominal, robust)``: :func:`sampled_lower_bound` for both (robust ``None``
    without uncertainty channels) from one float64 search -- the nominal candidates
    (``Delta = 0``) are among the robust ones, so they are computed once; when the
    robust search's best is ``Delta = 0`` the nominal bound is reused (the same proof)."""
    h = check_period(period, "period")
    loop = SampledLoop.of(system, controller, loop)
    robust = system.uncertain
    found = _search(system, controller, loop, h, (0.0, 1.0, -1.0) if robust else (0.0,), scales)
    nominal = _finish(system, loop, h, found.get(0.0), False)
    if not robust:
        return nominal, None
    best = max(found.values(), key=lambda c: c[0], default=None)
    if best is not None and best[2] == 0.0:
        return nominal, nominal
    return nominal, _finish(system, loop, h, best, True)


def _prove(system: FTCSystem, loop: SampledLoop, h: float, rates: Matrix, delta: float, F: list[Matrix],
           doublings: int, target: float = 0.0) -> tuple[float | None, int]:
    """``(lower, p')``: the lower end of the ball enclosure of the ratio's square root
    (``None`` when no enclosure excludes 0), the largest over the :math:`K = 2^{p'} + 1`,
    :math:`p' \\le` ``doublings`` (each a proved bound: the doublings can widen the
    enclosure past use before they end); at :data:`PROOF_BITS` first, again at
    :data:`~ftc_verify.analysis.rigorous.PRECISION_BITS` (Arb's exponential) when it
    lies more than :data:`PROOF_RTOL` below ``target`` (the float64 value)."""
    from ..rigorous import PRECISION_BITS

    best: tuple[float | None, int] = (None, doublings)
    for bits in (PROOF_BITS, PRECISION_BITS):
        found = _prove_at(system, loop, h, rates, delta, F, doublings, bits)
        if found[0] is not None and (best[0] is None or found[0] > best[0]):
            best = found
        if best[0] is not None and best[0] >= target * (1.0 - PROOF_RTOL):
            break
    return best


def _prove_at(system: FTCSystem, loop: SampledLoop, h: float, rates: Matrix, delta: float, F: list[Matrix],
              doublings: int, bits: int) -> tuple[float | None, int]:
    """:func:`_prove` at Arb's working precision ``bits``."""
    import flint

    from ..rigorous import precision
    from .sampled_balls import ball_generator
    best: tuple[float | None, int] = (None, doublings)
    with precision(bits):
        try:
            aug, resets, _ = _moved(loop, system, h, True)
        except ZeroDivisionError:  # the transform not proved invertible: nothing proved
            return best
        if delta == 0.0:
            aug = aug.nominal()
        P = loop.restriction()
        Q = ball_generator(system.chain, rates, rates, loop.literals).value
        hb = loop.period_ball(h)
        ops = _Ops(True)
        blocks = _blocks(ops, aug, P, Q, hb, delta, system.dims[3])
        terms = _terms(ops, blocks, resets, F)
        levels = [(num.value[0, 0], den.value[0, 0])
                  for num, den in _ratios(ops, blocks, resets, F, hb, doublings, terms)]
        levels += _eigen_levels(blocks, terms, hb, doublings)  # the same p' again, each a bound
        for at, (num, den) in enumerate(levels):
            level = at % (doublings + 1)
            ratio = num / den
            if not ratio > 0:
                continue
            root = ratio.sqrt()
            lower = math.nextafter(float(root.mid()) - 2.0 * float(root.rad()), -math.inf)
            if lower > 0 and bool(flint.arb(lower) < root) and (best[0] is None or lower > best[0]):
                best = (lower, level)
    return best
