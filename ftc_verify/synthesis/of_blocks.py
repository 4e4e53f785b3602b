r"""The blocks of output-feedback synthesis: the augmented plant and the controller's blocks.

A dynamic controller with FDI-mode entries :math:`(\hat A_j, \hat B_j, \hat C_j, \hat D_j)`
is the static gain :math:`\mathcal K_j = [[\hat A_j, \hat B_j], [\hat C_j, \hat D_j]]` of
the augmented plant (state :math:`(x, x_c)`, input :math:`(\dot x_c, u)`) through
:math:`\bar C_i` (the barred matrices of :mod:`ftc_verify.analysis.closedloop`, the
paper's Section V); :mod:`ftc_verify.synthesis.output_feedback` designs on it. Here: the
augmented plant, the conversions between controllers and blocks, the observer-based
controllers of the baseline and the scaling of blocks onto a gain bound.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..analysis.closedloop import barred
from ..controllers.controller import Controller
from ..model.system import FTCSystem, Matrix, Mode
from .starts import lqr_gain

__all__ = ["OBSERVER_SCALES", "augmented_system", "bounded_blocks", "controller_from_blocks", "controller_blocks",
           "observer_designs"]

#: Observer Riccati input weights (the scale search of the baseline).
OBSERVER_SCALES = (1e-2, 1.0, 1e2)


def augmented_system(system: FTCSystem, n_c: int | None = None) -> tuple[FTCSystem, list[Matrix]]:
    """The augmented plant of the module docstring and the :math:`\\bar C_i` per true mode.

    Its modes are ``A = A0bar``, ``B = B0bar``, ``C = C1bar``, ``D = Dbar`` and the two
    channels ``(A1bar[:, :p1], A2bar[:q1])``, ``(A1bar[:, p1:], B2bar[q1:])``: state
    feedback ``ubar = G xbar`` on it is the loop of
    :func:`~ftc_verify.analysis.closedloop.closed_loop` when ``G = K_j Cbar_i``. ``n_c``: the
    controller order (default ``n``)."""
    n = system.dims[0] if n_c is None else n_c
    modes, cbars = [], []
    for md in system.modes:
        bar = barred(md, md.measured, n)
        entries: dict[str, Any] = dict(A=bar.A0bar, B=bar.B0bar, C=bar.C1bar, D=bar.Dbar)
        if bar.A1bar is not None and bar.A2bar is not None and bar.B2bar is not None:
            k = bar.split
            qa = 0 if md.A2 is None else md.A2.shape[0]
            if md.A1 is not None:
                entries |= dict(A1=bar.A1bar[:, :k], A2=bar.A2bar[:qa])
            if md.B1 is not None:
                entries |= dict(B1=bar.A1bar[:, k:], B2=bar.B2bar[qa:])
        modes.append(Mode(**entries))
        cbars.append(bar.Cbar)
    return FTCSystem(f"{system.name} (augmented)", tuple(modes), system.chain), cbars


def controller_from_blocks(system: FTCSystem, blocks: list[Matrix], name: str) -> Controller:
    """The dynamic controller whose FDI-mode entries are the blocks ``K_j`` (module docstring);
    its order is read from the blocks (``rows - inputs``: 0 for static output feedback)."""
    n = blocks[0].shape[0] - system.dims[1]
    return Controller.dynamic([K[:n, :n] for K in blocks], [K[:n, n:] for K in blocks],
                              [K[n:, :n] for K in blocks], [K[n:, n:] for K in blocks], name=name)


def controller_blocks(controller: Controller) -> list[Matrix]:
    """The blocks ``K_j = [[Ac_j, Bc_j], [Cc_j, Dc_j]]`` of ``controller``, one per entry
    (the inverse of :func:`controller_from_blocks`)."""
    return [np.block([[a, b], [c, d]]) for a, b, c, d in zip(controller.Ac, controller.Bc, controller.Cc,
                                                              controller.Dc)]


def observer_designs(system: FTCSystem, gains: list[Matrix]) -> list[tuple[str, Controller]]:
    """The observer-based controllers of the module docstring for state-feedback ``gains``
    (one per FDI mode), one per observer weight; none where the dual Riccati equation has
    no stabilising solution."""
    out = []
    for rho in OBSERVER_SCALES:
        blocks = []
        for md, K in zip(system.modes, gains):
            Cy = md.measured
            Q = md.D @ md.D.T + 1e-2 * np.eye(md.n)
            Kd = lqr_gain(md.A.T, Cy.T, Q, rho * np.eye(Cy.shape[0]))
            if Kd is None:
                break
            L = Kd.T
            blocks.append(np.block([[md.A + md.B @ K + L @ Cy, -L], [K, np.zeros((K.shape[0], Cy.shape[0]))]]))
        else:
            out.append((f"observer rho={rho:g}", controller_from_blocks(system, blocks, f"observer rho={rho:g}")))
    return out


def bounded_blocks(blocks: list[Matrix], k_max: float | None) -> tuple[list[Matrix], bool]:
    r"""Each block with :math:`\|K_j\|_2 > k_{max}` scaled onto the bound (the norm of
    :func:`~ftc_verify.synthesis.hinf_descent.within_bound`, as the state-feedback starts
    are scaled), so that the computed norm is at most ``k_max``; whether any was."""
    if k_max is None:
        return list(blocks), False
    out, scaled = [], False
    for K in blocks:
        norm = float(np.linalg.norm(K, 2))
        while norm > k_max:
            K, scaled = K * (k_max / norm * (1.0 - 1e-12)), True
            norm = float(np.linalg.norm(K, 2))
        out.append(K)
    return out, scaled
