r"""Exact expected output energy and worst-case disturbances, from the moment equations.

For a :class:`~ftc_verify.analysis.closedloop.ClosedLoop` (continuous time, no sample-and-hold)
with :math:`\dot\xi = A_\theta \xi + B_\theta w`, :math:`z = C_\theta \xi`, the conditional
moments :math:`X_s = E[\xi\xi^T 1\{\theta = s\}]` obey (Dynkin's formula, derived here)

.. math::

    \dot X_s = A_s X_s + X_s A_s^T + B_s w\, m_s^T + m_s w^T B_s^T + \sum_{s'} Q_{s's} X_{s'},
    \quad \dot m_s = A_s m_s + B_s w\, p_s + \sum_{s'} Q_{s's} m_{s'},

with :math:`m_s = E[\xi 1\{\theta=s\}]`, :math:`p = P(\theta = \cdot)`, :math:`\theta` the
state ``(true, fdi, phase)`` of the joint chain (:mod:`ftc_verify.model.chain`, ``n_states``
of them; :math:`Q` = :meth:`JointChain.generator` at the rate array ``beta``; the phases of
a detection share their loop matrices), and
:math:`E\int |z|^2 = \int \sum_s \operatorname{tr}(C_s X_s C_s^T)\,dt`. Both are folded into
*one* homogeneous jump-linear system by augmenting the state, so that the second-moment
generator of :mod:`ftc_verify.analysis.moments.stability` applies unchanged:

* a disturbance produced by an exosystem :math:`\dot\zeta = S\zeta`, :math:`w = c^T\zeta`
  (the paper's :math:`e^{-0.1t}\sin t`, steps, sines) gives
  :math:`\tilde\xi = (\xi, \zeta)`, :math:`\tilde A_s = [[A_s, B_s c^T], [0, S]]`;
* a piecewise-constant disturbance gives :math:`\tilde\xi = (\xi, 1)`,
  :math:`\tilde A_s = [[A_s, B_s w_k], [0, 0]]` on piece :math:`k`.

Then :math:`v(t) = \operatorname{vech}(\tilde X)(t) = e^{\mathcal{L} t} v_0`, and the energy
:math:`\ell^T \int_0^T e^{\mathcal{L}t} dt\, v_0` is the corner block of one matrix
exponential (Van Loan), exact to rounding; an infinite horizon uses
:math:`-\ell^T \mathcal{L}^{-1} v_0` when :math:`\mathcal{L}` is Hurwitz.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from ..closedloop import ClosedLoop
from ...errors import ValidationError
from ...model.system import Matrix
from .sampled_lower_ops import row_exponent
from .stability import abscissa_below, duplication_matrix, second_moment_generator

__all__ = [
    "EXOSYSTEMS",
    "ExactEnergy",
    "exact_energy",
    "output_blocks",
    "WorstCase",
    "worst_case_disturbance",
]

#: name -> (S, c, zeta0): w = c' zeta with zeta' = S zeta, zeta(0) = zeta0 (as ``paths.DISTURBANCES``)
EXOSYSTEMS: dict[str, tuple[Matrix, Matrix, Matrix]] = {
    "paper": (np.array([[-0.1, 1.0], [-1.0, -0.1]]), np.array([1.0, 0.0]), np.array([0.0, 1.0])),
    "zero": (-np.ones((1, 1)), np.zeros(1), np.zeros(1)),  # decaying, so infinite horizons work
    "step": (np.zeros((1, 1)), np.ones(1), np.ones(1)),
    "sine": (np.array([[0.0, 1.0], [-1.0, 0.0]]), np.array([1.0, 0.0]), np.array([0.0, 1.0])),
}


def _augmented(loop: ClosedLoop, extra: list[Matrix], top_right: list[Matrix]) -> ClosedLoop:
    """The loop with state ``(xi, eta)``: ``A = [[A_s, top_right[s]], [0, extra]]``."""
    A = []
    for s, As in enumerate(loop.A):
        k = extra[s].shape[0]
        A.append(np.block([[As, top_right[s]], [np.zeros((k, As.shape[0])), extra[s]]]))
    Cz = [np.hstack([C, np.zeros((C.shape[0], extra[0].shape[0]))]) for C in loop.Cz]
    Bw = [np.zeros((a.shape[0], 1)) for a in A]
    return ClosedLoop(loop.chain, tuple(A), tuple(Bw), tuple(Cz), tuple(() for _ in A), loop.controller)


def _energy_functional(loop: ClosedLoop) -> Matrix:
    """Row vector ``l`` with ``l @ vech-stack(X) = sum_s tr(C_s X_s C_s^T)``."""
    n = loop.n
    D, _ = duplication_matrix(n)
    return np.concatenate([(C.T @ C).reshape(-1, order="F") @ D for C in loop.Cz])


def _vech(X: Matrix) -> Matrix:
    n = X.shape[0]
    return np.concatenate([X[c:, c] for c in range(n)])


def output_blocks(L: Matrix, ell: Matrix, tau: float) -> tuple[Matrix, Matrix]:
    r""":math:`(e^{\mathcal L \tau}, \ell^T \int_0^\tau e^{\mathcal L s} ds)` from one
    exponential of size :math:`N + 1`, in balanced coordinates.

    With :math:`D` the diagonal of powers of two that balances :math:`\mathcal L`
    (``scipy.linalg.matrix_balance``, no permutation) and :math:`B = D^{-1}\mathcal L D`,
    :math:`e^{\mathcal L\tau} = D e^{B\tau} D^{-1}` and :math:`\ell^T\int_0^\tau e^{\mathcal
    L s}ds = (\ell^T D)\int_0^\tau e^{Bs}ds\, D^{-1}`; and
    :math:`\exp\big(\big[\begin{smallmatrix} 0 & 2^{-k} r^T \\ 0 & B\end{smallmatrix}\big]\tau\big)
    = \big[\begin{smallmatrix} 1 & 2^{-k} r^T \int_0^\tau e^{B s} ds \\ 0 & e^{B
    \tau}\end{smallmatrix}\big]` (differentiate in :math:`\tau`) for the row :math:`r^T =
    \ell^T D`, multiplied back by :math:`2^k`. Every scaling is a power of two, so exact; :math:`k`
    is :func:`~ftc_verify.analysis.moments.sampled_lower_ops.row_exponent`'s. Without them,
    loops in physical units lost digits: disturbances and outputs scaled by 1e6 put
    entries of very different sizes into :math:`\mathcal L` and the row, which set the
    exponential's squarings (the paper loop's sampled energy 1.7e-6 relative from the
    unscaled loop's; 1.4e-10 balanced)."""
    N = L.shape[0]
    d = (scipy.linalg.matrix_balance(L, permute=False, separate=True)[1][0] if np.all(np.isfinite(L))
         else np.ones(N))  # a non-finite generator: its blocks are not finite either
    B = L / d[:, None] * d[None, :]
    row = np.asarray(ell, dtype=float).reshape(-1) * d
    k = row_exponent(float(np.abs(row).sum()) * abs(tau), float(np.max(np.abs(B).sum(axis=1), initial=0.0)) * abs(tau))
    M = np.zeros((N + 1, N + 1))
    M[0, 1:], M[1:, 1:] = row * 2.0 ** -k, B
    E = scipy.linalg.expm(M * tau)
    return d[:, None] * E[1:, 1:] / d[None, :], E[0, 1:] * 2.0 ** k / d


