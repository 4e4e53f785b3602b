r"""Proved lower bounds of the worst-case gain: the other side of every certified gamma.

The certified :math:`\gamma` of Theorem 3.2 / Lemma 4.1 bounds from above the
stochastic :math:`L_2` gain :math:`\sup_w (E\|z\|^2 / E\|w\|^2)^{1/2}` over adapted
disturbances :math:`w` (zero initial state, any initial joint state), every rate vector
of the box and every :math:`\|\Delta\| \le 1`. A lower bound needs one admissible
disturbance, one rate vector :math:`\rho` of the box and one :math:`\Delta`, and the
exact value of their ratio. Derived here:

**The disturbance.** :math:`w = F_{\theta_t} \xi + v(t)` with :math:`v(t) = e\cos\omega t`
(adapted: it uses the state and the joint state; :math:`e` real). The loop
:math:`\dot\xi = \tilde A_s \xi + B_{w,s} v`, :math:`\tilde A_s = A_s + B_{w,s} F_s`, is
linear in :math:`v`. Start at :math:`\xi_0 = 0` with the joint state distributed as a
stationary distribution :math:`\pi` of :math:`Q(\rho)` (a mixture of initial states:
its ratio is at most the largest ratio of a single initial state). With :math:`m_s =
E[\xi 1\{\theta = s\}]` and :math:`X_s = E[\xi\xi^T 1\{\theta = s\}]`, Dynkin's formula
gives

.. math::

    \dot m_s = \tilde A_s m_s + \sum_t Q_{ts} m_t + \pi_s B_{w,s} v, \qquad
    \dot X_s = \tilde{\mathcal L}(X)_s + B_{w,s} v m_s^T + m_s v^T B_{w,s}^T .

If :math:`\tilde{\mathcal L}` is mean-square stable (proved), both converge to a periodic
steady state: :math:`m_s = \mathrm{Re}(M_s e^{i\omega t})` with
:math:`(i\omega - \tilde{\mathcal A}) M = (\pi_s B_{w,s} e)_s` (:math:`\tilde{\mathcal A}`
the first-moment operator), and the period average :math:`\bar X` of :math:`X` solves
:math:`\tilde{\mathcal L}(\bar X)_s = -c\,(B_{w,s} e\, M_{r,s}^T + M_{r,s} e^T B_{w,s}^T)`
with :math:`M_r = \mathrm{Re}\,M` and :math:`c = 1/2` (:math:`c = 1` at
:math:`\omega = 0`), since the average of :math:`\cos\omega t\,\mathrm{Re}(M e^{i\omega
t})^T` is :math:`c\,M_r^T`. The energies grow linearly in the horizon at the rates

.. math::

    N = \sum_s \operatorname{tr}(C_{z,s}\bar X_s C_{z,s}^T), \qquad
    D = \sum_s \bigl(\operatorname{tr}(F_s \bar X_s F_s^T) + 2c\, e^T F_s M_{r,s}\bigr) + c\,|e|^2 ,

so the ratio over :math:`[0, T]` of the truncated disturbance (which is in :math:`L_2`)
tends to :math:`N/D`: the gain is at least :math:`\sqrt{N/D}`. With :math:`\Delta`
constant per joint state (an admissible time-varying uncertainty) the same holds for the
perturbed loop, a lower bound of the robust gain.

**The choice.** :math:`F_s = \gamma_F^{-2} B_{w,s}^T P_s` from the coupled bounded-real
Riccati equations at :math:`\rho`,
:math:`\tilde A_s^T P_s + P_s \tilde A_s + \sum_t q_{st} P_t + C_{z,s}^T C_{z,s} - \gamma_F^2
F_s^T F_s = 0`, solved by policy iteration (each step a coupled Lyapunov equation, the
maximising player's Newton step) at the smallest :math:`\gamma_F` found feasible by
bisection: the worst-case feedback, which makes the loop nearly marginal, so that a
small :math:`v` near resonance gives a ratio close to :math:`\gamma_F^2`. The frequency
is the best of :math:`\omega = 0` and the imaginary parts of the rightmost eigenvalues of
:math:`\tilde{\mathcal A}`; :math:`e` is the top generalised eigenvector of the two
quadratic forms :math:`N(e)`, :math:`D(e)` (:mod:`~ftc_verify.analysis.excitation`).
The rate vector is the best of the box's centre, its lowest and highest rates and the
worst spectral-abscissa vertex (:mod:`~ftc_verify.analysis.rate_candidates`). The constant
:math:`\Delta` of the robust bound, and its :math:`\gamma_F`, come from
:mod:`~ftc_verify.analysis.worst_delta`. This search runs in the coordinates :math:`x = T\tilde x`
of :func:`~ftc_verify.analysis.conditioning.conditioning_transform` (its feedback :math:`\tilde F`
used as :math:`F = \tilde F T^{-1}`): the ratio is invariant under a similarity, the float search is not.

**The proof.** :math:`F`, :math:`e`, :math:`\omega`, :math:`\rho` are floats taken as
exact; the loop is :func:`~ftc_verify.analysis.exact.exact_loop` (the numbers the user
wrote) plus :math:`B_{w,s}F_s` in ball arithmetic; :math:`\tilde{\mathcal L}` is proved
stable (:class:`~ftc_verify.analysis.verdict.StabilityProver`). The moments are then
enclosed in the coordinates :math:`\tilde x = S x` (``_conditioned``: :math:`S` the float
``T_inv`` of the search's transform composed with the feedback loop's, taken exact, and a
ball enclosing its exact inverse, so the balls enclose an exact similarity of the loop
as written and :math:`N`, :math:`D` are unchanged): :math:`\pi` and :math:`M` by FLINT's
certified linear solves, :math:`\bar X` by a float64 solve and its residual proved in
balls (``_residual_moments``; FLINT's solve of the whole moment system when that proof
fails); the bound is the lower end of the enclosure of :math:`\sqrt{N/D}`. Above
:data:`~ftc_verify.analysis.verdict.SOLVE_LIMIT` rows no bound is computed (none could be
proved); a bound not computed or not proved says why in its ``method``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ..jsonable import fields_dict
from ..model.system import Matrix
from .closedloop import ClosedLoop
from .bounded_real import POLICY_RTOL, SEARCH_RTOL, RateEnvelope, bounded_real_solution, least_eigenvalue
from .conditioning import Similarity, conditioning_transform
from .excitation import best_excitation
from .rate_candidates import ASCENT_MARGIN, candidate_rates, stationary_at, vertex_ascent
from .exact import ball_generator, ball_matrices, exact_loop, literals_of, written_box
from ..interrupts import deferred_signals
from .rigorous import Ball, ball, midpoint, precision, proven_positive_definite, tight_solve
from .moments.stability import generator_size, lyapunov_stack_solution
from .verdict import SOLVE_LIMIT, StabilityProver, ball_lyapunov_solution

__all__ = ["GainLowerBound", "gain_lower_bound", "float_gain", "worst_case_feedback", "exceeds", "FALL_TOL",
           "BISECTION_RTOL", "within_solve_limit"]

#: Relative width of the float bisection on the gain.
BISECTION_RTOL = 1e-5


@dataclass(frozen=True)
class GainLowerBound:
    """A lower bound of the worst-case gain and what attains it (module docstring).

    ``value`` is the proved lower bound (``None`` when the proof could not be made:
    ``method`` says why; ``estimate`` is then the float value of the same construction);
    ``float_gain`` the float worst-case gain at ``rates`` by bisection (not proved; the
    level of the feedback used, ``ABOVE_CERTIFIED`` times the certified gamma, when that
    bisection failed);
    ``delta`` names the constant uncertainty; ``frequency`` and ``direction`` give
    :math:`v(t) = e\\cos\\omega t`; ``feedback`` the gains :math:`F_s`, one per joint state."""

    value: float | None
    estimate: float
    float_gain: float
    rates: Matrix
    delta: str
    frequency: float
    direction: Matrix
    feedback: tuple[Matrix, ...]
    method: str
    seconds: float

    @property
    def proved(self) -> bool:
        """The bound was proved in ball arithmetic."""
        return self.value is not None

    def to_dict(self) -> dict[str, object]:
        """JSON-ready summary (the feedback gains omitted)."""
        d = fields_dict(self)
        d.pop("feedback", None)
        d["proved"] = self.proved
        return d


def _ms_stable(A: Sequence[Matrix], Q: Matrix) -> bool:
    r"""Float64: :math:`\mathcal L(X) = -I` has a solution positive definite in every joint state, i.e. a
    negative abscissa (the operator is resolvent positive, :mod:`~ftc_verify.analysis.verdict`): one solve."""
    X = lyapunov_stack_solution(A, Q)
    return X is not None and least_eigenvalue(X) > 0


def _dense_adjoint(A: Sequence[Matrix], Q: Matrix, R: Sequence[Matrix],
                   start: Sequence[Matrix] | None = None) -> list[Matrix] | None:
    r""":math:`A_s^T P_s + P_s A_s + \sum_t q_{st} P_t = -R_s`, dense (``start`` unused; near marginal loops GMRES
    is slow): :func:`~ftc_verify.analysis.moments.stability.lyapunov_stack_solution` in adjoint form."""
    P = lyapunov_stack_solution([a.T for a in A], np.asarray(Q).T, R)
    return None if P is None else list(P)


#: A step of the lower bounds' policy iteration that lowers ``P`` by more than this (relative
#: to ``max |P|``, in the least eigenvalue of the step) ends the iteration (``_rising_adjoint``).
FALL_TOL = 1e-6


def _rising_adjoint(A: Sequence[Matrix], Q: Matrix, R: Sequence[Matrix],
                    start: Sequence[Matrix] | None = None) -> list[Matrix] | None:
    r""":func:`_dense_adjoint` for the lower bounds' policy iterations, ``None`` when the new
    iterate falls below the last one (``start``, which
    :func:`~ftc_verify.analysis.bounded_real.bounded_real_solution` passes) by more than
    :data:`FALL_TOL`. With :math:`F_{k+1} = \gamma^{-2}B^T P_k`, subtracting step
    :math:`k`'s equation, rewritten with :math:`A + BF_{k+1}`, from step :math:`k+1`'s gives
    :math:`\tilde{\mathcal L}_{k+1}^*(P_{k+1} - P_k) = -\gamma^2 (F_{k+1} - F_k)^T(F_{k+1} - F_k)
    \preceq 0`: while :math:`A + BF_{k+1}` is mean-square stable the iterates rise. The
    Riccati operator :math:`\mathcal R` is convex, so with a stabilising solution
    :math:`P^*`, :math:`\tilde{\mathcal L}_{k+1}^*(P^* - P_{k+1}) = \mathcal R(P_k) +
    \mathcal R'(P_k)(P^* - P_k) - \mathcal R(P^*) \preceq 0`: the iterates stay below
    :math:`P^*` and, from a stabilising start, stabilising (the maximising player's Newton
    iteration, monotone from below), so a clear fall means no solution at this level: it
    is decided in a step or two instead of the :data:`~ftc_verify.analysis.bounded_real.STALL_STEPS`
    a stall takes (a level found feasible ends the same way). Float only: a level is decided,
    not proved (the candidate rate vectors of :func:`gain_lower_bound`, at a certified gamma,
    got the same feedback with and without it on seven random n = 8, m = 3 loops)."""
    P = _dense_adjoint(A, Q, R)
    if P is None or start is None:
        return P
    scale = max(np.finfo(float).tiny, float(np.abs(np.asarray(P)).max()))
    if least_eigenvalue(np.asarray(P) - np.asarray(start)) < -FALL_TOL * scale:
        return None
    return P


def worst_case_feedback(A: Sequence[Matrix], Bw: Sequence[Matrix], Cz: Sequence[Matrix], Q: Matrix,
                        gamma: float, start: Sequence[Matrix] | None = None,
                        rtol: float = POLICY_RTOL) -> tuple[Matrix, ...] | None:
    r"""The worst-case disturbance feedback :math:`F_s = \gamma^{-2} B_{w,s}^T P_s` of the
    coupled bounded-real Riccati equations at ``gamma`` (module docstring): the policy
    iteration of :func:`~ftc_verify.analysis.bounded_real.bounded_real_solution` at the one
    rate vector of ``Q`` (:meth:`~ftc_verify.analysis.bounded_real.RateEnvelope.at`), each
    step a dense solve, from ``start`` (a feedback that makes the loop mean-square stable;
    default :math:`F = 0`) until ``P`` changes by at most ``rtol`` relatively; ``None``
    when it fails (``P`` not positive semidefinite, not finite, no convergence, or an
    iterate that falls, ``_rising_adjoint``): then
    ``gamma`` is, in float64, at or below the gain. A float search only: what it returns
    is proved afterwards or not used."""
    found = bounded_real_solution(A, Bw, Cz, RateEnvelope.at(Q), gamma, start=start, rtol=rtol,
                                  solve=_rising_adjoint)
    return None if found is None else tuple(found[1])


def float_gain(A: Sequence[Matrix], Bw: Sequence[Matrix], Cz: Sequence[Matrix], Q: Matrix, *,
               upper: float | None = None, rtol: float = BISECTION_RTOL, above: float | None = None,
               start: Sequence[Matrix] | None = None, climb: float = 0.1,
               converge: bool = True) -> tuple[float, tuple[Matrix, ...]] | None:
    """The float worst-case gain at one rate vector by bisection on :func:`worst_case_feedback`
    (started at ``upper``, each step warm-started from the last feasible feedback and run
    to :data:`~ftc_verify.analysis.bounded_real.SEARCH_RTOL`: a level is decided long before
    the policy iteration converges), and the feedback at the smallest feasible gamma
    found, converged to :data:`~ftc_verify.analysis.bounded_real.POLICY_RTOL` (``None``
    when the loop is not mean-square stable). ``above``: a level already found infeasible
    (:func:`exceeds`): the search goes on from it as if it had just failed there (the
    same steps, the failed test not repeated), its first step up by ``climb`` (relative; later ones
    by 10 % as from ``upper``). ``start``: a feedback of a nearby loop
    tried first at the levels above the bracket (``_feasible``: a failure is decided
    from ``F = 0``, so the levels decided are the same). ``converge=False``: the feedback
    returned is the bisection's (converged to ``SEARCH_RTOL`` only), for a search that
    uses the gain alone."""
    if not _ms_stable(A, Q):
        return None
    lo, hi = 0.0, upper if upper is not None and upper > 0 else 1.0
    if above is not None:  # found infeasible there already: the next level up
        lo, hi = above, above * (1.0 + climb if above < 2.0 * (upper or 1.0) else 2.0)
    F = _feasible(A, Bw, Cz, Q, hi, start)
    while F is None:  # below the gain: up by 10 % near the start, then doubling
        lo, hi = hi, hi * (1.1 if hi < 2.0 * (upper or 1.0) else 2.0)
        if hi > 1e300:
            return None
        F = _feasible(A, Bw, Cz, Q, hi, start)
    step = 1e-3
    while lo == 0.0 and hi > 1e-300:
        trial = hi * (1.0 - step)
        found = worst_case_feedback(A, Bw, Cz, Q, trial, F, rtol=SEARCH_RTOL)
        if found is None:
            lo = trial
        else:
            hi, F, step = trial, found, min(0.5, 8 * step)
    while hi - lo > rtol * hi:
        mid = math.sqrt(lo * hi) if lo > 0 else 0.5 * hi
        found = worst_case_feedback(A, Bw, Cz, Q, mid, F, rtol=SEARCH_RTOL)
        if found is None:
            lo = mid
        else:
            hi, F = mid, found
    if not converge:
        return hi, F
    final = worst_case_feedback(A, Bw, Cz, Q, hi, F)  # the feedback at the level found, converged
    return hi, F if final is None else final


def _feasible(A: Sequence[Matrix], Bw: Sequence[Matrix], Cz: Sequence[Matrix], Q: Matrix, gamma: float,
              start: Sequence[Matrix] | None) -> tuple[Matrix, ...] | None:
    """:func:`worst_case_feedback` at ``gamma`` to ``SEARCH_RTOL``, from ``start`` (a
    feedback of a nearby loop, which need not make this loop mean-square stable) and,
    when that fails, from ``F = 0``. A positive semidefinite solution of the coupled
    Riccati equations found from any start bounds the gain by ``gamma`` (the stochastic
    bounded-real lemma, the loop being mean-square stable), so the start moves only the
    cost, not which levels are found feasible (up to float64 near the gain itself)."""
    if start is not None:
        found = worst_case_feedback(A, Bw, Cz, Q, gamma, start, rtol=SEARCH_RTOL)
        if found is not None:
            return found
    return worst_case_feedback(A, Bw, Cz, Q, gamma, rtol=SEARCH_RTOL)


def _proved_ratio(loop: ClosedLoop, deltas: dict[str, Matrix], sim: Similarity, F: Sequence[Matrix], rates: Matrix,
                  omega: float, e: Matrix, bits: int = 128) -> tuple[float | None, str]:
    """The lower end of the enclosure of ``sqrt(N/D)`` (module docstring, the proof)."""
    import flint

    n, S = loop.n, len(loop.A)
    if not within_solve_limit(loop):
        return None, _too_large(loop)
    literals = literals_of(loop)
    made: dict[int, ClosedLoop] = {}

    def exact_here() -> ClosedLoop:  # exact_loop at the working precision, made once
        bits_now = int(flint.ctx.prec)
        if bits_now not in made:
            made[bits_now] = exact_loop(loop)
        return made[bits_now]

    def enclosures() -> tuple[Ball, ...]:
        """The feedback loop's state matrices at the working precision."""
        exact = exact_here()
        A = ball_matrices(exact.A)
        if deltas:
            A = tuple(a + _perturbation(chans, deltas, a) for a, chans in zip(A, exact.channels))
        return tuple(a + b @ ball(f) for a, b, f in zip(A, ball_matrices(exact.Bw), F))

    with precision(bits):
        exact, original = exact_here(), enclosures()
        At, Bw, Cz, Fb = _conditioned(sim, original, ball_matrices(exact.Bw), ball_matrices(exact.Cz), F)
        q = ball_generator(loop.chain, rates, literals)
    float_loop = replace(loop.nominal(), A=tuple(midpoint(a) for a in original), source=None)
    prover = StabilityProver.for_matrices(float_loop, sim, enclosures)
    verdict = prover.certify(rates)
    if verdict.verdict != "stable":
        return None, f"not proved: the worst-case feedback loop was not proved stable ({verdict.method})"
    with precision(bits):
        # pi' Q = 0 and sum(pi) = 1: S - 1 balance equations and the normalisation (the
        # balance equations of a generator sum to zero, so the one left out holds too)
        sq = flint.arb_mat(S, S)
        rhs = flint.arb_mat(S, 1)
        for s in range(S - 1):
            for t in range(S):
                sq[s, t] = q[t][s]
        for t in range(S):
            sq[S - 1, t] = 1
        rhs[S - 1, 0] = 1
        try:
            with deferred_signals():
                pi = sq.solve(rhs)
        except (ZeroDivisionError, ValueError):
            return None, "not proved: the stationary distribution could not be enclosed"
        eb = ball(np.asarray(e, dtype=float).reshape(-1, 1))
        m = _first_moments(At, Bw, q, pi, eb, omega)
        if m is None:
            return None, "not proved: the first moments could not be enclosed"
        weight = flint.arb(1) if omega == 0.0 else flint.arb(0.5)
        Mr = [Ball(flint.arb_mat([[m[s * n + r, 0]] for r in range(n)])) for s in range(S)]
        G = [(Bw[s] @ eb @ Mr[s].T + Mr[s] @ eb.T @ Bw[s].T) * weight for s in range(S)]
        X, how = _residual_moments(At, q, G, loop.chain.generator(rates)), "a float64 solve and its proved residual"
        if X is None:  # the enclosure by FLINT's certified solve of the whole moment system
            X, how = ball_lyapunov_solution(At, q, bits, G), f"{bits}-bit balls"
        if X is None:
            return None, "not proved: the averaged second moments could not be enclosed"
        N = flint.arb(0)
        D = weight * (eb.T @ eb).value[0, 0]
        for s in range(S):
            N += sum((Cz[s] @ X[s] @ Cz[s].T).value[k, k] for k in range(Cz[s].shape[0]))
            D += sum((Fb[s] @ X[s] @ Fb[s].T).value[k, k] for k in range(Fb[s].shape[0]))
            D += 2 * weight * (eb.T @ Fb[s] @ Mr[s]).value[0, 0]
        if not (D > 0 and N >= 0):
            return None, "not proved: the energy rates could not be enclosed"
        ratio = (N / D).sqrt()
        return float(ratio.lower()), (f"w = F x + e cos({omega:.6g} t): its stationary energy ratio enclosed "
                                      f"({how}), the feedback loop proved mean-square stable")


