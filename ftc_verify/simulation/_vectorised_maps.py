r"""One-step maps of the sampled-data loop on the augmented state (for the energies).

With the augmented state :math:`z = (x, x_c)` (:math:`n_z = n + n_c`), an interval of
length :math:`h` in dynamics id :math:`d` (a joint mode :math:`(i, j)` with one
:math:`\Delta` value, controller entry :math:`e`) is the affine map
:math:`z \mapsto F z + G w` (module :mod:`ftc_verify.simulation.reference`):

.. math::

    F = \begin{bmatrix} \Phi + \Gamma B D_{c,e} M_i & \Gamma B C_{c,e} \\
                        \Gamma_c M_i & \Phi_c \end{bmatrix}, \qquad
    G = \begin{bmatrix} \Gamma D_i \\ 0 \end{bmatrix},

with :math:`\Phi, \Gamma` of the perturbed :math:`A` of true mode :math:`i` and
:math:`\Phi_c, \Gamma_c` of the controller entry (:mod:`ftc_verify.simulation.discretise`).
The tables keep :math:`BK = [B D_{c,e} M_i,\; B C_{c,e}]` (``n x n_z``), so that the top
block row is :math:`[\Phi, 0] + \Gamma\, BK`; the performance output is
:math:`y = [C_i,\ 0]\, z`. For static state feedback (:math:`n_c = 0`, :math:`M_i = I`)
this is :math:`F = \Phi + \Gamma B K_j`, :math:`G = \Gamma D_i`, computed as before.
These maps are those of a whole interval that starts at a control sample; the pieces of a
period cut by jumps, with the controller's output held, are :func:`held_maps`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..controllers.controller import Controller
from ..model.system import FTCSystem
from . import discretise
from .delta import delta_shapes
from .discretise import controller_zoh, one_norms, phi_gamma, taylor_series

__all__ = ["Tables", "tables", "loop_matrices", "held_maps", "full_maps"]


@dataclass(frozen=True)
class Tables:
    """Per dynamics id ``d`` (a joint mode with one ``Delta`` value) and per state-matrix
    id ``a`` (a true mode with one ``Delta1`` value) the matrices of the loop."""

    A: np.ndarray  # (Ga, n, n) perturbed state matrices
    d_a: np.ndarray  # (Dn,) state-matrix id of each dynamics id
    d_true: np.ndarray  # (Dn,) true mode of each dynamics id
    d_entry: np.ndarray  # (Dn,) controller entry of each dynamics id
    BK: np.ndarray  # (Dn, n, nz) perturbed B times [Dc M, Cc]
    Bd: np.ndarray  # (Dn, n, nu) perturbed B
    K: np.ndarray  # (Dn, nu, nz) [Dc M, Cc] of the id's controller entry
    Dm: np.ndarray  # (Dn, n, nw)
    Cz: np.ndarray  # (m, ny, nz) performance output [C_i, 0]
    M: np.ndarray  # (m, nv, n) measurement of each true mode
    controller: Controller

    @property
    def n(self) -> int:
        """Plant states."""
        return int(self.A.shape[1])

    @property
    def nz(self) -> int:
        """Augmented states ``n + n_c``."""
        return int(self.BK.shape[2])


def _stacked_channels(system: FTCSystem) -> tuple[np.ndarray | None, ...]:
    """Uncertainty weights stacked over modes (zeros where a mode lacks a channel)."""
    s1, s2 = delta_shapes(system)
    n, nu, _, _ = system.dims
    out: list[np.ndarray | None] = []
    for shape, left, right, width in ((s1, "A1", "A2", n), (s2, "B1", "B2", nu)):
        if shape is None:
            out += [None, None]
            continue
        L = np.zeros((system.m, n, shape[0]))
        R = np.zeros((system.m, shape[1], width))
        for i, md in enumerate(system.modes):
            if getattr(md, left) is not None:
                L[i], R[i] = getattr(md, left), getattr(md, right)
        out += [L, R]
    return tuple(out)


def _input_maps(system: FTCSystem, controller: Controller, d_true: np.ndarray, d_fdi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(K, entry, M)``: ``K = [Dc M, Cc]`` per dynamics id, its controller entry and
    the stacked measurements."""
    m = system.m
    entry = d_true * m + d_fdi if controller.full_information(m) else d_fdi
    M = np.stack([controller.measurement(md) for md in system.modes])
    Dc = np.stack(controller.Dc)[entry]
    K = Dc if controller.measures == "state" else Dc @ M[d_true]
    if controller.n_c:
        K = np.concatenate((K, np.stack(controller.Cc)[entry]), axis=2)
    return K, entry, M