def _propagate(L: Matrix, ell: Matrix, v0: Matrix, horizon: float) -> tuple[Matrix, float]:
    """``(v(T), int_0^T ell' v dt)`` with ``v' = L v`` exactly (:func:`output_blocks`)."""
    F, g = output_blocks(L, ell, horizon)
    return F @ v0, float(g @ v0)


@dataclass(frozen=True)
class ExactEnergy:
    """``E int_0^T |z|^2`` and ``int_0^T |w|^2`` for one disturbance, start and rate array."""

    y_energy: float
    w_energy: float
    horizon: float
    disturbance: str

    @property
    def ratio(self) -> float:
        """``E||z||^2 / ||w||^2``."""
        return self.y_energy / self.w_energy if self.w_energy > 0 else math.inf


def exact_energy(
    loop: ClosedLoop,
    *,
    beta: Matrix,
    disturbance: str = "paper",
    horizon: float = math.inf,
    x0: Matrix | None = None,
    start: tuple[int, int] = (0, 0),
) -> ExactEnergy:
    """Exact expected output energy for a named exosystem disturbance (module docstring).

    ``horizon=inf`` requires a Hurwitz augmented generator (mean-square stable loop and
    a decaying disturbance, e.g. ``paper``); each disturbance channel gets the same
    shape, as in :func:`ftc_verify.simulation.paths.disturbance`. Works on the nominal loop or one
    with a fixed ``Delta`` applied (``ClosedLoop`` built from ``perturbed`` matrices).
    ``beta`` is a rate array of the loop's chain (:meth:`JointChain.check_beta`: ``beta``,
    or ``[beta, false_alarm]``); ``start`` is the initial ``(true, fdi)``, at phase 0.

    The infinite horizon's condition, the augmented generator's spectral abscissa below
    ``-1e-10 max(1, max |L_ij|)``, is first shown (float64, with a rounding margin) by
    :func:`~ftc_verify.analysis.moments.stability.abscissa_below` (a Lyapunov stack
    checked by Cholesky factors); only where that test does not show it are the dense
    eigenvalues computed (the three-tank observer loop: 576 rows, 64 rate vertices, an
    eigenvalue problem each before).
    """
    if disturbance not in EXOSYSTEMS:
        raise ValidationError(f"disturbance: no exact model for {disturbance!r}; choose from {sorted(EXOSYSTEMS)}")
    if not (horizon > 0):
        raise ValidationError(f"horizon: must be positive, got {horizon!r}")
    beta = loop.chain.check_beta(beta)
    s0 = loop.chain.start_state(start)
    n = loop.n
    x_init = np.zeros(n) if x0 is None else np.asarray(x0, dtype=float).reshape(-1)
    if x_init.shape != (n,):
        raise ValidationError(f"x0: expected {n} entries, got {x_init.shape}")
    S, c, zeta0 = EXOSYSTEMS[disturbance]
    nw = loop.Bw[0].shape[1]
    # every disturbance channel is a copy of the scalar shape: one exosystem, w = 1 c' zeta
    aug = _augmented(loop, [S] * loop.chain.n_states, [Bw @ np.ones((nw, 1)) @ c[None, :] for Bw in loop.Bw])
    L = second_moment_generator(aug, beta)
    ell = _energy_functional(aug)
    xz = np.append(x_init, zeta0)
    size = aug.n * (aug.n + 1) // 2
    v = np.zeros(L.shape[0])
    v[s0 * size:(s0 + 1) * size] = _vech(np.outer(xz, xz))
    if math.isinf(horizon):
        # Hurwitz to a margin: shown by the float shift test (one solve and Cholesky factors), and
        # only where it does not show it, decided by the dense eigenvalues as before
        threshold = -1e-10 * max(1.0, float(np.max(np.abs(L))))
        if not abscissa_below(aug, beta, threshold) and np.max(np.linalg.eigvals(L).real) >= threshold:
            raise ValidationError(
                "horizon: an infinite horizon needs a mean-square stable loop and a decaying disturbance"
            )
        y_total = float(-ell @ np.linalg.solve(L, v))
    else:
        _, y_total = _propagate(L, ell, v, horizon)
    w_total = nw * _exo_energy(S, c, zeta0, horizon)
    return ExactEnergy(y_total, w_total, horizon, disturbance)