def _too_large(loop: ClosedLoop) -> str:
    """Why no bound is computed above :data:`~ftc_verify.analysis.verdict.SOLVE_LIMIT` rows."""
    return f"not computed: the moment equations ({generator_size(loop)} rows) exceed the ball-arithmetic limit ({SOLVE_LIMIT})"


def _conditioned(sim: Similarity, At: Sequence[Ball], Bw: Sequence[Ball], Cz: Sequence[Ball],
                 F: Sequence[Matrix]) -> tuple[list[Ball], list[Ball], list[Ball], list[Ball]]:
    r"""The feedback loop's balls in the coordinates :math:`\tilde x = S x`, :math:`S` the float
    ``sim.T_inv`` taken exact and :math:`T` a ball enclosing its exact inverse (FLINT):
    :math:`S A_s T`, :math:`S B_{w,s}`, :math:`C_{z,s} T`, :math:`F_s T`. They enclose an exact
    similarity of the loop as written, so the moments and energy rates computed from them are
    the loop's (:math:`\tilde X = S X S^T`, :math:`N` and :math:`D` unchanged); the
    residual proof and the solves then run well-conditioned. The original coordinates when
    :math:`S` is not proved invertible. Call inside a precision block."""
    Sb = ball(sim.T_inv)
    try:
        Tb = Ball(Sb.value.inv())
    except (ZeroDivisionError, ValueError):
        Sb = Tb = ball(np.eye(At[0].shape[0]))
    return ([Sb @ a @ Tb for a in At], [Sb @ b for b in Bw], [c @ Tb for c in Cz],
            [ball(np.asarray(f, dtype=float)) @ Tb for f in F])