def tables(system: FTCSystem, controller: Controller, a_true: np.ndarray, a_d1: np.ndarray | None,
           d_true: np.ndarray, d_fdi: np.ndarray, d_d2: np.ndarray | None, d_a: np.ndarray) -> Tables:
    """Batched perturbed matrices (eq. (13)): ``a`` entries ``(true, Delta1)`` and ``d``
    entries ``(true, fdi, Delta2)``; ``d_a`` maps each ``d`` to its ``a``."""
    A1, A2, B1, B2 = _stacked_channels(system)
    Am = np.stack([md.A for md in system.modes])
    Bm = np.stack([md.B for md in system.modes])
    Dm = np.stack([md.D for md in system.modes])
    A = Am[a_true].copy()
    if A1 is not None and A2 is not None and a_d1 is not None:
        A += A1[a_true] @ a_d1 @ A2[a_true]
    B = Bm[d_true].copy()
    if B1 is not None and B2 is not None and d_d2 is not None:
        B += B1[d_true] @ d_d2 @ B2[d_true]
    K, entry, M = _input_maps(system, controller, d_true, d_fdi)
    Cz = np.stack([md.C for md in system.modes])
    if controller.n_c:
        Cz = np.concatenate((Cz, np.zeros(Cz.shape[:2] + (controller.n_c,))), axis=2)
    return Tables(A, d_a, d_true, entry, B @ K, B, K, Dm[d_true], Cz, M, controller)


def _controller_rows(tab: Tables, d: np.ndarray, h: np.ndarray, F: np.ndarray) -> None:
    r"""Fill the bottom block row :math:`[\Gamma_c M_i,\ \Phi_c]` of ``F`` (if ``n_c > 0``)."""
    n = tab.n
    if tab.nz == n:
        return
    Phic, Gamc = controller_zoh(tab.controller, tab.d_entry[d], h)
    F[:, n:, :n] = Gamc @ tab.M[tab.d_true[d]]
    F[:, n:, n:] = Phic


def _affine(GD: np.ndarray, wvals: np.ndarray) -> np.ndarray:
    """``GD w`` per interval (``(N, n, nw) x (N, nw)``)."""
    return GD[:, :, 0] * wvals[:, 0:1] if GD.shape[2] == 1 else np.einsum("pij,pj->pi", GD, wvals)


def _grouped_plant(tab: Tables, d: np.ndarray, h: np.ndarray, wvals: np.ndarray, used: np.ndarray,
                   F: np.ndarray, g: np.ndarray) -> None:
    r"""Top rows of ``F`` and ``g`` per dynamics id: without squaring straight from the
    Taylor data of :func:`taylor_series`, :math:`F = R_\Phi P + R_\Gamma (P\, BK)`,
    :math:`g = (R_\Gamma (P D)) w` with the stacked powers ``P`` (two matrix products)."""
    n, nz = tab.n, tab.nz
    nw = tab.Dm.shape[2]
    norms = one_norms(tab.A)
    for dd in used:
        idx = np.flatnonzero(d == dd) if used.size > 1 else slice(None)
        a = int(tab.d_a[dd])
        s, powers, Rphi, Rgam = taylor_series(tab.A[a], h[idx], float(norms[a]))
        q1 = powers.shape[0]
        if s == 0:
            top = (Rgam @ (powers @ tab.BK[dd]).reshape(q1, n * nz)).reshape(-1, n, nz)
            top[:, :, :n] += (Rphi @ powers.reshape(q1, n * n)).reshape(-1, n, n)
            GD = (Rgam @ (powers @ tab.Dm[dd]).reshape(q1, n * nw)).reshape(-1, n, nw)
        else:
            Phi = (Rphi @ powers.reshape(q1, n * n)).reshape(-1, n, n)
            Gam = (Rgam @ powers.reshape(q1, n * n)).reshape(-1, n, n)
            for _ in range(s):
                Gam = Gam + Phi @ Gam
                Phi = Phi @ Phi
            top = (Gam.reshape(-1, n) @ tab.BK[dd]).reshape(-1, n, nz)
            top[:, :, :n] += Phi
            GD = (Gam.reshape(-1, n) @ tab.Dm[dd]).reshape(-1, n, nw)
        F[idx, :n] = top
        g[idx, :n] = _affine(GD, wvals[idx])


