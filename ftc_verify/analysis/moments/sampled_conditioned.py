r"""The coordinates the sampled loop's stability proofs run in: a similarity with a ball inverse.

The one-period map :math:`T` of :mod:`~ftc_verify.analysis.moments.sampled` acts on the
second moments of :math:`\zeta = (x, x_c)`; a state similarity of condition
:math:`\kappa` in the user's model (states in badly scaled, mixed coordinates) makes the
moment space's condition about :math:`\kappa^2`, and every ball of the proofs
(:mod:`~ftc_verify.analysis.moments.sampled_proof`,
:mod:`~ftc_verify.analysis.moments.sampled_taylor`) is amplified by it: on the paper
loop moved by a similarity of condition 1e3 the ``h_max`` bracket was not proved, at
1e4 the verdict at 0.05 s was "undecided" (``benchmarks/results/h31r.md``).

**Invariance** (derived here). Take :math:`z = T_d \tilde z` on the augmented state
:math:`z = (x, u, x_c)` of the balanced coordinates (:attr:`SampledLoop.scale`) with
:math:`T_d` acting on :math:`(x, x_c)` as :math:`T_r` and on :math:`u` as a diagonal
(so :math:`P T_d = T_r P`). Then :math:`\tilde{\bar A}_s = T_d^{-1} \bar A_s T_d`,
:math:`\tilde R_s = T_d^{-1} R_s T_r`, the moments :math:`Z_s = T_d \tilde Z_s T_d^T`,
and the one-period map of the moved data is
:math:`\tilde T = \mathcal C^{-1} T \mathcal C` with :math:`\mathcal C = \operatorname
{blockdiag}_s L_r (T_r \otimes T_r) D_r` (congruence of each joint state's block):
the same spectrum at every rate, so stability and ``h_max`` are those of the loop as
written.

**Soundness does not depend on** :math:`T_d`. The proofs form the moved data in ball
arithmetic (:func:`ball_data`): :math:`T_d` an exact float matrix,
:math:`T_d^{-1}` Arb's ball inverse (containing the exact inverse), the written flows
and resets as the balls the proofs use without a similarity
(:func:`~ftc_verify.analysis.moments.sampled_proof.written_flow`,
:func:`~ftc_verify.analysis.moments.sampled_proof.ball_resets`). So each ball of
:math:`\tilde{\bar A}_s, \tilde R_s` contains the exact transform of the numbers as
written, and a proof for the moved loop is one for the written loop.

**Choice of** :math:`T_r` (a float choice). The proofs receive the sampled loop only, not
the system file's disturbance and output, so :func:`conditioned` takes the
:func:`~ftc_verify.analysis.conditioning.conditioning_transform` of the loop's own
continuous closed loop on :math:`(x, x_c)` (:math:`A_{cl,s} = P \bar A_s R_s(0) +
\bigl[\begin{smallmatrix} 0 & 0 \\ B_c M & A_c\end{smallmatrix}\bigr]`) with the
feedback's own input and output, :math:`B_w = [B_i; 0]`, :math:`C_z = [D_c M_i, C_c]`:
both transform with the state (:math:`B \to S B`, :math:`K \to K S^{-1}`), so the
balanced realisation undoes a similarity of the states, as
:func:`~ftc_verify.analysis.moments.sampled_frame.loop_similarity` does for the gain.
It is used when it is
:func:`~ftc_verify.analysis.moments.sampled_frame.usable` (the same rule: condition number
above :data:`~ftc_verify.analysis.moments.sampled_frame.CONDITION`, the condition of its
non-diagonal part below :data:`~ftc_verify.analysis.moments.sampled_frame.LIMIT`): a loop
written in good coordinates is proved as before, bit for bit; one in units ``1e-6`` and
``1e6`` (a transform of condition ``1e12``, all but a few units of it an exact diagonal)
is moved, as one in units ``1e-3`` and ``1e3`` was. Two diagonals of powers of two
(exact) follow the transform: its columns scaled to unit norm (the moved states of
comparable size: with the controller's states in units ``1e-3`` the transform's columns
were ``1e-3`` apart and the ``h_max`` bracket ``1e-2`` wide, ``8e-4`` in good units),
then the held input balanced against the moved states.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import scipy.linalg

from ...model.system import Matrix
from ..rigorous import Ball
from .sampled import SampledLoop

__all__ = ["ConditionedLoop", "conditioned", "moved_loop", "loop_transform", "ball_data", "written_data"]


@dataclass(frozen=True, eq=False)
class ConditionedLoop(SampledLoop):
    """A :class:`SampledLoop` in the coordinates :math:`z = T_d \\tilde z` of the module
    docstring: ``flow`` and :meth:`resets` are the moved float64 data (``scale`` all ones:
    the balancing is in ``T``), ``base`` the loop as built, ``T`` (``d x d``, exact floats)
    and ``T_inv`` its float inverse. Every float stage of
    :mod:`~ftc_verify.analysis.moments.sampled` runs on it unchanged; the ball proofs form
    its data by :func:`ball_data`."""

    base: SampledLoop | None = None
    T: Matrix | None = None
    T_inv: Matrix | None = None

    @property
    def T_r(self) -> Matrix:
        """:math:`T_r = P T_d P^T` on :math:`(x, x_c)`."""
        assert self.T is not None
        P = self.restriction()
        return np.asarray(P @ self.T @ P.T)

    def resets(self, h: float) -> tuple[Matrix, ...]:
        """:math:`T_d^{-1} R_s T_r` (float64) of the base loop's resets."""
        assert self.base is not None and self.T_inv is not None
        Tr = self.T_r
        return tuple(self.T_inv @ R @ Tr for R in self.base.resets(h))


