r"""An independent reference for the stochastic :math:`H_\infty` norm of a nominal MJLS.

For a Markov jump linear system with a *fixed* generator :math:`Q` (``Q[s, t]`` the rate
:math:`s \to t`, rows summing to zero) and, per mode :math:`s`,

.. math::

    \dot x = A_s x + B_s w, \qquad z = C_s x, \qquad x(0) = 0,

the norm is :math:`\sup_{w \ne 0} \|z\|_2 / \|w\|_2` over every initial mode. No SDP solver
is involved here: the value comes from the coupled Riccati equations of the bounded real
lemma, solved by Newton's method on coupled Lyapunov equations, and a bisection on
:math:`\gamma`. Derivation (written out for this module):

**(1) Bounded real lemma** (continuous-time MJLS; de Souza & Fragoso 1993, Costa,
Fragoso & Todorov 2013, ch. 7). For a mean-square stable loop, :math:`\gamma` exceeds the
norm iff the coupled equations

.. math::

    F_s(P) := A_s^T P_s + P_s A_s + \sum_t Q_{st} P_t + \gamma^{-2} P_s B_s B_s^T P_s
              + C_s^T C_s = 0 \tag{1}

have a solution :math:`P_s \succeq 0` that is *stabilising*: the coupled operator
:math:`\mathcal L_P` of (2) with :math:`M_s = A_s + \gamma^{-2} B_s B_s^T P_s` is Hurwitz.
The Schur complement of the inequality :math:`F_s(P) \prec 0` is the LMI of Theorem 3.2
(:mod:`ftc_verify.analysis.lmi`), so both compute the same number by unrelated means.

**(2) Coupled Lyapunov operator and mean-square stability.** For matrices :math:`M_s`,

.. math::

    \mathcal L_M(X)_s = M_s^T X_s + X_s M_s + \sum_t Q_{st} X_t . \tag{2}

It is the adjoint, for :math:`\langle X, Y\rangle = \sum_s \operatorname{tr}(X_s Y_s)`, of
the second-moment generator :math:`X_s \mapsto M_s X_s + X_s M_s^T + \sum_t Q_{ts} X_t`
(:mod:`ftc_verify.analysis.moments.stability`), so it has the same spectrum; the loop with state
matrices :math:`M_s` is mean-square stable iff its abscissa is negative
(:func:`mjls_abscissa`). It is resolvent positive (a Lyapunov operator plus
non-negative off-diagonal coupling), so when it is Hurwitz, :math:`-\mathcal L_M^{-1}`
maps positive semidefinite tuples to positive semidefinite tuples. It is formed here in
``vech`` coordinates, :math:`\operatorname{blockdiag}_s L_n (I \otimes M_s^T + M_s^T \otimes I)
D_n + Q \otimes I_{n(n+1)/2}` (column-major ``vec``; :math:`D_n, L_n` duplication and
elimination).

**(3) Newton's method.** :math:`F` is convex (:math:`\gamma^{-2} P B B^T P` is matrix
convex) with derivative :math:`F'(P)[H] = \mathcal L_{M(P)}(H)`, and
:math:`F(P) = \mathcal L_{M(P)}(P) - \gamma^{-2} P B B^T P + C^T C`, so the Newton step
:math:`F(P_k) + F'(P_k)[P_{k+1} - P_k] = 0` is the coupled Lyapunov equation

.. math::

    \mathcal L_{M(P_k)}(P_{k+1})_s = \gamma^{-2} P_{k,s} B_s B_s^T P_{k,s} - C_s^T C_s ,
    \qquad P_0 = 0 . \tag{3}

Convexity gives :math:`F(P_{k+1}) \ge F(P_k) + F'(P_k)[P_{k+1} - P_k] = 0`, hence, with
:math:`\mathcal L_{M(P_k)}` Hurwitz, :math:`P_{k+1} - P_k = -\mathcal L^{-1}_{M(P_k)}(F(P_k))
\succeq 0` for :math:`k \ge 1` (and for :math:`k = 0` since :math:`F(0) = C^T C \succeq 0`);
and for any :math:`\hat P` with :math:`F(\hat P) \preceq 0`,
:math:`\mathcal L_{M(P_k)}(\hat P - P_{k+1}) \preceq F(\hat P) \preceq 0`, so
:math:`P_{k+1} \preceq \hat P`. With :math:`X = -P`, :math:`R(X) = -F(-X)` is concave with
resolvent-positive derivative, and Damm & Hinrichsen (2001, Newton's method for concave
operators with resolvent positive derivatives) prove the rest: if the open loop is
mean-square stable (:math:`\mathcal L_{M(0)} = \mathcal L_A` Hurwitz) and some
:math:`\hat P` exists, every :math:`\mathcal L_{M(P_k)}` is Hurwitz and :math:`P_k`
increases to the minimal solution of (1), which is stabilising when :math:`F(\hat P) \prec 0`
is possible, i.e. for every :math:`\gamma` above the norm.

**(4) The test of one** :math:`\gamma` (:func:`coupled_riccati`). Iterate (3) from 0 and
declare :math:`\gamma` *infeasible* when an iterate decreases or leaves the semidefinite
cone (beyond rounding), the coupled Lyapunov equation is singular, the iterates grow by
:math:`10^{12}` or do not converge in :data:`MAX_NEWTON` steps -- by (3) none of this
happens above the norm. :math:`\gamma` is *feasible* only when the limit passes an a
posteriori check: :math:`P_s \succeq 0`, residual of (1) at rounding level, and
:math:`\mathcal L_{M(P)}` Hurwitz (a stabilising solution: :math:`\gamma` > norm by (1)).
So a feasible answer is checked; an infeasible one rests on the convergence theorem.

**(5) The norm** (:func:`mjls_hinf_bounds`). Infinite when the open loop is not mean-square
stable, 0 when every :math:`B_s` or every :math:`C_s` is zero. Otherwise, starting at
:math:`\gamma_0 = \max_s \|C_s (-(A_s + \tfrac12 Q_{ss} I))^{-1} B_s\|_2` (or 1), halve
until infeasible or double until feasible (no per-mode quantity bounds the MJLS norm in
general), then bisect geometrically until ``upper / lower - 1 <= rtol``.

Tried and not used: a Gauss-Seidel sweep over modes, each step the single-mode
:math:`H_\infty` Riccati equation of :math:`A_s + \tfrac12 Q_{ss} I` with constant term
:math:`C_s^T C_s + \sum_{t \ne s} Q_{st} P_t` (``scipy.linalg.solve_continuous_are`` with
:math:`R = -\gamma^2 I`). It converges linearly with a rate that tends to 1 at the norm:
at :math:`\gamma` = norm :math:`(1 + 10^{-6})` it took 1349-3000+ sweeps (3-7 s) on n = 2..6
identical-mode loops, against 13-15 Newton steps (5-15 ms) for (3).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike

from ..analysis.closedloop import ClosedLoop
from ..model.system import JointChain, Matrix
from .illconditioned import PeerLoop, similarity, two_mode_chain

__all__ = [
    "MAX_NEWTON",
    "HinfBounds",
    "MultiModePeer",
    "RiccatiSolution",
    "coupled_operator",
    "coupled_riccati",
    "mjls_abscissa",
    "mjls_hinf_bounds",
    "mjls_hinf_norm",
    "mjls_hinf_norm_of_loop",
    "multi_mode_loop",
    "point_chain",
]

#: Newton steps (3) allowed per gamma (quadratic convergence needs about 5-15).
MAX_NEWTON = 100
#: Relative tolerances: decrease / indefiniteness of iterates, convergence, residual.
_MONOTONE_TOL, _STEP_TOL, _STALL_TOL, _RESIDUAL_TOL = 1e-8, 1e-12, 1e-8, 1e-7
#: Growth of the iterates beyond which the iteration counts as divergent.
_GROWTH = 1e12


@dataclass(frozen=True, eq=False)
class RiccatiSolution:
    """Outcome of Newton's method (3) at one ``gamma`` (module docstring, step (4)).

    ``feasible`` means a stabilising solution of (1) was found and checked, so
    ``gamma`` is above the norm; otherwise ``reason`` says which test failed.
    ``abscissa`` is that of the closed-loop operator (2) (``nan`` when not reached).
    """

    gamma: float
    feasible: bool
    P: tuple[Matrix, ...] | None
    iterations: int
    abscissa: float
    residual: float
    reason: str


@dataclass(frozen=True, eq=False)
class HinfBounds:
    """The final bisection bracket: ``lower`` infeasible, ``upper`` feasible (checked)."""

    lower: float
    upper: float
    evaluations: int


@lru_cache(maxsize=32)
def _vech_maps(n: int) -> tuple[Matrix, Matrix]:
    """``(D, L)`` with ``vec(X) = D vech(X)`` (symmetric ``X``), ``vech(X) = L vec(X)``."""
    pairs = [(r, c) for c in range(n) for r in range(c, n)]
    D = np.zeros((n * n, len(pairs)))
    L = np.zeros((len(pairs), n * n))
    for k, (r, c) in enumerate(pairs):
        D[c * n + r, k] = D[r * n + c, k] = 1.0
        L[k, c * n + r] = 1.0
    for X in (D, L):
        X.setflags(write=False)
    return D, L


def coupled_operator(M: Sequence[Matrix], Q: Matrix) -> Matrix:
    """The matrix of :math:`\\mathcal L_M` (eq. (2)) acting on stacked ``vech(X_s)``."""
    n = M[0].shape[0]
    D, L = _vech_maps(n)
    eye = np.eye(n)
    blocks = [L @ (np.kron(eye, Ms.T) + np.kron(Ms.T, eye)) @ D for Ms in M]
    return scipy.linalg.block_diag(*blocks) + np.kron(Q, np.eye(D.shape[1]))


def mjls_abscissa(M: Sequence[Matrix], Q: Matrix) -> float:
    """Spectral abscissa of eq. (2); the loop ``M`` is mean-square stable iff it is < 0."""
    return float(np.max(scipy.linalg.eigvals(coupled_operator(M, Q), check_finite=False).real))


def _unstack(v: Matrix, n: int, count: int) -> list[Matrix]:
    D, _ = _vech_maps(n)
    Xs = [(D @ part).reshape(n, n, order="F") for part in np.split(v, count)]
    return [0.5 * (X + X.T) for X in Xs]


def _stack(X: Sequence[Matrix]) -> Matrix:
    _, L = _vech_maps(X[0].shape[0])
    return np.concatenate([L @ np.asarray(x).reshape(-1, order="F") for x in X])


def _residual(A: Sequence[Matrix], BB: Sequence[Matrix], CC: Sequence[Matrix], Q: Matrix,
              P: Sequence[Matrix], g2: float) -> float:
    """Largest ``||F_s(P)||_F`` of eq. (1) relative to the size of its terms."""
    worst = 0.0
    for s, (As, Ps) in enumerate(zip(A, P)):
        coupling = sum(Q[s, t] * Pt for t, Pt in enumerate(P))
        quad = g2 * Ps @ BB[s] @ Ps
        F = As.T @ Ps + Ps @ As + coupling + quad + CC[s]
        scale = (2 * np.linalg.norm(As) * np.linalg.norm(Ps) + np.abs(Q[s]).sum() * max(np.linalg.norm(Pt) for Pt in P)
                 + np.linalg.norm(quad) + np.linalg.norm(CC[s]))
        worst = max(worst, float(np.linalg.norm(F) / max(scale, np.finfo(float).tiny)))
    return worst


def coupled_riccati(A: Sequence[ArrayLike], Bw: Sequence[ArrayLike], Cz: Sequence[ArrayLike], Q: ArrayLike,
                    gamma: float) -> RiccatiSolution:
    """Newton's method (3) for the coupled equations (1) at ``gamma``, with the tests of
    step (4) of the module docstring. Assumes a mean-square stable open loop (``P_0 = 0``
    must be stabilising); :func:`mjls_hinf_bounds` checks that first."""
    As, Bs, Cs, Qm = _checked(A, Bw, Cz, Q)
    return _newton(As, [B @ B.T for B in Bs], [C.T @ C for C in Cs], Qm, float(gamma))


def _newton(A: list[Matrix], BB: list[Matrix], CC: list[Matrix], Q: Matrix, gamma: float) -> RiccatiSolution:
    n, count, g2 = A[0].shape[0], len(A), gamma ** -2.0
    P = [np.zeros((n, n)) for _ in A]
    first = 0.0
    nan = float("nan")

    def fail(k: int, why: str) -> RiccatiSolution:
        return RiccatiSolution(gamma, False, None, k, nan, nan, why)

    step = math.inf
    for k in range(1, MAX_NEWTON + 1):
        M = [As + g2 * BBs @ Ps for As, BBs, Ps in zip(A, BB, P)]
        rhs = _stack([g2 * Ps @ BBs @ Ps - CCs for Ps, BBs, CCs in zip(P, BB, CC)])
        try:
            v = scipy.linalg.solve(coupled_operator(M, Q), rhs, check_finite=False)
        except (np.linalg.LinAlgError, ValueError):
            return fail(k, "singular coupled Lyapunov equation")
        if not np.all(np.isfinite(v)):
            return fail(k, "non-finite Newton iterate")
        new = _unstack(v, n, count)
        size = max(float(np.linalg.norm(X, 2)) for X in new)
        first = first or size
        if size > _GROWTH * max(first, np.finfo(float).tiny):
            return fail(k, f"iterates grew by more than {_GROWTH:g}")
        tol = _MONOTONE_TOL * size
        if any(np.linalg.eigvalsh(X - Y)[0] < -tol or np.linalg.eigvalsh(X)[0] < -tol for X, Y in zip(new, P)):
            return fail(k, "Newton iterates not increasing (gamma below the norm)")
        step = max(float(np.linalg.norm(X - Y, 2)) for X, Y in zip(new, P)) / max(size, np.finfo(float).tiny)
        P = new
        if step <= _STEP_TOL:
            break
    if step > _STALL_TOL:
        return fail(MAX_NEWTON, f"no convergence in {MAX_NEWTON} Newton steps (last relative step {step:.2g})")
    abscissa = mjls_abscissa([As + g2 * BBs @ Ps for As, BBs, Ps in zip(A, BB, P)], Q)
    residual = _residual(A, BB, CC, Q, P, g2)
    ok = abscissa < 0 and residual <= _RESIDUAL_TOL
    reason = "stabilising solution" if ok else (
        f"limit not stabilising (closed-loop abscissa {abscissa:.3g})" if abscissa >= 0
        else f"residual {residual:.2g} of eq. (1) too large")
    return RiccatiSolution(gamma, ok, tuple(P) if ok else None, k, abscissa, residual, reason)


def _checked(A: Sequence[ArrayLike], Bw: Sequence[ArrayLike], Cz: Sequence[ArrayLike],
             Q: ArrayLike) -> tuple[list[Matrix], list[Matrix], list[Matrix], Matrix]:
    As = [np.asarray(a, dtype=float) for a in A]
    Bs = [np.asarray(b, dtype=float) for b in Bw]
    Cs = [np.asarray(c, dtype=float) for c in Cz]
    Qm = np.asarray(Q, dtype=float)
    count = len(As)
    if count == 0 or len(Bs) != count or len(Cs) != count or Qm.shape != (count, count):
        raise ValueError(f"expected equally many A, Bw, Cz and a {count} x {count} generator, got "
                         f"{len(As)}, {len(Bs)}, {len(Cs)} and {Qm.shape}")
    n = As[0].shape[0]
    for s, (a, b, c) in enumerate(zip(As, Bs, Cs)):
        if a.shape != (n, n) or b.ndim != 2 or b.shape[0] != n or c.ndim != 2 or c.shape[1] != n:
            raise ValueError(f"mode {s}: shapes A {a.shape}, Bw {b.shape}, Cz {c.shape} do not fit n = {n}")
    off = ~np.eye(count, dtype=bool)
    if np.any(Qm[off] < 0) or np.any(np.abs(Qm.sum(axis=1)) > 1e-9 * max(1.0, float(np.abs(Qm).max()))):
        raise ValueError("Q is not a generator (off-diagonal rates >= 0, rows summing to zero)")
    return As, Bs, Cs, Qm


def mjls_hinf_bounds(A: Sequence[ArrayLike], Bw: Sequence[ArrayLike], Cz: Sequence[ArrayLike], Q: ArrayLike,
                     *, rtol: float = 1e-6) -> HinfBounds:
    """Bracket of the norm, ``upper / lower - 1 <= rtol`` (module docstring, step (5)).

    ``upper`` is a ``gamma`` with a checked stabilising solution of (1); ``lower`` one
    where Newton's method failed. ``(inf, inf)`` when the open loop is not mean-square
    stable, ``(0, 0)`` when the input or the output is zero in every mode.
    """
    As, Bs, Cs, Qm = _checked(A, Bw, Cz, Q)
    if not rtol > 0:
        raise ValueError(f"rtol must be positive, got {rtol}")
    if mjls_abscissa(As, Qm) >= 0:
        return HinfBounds(math.inf, math.inf, 0)
    if all(not np.any(B) for B in Bs) or all(not np.any(C) for C in Cs):
        return HinfBounds(0.0, 0.0, 0)
    BB, CC = [B @ B.T for B in Bs], [C.T @ C for C in Cs]
    evaluations = 0

    def feasible(g: float) -> bool:
        nonlocal evaluations
        evaluations += 1
        return _newton(As, BB, CC, Qm, g).feasible

    eye, gains = np.eye(As[0].shape[0]), []
    for s, (a, b, c) in enumerate(zip(As, Bs, Cs)):  # the start gamma_0 of step (5)
        try:
            gains.append(float(np.linalg.norm(c @ np.linalg.solve(-(a + 0.5 * Qm[s, s] * eye), b), 2)))
        except np.linalg.LinAlgError:
            continue
    g = max([x for x in gains if math.isfinite(x) and x > 0], default=1.0)
    if feasible(g):
        hi = g
        for _ in range(200):
            g *= 0.5
            if not feasible(g):
                break
            hi = g
        else:  # feasible down to 2**-200 of the start: zero up to rounding
            return HinfBounds(0.0, hi, evaluations)
        lo = g
    else:
        lo = g
        for _ in range(200):
            g *= 2.0
            if feasible(g):
                break
            lo = g
        else:
            raise RuntimeError(f"no feasible gamma up to {g:.3g} although the open loop is mean-square stable")
        hi = g
    while hi > lo * (1.0 + rtol):
        mid = math.sqrt(lo * hi)
        if feasible(mid):
            hi = mid
        else:
            lo = mid
    return HinfBounds(lo, hi, evaluations)


def mjls_hinf_norm(A: Sequence[ArrayLike], Bw: Sequence[ArrayLike], Cz: Sequence[ArrayLike], Q: ArrayLike,
                   *, rtol: float = 1e-6) -> float:
    """Stochastic :math:`H_\\infty` norm of the MJLS ``(A_s, Bw_s, Cz_s)`` with generator ``Q``.

    Returns the *lower* end of the bracket of :func:`mjls_hinf_bounds`, so that the
    value is at most the norm and within ``rtol`` relative of it: a certified upper
    bound below it is wrong (up to the rounding of this computation). ``inf`` when the
    loop is not mean-square stable.
    """
    return mjls_hinf_bounds(A, Bw, Cz, Q, rtol=rtol).lower


def mjls_hinf_norm_of_loop(loop: ClosedLoop, beta: ArrayLike | None = None, *, rtol: float = 1e-6) -> float:
    """:func:`mjls_hinf_norm` of the nominal ``loop`` (a
    :class:`~ftc_verify.analysis.closedloop.ClosedLoop`; uncertainty channels ignored)
    with the generator ``loop.chain.generator(beta)`` (``beta`` defaults to the midpoint
    of the box)."""
    chain = loop.chain
    Q = chain.generator(chain.midpoint() if beta is None else beta)
    return mjls_hinf_norm(loop.A, loop.Bw, loop.Cz, Q, rtol=rtol)


@dataclass(frozen=True, eq=False)
class MultiModePeer(PeerLoop):
    """A genuine multi-mode loop (different ``A_s`` per joint mode) on a chain whose
    ``beta`` box is one point, its well-conditioned original and the similarity ``S``
    (``x' = S x``) between them. The references are computed on the original."""

    @property
    def generator(self) -> Matrix:
        """The one generator of the (degenerate) ``beta`` box."""
        return self.original.chain.generator(self.original.chain.midpoint())

    @property
    def abscissa(self) -> float:
        """Spectral abscissa of the second-moment generator (eq. (2)), on the original."""
        return mjls_abscissa(self.original.A, self.generator)

    def reference_norm(self, *, rtol: float = 1e-6) -> float:
        """:func:`mjls_hinf_norm_of_loop` on the original coordinates."""
        return mjls_hinf_norm_of_loop(self.original, rtol=rtol)


def point_chain(chain: JointChain | None = None) -> JointChain:
    """``chain`` (default the paper's two-mode chain) with its rate box (detection and, when
    given, false-alarm rates) collapsed to its midpoint, so that the loop has one
    generator; its phases and variant kept."""
    chain = two_mode_chain() if chain is None else chain
    beta, false_alarm = chain.split(chain.midpoint())
    if false_alarm is None:
        return replace(chain, beta_min=beta, beta_max=beta.copy())
    return replace(chain, beta_min=beta, beta_max=beta.copy(), false_alarm_min=false_alarm,
                   false_alarm_max=false_alarm.copy())


def multi_mode_loop(seed: int, n: int, *, norm: float | None = None, diagonal_condition: float = 1.0,
                    transform_condition: float = 1.0, chain: JointChain | None = None,
                    max_draws: int = 50) -> MultiModePeer:
    """A mean-square stable loop with different modes, drawn from
    ``numpy.random.default_rng(seed)`` on :func:`point_chain` of ``chain``.

    Per joint state (one per pair with the paper's FDI model; a chain with detection
    phases draws a matrix per phase too): ``A_s`` standard normal shifted so that its abscissa is in
    ``-[0.2, 1.5]``, ``Bw_s`` n x 1 and ``Cz_s`` 1 x n standard normal (redrawn from the
    same stream until the MJLS is mean-square stable); with ``norm`` every ``Cz_s`` is
    scaled so that the :func:`mjls_hinf_norm` is ``norm`` (the norm is linear in ``Cz``).
    Then moved by :func:`~ftc_verify.testing.illconditioned.similarity` as in
    :func:`~ftc_verify.testing.illconditioned.identical_mode_loop`.
    """
    rng = np.random.default_rng(seed)
    chain = point_chain(chain)
    count = chain.n_states
    Q = chain.generator(chain.midpoint())
    for _ in range(max_draws):
        A = []
        for _s in range(count):
            X = rng.standard_normal((n, n))
            A.append(X - (np.max(np.linalg.eigvals(X).real) + rng.uniform(0.2, 1.5)) * np.eye(n))
        Bw = [rng.standard_normal((n, 1)) for _s in range(count)]
        Cz = [rng.standard_normal((1, n)) for _s in range(count)]
        if mjls_abscissa(A, Q) < 0:
            break
    else:
        raise RuntimeError(f"no mean-square stable draw for seed {seed}, n {n} in {max_draws} draws")
    if norm is not None:
        factor = norm / mjls_hinf_bounds(A, Bw, Cz, Q, rtol=1e-10).upper
        Cz = [factor * C for C in Cz]
    S = similarity(rng, n, diagonal_condition, transform_condition)
    S_inv = np.linalg.inv(S)

    def make(a: Sequence[Matrix], b: Sequence[Matrix], c: Sequence[Matrix]) -> ClosedLoop:
        return ClosedLoop(chain, tuple(a), tuple(b), tuple(c), ((),) * count, "multi-mode peer")

    original = make(A, Bw, Cz)
    moved = make([S @ a @ S_inv for a in A], [S @ b for b in Bw], [c @ S_inv for c in Cz])
    return MultiModePeer(moved, original, S, seed, float(diagonal_condition), float(transform_condition))