def _residual_moments(At: Sequence[Ball], q: list[list[Any]], G: Sequence[Ball], Q: Matrix) -> list[Ball] | None:
    r"""An enclosure of :math:`\bar X` with :math:`\tilde{\mathcal L}(\bar X) = -G` (``At``, ``q``)
    without a ball solve of the whole system; ``None`` when this proof fails. With float
    :math:`\tilde X` (the float equation) and :math:`\hat Y` (:math:`\tilde{\mathcal L}(\hat Y) = -2I`),
    proved: :math:`\hat Y_s \succ 0`, :math:`-\tilde{\mathcal L}(\hat Y)_s - I \succ 0` (so
    :math:`\tilde{\mathcal L}` is stable and :math:`-\tilde{\mathcal L}^{-1}` maps positive
    semidefinite stacks to positive semidefinite ones, :mod:`~ftc_verify.analysis.verdict`),
    and :math:`\|R\|_F \le r` for :math:`R = \tilde{\mathcal L}(\tilde X) + G`. Then
    :math:`E = \bar X - \tilde X = -\tilde{\mathcal L}^{-1}(R)` has :math:`-rY \preceq E \preceq rY`,
    :math:`Y = -\tilde{\mathcal L}^{-1}(I) \preceq \hat Y`, and :math:`-M \preceq E \preceq M` gives
    :math:`|E_{ij}| \le (M_{ii} M_{jj})^{1/2}` (:doc:`/theory/certificates`). A few ``n x n``
    ball products per joint state. Call inside a precision block."""
    import flint

    n, S = At[0].shape[0], len(At)
    A = [midpoint(a) for a in At]
    Xt = lyapunov_stack_solution(A, Q, [0.5 * (midpoint(g) + midpoint(g).T) for g in G])
    Yh = lyapunov_stack_solution(A, Q, [2.0 * np.eye(n)] * S)
    if Xt is None or Yh is None:
        return None

    def operator(X: Sequence[Ball]) -> list[Ball]:
        return [a @ X[s] + X[s] @ a.T + sum((Ball(q[t][s] * X[t].value) for t in range(S) if q[t][s] != 0),
                                            0 * X[s]) for s, a in enumerate(At)]

    Xb, Yb = [ball(0.5 * (x + x.T)) for x in Xt], [ball(0.5 * (y + y.T)) for y in Yh]
    if not (all(proven_positive_definite(-y - np.eye(n)) for y in operator(Yb))
            and all(proven_positive_definite(y) for y in Yb)):  # stable, by itself (verdict module)
        return None
    r = sum((e * e for res, g in zip(operator(Xb), G) for e in (res + g).value.entries()), flint.arb(0)).sqrt()
    out = []
    for x, y in zip(Xb, Yh):
        X = flint.arb_mat(x.value)
        for i in range(n):
            for j in range(n):
                rad = r * (flint.arb(float(y[i, i])) * flint.arb(float(y[j, j]))).sqrt()
                X[i, j] += (-rad).union(rad)
        if not all(v.is_finite() for v in X.entries()):
            return None
        out.append(Ball(X))
    return out


