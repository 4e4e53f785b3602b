r"""The closed-loop representation every analysis runs on.

A :class:`ClosedLoop` is a linear jump system on the joint (true, FDI) chain: for each
joint mode :math:`s = (i, j)`

.. math::

    \dot\xi = \Bigl(A_s + \sum_k E_{s,k} \Delta_k F_{s,k}\Bigr)\xi + B_{w,s} w,
    \qquad z = C_{z,s} \xi, \qquad \|\Delta_k\| \le 1,

where the :math:`(E, F)` pairs are the norm-bounded uncertainty channels. For state
feedback :math:`u = K_j x` (paper eqs. (2), (13)):

.. math::

    A_s = A_i + B_i K_j,\quad (E, F) \in \{(A1_i, A2_i),\ (B1_i, B2_i K_j)\},\quad
    B_{w,s} = D_i,\quad C_{z,s} = C_i .

Dynamic output-feedback controllers build the same type with the augmented state.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from .errors import ValidationError
from .model import FTCSystem, JointChain, Matrix, as_matrix

__all__ = ["Channel", "ClosedLoop", "state_feedback_loop", "gain_loop"]


@dataclass(frozen=True, eq=False)
class Channel:
    """One norm-bounded uncertainty channel ``E Delta F`` with ``||Delta|| <= 1``."""

    E: Matrix
    F: Matrix
    name: str


@dataclass(frozen=True, eq=False)
class ClosedLoop:
    """Closed loop on the joint chain; per joint mode ``s = true * m + fdi``.

    Attributes
    ----------
    chain : JointChain
        The joint (true, FDI) chain and its rate bounds.
    A, Bw, Cz : tuple of arrays, one per joint mode
        Closed-loop state matrix, disturbance input and performance output.
    channels : tuple of tuples of :class:`Channel`, one per joint mode
        Uncertainty channels (empty for a nominal loop).
    controller : str
        What produced the loop (for reports).
    """

    chain: JointChain
    A: tuple[Matrix, ...]
    Bw: tuple[Matrix, ...]
    Cz: tuple[Matrix, ...]
    channels: tuple[tuple[Channel, ...], ...]
    controller: str = "state feedback"

    def __post_init__(self) -> None:
        count = self.chain.m ** 2
        for name in ("A", "Bw", "Cz", "channels"):
            if len(getattr(self, name)) != count:
                raise ValidationError(
                    f"ClosedLoop.{name}: expected {count} joint modes, got {len(getattr(self, name))}"
                )

    @property
    def n(self) -> int:
        """Closed-loop state dimension."""
        return int(self.A[0].shape[0])

    @property
    def modes(self) -> tuple[tuple[int, int], ...]:
        """Joint modes ``(true, fdi)``, 0-based, in index order."""
        return self.chain.joint_modes

    @property
    def uncertain(self) -> bool:
        """True when some joint mode has an uncertainty channel."""
        return any(self.channels)

    def nominal(self) -> "ClosedLoop":
        """The loop with every uncertainty channel removed (``Delta = 0``)."""
        return ClosedLoop(self.chain, self.A, self.Bw, self.Cz, tuple(() for _ in self.A), self.controller)

    def with_chain(self, chain: JointChain) -> "ClosedLoop":
        """The same loop on another chain with the same number of modes."""
        if chain.m != self.chain.m:
            raise ValidationError(f"with_chain: chain has {chain.m} modes, the loop {self.chain.m}")
        return ClosedLoop(chain, self.A, self.Bw, self.Cz, self.channels, self.controller)

    def perturbed(self, deltas: Mapping[str, Matrix]) -> tuple[Matrix, ...]:
        """State matrices ``A_s + sum_k E_k Delta_k F_k`` for given ``Delta`` per channel
        name (a channel missing from ``deltas`` stays at ``Delta = 0``)."""
        out = []
        for A, chans in zip(self.A, self.channels):
            M = A.copy()
            for ch in chans:
                if ch.name in deltas:
                    M = M + ch.E @ np.asarray(deltas[ch.name]) @ ch.F
            out.append(M)
        return tuple(out)


def state_feedback_loop(system: FTCSystem, gains: Sequence[Matrix], *, controller: str | None = None) -> ClosedLoop:
    """Closed loop of ``system`` under state feedback.

    ``gains`` has one ``nu x n`` matrix per FDI mode (``u = K[l_t] x``), or ``m * m``
    matrices indexed ``s = true * m + fdi`` for a full-information controller
    ``u = K[r_t, l_t] x`` (the Markov-jump baseline).
    """
    m = system.m
    n, nu, _, _ = system.dims
    if len(gains) not in (m, m * m):
        raise ValidationError(f"gains: expected {m} (FDI-mode) or {m * m} (full-information) matrices, got {len(gains)}")
    Ks = [as_matrix(K, f"gain[{k + 1}].K") for k, K in enumerate(gains)]
    for k, K in enumerate(Ks, start=1):
        if K.shape != (nu, n):
            raise ValidationError(f"gain[{k}].K: expected shape {(nu, n)} (nu x n), got {K.shape}")
    full_info = len(Ks) == m * m
    label = controller or ("full-information state feedback" if full_info else "FDI-mode state feedback")
    return gain_loop(system, Ks, label)


def gain_loop(system: FTCSystem, gains: Sequence[Any], controller: str) -> ClosedLoop:
    """Assemble the state-feedback loop from ``m`` (FDI-mode) or ``m * m`` gains, without
    validation, so that the gains may also be cvxpy expressions (synthesis LMIs)."""
    m = system.m
    full_info = len(gains) == m * m
    A, Bw, Cz, chans = [], [], [], []
    for i, j in system.chain.joint_modes:
        md = system.modes[i]
        K = gains[i * m + j] if full_info else gains[j]
        A.append(md.A + md.B @ K)
        Bw.append(md.D)
        Cz.append(md.C)
        c = []
        if md.A1 is not None and md.A2 is not None:
            c.append(Channel(md.A1, md.A2, "Delta1 (A)"))
        if md.B1 is not None and md.B2 is not None:
            c.append(Channel(md.B1, md.B2 @ K, "Delta2 (B)"))
        chans.append(tuple(c))
    return ClosedLoop(system.chain, tuple(A), tuple(Bw), tuple(Cz), tuple(chans), controller)
