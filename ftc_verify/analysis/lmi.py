r"""LMI blocks of the analysis conditions, assembled in one place.

The same functions build each block from cvxpy variables (solver path) and from the
numbers a solver returned (certificate path): they only use ``+``, ``@``, ``.T``,
scalar products and a ``bmat`` passed in (``cvxpy.bmat`` or :func:`numpy.block`).

For joint state :math:`s` of the chain of :mod:`ftc_verify.model.chain` (pair
:math:`(i, j)` = (true, FDI), and a detection phase) with generator row :math:`q_s`
(evaluated at one vertex of the few rates that the row contains), let

.. math::

    \Pi_s = A_s^T P_s + P_s A_s + \sum_{s'} q_{s s'} P_{s'} .

* Theorem 3.1 (mean-exponential stability): :math:`\Pi_s < 0` (paper eq. (4); the
  coupling sum reproduces both indicator cases, see :meth:`JointChain.generator`).
* Theorem 3.2 (nominal :math:`H_\infty`, :math:`g = \gamma^2`): the Schur form of
  eq. (12) with the output term moved into its own block,

  .. math::

      \begin{bmatrix} \Pi_s & P_s B_{w,s} & C_{z,s}^T \\ \cdot & -g I & 0 \\
      \cdot & \cdot & -I \end{bmatrix} < 0 .

* Lemma 4.1 (robust, gains fixed): eq. (16) with :math:`\lambda_{s,k} = \varepsilon^{-1}`
  (resp. :math:`\delta^{-1}`), since
  :math:`P E \Delta F + F^T \Delta^T E^T P \le \lambda F^T F + \lambda^{-1} P E E^T P`;
  by Schur complements

  .. math::

      \begin{bmatrix} \Pi_s + \sum_k \lambda_k F_k^T F_k & P_s E_1 & \cdots & P_s B_{w,s} & C_{z,s}^T \\
      \cdot & -\lambda_1 I & & & \\ & & \ddots & & \\ \cdot & & & -g I & \\
      \cdot & & & & -I \end{bmatrix} < 0,

  which is linear in :math:`(P, \lambda, g)` once the gains are fixed.

**Why these are the conditions for any joint chain** (re-derived for the richer FDI
model). Nothing above uses the paper's particular generator: with
:math:`V = \xi^T P_{\theta_t} \xi` and *any* generator :math:`Q` (off-diagonal rates
:math:`\ge 0`, rows summing to zero), Dynkin's formula gives
:math:`\frac{d}{dt} E[V] = E[\xi^T \Pi_{\theta_t} \xi]` (plus the :math:`w, z, \Delta`
terms of the :math:`H_\infty` and robust blocks), so the blocks hold *row by row*: the
block of state :math:`s` is all that is needed while the chain sits in :math:`s`, for
every initial state; irreducibility is never used. The phases of an Erlang delay are
states like any other (one :math:`P_s` each; the loop matrices of a pair repeat), a false
alarm is a transition out of a matched state.

**Covering the rate box.** Row :math:`s` of the generator depends affinely on few rates
(:meth:`JointChain.row_rates`: the :math:`\beta_{ji}` of a detection state, entering as
:math:`k \beta_{ji}`; the false-alarm rates out of :math:`i` for a matched state), and
each block is affine in row :math:`s`; so imposing it at every vertex of those rates
(:meth:`JointChain.row_rate_points`) covers the whole box (paper, Remark 3): with the
paper's model ``m + 2 m (m - 1)`` blocks instead of ``m**2 * 2**(m (m - 1))``. The
certificate is proved for the generator entries as floats (``k * beta`` rounded once
when ``k`` is not a power of two).

**Missed detections** (a vertex with :math:`\beta_{ji} = 0`). :math:`Q` is still a
generator there: the detection states of the pair :math:`(i, j)` have no exit except,
with ``fault_during_delay``, a new fault; without it the first phase of the pair (the one a
fault enters) is absorbing. The block of a detection state at :math:`\beta_{ji} = 0`
loses its detection coupling, :math:`\Pi_s = A_s^T P_s + P_s A_s` (plus the fault
coupling of the variant): :math:`P_s` must be a Lyapunov (resp. bounded
real, robust bounded real) certificate of the *frozen mismatched loop* (true mode
:math:`i` under the controller of FDI mode :math:`j`) on its own. So a certificate at
such a vertex means: the loop is mean-square stable, with the certified :math:`\gamma`,
even for an FDI that never detects that fault -- the mismatched loop held for ever after
it -- and, by the affine argument, for every detection rate in the interval, however
slow. A missed detection is not always certifiable: if the frozen mismatched loop is
unstable, so is the jump loop at that vertex (the absorbing block of the second-moment
generator is that loop's Lyapunov operator), and both the exact test and the LMIs say so.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

import scipy.linalg

from .closedloop import ClosedLoop
from ..model.system import Matrix, Mode

__all__ = [
    "BlockSpec",
    "block_specs",
    "lyapunov_block",
    "xy_block",
    "dilated_block",
    "null_basis",
    "projection",
    "BlockCheck",
    "Certificate",
    "check_certificate",
]

Bmat = Callable[[list[list[Any]]], Any]


@dataclass(frozen=True, eq=False)
class BlockSpec:
    """One LMI instance: joint state ``s`` (pair ``(true, fdi)``, detection ``phase`` of
    ``phases``) at one vertex ``beta`` of the rates that enter its generator row.

    ``beta`` is a rate array (shape :attr:`JointChain.rate_shape`: the rates of the row at
    that vertex, the others at the box's midpoint), ``q_row`` the generator row there,
    ``rates`` the row's rates at that vertex as :meth:`JointChain.row_label` writes them
    (empty when the row depends on no uncertain rate)."""

    s: int
    true: int
    fdi: int
    beta: Matrix
    q_row: Matrix
    rates: str = ""
    phase: int = 0
    phases: int = 1

    @property
    def label(self) -> str:
        """Human-readable name, 1-based modes as in the paper (with the paper's FDI model
        ``(true 1, fdi 2) beta[2][1]=2.5``)."""
        base = f"(true {self.true + 1}, fdi {self.fdi + 1}"
        base += f", phase {self.phase + 1}/{self.phases})" if self.phases > 1 and self.true != self.fdi else ")"
        return f"{base} {self.rates}" if self.rates else base


def block_specs(loop: ClosedLoop) -> tuple[BlockSpec, ...]:
    """All LMI instances that cover the rate box: every joint state at every vertex of
    the rates that enter its row (:meth:`JointChain.row_rate_points`)."""
    chain = loop.chain
    specs = []
    for s, (i, j, p) in enumerate(chain.states):
        for point in chain.row_rate_points(s):
            specs.append(BlockSpec(s, i, j, point, chain.row_generator(s, point), chain.row_label(s, point), p,
                                   chain.delay_phases))
    return tuple(specs)


def _bordered(first: list[Any], diag: list[Any], cols: list[int], bmat: Bmat) -> Any:
    """The symmetric block matrix ``[[X, b_1, ..., b_k], [b_1', d_1, 0], ..., [b_k', 0, d_k]]``
    from ``first = [X, b_1, ..., b_k]``, ``diag = [d_1, ..., d_k]`` of sizes ``cols``."""
    rows: list[list[Any]] = [first]
    for r, (c, d) in enumerate(zip(cols, diag)):
        row: list[Any] = [first[r + 1].T]
        for q, c2 in enumerate(cols):
            row.append(d if q == r else np.zeros((c, c2)))
        rows.append(row)
    return bmat(rows)


def _coupling(loop: ClosedLoop, spec: BlockSpec, P: Sequence[Any]) -> Any:
    r""":math:`\sum_t q_{st} P_t = \sum_{t \ne s} q_{st} (P_t - P_s)`: a generator row sums
    to zero, so this form uses the off-diagonal rates only (the float diagonal, their
    rounded negated sum, never enters the certificate). On ball matrices (the proof) the
    rates are the enclosures of :func:`~ftc_verify.analysis.exact.ball_generator`: the
    rates as the user wrote them."""
    from .rigorous import Ball

    s = spec.s
    total = 0 * P[s]
    if isinstance(P[s], Ball):
        from .exact import ball_generator, literals_of

        row = ball_generator(loop.chain, spec.beta, literals_of(loop))[s]
        for t, q in enumerate(spec.q_row):
            if t != s and q != 0.0:
                total = total + (P[t] - P[s]) * row[t]
        return total
    for t, q in enumerate(spec.q_row):
        if t != s and q != 0.0:
            total = total + float(q) * (P[t] - P[s])
    return total


def lyapunov_block(
    loop: ClosedLoop,
    spec: BlockSpec,
    P: Sequence[Any],
    lam: Sequence[Any] | None,
    g: Any | None,
    bmat: Bmat,
    *,
    schur_F: bool = False,
) -> Any:
    r"""The analysis block of ``spec`` (module docstring).

    ``g is None`` gives Theorem 3.1's block; ``lam is None`` drops the uncertainty
    channels (Theorem 3.2); both given give Lemma 4.1's block. ``lam`` holds one
    multiplier per channel of joint state ``spec.s``.

    ``schur_F=True`` writes each :math:`\lambda_k F_k^T F_k` term in Schur form, as an
    extra row :math:`[F_k \;\; 0 \cdots -\lambda_k^{-1} I]`; this is the same
    inequality, and it is linear in :math:`F_k` when :math:`F_k` depends on the gains
    (the gain step of eq. (18)); ``lam`` must then be numbers.
    """
    s = spec.s
    A, Ps = loop.A[s], P[s]
    pi = A.T @ Ps + Ps @ A + _coupling(loop, spec, P)
    if g is None:
        return pi
    chans = loop.channels[s] if lam is not None else ()
    Bw, Cz = loop.Bw[s], loop.Cz[s]
    if not schur_F:
        for k, ch in enumerate(chans):
            pi = pi + lam[k] * (ch.F.T @ ch.F)  # type: ignore[index]
    cols = [ch.E.shape[1] for ch in chans] + [Bw.shape[1], Cz.shape[0]]
    first = [pi] + [Ps @ ch.E for ch in chans] + [Ps @ Bw, Cz.T]
    diag = [-lam[k] * np.eye(c) for k, c in enumerate(cols[:-2])]  # type: ignore[index]
    diag += [-g * np.eye(cols[-2]), -np.eye(cols[-1])]
    if schur_F:
        for k, ch in enumerate(chans):
            cols.append(ch.F.shape[0])
            first.append(ch.F.T)
            diag.append(-(1.0 / float(lam[k])) * np.eye(ch.F.shape[0]))  # type: ignore[index]
    return _bordered(first, diag, cols, bmat)


def xy_block(
    mode: Mode,
    X: Sequence[Any],
    s: int,
    Y: Any | None,
    eps: Any,
    delta: Any,
    g: Any,
    q_row: Matrix | None,
    bmat: Bmat,
) -> Any:
    r"""Lemma 4.1's inequality for joint state ``s`` in :math:`X_s = P_s^{-1}`, :math:`Y_s = K X_s`.

    Derived here from eq. (16) by the congruence :math:`X_s (\cdot) X_s`, with
    :math:`\varepsilon = \lambda_1^{-1}`, :math:`\delta = \lambda_2^{-1}` and Schur
    complements; rows ``x | A2 | C | B2 | D | s'``:

    .. math::

        \begin{bmatrix}
        \Phi & X A_2^T & X C^T & Y^T B_2^T & D & \sqrt{q_{ss'}} X \\
        \cdot & -\varepsilon I &&&& \\ \cdot && -I &&& \\ \cdot &&& -\delta I && \\
        \cdot &&&& -g I & \\ \cdot &&&&& -X_{s'}
        \end{bmatrix} < 0, \quad
        \Phi = A_0 X + X A_0^T + B_0 Y + Y^T B_0^T + q_{ss} X + \varepsilon A_1 A_1^T
                + \delta B_1 B_1^T,

    where :math:`q_{ss} X + \sum_{s' \ne s} q_{ss'} X X_{s'}^{-1} X` is
    :math:`X (\sum_{s'} q_{ss'} P_{s'}) X` (the last column, one per :math:`q_{ss'} > 0`).
    ``Y = None`` drops the gain terms (for :func:`projection`); ``q_row = None`` drops
    all coupling (a common ``X`` for every mode, where it cancels since rows of ``Q``
    sum to zero). The paper's eq. (17) is this block projected (Theorem 4.1).
    """
    Xs = X[s]
    n = mode.n
    phi = mode.A @ Xs + Xs @ mode.A.T
    if Y is not None:
        phi = phi + mode.B @ Y + Y.T @ mode.B.T
    couple: list[tuple[float, Any]] = []
    if q_row is not None:
        phi = phi + float(q_row[s]) * Xs
        couple = [(float(q), X[t]) for t, q in enumerate(q_row) if t != s and q > 0]
    if mode.A1 is not None:
        phi = phi + eps * (mode.A1 @ mode.A1.T)
    if mode.B1 is not None:
        phi = phi + delta * (mode.B1 @ mode.B1.T)
    first: list[Any] = [phi]
    diag: list[Any] = []
    if mode.A1 is not None and mode.A2 is not None:
        first.append(Xs @ mode.A2.T)
        diag.append(-eps * np.eye(mode.A2.shape[0]))
    first.append(Xs @ mode.C.T)
    diag.append(-np.eye(mode.C.shape[0]))
    if mode.B2 is not None:
        q2 = mode.B2.shape[0]
        first.append(Y.T @ mode.B2.T if Y is not None else np.zeros((n, q2)))
        diag.append(-delta * np.eye(q2))
    first.append(mode.D)
    diag.append(-g * np.eye(mode.D.shape[1]))
    for q, Xt in couple:
        first.append(np.sqrt(q) * Xs)
        diag.append(-Xt)
    return _bordered(first, diag, [d.shape[0] for d in diag], bmat)


def dilated_block(mode: Mode, X: Sequence[Any], G: Any, s: int, Y: Any, eps: Any, delta: Any, g: Any,
                  q_row: Matrix, tau: Any, bmat: Bmat) -> Any:
    r""":func:`xy_block` dilated by a slack :math:`G` (S-variable form), gain :math:`K = Y G^{-1}`.

    :func:`xy_block` is :math:`R^T \Theta R < 0` with :math:`R = [[I, 0], [A_{cl}^T, H_K^T],
    [0, I]]`, :math:`\Theta = [[N, X, \ast], [X, 0, 0], [\ast, 0, -W]]` (``N``: the
    :math:`A_{cl}`-free part of :math:`\Phi`; :math:`H_K = B_2 K` the gain-dependent row,
    the other rows kept as in :func:`xy_block`). The columns of :math:`R` span
    :math:`\ker [A_{cl}^T, -I, H_K^T]`, so by Finsler's lemma it holds iff
    :math:`\Theta + \operatorname{He}(\mathcal G [A_{cl}^T, -I, H_K^T]) < 0` for some
    :math:`\mathcal G`; restricting :math:`\mathcal G = [G^T; \tau G^T; 0]` (sufficient;
    :math:`G = X` and a small :math:`\tau` recover the original) gives, rows
    ``x | x' | A2 | C | B2 | D | s'``,

    .. math::

        \begin{bmatrix}
        \Phi_G & X - G^T + \tau (A G + B Y) & X A_2^T & X C^T & Y^T B_2^T & D & \sqrt{q_{ss'}} X \\
        \cdot & -\tau (G + G^T) & 0 & 0 & \tau Y^T B_2^T & 0 & 0 \\
        \cdot & \cdot & -\varepsilon I &&&& \\ &&& -I &&& \\ &&&& -\delta I && \\
        &&&&& -g I & \\ &&&&&& -X_{s'}
        \end{bmatrix} < 0,

    :math:`\Phi_G = A G + G^T A^T + B Y + Y^T B^T + q_{ss} X + \varepsilon A_1 A_1^T +
    \delta B_1 B_1^T`, linear in :math:`(X, G, Y, \varepsilon, \delta, g)` for fixed
    :math:`\tau`. :math:`G, Y` may be shared by joint states (one per FDI mode) while
    every state keeps its own :math:`X_s` (de Oliveira--Skelton, Shaked dilations).
    """
    Xs, n = X[s], mode.n
    AG = mode.A @ G + mode.B @ Y
    phi = AG + AG.T + float(q_row[s]) * Xs
    if mode.A1 is not None:
        phi = phi + eps * (mode.A1 @ mode.A1.T)
    if mode.B1 is not None:
        phi = phi + delta * (mode.B1 @ mode.B1.T)
    top: list[Any] = [phi, Xs - G.T + tau * AG]
    mid: list[Any] = [None, -tau * (G + G.T)]
    diag: list[Any] = []
    if mode.A1 is not None and mode.A2 is not None:
        top.append(Xs @ mode.A2.T)
        mid.append(np.zeros((n, mode.A2.shape[0])))
        diag.append(-eps * np.eye(mode.A2.shape[0]))
    top.append(Xs @ mode.C.T)
    mid.append(np.zeros((n, mode.C.shape[0])))
    diag.append(-np.eye(mode.C.shape[0]))
    if mode.B2 is not None:
        top.append(Y.T @ mode.B2.T)
        mid.append(tau * (Y.T @ mode.B2.T))
        diag.append(-delta * np.eye(mode.B2.shape[0]))
    top.append(mode.D)
    mid.append(np.zeros((n, mode.D.shape[1])))
    diag.append(-g * np.eye(mode.D.shape[1]))
    for t, q in enumerate(q_row):
        if t != s and q > 0:
            top.append(np.sqrt(float(q)) * Xs)
            mid.append(np.zeros((n, n)))
            diag.append(-X[t])
    mid[0] = top[1].T
    sizes = [n, n] + [d.shape[0] for d in diag]
    rows: list[list[Any]] = [top, mid]
    for r, d in enumerate(diag):
        row: list[Any] = [top[r + 2].T, mid[r + 2].T]
        row += [d if q == r else np.zeros((sizes[r + 2], sizes[q + 2])) for q in range(len(diag))]
        rows.append(row)
    return bmat(rows)


def null_basis(mode: Mode) -> tuple[Matrix, Matrix | None]:
    """Orthonormal basis ``[W1; W2]`` of ``ker([B0' B2'])`` (``ker(B0')`` without a B
    channel), split into the ``x`` part ``W1`` and the ``B2`` part ``W2``."""
    n = mode.n
    M = mode.B.T if mode.B2 is None else np.hstack([mode.B.T, mode.B2.T])
    W = scipy.linalg.null_space(M)
    return W[:n], (None if mode.B2 is None else W[n:])


def projection(mode: Mode, coupled: int) -> Matrix:
    """The congruence ``N`` of Theorem 4.1: rows ``x | A2 | C | B2 | D | s'`` of
    :func:`xy_block`, columns ``z | A2 | C | D | s'``; the ``x`` and ``B2`` rows are
    ``W1 z`` and ``W2 z``. ``N' Psi N`` eliminates the gain by the projection lemma
    (the other projection, onto ``ker([I 0 ...])``, is negative by construction)."""
    W1, W2 = null_basis(mode)
    n, k = W1.shape
    sizes = []  # (rows, cols) of identity blocks after z
    if mode.A2 is not None:
        sizes.append(mode.A2.shape[0])
    sizes.append(mode.C.shape[0])
    q2 = 0 if mode.B2 is None else mode.B2.shape[0]
    tail = [mode.D.shape[1]] + [n] * coupled
    rows_total = n + sum(sizes) + q2 + sum(tail)
    cols_total = k + sum(sizes) + sum(tail)
    N = np.zeros((rows_total, cols_total))
    N[:n, :k] = W1
    r, c = n, k
    for size in sizes:
        N[r:r + size, c:c + size] = np.eye(size)
        r, c = r + size, c + size
    if W2 is not None:
        N[r:r + q2, :k] = W2
        r += q2
    for size in tail:
        N[r:r + size, c:c + size] = np.eye(size)
        r, c = r + size, c + size
    return N


@dataclass(frozen=True)
class BlockCheck:
    """One rebuilt block: the float screen and the proof.

    ``max_eig`` is the largest eigenvalue of the block in the conditioned coordinates
    after Jacobi scaling (``D^-1 M D^-1``, ``D = sqrt|diag M|``; a float64 diagnostic,
    negative for a candidate worth proving); ``ok`` means the block was *proved* negative
    definite in the original coordinates (ball arithmetic)."""

    label: str
    max_eig: float
    ok: bool


@dataclass(frozen=True)
class Certificate:
    """Independent check of an LMI answer.

    ``ok`` is true only if every block and every ``P_s`` was proved definite (negative,
    positive) in ball arithmetic at :data:`~ftc_verify.analysis.rigorous.PRECISION_BITS`
    bits, from the loop's float data and the answer taken as exact (module
    :mod:`ftc_verify.analysis.rigorous`): no margin, so none that fails to scale with the
    problem. ``p_max_condition`` is reported, not required (physical units make large
    condition numbers legitimate).
    """

    ok: bool
    condition: str
    blocks: tuple[BlockCheck, ...]
    p_min_eig: float
    p_max_condition: float
    gamma: float | None
    proved: str = ""

    @property
    def worst_margin(self) -> float:
        """Smallest ``-max_eig`` over the (Jacobi-scaled, float) blocks; positive = strictly feasible."""
        return min(-b.max_eig for b in self.blocks)

    @property
    def reason(self) -> str:
        """Why the check failed (empty when it passed)."""
        if self.ok:
            return ""
        bad = [b.label for b in self.blocks if b.max_eig >= 0]
        parts = []
        if bad:
            parts.append(f"blocks not negative definite: {', '.join(bad[:4])}")
        if self.p_min_eig <= 0:
            parts.append(f"P not positive definite (min eig {self.p_min_eig:.3g})")
        if not parts:
            parts.append(self.proved or "not proved in ball arithmetic")
        return "; ".join(parts)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary."""
        worst = max(self.blocks, key=lambda b: b.max_eig)
        return {
            "ok": self.ok,
            "condition": self.condition,
            "blocks": len(self.blocks),
            "worst_block": worst.label,
            "worst_max_eig": worst.max_eig,
            "worst_margin": self.worst_margin,
            "p_min_eig": self.p_min_eig,
            "p_max_condition": self.p_max_condition,
            "gamma": self.gamma,
            "proved": self.proved,
            "reason": self.reason,
        }


def _jacobi_max_eig(M: Matrix) -> float:
    """Largest eigenvalue of ``D^-1 M D^-1``, ``D = sqrt|diag M|`` (``inf`` if not finite)."""
    M = 0.5 * (M + M.T)
    d = np.sqrt(np.abs(np.diag(M)))
    d[d == 0] = 1.0
    S = M / d[:, None] / d[None, :]
    if not np.all(np.isfinite(S)):
        return math.inf
    return float(np.linalg.eigvalsh(S)[-1])


def check_certificate(
    loop: ClosedLoop,
    condition: str,
    P: Sequence[Matrix],
    lam: Sequence[Sequence[float]] | None,
    g: float | None,
    *,
    similarity: Any = None,
) -> Certificate:
    r"""Rebuild every block of ``condition`` from numbers and prove it.

    ``condition`` is a label (``"theorem-3.1"``, ``"theorem-3.2"``, ``"lemma-4.1"``);
    the arguments select the block as in :func:`lyapunov_block`. ``P`` are the Lyapunov
    matrices in the coordinates of ``similarity`` (a
    :class:`~ftc_verify.analysis.conditioning.Similarity`; the original coordinates when
    ``None``): the certificate is :math:`P_s^{orig} = T^{-T} P_s T^{-1}` (with the float
    ``T_inv`` as given, formed exactly in ball arithmetic).

    1. Float screen, in the conditioned coordinates: every Jacobi-scaled block has a
       negative largest eigenvalue and every ``P_s`` a positive smallest one.
    2. Proof, in the original coordinates: every block :math:`M(P^{orig})` rebuilt by
       :func:`lyapunov_block` on ball matrices, and :math:`-M` and every
       :math:`P^{orig}_s` proved positive definite, on the loop formed in ball arithmetic
       from the numbers the user wrote (:func:`~ftc_verify.analysis.exact.exact_loop`)
       (:func:`~ftc_verify.analysis.rigorous.proven_positive_definite`, preconditioned by
       :math:`T` on the state rows). The coupling uses the off-diagonal rates of
       :meth:`~ftc_verify.model.chain.JointChain.row_generator` only (``_coupling``).
    """
    from .exact import exact_loop
    from .rigorous import ball, ball_bmat, precision, proven_positive_definite

    T = np.eye(loop.n) if similarity is None else similarity.T
    T_inv = np.eye(loop.n) if similarity is None else similarity.T_inv
    conditioned = loop if similarity is None else similarity.apply(loop)
    Pn = [0.5 * (np.asarray(p, dtype=float) + np.asarray(p, dtype=float).T) for p in P]
    specs = block_specs(loop)
    screen = []
    for spec in specs:
        lam_s = None if lam is None else [float(v) for v in lam[spec.s]]
        M = np.asarray(lyapunov_block(conditioned, spec, Pn, lam_s, g, np.block), dtype=float)
        screen.append(_jacobi_max_eig(M))
    p_min, p_cond = math.inf, 0.0
    for p in Pn:
        ev = np.linalg.eigvalsh(p) if np.all(np.isfinite(p)) else np.array([-math.inf, math.inf])
        p_min = min(p_min, float(ev[0]))
        p_cond = max(p_cond, float(ev[-1] / ev[0]) if ev[0] > 0 else math.inf)
    proved = [False] * len(specs)
    note = "float screen failed: not proved"
    if p_min > 0 and all(e < 0 for e in screen):
        with precision():
            original = exact_loop(loop)
            S = ball(T_inv)
            Pb = [S.T @ ball(p) @ S for p in Pn]
            p_ok = all(proven_positive_definite(p, T) for p in Pb)
            for k, spec in enumerate(specs):
                lam_s = None if lam is None else [float(v) for v in lam[spec.s]]
                M = lyapunov_block(original, spec, Pb, lam_s, g, ball_bmat)
                C = np.eye(M.shape[0])
                C[:loop.n, :loop.n] = T
                proved[k] = p_ok and proven_positive_definite(-M, C)
        note = ("every block and P_s proved definite in 128-bit ball arithmetic" if all(proved)
                else ("P_s not proved positive definite" if not p_ok else "a block not proved negative definite"))
    checks = tuple(BlockCheck(spec.label, e, ok) for spec, e, ok in zip(specs, screen, proved))
    gamma = None if g is None else math.sqrt(max(g, 0.0))
    return Certificate(all(proved), condition, checks, p_min, p_cond, gamma, note)