def _first_moments(At: Sequence[Ball], Bw: Sequence[Ball], q: list[list[Any]], pi: Any, eb: Ball,
                   omega: float) -> Any:
    """The enclosure of ``[Mr; Mi]`` (module docstring), ``(i omega I - Ac) M = b`` with
    ``(Ac m)_s = At_s m_s + sum_t q_ts m_t``, ``b_s = pi_s B_s e``: FLINT's solve of
    ``(i omega I - Ac)`` in complex balls (:func:`~ftc_verify.analysis.rigorous.tight_solve`;
    ``S n`` rows, where the real form ``[[-Ac, -omega I], [omega I, -Ac]] [Mr; Mi] = [b; 0]``
    has twice as many: its interval LU grew to radii 1e-11 relative near resonance and
    fell back to the preconditioned solve, 15x the complex LU's time at n = 8, m = 3); at
    ``omega = 0``, ``Mi = 0`` and ``-Ac Mr = b`` is solved in real balls. Returned as the
    real column ``[Mr; Mi]`` (``[Mr]`` at ``omega = 0``); ``None`` when FLINT cannot prove
    the system nonsingular. Call inside a precision block."""
    import flint

    S, n = len(At), At[0].shape[0]
    K = S * n
    complex_form = omega != 0.0
    G1 = flint.acb_mat(K, K) if complex_form else flint.arb_mat(K, K)
    for s in range(S):
        a = At[s].value
        for r in range(n):
            for c in range(n):
                G1[s * n + r, s * n + c] = -a[r, c]
            if complex_form:
                G1[s * n + r, s * n + r] += flint.acb(0, omega)  # type: ignore[assignment]
        for t in range(S):
            if q[t][s] != 0:
                for r in range(n):
                    G1[s * n + r, t * n + r] -= q[t][s]
    b1 = flint.acb_mat(K, 1) if complex_form else flint.arb_mat(K, 1)
    for s in range(S):
        Be = (Bw[s] @ eb).value
        for r in range(n):
            b1[s * n + r, 0] = pi[s, 0] * Be[r, 0]
    x = tight_solve(G1, b1)
    if x is None or not complex_form:
        return x
    out = flint.arb_mat(2 * K, 1)
    for k in range(K):
        out[k, 0], out[K + k, 0] = x[k, 0].real, x[k, 0].imag
    return out


