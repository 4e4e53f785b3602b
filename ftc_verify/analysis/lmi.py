r"""LMI blocks of the analysis conditions, assembled in one place.

The same functions build each block from cvxpy variables (solver path) and from the
numbers a solver returned (certificate path): they only use ``+``, ``@``, ``.T``,
scalar products and a ``bmat`` passed in (``cvxpy.bmat`` or :func:`numpy.block`).

For joint mode :math:`s = (i, j)` with generator row :math:`q_s` (evaluated at one end
of the only rate, :math:`\beta_{ji}`, that the row contains), let

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

Each block depends on one rate :math:`\beta_{ji}` affinely, so imposing it at both
interval ends covers the whole ``beta`` box (paper, Remark 3) with ``m + 2 m (m - 1)``
blocks instead of ``m**2 * 2**(m (m - 1))``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

import scipy.linalg

from ..analysis.closedloop import ClosedLoop
from ..model.system import Matrix, Mode

__all__ = [
    "CERT_RTOL",
    "MAX_CONDITION",
    "BlockSpec",
    "block_specs",
    "lyapunov_block",
    "xy_block",
    "null_basis",
    "projection",
    "BlockCheck",
    "Certificate",
    "check_certificate",
]

#: A block passes when ``max eig <= -CERT_RTOL * max(1, ||block||_2)``.
CERT_RTOL = 1e-8
#: Largest accepted condition number of each Lyapunov matrix ``P_s``.
MAX_CONDITION = 1e8

Bmat = Callable[[list[list[Any]]], Any]


@dataclass(frozen=True, eq=False)
class BlockSpec:
    """One LMI instance: joint mode ``s = (true, fdi)`` at one end ``beta`` of its rate."""

    s: int
    true: int
    fdi: int
    beta: float  # value of beta[fdi, true]; nan on diagonal modes (row independent of beta)
    q_row: Matrix

    @property
    def label(self) -> str:
        """Human-readable name, 1-based modes as in the paper."""
        base = f"(true {self.true + 1}, fdi {self.fdi + 1})"
        return base if math.isnan(self.beta) else f"{base} beta[{self.fdi + 1}][{self.true + 1}]={self.beta:g}"


def block_specs(loop: ClosedLoop) -> tuple[BlockSpec, ...]:
    """All LMI instances that cover the ``beta`` box (both ends of each row's rate)."""
    chain = loop.chain
    specs = []
    for s, (i, j) in enumerate(chain.joint_modes):
        for b in chain.row_beta_ends(i, j):
            specs.append(BlockSpec(s, i, j, b, chain.row_generator(i, j, 0.0 if math.isnan(b) else b)))
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


def _coupling(q_row: Matrix, P: Sequence[Any], s: int) -> Any:
    total = 0 * P[s]
    for t, q in enumerate(q_row):
        if q != 0.0:
            total = total + float(q) * P[t]
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
    multiplier per channel of joint mode ``spec.s``.

    ``schur_F=True`` writes each :math:`\lambda_k F_k^T F_k` term in Schur form, as an
    extra row :math:`[F_k \;\; 0 \cdots -\lambda_k^{-1} I]`; this is the same
    inequality, and it is linear in :math:`F_k` when :math:`F_k` depends on the gains
    (the gain step of eq. (18)); ``lam`` must then be numbers.
    """
    s = spec.s
    A, Ps = loop.A[s], P[s]
    pi = A.T @ Ps + Ps @ A + _coupling(spec.q_row, P, s)
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
    eps: Any | None,
    delta: Any | None,
    g: Any,
    q_row: Matrix | None,
    bmat: Bmat,
) -> Any:
    r"""Lemma 4.1's inequality for joint mode ``s`` in :math:`X_s = P_s^{-1}`, :math:`Y_s = K X_s`.

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
    """Largest eigenvalue of one rebuilt block and the margin it had to beat."""

    label: str
    max_eig: float
    scale: float
    ok: bool


@dataclass(frozen=True)
class Certificate:
    """Independent numpy check of an LMI answer.

    ``ok`` is true only if every block's largest eigenvalue is below
    ``-CERT_RTOL * max(1, ||block||_2)`` and every ``P_s`` is positive definite with
    ``cond(P_s) <= MAX_CONDITION``.
    """

    ok: bool
    condition: str
    blocks: tuple[BlockCheck, ...]
    p_min_eig: float
    p_max_condition: float
    gamma: float | None
    rtol: float = CERT_RTOL
    max_condition: float = MAX_CONDITION

    @property
    def worst_margin(self) -> float:
        """Smallest ``-max_eig / scale`` over the blocks (positive = strictly feasible)."""
        return min(-b.max_eig / b.scale for b in self.blocks)

    @property
    def reason(self) -> str:
        """Why the check failed (empty when it passed)."""
        bad = [b.label for b in self.blocks if not b.ok]
        parts = []
        if bad:
            parts.append(f"blocks not negative definite with margin: {', '.join(bad[:4])}")
        if self.p_min_eig <= 0 or self.p_max_condition > self.max_condition:
            parts.append(f"P not well-conditioned positive definite (min eig {self.p_min_eig:.3g}, cond {self.p_max_condition:.3g})")
        return "; ".join(parts)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary."""
        worst = min(self.blocks, key=lambda b: -b.max_eig / b.scale)
        return {
            "ok": self.ok,
            "condition": self.condition,
            "blocks": len(self.blocks),
            "worst_block": worst.label,
            "worst_max_eig": worst.max_eig,
            "worst_margin": self.worst_margin,
            "p_min_eig": self.p_min_eig,
            "p_max_condition": self.p_max_condition,
            "rtol": self.rtol,
            "gamma": self.gamma,
            "reason": self.reason,
        }


def check_certificate(
    loop: ClosedLoop,
    condition: str,
    P: Sequence[Matrix],
    lam: Sequence[Sequence[float]] | None,
    g: float | None,
) -> Certificate:
    """Rebuild every block of ``condition`` from numbers and check it with numpy.

    ``condition`` is a label (``"theorem-3.1"``, ``"theorem-3.2"``, ``"lemma-4.1"``);
    the arguments select the block as in :func:`lyapunov_block`.
    """
    Pn = [0.5 * (np.asarray(p, dtype=float) + np.asarray(p, dtype=float).T) for p in P]
    checks = []
    for spec in block_specs(loop):
        lam_s = None if lam is None else [float(v) for v in lam[spec.s]]
        M = np.asarray(lyapunov_block(loop, spec, Pn, lam_s, g, np.block), dtype=float)
        M = 0.5 * (M + M.T)
        eig = np.linalg.eigvalsh(M)
        scale = max(1.0, float(np.max(np.abs(eig))))
        checks.append(BlockCheck(spec.label, float(eig[-1]), scale, bool(eig[-1] <= -CERT_RTOL * scale)))
    p_min, p_cond, p_ok = math.inf, 0.0, True
    for p in Pn:
        ev = np.linalg.eigvalsh(p)
        p_min = min(p_min, float(ev[0]))
        cond = float(ev[-1] / ev[0]) if ev[0] > 0 else math.inf
        p_cond = max(p_cond, cond)
        p_ok &= bool(ev[0] > 0 and cond <= MAX_CONDITION)
    ok = p_ok and all(c.ok for c in checks)
    gamma = None if g is None else math.sqrt(max(g, 0.0))
    return Certificate(ok, condition, tuple(checks), p_min, p_cond, gamma)