def loop_transform(loop: SampledLoop) -> tuple[Matrix, Matrix] | None:
    """``(T_d, T_d^{-1})`` on the balanced augmented state of ``loop`` (module docstring), or
    ``None`` when the conditioning transform is not formed or not
    :func:`~ftc_verify.analysis.moments.sampled_frame.usable`."""
    from ...errors import FTCError
    from ..closedloop import ClosedLoop
    from ..conditioning import conditioning_transform
    from .sampled_frame import usable

    n, nu, d = loop.n, loop.nu, loop.d
    sc = loop.scale
    P = loop.restriction()
    idx = np.r_[0:n, n + nu:d]
    c = loop.controller
    A, Bw, Cz = [], [], []
    for flow, R, M, e in zip(loop.flow, loop.resets(0.0), loop.measurement, loop.entry):
        Ab = flow * sc[:, None] / sc[None, :]  # the user's coordinates (powers of two: exact)
        Ru = R * sc[:, None] / loop.scale_r[None, :]
        Acl = P @ Ab @ Ru
        if loop.nc:
            Acl[n:, :n] += c.Bc[e] @ M
            Acl[n:, n:] += c.Ac[e]
        A.append(Acl)
        Bw.append(np.vstack([Ab[:n, n:n + nu], np.zeros((loop.nc, nu))]))
        Cz.append(Ru[n:n + nu, :])
    if not all(np.all(np.isfinite(x)) for x in A + Bw + Cz):
        return None
    cl = ClosedLoop(loop.chain, tuple(A), tuple(Bw), tuple(Cz), tuple(() for _ in A), "sampled conditioning",
                    n if loop.nc else None)
    try:
        sim = conditioning_transform(cl)
    except (np.linalg.LinAlgError, ValueError, FTCError):
        return None
    if not usable(sim):
        return None
    T, T_inv = np.eye(d), np.eye(d)
    T[np.ix_(idx, idx)] = np.asarray(sim.T, dtype=float) / sc[idx][:, None]
    T_inv[np.ix_(idx, idx)] = np.asarray(sim.T_inv, dtype=float) * sc[idx][None, :]
    # powers of two: the moved states of comparable size (the transform's columns of unit norm;
    # exact): the transform chosen in units 1e-3 of x_c had columns 1e-3 apart, the bracket 1e-2 wide
    cols = 2.0 ** -np.round(np.log2(np.linalg.norm(T, axis=0)))
    T, T_inv = T * cols[None, :], T_inv / cols[:, None]
    # powers of two: the held input against the moved states (exact)
    pattern = np.eye(d)
    for flow, R in zip(loop.flow, loop.resets(0.0)):
        pattern += np.abs(T_inv @ flow @ T) + np.abs(T_inv @ R @ P @ T)
    if np.all(np.isfinite(pattern)):
        _, (found, _) = scipy.linalg.matrix_balance(pattern, permute=False, separate=True)
        T, T_inv = T * found[None, :], T_inv / found[:, None]
    return T, T_inv