def _exo_energy(S: Matrix, c: Matrix, zeta0: Matrix, span: float) -> float:
    """``int_0^span (c' e^{S t} zeta0)^2 dt`` exactly (Lyapunov / Van Loan)."""
    q = S.shape[0]
    if math.isinf(span):
        W = scipy.linalg.solve_continuous_lyapunov(S.T, -np.outer(c, c))
        return float(zeta0 @ W @ zeta0)
    M = np.block([[-S.T, np.outer(c, c)], [np.zeros((q, q)), S]]) * span
    E = scipy.linalg.expm(M)
    W = E[q:, q:].T @ E[:q, q:]
    return float(zeta0 @ W @ zeta0)


@dataclass(frozen=True, eq=False)
class WorstCase:
    """Largest ``E||z||^2 / ||w||^2`` over piecewise-constant ``w`` on ``[0, T]`` (zero start).

    ``gain = sqrt(ratio)`` is a *lower bound* of the stochastic L2 gain of the loop (the
    supremum over all ``w`` in L2[0, inf)), so ``gain <= certified gamma`` must hold; the
    gap measures the conservatism of the LMI certificate. ``w`` has one row per piece.
    """

    ratio: float
    t: Matrix
    w: Matrix
    horizon: float
    pieces: int

    @property
    def gain(self) -> float:
        """``sqrt(ratio)``."""
        return math.sqrt(max(self.ratio, 0.0))


