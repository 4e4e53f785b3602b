r"""Certificate candidates of Theorem 3.2 from the coupled bounded-real Riccati equations, without an SDP.

For a joint chain with generator :math:`Q` (one rate vector of the box) and the nominal
loop :math:`(A_s, B_{w,s}, C_{z,s})` of :mod:`ftc_verify.analysis.closedloop`, the
bounded real lemma of the jump system (de Souza & Fragoso 1993; Costa, Fragoso & Todorov
2013, ch. 7; written out in :mod:`ftc_verify.testing.references`) says that
:math:`\gamma` exceeds the worst-case gain iff the coupled Riccati equations

.. math::

    A_s^T P_s + P_s A_s + \sum_t q_{st} P_t + C_{z,s}^T C_{z,s} + \varepsilon I
    + \gamma^{-2} P_s B_{w,s} B_{w,s}^T P_s = 0 \tag{1}

have a stabilising solution (here with :math:`\varepsilon = 0`). With
:math:`\varepsilon > 0`, a solution of (1) satisfies the Riccati *inequality* of the
unperturbed data with margin :math:`\varepsilon I`, and :math:`P_s \succ 0`; by the
Schur complement on the :math:`-\gamma^2 I` and :math:`-I` rows it is the strict LMI of
Theorem 3.2 (:func:`~ftc_verify.analysis.lmi.lyapunov_block`, :math:`g = \gamma^2`) at
that rate vector.

**The box.** Theorem 3.2's blocks must hold with the same :math:`P` at every vertex of
the rates of each generator row. Row :math:`s` is affine in its rates
(:meth:`~ftc_verify.model.chain.JointChain.row_rates`): over the box it is
:math:`\bar q_s + \sum_r \sigma_r d_{s,r}`, :math:`|\sigma_r| \le 1` (midpoint and half
ranges, :class:`RateEnvelope`), so its coupling is
:math:`\sum_t \bar q_{st} P_t + \sum_r \sigma_r G_{s,r}`,
:math:`G_{s,r} = \sum_{t \ne s} d_{s,r,t}(P_t - P_s)`. With a pinned vertex
:math:`\hat\sigma` and the matrix absolute value :math:`|G|`,
:math:`\sigma G \preceq \hat\sigma G + (|G| - \hat\sigma G)` for every
:math:`|\sigma| \le 1`; hence a solution of

.. math::

    A_s^T P_s + P_s A_s + \sum_t \hat q_{st} P_t + E_s(P) + C_{z,s}^T C_{z,s} + \varepsilon I
    + \gamma^{-2} P_s B_{w,s} B_{w,s}^T P_s = 0, \quad
    E_s(P) = \sum_r (|G_{s,r}| - \hat\sigma_r G_{s,r}) \succeq 0 , \tag{3}

(:math:`\hat q` the generator at the pinned vertex) satisfies the Riccati inequality
with margin :math:`\varepsilon I` at *every* vertex: a candidate for the whole box.
:math:`E_s = 0` where :math:`G_{s,r}` is definite and :math:`\hat\sigma_r` its sign
(then (3) is (1) at the worst vertex); :meth:`RateEnvelope.pinned` takes
:math:`\hat\sigma_r = \operatorname{sign}\operatorname{tr} G_{s,r}`. The construction
is conservative where :math:`G` is indefinite (measured: the certified level 0.07-0.6 %
above the SDP's on random loops). :func:`~ftc_verify.analysis.lmi.check_certificate`
proves or rejects the candidate at every vertex in ball arithmetic (on the loop as the
user wrote it, through the conditioning similarity). Nothing here is trusted: a rejected
candidate sends the caller to the SDP (:func:`~ftc_verify.analysis.lmi_analysis.hinf_gamma`).

**Solving (3).** Policy iteration (the maximising player's Newton step, the iteration
of :func:`~ftc_verify.analysis.lower_bound.worst_case_feedback`, with a linear solver of
the right complexity): from :math:`F = 0`, :math:`E = 0`, solve the coupled Lyapunov
equation

.. math::

    \tilde A_s^T P_s + P_s \tilde A_s + \sum_t \hat q_{st} P_t = -(C_{z,s}^T C_{z,s} + \varepsilon I + E_s
    - \gamma^2 F_s^T F_s), \qquad \tilde A_s = A_s + B_{w,s} F_s , \tag{2}

then :math:`F_s = \gamma^{-2} B_{w,s}^T P_s`, :math:`E_s = E_s(P)`; at a fixed point
(2) is (3). It fails (:math:`\gamma` too low, in float64, for this construction) when a
solve of (2) fails, an iterate after the first is not positive semidefinite, or the
iteration stops contracting or converging.

**Solving (2) in** :math:`O(m^2 n^3)` **per iteration** (:func:`coupled_lyapunov`), not by the
:math:`(m^2 n^2)^3` dense Kronecker system. Split the operator
:math:`\mathcal L(P)_s = \hat A_s^T P_s + P_s \hat A_s + \sum_{t \ne s} q_{st} P_t`,
:math:`\hat A_s = \tilde A_s + \tfrac12 q_{ss} I`, into its block diagonal
:math:`\mathcal D` (one Lyapunov operator per joint state, solved by Bartels--Stewart on
one real Schur form per state, LAPACK ``trsyl``) and the coupling :math:`\mathcal N`.
:math:`\mathcal L` is resolvent positive; when it is Hurwitz (the loop mean-square
stable), :math:`\mathcal L = \mathcal D + \mathcal N` is a regular splitting, so
:math:`\rho(\mathcal D^{-1}\mathcal N) < 1` and the preconditioned equation
:math:`(I + \mathcal D^{-1}\mathcal N) P = -\mathcal D^{-1} R` is solved by GMRES, each
product :math:`m^2` Schur-based Sylvester solves and a coupling sum. Stacks of at most
:data:`DENSE_ROWS` ``vech`` rows are solved densely instead
(:func:`~ftc_verify.analysis.moments.stability.lyapunov_stack_solution`, faster there).

**Gamma.** Bisection on :math:`\gamma` (geometric) between a failing and a succeeding
level of the iteration with :math:`\varepsilon = 0` (the envelope pinned at the first
feasible level), warm-started from the last
feasible feedback, to :data:`BISECTION_RTOL`; the candidate is then solved at
:math:`\gamma(1 + 2\rho)` with :math:`\varepsilon = \rho|\rho| \max_s \|C_{z,s}\|^2`
(:func:`candidate_margin`) for :math:`\rho` in :data:`CANDIDATE_LADDER` until a
certificate passes. The margin is second order in :math:`\rho` because
:math:`\varepsilon I` enters (1) in every direction of the state, also those that
:math:`C_z` does not see: it raises the level by about :math:`\varepsilon` times the
trace of the worst-case second moment, which on a random n = 48, m = 3 loop (seed 5100)
exceeded the :math:`2\rho\gamma` step with :math:`\varepsilon = \rho \|C_z\|^2` on every
rung (no candidate, then an SDP of 10,585 variables). The proof needs only
:math:`\varepsilon` above the float residual of the solution (the blocks are proved in
128-bit ball arithmetic), so :math:`\rho^2` keeps every rung solvable
(measured there: :math:`\varepsilon = 10^{-8}\|C_z\|^2` at :math:`+2\cdot 10^{-4}` certified).

**Bounded work.** A policy iteration stops after :data:`MAX_POLICY_STEPS` steps or when
it stops contracting, each GMRES solve after :data:`POLICY_GMRES_RESTARTS` restarts of 60
steps (converging ones take 20-60 steps at n = 48; an unstable iterate never converges).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.linalg.lapack
import scipy.sparse.linalg

from ..claimtext import upper_text
from ..model.chain import JointChain
from ..model.system import Matrix
from .closedloop import ClosedLoop
from .conditioning import Similarity
from .lmi import Certificate, check_certificate

__all__ = ["least_eigenvalue", "BISECTION_RTOL", "DENSE_ROWS", "POLICY_RTOL", "SEARCH_RTOL", "CANDIDATE_LADDER", "MAX_POLICY_STEPS", "STALL_RATIO", "coupled_lyapunov",
           "POLICY_GMRES_RESTARTS", "candidate_margin", "lyapunov_candidate", "batched_lyapunov",
           "LyapunovSolver",
           "RateEnvelope", "bounded_real_solution", "float_hinf_norm", "RiccatiCandidate", "riccati_candidate"]

#: Relative width of the final bisection bracket of :func:`float_hinf_norm`.
BISECTION_RTOL = 1e-4
#: Relative steps ``rho`` above the float norm tried for a candidate (at ``gamma (1 + 2 rho)``,
#: margin :func:`candidate_margin`).
CANDIDATE_LADDER = (1e-4, 1e-3, 1e-2)
#: GMRES restarts (of 60 steps) of each coupled Lyapunov solve of the policy iteration (module docstring).
POLICY_GMRES_RESTARTS = 10
#: Policy-iteration steps before :func:`bounded_real_solution` gives up.
MAX_POLICY_STEPS = 60
#: Relative change of ``P`` at which the policy iteration has converged (the candidate).
POLICY_RTOL = 1e-10
#: The same for the feasibility tests of the bisection (a level is decided long before).
SEARCH_RTOL = 1e-6
#: From this step on, an iteration whose step shrinks by less than :data:`STALL_RATIO` is stopped (not contracting).
STALL_STEPS = 12
#: The contraction an iteration must keep up after ``STALL_STEPS`` steps (the envelope term makes
#: it linear, measured 0.25-0.55 per step on random n = 12, m = 4 loops with uncertainty).
STALL_RATIO = 0.9
#: Re-pinnings of the envelope at the first feasible level (:func:`float_hinf_norm`).
PIN_ROUNDS = 3
#: Stacks of at most this many ``vech`` rows are solved densely
#: (:func:`~ftc_verify.analysis.moments.stability.lyapunov_stack_solution`), larger ones by GMRES.
DENSE_ROWS = 400


class _Schur:
    """Real Schur forms ``hat A_s = U_s T_s U_s^T`` (module docstring) for Bartels--Stewart."""

    def __init__(self, A: Sequence[Matrix], Q: Matrix) -> None:
        n = A[0].shape[0]
        self.forms = [scipy.linalg.schur(a + 0.5 * Q[s, s] * np.eye(n), output="real") for s, a in enumerate(A)]

    def solve(self, s: int, W: Matrix) -> Matrix | None:
        """``X`` with ``hat A_s^T X + X hat A_s = W``; ``None`` when singular."""
        T, U = self.forms[s]
        C = U.T @ W @ U
        X, scale, info = scipy.linalg.lapack.dtrsyl(T, T, C, trana="T", tranb="N", isgn=1)
        if info < 0 or scale == 0:
            return None
        X = U @ (X / scale) @ U.T
        return 0.5 * (X + X.T)


def candidate_margin(rho: float, scale: float) -> float:
    r"""The margin :math:`\varepsilon = \rho |\rho|\,` ``scale`` of the candidate at
    :math:`\gamma(1 + 2\rho)` (``scale`` :math:`= \max_s \|C_{z,s}\|^2`; module docstring:
    second order in :math:`\rho`; negative for a negative :math:`\rho`)."""
    return rho * abs(rho) * scale


def _policy_solve(A: Sequence[Matrix], Q: Matrix, R: Sequence[Matrix], start: Sequence[Matrix] | None) -> list[Matrix] | None:
    """:func:`batched_lyapunov` with at most :data:`POLICY_GMRES_RESTARTS` restarts (bounded work)."""
    return batched_lyapunov(A, Q, R, start, maxiter=POLICY_GMRES_RESTARTS)


def _schur_solve(A: Sequence[Matrix], Q: Matrix, R: Sequence[Matrix], start: Sequence[Matrix] | None) -> list[Matrix] | None:
    """:func:`coupled_lyapunov` (backward stable: the candidate's tight steps) with the same bound."""
    return coupled_lyapunov(A, Q, R, start, maxiter=POLICY_GMRES_RESTARTS)


def batched_lyapunov(A: Sequence[Matrix], Q: Matrix, R: Sequence[Matrix], start: Sequence[Matrix] | None = None,
                     rtol: float = 1e-11, maxiter: int = POLICY_GMRES_RESTARTS) -> list[Matrix] | None:
    r"""The stack of :func:`coupled_lyapunov` (eq. (2)) by right-preconditioned GMRES,
    every operation batched over the joint states (a few numpy calls per product, not
    :math:`m^2` LAPACK calls: the Python overhead dominated small blocks).

    The operator :math:`\mathcal L = \mathcal D + \mathcal N` is applied exactly;
    the preconditioner is :math:`\mathcal D^{-1}` through the eigen-decompositions
    :math:`\hat A_s = V_s \Lambda_s V_s^{-1}`: with :math:`Y = V_s^T X V_s`,
    :math:`V_s^T(\hat A_s^T X + X \hat A_s)V_s = \Lambda_s Y + Y \Lambda_s`, so
    :math:`\mathcal D_s^{-1}(W) = V_s^{-T}\,[(V_s^T W V_s)_{ij} / (\lambda_i + \lambda_j)]\,V_s^{-1}`
    (real part). GMRES solves :math:`\mathcal L(\mathcal D^{-1} y) = -R`,
    :math:`P = \mathcal D^{-1} y`, so ``rtol`` bounds the *true* relative residual
    :math:`\|\mathcal L(P) + R\| / \|R\|` whatever the conditioning of :math:`V_s`
    (a poor preconditioner costs iterations). When GMRES does not converge in ``maxiter``
    restarts (rounding in an ill-conditioned :math:`V_s` can stall the residual: seen at
    n = 48, m = 3) or some :math:`\|V_s\|_F \|V_s^{-1}\|_F > 10^8`, the answer is
    :func:`coupled_lyapunov`'s with the same budget; small stacks go to its dense solve."""
    n, S = A[0].shape[0], len(A)
    Q = np.asarray(Q, dtype=float)
    if S * n * (n + 1) // 2 <= DENSE_ROWS:
        return coupled_lyapunov(A, Q, R, start, rtol=rtol, maxiter=maxiter)
    Ah = np.stack([np.asarray(a, dtype=float) for a in A]) + 0.5 * np.diagonal(Q)[:, None, None] * np.eye(n)
    AhT = Ah.transpose(0, 2, 1)
    off = Q - np.diag(np.diagonal(Q))
    with np.errstate(all="ignore"):
        lam, V = np.linalg.eig(Ah)
        try:
            Vinv = np.linalg.inv(V)
        except np.linalg.LinAlgError:
            return coupled_lyapunov(A, Q, R, start, rtol=rtol, maxiter=maxiter)
        denom = lam[:, :, None] + lam[:, None, :]
        kappa = np.linalg.norm(V, axis=(1, 2)) * np.linalg.norm(Vinv, axis=(1, 2))
    if not np.all(np.isfinite(kappa)) or kappa.max() > 1e8 or not np.all(np.abs(denom) > 0):
        return coupled_lyapunov(A, Q, R, start, rtol=rtol, maxiter=maxiter)
    VT, VinvT = V.transpose(0, 2, 1), Vinv.transpose(0, 2, 1)

    def inverse(W: Matrix) -> Matrix:
        X = (VinvT @ ((VT @ W @ V) / denom) @ Vinv).real
        return 0.5 * (X + X.transpose(0, 2, 1))

    def apply(X: Matrix) -> Matrix:
        return AhT @ X + X @ Ah + np.einsum("st,tij->sij", off, X)

    def matvec(v: Matrix) -> Matrix:
        return apply(inverse(np.asarray(v, dtype=float).reshape(S, n, n))).ravel()

    rhs = -np.stack([np.asarray(r, dtype=float) for r in R])
    x0 = None
    if start is not None:
        P0 = np.stack([np.asarray(p, dtype=float) for p in start])
        x0 = (AhT @ P0 + P0 @ Ah).ravel()  # D(P0): the y with D^{-1} y = P0
    try:
        op = scipy.sparse.linalg.LinearOperator((S * n * n, S * n * n), matvec=matvec, dtype=float)
        y, info = scipy.sparse.linalg.gmres(op, rhs.ravel(), x0=x0, rtol=rtol, atol=0.0,
                                            restart=min(S * n * n, 60), maxiter=maxiter)
    except (np.linalg.LinAlgError, ValueError, scipy.linalg.LinAlgError):
        info = -1
    if info != 0 or not np.all(np.isfinite(y)):  # stalled (eigenvectors ill-conditioned) or not stable
        return coupled_lyapunov(A, Q, R, start, rtol=rtol, maxiter=maxiter)
    return list(inverse(y.reshape(S, n, n)))


#: A solver of eq. (2): ``(A, Q, R, start) -> P`` or ``None`` (:func:`coupled_lyapunov`).
LyapunovSolver = Callable[[Sequence[Matrix], Matrix, Sequence[Matrix], Sequence[Matrix] | None], list[Matrix] | None]


def coupled_lyapunov(A: Sequence[Matrix], Q: Matrix, R: Sequence[Matrix],
                     start: Sequence[Matrix] | None = None, rtol: float = 1e-11,
                     maxiter: int = 40) -> list[Matrix] | None:
    r"""The stack :math:`P` with :math:`A_s^T P_s + P_s A_s + \sum_t q_{st} P_t = -R_s`
    (eq. (2)), by GMRES on the block-diagonally preconditioned operator (module
    docstring); ``start`` a first guess. ``None`` when a Schur solve is singular, GMRES
    does not converge or the result is not finite (for a resolvent-positive operator: the
    loop is, in float64, not mean-square stable). ``rtol``: GMRES's relative residual
    (of the preconditioned system); a caller that checks the solution afterwards (the
    shift test of :func:`~ftc_verify.analysis.moments.stability.abscissa_below`) can
    take a much looser one; ``maxiter``: GMRES restarts (of 60 steps) at most."""
    n, S = A[0].shape[0], len(A)
    Q = np.asarray(Q, dtype=float)
    if S * n * (n + 1) // 2 <= DENSE_ROWS:  # small: the dense vech system of the stability module
        from .moments.stability import lyapunov_stack_solution

        X = lyapunov_stack_solution([a.T for a in A], Q.T, R)
        return None if X is None else list(X)
    schur = _Schur(A, Q)
    size = n * n

    def coupling(X: list[Matrix], s: int) -> Matrix:
        out = np.zeros((n, n))
        for t in range(S):
            if t != s and Q[s, t] != 0.0:
                out += Q[s, t] * X[t]
        return out

    def precondition(W: list[Matrix]) -> list[Matrix]:
        out = []
        for s in range(S):
            X = schur.solve(s, W[s])
            if X is None:
                raise np.linalg.LinAlgError("singular Lyapunov operator")
            out.append(X)
        return out

    def split(v: Matrix) -> list[Matrix]:
        return [v[s * size:(s + 1) * size].reshape(n, n) for s in range(S)]

    def matvec(v: Matrix) -> Matrix:
        X = split(np.asarray(v, dtype=float).ravel())
        Y = precondition([coupling(X, s) for s in range(S)])
        return np.asarray(v, dtype=float).ravel() + np.concatenate([y.ravel() for y in Y])

    try:
        rhs = np.concatenate([x.ravel() for x in precondition([-np.asarray(r, dtype=float) for r in R])])
        op = scipy.sparse.linalg.LinearOperator((S * size, S * size), matvec=matvec, dtype=float)
        x0 = None if start is None else np.concatenate([np.asarray(p, dtype=float).ravel() for p in start])
        v, info = scipy.sparse.linalg.gmres(op, rhs, x0=x0, rtol=rtol, atol=0.0,
                                            restart=min(S * size, 60), maxiter=maxiter)
    except (np.linalg.LinAlgError, ValueError, scipy.linalg.LinAlgError):
        return None
    if info != 0 or not np.all(np.isfinite(v)):
        return None
    return [0.5 * (X + X.T) for X in split(v)]


@dataclass(frozen=True, eq=False)
class RateEnvelope:
    r"""The generator rows over the rate box (module docstring, eq. (3)): row :math:`s`
    at any rate vector of the box is :math:`\bar q_s + \sum_r \sigma_r d_{s,r}`,
    :math:`|\sigma_r| \le 1`; ``signs`` pins each :math:`\sigma_r` to a vertex
    (``Q`` is the generator there), the rest of the envelope is the correction."""

    mid: Matrix
    half: tuple[tuple[Matrix, ...], ...]
    signs: tuple[tuple[float, ...], ...]

    @classmethod
    def of(cls, chain: JointChain) -> RateEnvelope:
        """The envelope of ``chain``'s rate box (each row affine in its rates,
        :meth:`~ftc_verify.model.chain.JointChain.row_rates`), pinned at the lower corner."""
        lo, hi, mid = chain.rate_min, chain.rate_max, np.asarray(chain.midpoint(), dtype=float)
        half = []
        for s in range(chain.n_states):
            rows = []
            for r in chain.row_rates(s):
                up, down = mid.copy(), mid.copy()
                up[r], down[r] = hi[r], lo[r]
                d = 0.5 * (np.asarray(chain.row_generator(s, up)) - np.asarray(chain.row_generator(s, down)))
                if np.any(d):
                    rows.append(d)
            half.append(tuple(rows))
        return cls(np.array(chain.generator(mid), dtype=float), tuple(half),
                   tuple(tuple(-1.0 for _ in rows) for rows in half))

    @classmethod
    def at(cls, Q: Matrix) -> RateEnvelope:
        """The envelope of one rate vector (generator ``Q``): no half ranges, no correction."""
        Q = np.array(Q, dtype=float)
        return cls(Q, tuple(() for _ in range(Q.shape[0])), tuple(() for _ in range(Q.shape[0])))

    @property
    def Q(self) -> Matrix:
        """The generator at the pinned vertex."""
        Q = self.mid.copy()
        for s, (rows, signs) in enumerate(zip(self.half, self.signs)):
            for d, sign in zip(rows, signs):
                Q[s] += sign * d
        return Q

    def _terms(self, P: Sequence[Matrix]) -> list[list[Matrix]]:
        r""":math:`G_{s,r} = \sum_{t \ne s} d_{s,r,t} (P_t - P_s)`."""
        return [[sum((float(q) * (P[t] - P[s]) for t, q in enumerate(d) if t != s and q != 0.0),
                     np.zeros_like(P[s])) for d in rows] for s, rows in enumerate(self.half)]

    def correction(self, P: Sequence[Matrix]) -> list[Matrix]:
        r""":math:`E_s = \sum_r (|G_{s,r}| - \sigma_r G_{s,r})` (matrix absolute value):
        every vertex's coupling is at most the pinned vertex's plus :math:`E_s`."""
        out = []
        for s, terms in enumerate(self._terms(P)):
            E = np.zeros_like(P[s])
            for G, sign in zip(terms, self.signs[s]):
                w, V = np.linalg.eigh(0.5 * (G + G.T))
                E += (V * (np.abs(w) - sign * w)) @ V.T
            out.append(E)
        return out

    def pinned(self, P: Sequence[Matrix]) -> RateEnvelope:
        r"""The envelope pinned at :math:`\sigma_r = \operatorname{sign} \operatorname{tr} G_{s,r}`
        (the vertex whose correction is smallest in trace: zero where :math:`G` is definite)."""
        signs = tuple(tuple(1.0 if float(np.trace(G)) >= 0 else -1.0 for G in terms) for terms in self._terms(P))
        return RateEnvelope(self.mid, self.half, signs)


def least_eigenvalue(P: Sequence[Matrix] | Matrix) -> float:
    """The least eigenvalue of a stack of symmetric matrices (one batched ``eigvalsh``)."""
    return float(np.linalg.eigvalsh(np.asarray(P))[..., 0].min())


def bounded_real_solution(A: Sequence[Matrix], Bw: Sequence[Matrix], Cz: Sequence[Matrix], box: RateEnvelope,
                          gamma: float, epsilon: float = 0.0, start: Sequence[Matrix] | None = None,
                          rtol: float = POLICY_RTOL,
                          solve: LyapunovSolver | None = None) -> tuple[list[Matrix], list[Matrix]] | None:
    r"""The stabilising solution ``P`` of eq. (3) (eq. (1) over the box) at ``gamma`` and
    ``epsilon`` and its feedback ``F`` (``(P, F)``), by policy iteration from the
    feedback ``start`` (default ``F = 0``; it must make the loop mean-square stable),
    the envelope term taken at the previous iterate; ``None`` when it fails (an iterate
    after the first not positive semidefinite, a failed solve, no convergence): then
    ``gamma`` is, in float64, too low for this construction. A float search: what it
    returns is proved or not used. ``rtol``: the relative change of ``P`` at which the
    iteration has converged. ``solve``: the linear solver of each step's coupled Lyapunov
    equation, called as ``solve(A, Q, R, start)`` like :func:`coupled_lyapunov` (default: with
    :data:`POLICY_GMRES_RESTARTS` restarts at most, :func:`batched_lyapunov` for a search
    (``rtol >= SEARCH_RTOL``), else the Schur forms, whose steps shrink below ``rtol``: the
    eigen-based inverse's rounding stalled a candidate of n = 48, m = 3 near 1e-10). The one policy iteration of the project: the lower bounds of
    :mod:`ftc_verify.analysis.lower_bound` run it at one rate vector
    (:meth:`RateEnvelope.at`), with their own solver."""
    n = A[0].shape[0]
    g2 = gamma * gamma
    F = [np.zeros((B.shape[1], n)) for B in Bw] if start is None else [np.asarray(f, dtype=float) for f in start]
    base = [c.T @ c + epsilon * np.eye(n) for c in Cz]
    Q = box.Q
    P_old: list[Matrix] | None = None
    E = [np.zeros((n, n)) for _ in A]
    last = math.inf
    # Without the envelope, every Newton iterate after the first is semidefinite at a feasible
    # level; with it (it enters at step 1, lagged) the first iterates may not be (measured up to
    # step 3 on n = 16, m = 3): there semidefiniteness is asked of the converged P only.
    checked_from = MAX_POLICY_STEPS if any(box.half) else 0
    for k in range(MAX_POLICY_STEPS):
        with np.errstate(all="ignore"):
            At = [a + b @ f for a, b, f in zip(A, Bw, F)]
            R = [r + e - g2 * f.T @ f for r, e, f in zip(base, E, F)]
        if not (np.isfinite(np.asarray(At)).all() and np.isfinite(np.asarray(R)).all()):
            return None
        P = (solve or (_policy_solve if rtol >= SEARCH_RTOL else _schur_solve))(At, Q, R, P_old)
        if P is None:
            return None
        scale = max(np.finfo(float).tiny, float(np.abs(np.asarray(P)).max()))
        if k > checked_from and least_eigenvalue(P) < -1e-9 * scale:
            return None
        F = [b.T @ p / g2 for b, p in zip(Bw, P)]
        E = box.correction(P)
        if P_old is not None:
            step = max(float(np.abs(p - q).max()) for p, q in zip(P, P_old)) / scale
            if step <= rtol:
                psd = least_eigenvalue(P) >= -1e-9 * scale
                return (P, F) if psd else None
            if k >= STALL_STEPS and step > STALL_RATIO * last:  # not contracting: treated as infeasible
                return None
            last = step
        P_old = P
    return None


def float_hinf_norm(A: Sequence[Matrix], Bw: Sequence[Matrix], Cz: Sequence[Matrix], box: RateEnvelope, *,
                    rtol: float = BISECTION_RTOL) -> tuple[float, list[Matrix], RateEnvelope] | None:
    """The smallest level of :func:`bounded_real_solution` (an upper end ``gamma`` of a
    bracket of relative width ``rtol``) and the feedback there, by geometric bisection
    warm-started from the last feasible feedback, and the envelope pinned as it was
    used (:meth:`RateEnvelope.pinned`, at the first feasible level); ``None`` when no level up to 1e300 is
    feasible or the input or output is zero."""
    if all(not np.any(b) for b in Bw) or all(not np.any(c) for c in Cz):
        return None
    n = A[0].shape[0]
    gains = []
    for s, (a, b, c) in enumerate(zip(A, Bw, Cz)):  # the frozen modes' DC gains: a start
        try:
            gains.append(float(np.linalg.norm(c @ np.linalg.solve(-(a + 0.5 * box.Q[s, s] * np.eye(n)), b), 2)))
        except np.linalg.LinAlgError:
            continue
    hi = max([x for x in gains if math.isfinite(x) and x > 0], default=1.0)
    lo = 0.0
    found = bounded_real_solution(A, Bw, Cz, box, hi, rtol=SEARCH_RTOL)
    while found is None:
        lo, hi = hi, 4.0 * hi
        if hi > 1e300:
            return None
        found = bounded_real_solution(A, Bw, Cz, box, hi, rtol=SEARCH_RTOL)
    for _ in range(PIN_ROUNDS):  # pin every row at the vertex its coupling prefers
        again = box.pinned(found[0])
        if again.signs == box.signs:
            break
        box = again
        found = bounded_real_solution(A, Bw, Cz, box, hi, start=found[1], rtol=SEARCH_RTOL) or found
    F = found[1]
    while lo == 0.0:
        trial = 0.5 * hi
        nxt = bounded_real_solution(A, Bw, Cz, box, trial, start=F, rtol=SEARCH_RTOL)
        if nxt is None:
            lo = trial
        else:
            hi, F = trial, nxt[1]
            if hi < 1e-300:
                return hi, F, box
    while hi - lo > rtol * hi:
        mid = math.sqrt(lo * hi)
        nxt = bounded_real_solution(A, Bw, Cz, box, mid, start=F, rtol=SEARCH_RTOL)
        if nxt is None:
            lo = mid
        else:
            hi, F = mid, nxt[1]
    return hi, F, box


@dataclass(frozen=True, eq=False)
class RiccatiCandidate:
    """What :func:`riccati_candidate` found: the float norm at the lower corner of the
    rate box (``None`` when none), the certified level and its certificate (``None``
    when no candidate passed), ``P`` in the coordinates of the target loop, the levels
    tried and why the last one failed; Lemma 4.1's multipliers
    (:mod:`~ftc_verify.analysis.robust_riccati`; ``None`` for Theorem 3.2)."""

    float_norm: float | None
    gamma: float | None
    certificate: Certificate | None
    P: tuple[Matrix, ...] | None
    tried: int
    message: str
    multipliers: tuple[tuple[float, ...], ...] | None = None


def riccati_candidate(original: ClosedLoop, target: ClosedLoop, similarity: Similarity | None) -> RiccatiCandidate:
    r"""A certified Theorem 3.2 level of ``original`` from the box Riccati equations (3)
    of ``target`` (``original`` in the coordinates of ``similarity``; nominal, no
    uncertainty channels), each candidate proved at every vertex of the box by
    :func:`~ftc_verify.analysis.lmi.check_certificate` (module docstring)."""
    box = RateEnvelope.of(target.chain)
    A, Bw, Cz = list(target.A), list(target.Bw), list(target.Cz)
    norm = float_hinf_norm(A, Bw, Cz, box)
    if norm is None:
        return RiccatiCandidate(None, None, None, None, 0, "no feasible level of the box Riccati equations")
    gamma0, F, box = norm
    scale = max(*(float(np.linalg.norm(c, 2)) ** 2 for c in Cz), np.finfo(float).tiny)
    why, tried = "", 0
    for rho in CANDIDATE_LADDER:
        gamma = gamma0 * (1.0 + 2.0 * rho)
        found = bounded_real_solution(A, Bw, Cz, box, gamma, candidate_margin(rho, scale), start=F)
        tried += 1
        if found is None:
            why = f"no Riccati solution at {gamma:.6g} with margin {rho * abs(rho):.1e} |C_z|^2"
            continue
        cert = check_certificate(original, "theorem-3.2", (P := tuple(found[0])), None, gamma * gamma, similarity=similarity)
        if cert.ok:
            return RiccatiCandidate(gamma0, gamma, cert, P, tried,
                                    f"float level {gamma0:.6g} of the box Riccati equations (no SDP); certified at "
                                    f"{upper_text(gamma)} (+{2 * rho:.1e} relative), margin {rho * abs(rho):.1e} |C_z|^2")
        why = cert.reason
    return RiccatiCandidate(gamma0, None, None, None, tried, f"no candidate passed ({tried} tried): {why}")


def lyapunov_candidate(original: ClosedLoop, target: ClosedLoop, similarity: Similarity | None) -> RiccatiCandidate:
    r"""A Theorem 3.1 certificate of ``original`` (nominal) from the coupled Lyapunov
    equations over the box, eq. (3) with no input and :math:`C_{z,s} = I`:
    :math:`A_s^T P_s + P_s A_s + \sum_t \hat q_{st} P_t + E_s(P) + I = 0`, solved by :func:`bounded_real_solution` (the envelope term lagged one step; the
    envelope re-pinned where the solution prefers, ``PIN_ROUNDS`` times). At every
    vertex the coupling is at most the pinned one plus :math:`E_s`, so
    :math:`\Pi_s(P) \preceq -I \prec 0` there: Theorem 3.1's blocks (eq. (4)) for the
    whole box, proved at every vertex by :func:`~ftc_verify.analysis.lmi.check_certificate`
    like an SDP's answer. ``gamma`` of the result is ``None``."""
    n, S = target.n, len(target.A)
    A, Bw, Cz = list(target.A), [np.zeros((n, 0))] * S, [np.eye(n)] * S
    box = RateEnvelope.of(target.chain)
    found = bounded_real_solution(A, Bw, Cz, box, 1.0)
    for _ in range(PIN_ROUNDS):
        if found is None:
            break
        again = box.pinned(found[0])
        if again.signs == box.signs:
            break
        box = again
        found = bounded_real_solution(A, Bw, Cz, box, 1.0) or found
    if found is None:
        return RiccatiCandidate(None, None, None, None, 1, "no solution of the coupled Lyapunov equations over the box")
    P = tuple(found[0])
    cert = check_certificate(original, "theorem-3.1", P, None, None, similarity=similarity)
    if not cert.ok:
        return RiccatiCandidate(None, None, None, None, 1, f"the coupled Lyapunov candidate was not proved: {cert.reason}")
    return RiccatiCandidate(None, None, cert, P, 1, "the coupled Lyapunov equations over the box (no SDP), proved at "
                            "every vertex")