def loop_matrices(tab: Tables, d: np.ndarray, h: np.ndarray, wvals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    r"""Closed-loop ZOH maps ``z -> F z + g`` of intervals with dynamics ids ``d``,
    lengths ``h`` and held disturbances ``wvals`` (N, nw): ``F`` of the module docstring,
    :math:`g = G w`.

    Few ids: per id from the Taylor data (:func:`_grouped_plant`); many ids: through
    :func:`phi_gamma`. The controller rows come from
    :func:`~ftc_verify.simulation.discretise.controller_zoh`."""
    n, nz = tab.n, tab.nz
    N = d.size
    F = np.empty((N, nz, nz))
    g = np.zeros((N, nz)) if nz > n else np.empty((N, nz))
    used = np.unique(d)
    if used.size > discretise._GROUP_LIMIT:
        Phi, Gam = phi_gamma(tab.A, h, tab.d_a[d])
        top = Gam @ tab.BK[d]
        top[:, :, :n] += Phi
        F[:, :n] = top
        g[:, :n] = np.einsum("pij,pj->pi", Gam, np.einsum("pij,pj->pi", tab.Dm[d], wvals))
    else:
        _grouped_plant(tab, d, h, wvals, used, F, g)
    _controller_rows(tab, d, h, F)
    return F, g


def held_maps(tab: Tables, d: np.ndarray, d0: np.ndarray, h: np.ndarray,
              wvals: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    r"""Maps of pieces of a period cut by jumps, with the controller's output held.

    A piece of length :math:`h` in dynamics id :math:`d` (the plant's true mode and
    :math:`\Delta` now) inside a period whose sample was taken in id :math:`d_0` (the
    entry :math:`e_0`, measurement :math:`M_0` and held :math:`u_0 = K_{d_0} z_0`,
    :math:`w_0`, :math:`v_0 = M_0 x_0` of the sample state :math:`z_0`) moves
    :math:`z = (x, x_c)` by

    .. math::

        z^+ = F_a z + F_b z_0 + g, \qquad
        F_a = \begin{bmatrix} \Phi & 0 \\ 0 & \Phi_{c,e_0} \end{bmatrix}, \quad
        F_b = \begin{bmatrix} \Gamma B_d K_{d_0} \\ [\Gamma_{c,e_0} M_0\ \ 0]
        \end{bmatrix}, \quad g = \begin{bmatrix} \Gamma D_d w_0 \\ 0 \end{bmatrix},

    with :math:`\Phi, \Gamma` of the perturbed :math:`A` of id :math:`d` at :math:`h`
    and :math:`\Phi_c, \Gamma_c` of entry :math:`e_0` at :math:`h` (their composition over
    the pieces is the controller's update over the whole period: :math:`v_0` is held).
    For :math:`d = d_0`, :math:`F_a + F_b` is the :func:`loop_matrices` map.
    Returns ``(Fa, Fb, g)``: ``(N, nz, nz)``, ``(N, nz, nz)``, ``(N, nz)``."""
    n, nz = tab.n, tab.nz
    N = d.size
    Phi, Gam = phi_gamma(tab.A, h, tab.d_a[d])
    Fa = np.zeros((N, nz, nz))
    Fb = np.zeros((N, nz, nz))
    g = np.zeros((N, nz))
    Fa[:, :n, :n] = Phi
    Fb[:, :n] = Gam @ tab.Bd[d] @ tab.K[d0]
    g[:, :n] = np.einsum("pij,pj->pi", Gam, np.einsum("pij,pj->pi", tab.Dm[d], wvals))
    if nz > n:
        Phic, Gamc = controller_zoh(tab.controller, tab.d_entry[d0], h)
        Fa[:, n:, n:] = Phic
        Fb[:, n:, :n] = Gamc @ tab.M[tab.d_true[d0]]
    return Fa, Fb, g


def full_maps(tab: Tables, step: float) -> tuple[np.ndarray, np.ndarray]:
    r"""Full-step maps :math:`F_d`, :math:`G_d` per dynamics id (``h = step``,
    :func:`phi_gamma`); for static state feedback :math:`F_d = \Phi + \Gamma B K`,
    :math:`G_d = \Gamma D`."""
    n, nz = tab.n, tab.nz
    Dn = tab.d_a.size
    h = np.full(Dn, step)
    Phi, Gam = phi_gamma(tab.A, h, tab.d_a)
    if nz == n:
        return Phi + Gam @ tab.BK, Gam @ tab.Dm
    F = np.empty((Dn, nz, nz))
    top = Gam @ tab.BK
    top[:, :, :n] += Phi
    F[:, :n] = top
    _controller_rows(tab, np.arange(Dn), h, F)
    G = np.zeros((Dn, nz, tab.Dm.shape[2]))
    G[:, :n] = Gam @ tab.Dm
    return F, G