def _perturbation(chans: Sequence[Any], deltas: dict[str, Matrix], like: Ball) -> Ball:
    """``sum_k E_k Delta_k F_k`` over the channels named in ``deltas`` (balls)."""
    out = 0 * like
    for ch in chans:
        if ch.name in deltas:
            out = out + ch.E @ ball(deltas[ch.name]) @ ch.F
    return out


def exceeds(A: Sequence[Matrix], Bw: Sequence[Matrix], Cz: Sequence[Matrix], Q: Matrix, gamma: float,
            start: Sequence[Matrix] | None = None) -> bool:
    """In float64: no stabilising Riccati solution at ``gamma`` (the gain is at least
    ``gamma``, or the loop is not mean-square stable), tried from ``start`` and from
    ``F = 0`` (``_feasible``): a cheap comparison."""
    return _feasible(A, Bw, Cz, Q, gamma, start) is None


#: The feedback is first taken at the certified gamma times this (nearly the worst case).
ABOVE_CERTIFIED = 1.0 + 1e-6
#: The bisection on the gain that refines the best candidate's feedback (a policy iteration
#: per step): to relative width ``REFINE_RTOL``; always up to ``REFINE_ROWS`` moment rows,
#: above only when the bound before it is more than ``REFINE_BELOW`` (issue 30's 0.2 %) below
#: the feedback's level (135-315-row loops proved 0.59-0.90 of their gain without it, lead11).
REFINE_RTOL, REFINE_ROWS, REFINE_BELOW = 1e-8, 120, 1.002