def _ball_invertible(T: Matrix) -> bool:
    """Arb's inverse of the exact float ``T`` exists at 64 bits (then at every higher precision
    too: the proofs' retries)."""
    from ..rigorous import ball, precision

    try:
        with precision(64):
            ball(T).value.inv()
    except ZeroDivisionError:
        return False
    return True


def conditioned(loop: SampledLoop) -> SampledLoop:
    """``loop`` itself when its coordinates are good (:func:`loop_transform` ``None``), else
    the :class:`ConditionedLoop` of it; computed once per loop (kept in ``loop.memo``)."""
    if isinstance(loop, ConditionedLoop):
        return loop
    found = loop.memo.get("conditioned")
    if found is not None:
        return found
    pair = loop_transform(loop)
    out: SampledLoop = loop
    if pair is not None and not _ball_invertible(pair[0]):
        pair = None  # the proofs need a ball inverse: the loop as written
    if pair is not None:
        out = moved_loop(loop, *pair)
    loop.memo["conditioned"] = out
    return out


def moved_loop(loop: SampledLoop, T: Matrix, T_inv: Matrix) -> ConditionedLoop:
    """The :class:`ConditionedLoop` of ``loop`` in the coordinates :math:`z = T \tilde z`
    (``T`` acting on :math:`(x, x_c)` and diagonally on :math:`u`; ``T_inv`` its float
    inverse, used only for the float data)."""
    from .stability import second_moment_matrix

    flows = tuple(np.asarray(T_inv @ F @ T) for F in loop.flow)
    modes = second_moment_matrix(list(flows), np.zeros((loop.states, loop.states)))
    return ConditionedLoop(loop.chain, flows, loop.measurement, loop.entry, loop.controller, loop.n, loop.nu,
                           modes, np.ones(loop.d), loop.speed, loop.literals, loop.written, base=loop, T=T,
                           T_inv=T_inv)


def ball_data(loop: ConditionedLoop, flows: list[Any], resets: list[Any]) -> tuple[list[Any], list[Any]]:
    """The moved flows :math:`T_d^{-1} \\bar A_s T_d` and resets :math:`T_d^{-1} R_s T_r` as
    balls from the base loop's balls ``flows`` and ``resets`` (module docstring: ``T``
    exact, the inverse Arb's ball inverse at the working precision)."""
    from ..rigorous import ball

    assert loop.T is not None
    T = ball(loop.T)  # its ball inverse exists (checked by conditioned at 64 bits)
    T_inv = Ball(T.value.inv())  # raises ZeroDivisionError when T is not proved invertible
    Tr = ball(loop.T_r)
    return [T_inv @ F @ T for F in flows], [T_inv @ R @ Tr for R in resets]


def written_data(loop: SampledLoop, h: float) -> tuple[list[Ball], list[Ball]]:
    """The flows :math:`\\bar A_s` and resets :math:`R_s` of ``loop`` as balls of the numbers
    as written (:func:`~ftc_verify.analysis.moments.sampled_proof.written_flow`,
    :func:`~ftc_verify.analysis.moments.sampled_proof.ball_resets`); for a
    :class:`ConditionedLoop` those of its base loop moved by its similarity in ball
    arithmetic (:func:`ball_data`)."""
    from .sampled_proof import ball_resets, written_flow

    if isinstance(loop, ConditionedLoop) and loop.base is not None:
        base = loop.base  # the periods it was told were written: the conditioned loop's
        base = base if base.written == loop.written else replace(base, written=loop.written)
        return ball_data(loop, [written_flow(base, A) for A in base.flow], ball_resets(base, h))
    return [written_flow(loop, A) for A in loop.flow], ball_resets(loop, h)