def worst_case_disturbance(
    loop: ClosedLoop,
    *,
    beta: Matrix,
    horizon: float = 30.0,
    pieces: int = 60,
    start: tuple[int, int] = (0, 0),
) -> WorstCase:
    r"""Maximise :math:`E\|z\|^2/\|w\|^2` over :math:`w` constant on ``pieces`` equal intervals.

    With a zero initial state, :math:`E\|z\|^2_{[0,T]} = w^T G w` is a quadratic form in the
    piece values (first moments are linear in :math:`w`, second moments quadratic). The
    state :math:`(\xi, 1)` with :math:`\tilde A_s = [[A_s, B_s w_k], [0, 0]]` carries the
    moment equations of the module docstring exactly across each piece, so every
    :math:`E\|z\|^2` is exact; :math:`G` follows by polarisation
    (:math:`G_{ab} = (E(e_a + e_b) - E(e_a) - E(e_b))/2`), all evaluations vectorised, and
    the maximiser is the top eigenvector of :math:`G`: ratio :math:`= \lambda_{max}(G) / h`.
    """
    if not (math.isfinite(horizon) and horizon > 0):
        raise ValidationError(f"horizon: must be a positive finite number, got {horizon!r}")
    if not (isinstance(pieces, int) and 1 <= pieces <= 400):
        raise ValidationError(f"pieces: must be an integer in 1..400, got {pieces!r}")
    beta = loop.chain.check_beta(beta)
    s0 = loop.chain.start_state(start)
    n = loop.n
    nw = loop.Bw[0].shape[1]
    h = horizon / pieces
    values = [np.zeros(nw)] + [np.eye(nw)[c] for c in range(nw)]
    pair_index = {}
    for c1 in range(nw):
        for c2 in range(c1 + 1, nw):
            pair_index[(c1, c2)] = len(values)
            values.append(np.eye(nw)[c1] + np.eye(nw)[c2])
    steps = []
    for wv in values:
        aug = _augmented(loop, [np.zeros((1, 1))] * loop.chain.n_states, [(Bw @ wv)[:, None] for Bw in loop.Bw])
        L = second_moment_generator(aug, beta)
        ell = _energy_functional(aug)
        size = L.shape[0]
        M = np.zeros((size + 1, size + 1))
        M[:size, :size] = L
        M[size, :size] = ell
        steps.append(scipy.linalg.expm(M * h))
    na = n + 1
    vsize = na * (na + 1) // 2
    v0 = np.zeros(steps[0].shape[0])
    e_last = np.zeros((na, na))
    e_last[n, n] = 1.0
    v0[s0 * vsize:(s0 + 1) * vsize] = _vech(e_last)
    basis = [(k, c) for k in range(pieces) for c in range(nw)]
    N = len(basis)
    cols: list[tuple[int, ...]] = [(a,) for a in range(N)] + [(a, b) for a in range(N) for b in range(a + 1, N)]
    # which precomputed step each column uses on each piece
    choice = np.zeros((pieces, len(cols)), dtype=np.int64)
    for j, col in enumerate(cols):
        for a in col:
            k, c = basis[a]
            if choice[k, j] == 0:
                choice[k, j] = 1 + c
            else:  # two channels on the same piece
                prev = choice[k, j] - 1
                choice[k, j] = pair_index[(min(prev, c), max(prev, c))]
    V = np.repeat(v0[:, None], len(cols), axis=1)
    for k in range(pieces):
        for idx in np.unique(choice[k]):
            sel = choice[k] == idx
            V[:, sel] = steps[idx] @ V[:, sel]
    energy = V[-1]
    single = energy[:N]
    G = np.diag(single)
    for j, col in enumerate(cols[N:], start=N):
        a, b = col
        G[a, b] = G[b, a] = 0.5 * (energy[j] - single[a] - single[b])
    eig, vec = np.linalg.eigh(G)
    top = vec[:, -1]
    w = np.zeros((pieces, nw))
    for a, (k, c) in enumerate(basis):
        w[k, c] = top[a]
    return WorstCase(float(eig[-1]) / h, np.linspace(0.0, horizon, pieces + 1), w, horizon, pieces)