def within_solve_limit(loop: ClosedLoop) -> bool:
    """The second moments (``S n (n + 1) / 2`` rows) and the first (``2 S n``) within
    :data:`~ftc_verify.analysis.verdict.SOLVE_LIMIT`: :func:`gain_lower_bound` computes a bound."""
    return generator_size(loop) <= SOLVE_LIMIT and 2 * len(loop.A) * loop.n <= SOLVE_LIMIT


def _unbounded(loop: ClosedLoop, label: str, why: str, start: float) -> GainLowerBound:
    """A bound not computed, and ``why`` (``value`` ``None``, the float values ``nan``)."""
    centre = 0.5 * np.add(*written_box(loop.chain.rate_min, loop.chain.rate_max))
    return GainLowerBound(None, math.nan, math.nan, centre, label, math.nan, np.zeros((loop.Bw[0].shape[1], 1)),
                          (), why, time.perf_counter() - start)


def gain_lower_bound(loop: ClosedLoop, *, deltas: Sequence[tuple[str, dict[str, Matrix]]] = (("Delta=0", {}),),
                     worst_rates: Matrix | None = None, upper: float | None = None) -> GainLowerBound:
    """The proved lower bound of the worst-case gain of ``loop`` (module docstring).

    Each candidate rate vector and constant uncertainty of ``deltas`` (a label and
    ``{channel name: Delta}``; ``Delta=0`` for the nominal gain) gets the worst-case
    feedback at ``upper * ABOVE_CERTIFIED`` (``upper`` a certified gamma, an upper bound of
    every candidate's gain) and its best excitation; the candidate of the largest float
    ratio is kept, its feedback refined by bisection on the gain (``REFINE_RTOL``, where
    ``REFINE_ROWS`` and ``REFINE_BELOW`` say), and its ratio proved. Without ``upper``, each candidate's
    gain is found by bisection (the search in conditioned coordinates). ``value`` is ``None``
    and ``method`` says why when no candidate loop is mean-square stable, or above
    :data:`~ftc_verify.analysis.verdict.SOLVE_LIMIT` rows (nothing is computed)."""
    start = time.perf_counter()
    label0 = deltas[0][0] if deltas else "Delta=0"
    if not within_solve_limit(loop):
        return _unbounded(loop, label0, _too_large(loop), start)
    search = conditioning_transform(loop)
    work = search.apply(loop)  # the float search, in well-conditioned coordinates
    nominal = work.nominal()
    gamma_f = None if upper is None else upper * ABOVE_CERTIFIED
    best: tuple[float, str, dict[str, Matrix], Matrix, tuple[Matrix, ...], float, Matrix, float, Matrix] | None = None
    top = -math.inf  # the score of best: its ratio (the ascended vertex: at least its float gain squared)
    for label, delta in deltas:
        A = work.perturbed(delta) if delta else nominal.A
        ascended = vertex_ascent(work, A, worst_rates, gamma_f)  # small loops only: (vertex, float gain)
        for rates in candidate_rates(loop, worst_rates, ascended):
            Q = loop.chain.generator(rates)
            pi = stationary_at(Q)
            if pi is None:
                continue
            if gamma_f is None:
                found = float_gain(A, work.Bw, work.Cz, Q)
                if found is None:
                    continue
                g, F = found
            else:
                F_or_none = worst_case_feedback(A, work.Bw, work.Cz, Q, gamma_f)
                if F_or_none is None:
                    continue
                g, F = gamma_f, F_or_none
            At = [a + b @ f for a, b, f in zip(A, work.Bw, F)]
            ratio, omega, e = best_excitation(At, work.Bw, work.Cz, F, Q, pi)
            score = ratio
            if ascended is not None and np.array_equal(rates, ascended[0]):  # ranked by its gain too
                score = max(ratio, (ascended[1] / (1.0 + ASCENT_MARGIN)) ** 2)
            if best is None or score > top:
                best, top = (ratio, label, delta, rates, F, g, pi, omega, e), score
    if best is None:
        return _unbounded(loop, label0, "not computed: no candidate rate vector gave a mean-square stable loop "
                          "with a worst-case feedback" + ("" if gamma_f is None else f" at gamma {gamma_f:.6g}"), start)
    ratio, label, delta, rates, F, g, pi, omega, e = best
    A = work.perturbed(delta) if delta else nominal.A
    Q = loop.chain.generator(rates)
    if gamma_f is not None and (generator_size(loop) <= REFINE_ROWS or math.sqrt(max(ratio, 0.0)) * REFINE_BELOW < gamma_f):
        found = float_gain(A, work.Bw, work.Cz, Q, upper=gamma_f, rtol=REFINE_RTOL)
        if found is not None:
            g, F = found
            At = [a + b @ f for a, b, f in zip(A, work.Bw, F)]
            ratio, omega, e = best_excitation(At, work.Bw, work.Cz, F, Q, pi)
    At = [a + b @ f for a, b, f in zip(A, work.Bw, F)]
    estimate = math.sqrt(max(ratio, 0.0))
    inner = conditioning_transform(replace(nominal, A=tuple(At), source=None))  # of the feedback loop, composed
    sim = Similarity(search.T @ inner.T, inner.T_inv @ search.T_inv, search.steps + inner.steps)
    F = tuple(f @ search.T_inv for f in F)  # w = F~ x~ = F~ T^-1 x: the feedback in the user's coordinates
    value, method = _proved_ratio(loop, delta, sim, F, rates, omega, e)
    return GainLowerBound(value, estimate, g, rates, label, omega, e, F, method, time.perf_counter() - start)
