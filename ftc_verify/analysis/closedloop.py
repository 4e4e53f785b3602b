r"""The closed-loop representation every analysis runs on.

A :class:`ClosedLoop` is a linear jump system on the joint chain of
:mod:`ftc_verify.model.chain` (true mode, FDI mode and, with phase-type detection
delays, the phase of a detection under way): for each joint state :math:`s` with pair
:math:`(i, j)` = (true, FDI)

.. math::

    \dot\xi = \Bigl(A_s + \sum_k E_{s,k} \Delta_k F_{s,k}\Bigr)\xi + B_{w,s} w,
    \qquad z = C_{z,s} \xi, \qquad \|\Delta_k\| \le 1,

where the :math:`(E, F)` pairs are the norm-bounded uncertainty channels. The matrices
of a state depend on its pair only (the controller sees the FDI mode :math:`j`, the plant
is in mode :math:`i`), so the phases of one pair repeat the same entries; the chain's
generator alone tells them apart.

:func:`closed_loop` builds it from ``(system, controller)`` for every controller of
:mod:`ftc_verify.controllers`, with the augmented state :math:`\xi = (x, x_c)`.
Re-derived from the plant (paper eqs. (1), (13)) and the controller
:math:`\dot x_c = A_{c,j} x_c + B_{c,j} v`, :math:`u = C_{c,j} x_c + D_{c,j} v`,
:math:`v = M_i x` (:math:`M_i = I` for state feedback, :math:`C_{y,i}` for output
feedback), in the paper's Section V notation with the controller
:math:`\mathcal K_j = [[A_{c,j}, B_{c,j}], [C_{c,j}, D_{c,j}]]`:

.. math::

    \bar A_{0i} = \begin{bmatrix} A_i & 0 \\ 0 & 0_{n_c} \end{bmatrix},\;
    \bar B_{0i} = \begin{bmatrix} 0 & B_i \\ I_{n_c} & 0 \end{bmatrix},\;
    \bar C_i = \begin{bmatrix} 0 & I_{n_c} \\ M_i & 0 \end{bmatrix},\;
    \bar D_i = \begin{bmatrix} D_i \\ 0 \end{bmatrix},\;
    \bar C_{1i} = [\,C_i \;\; 0\,],

    \bar A_{1i} = \begin{bmatrix} A1_i & B1_i \\ 0 & 0 \end{bmatrix},\;
    \bar A_{2i} = \begin{bmatrix} A2_i & 0 \\ 0 & 0 \end{bmatrix},\;
    \bar B_{2i} = \begin{bmatrix} 0 & 0 \\ 0 & B2_i \end{bmatrix},\;
    \Delta = \operatorname{diag}(\Delta_1, \Delta_2),

so that, for true mode :math:`i` and FDI mode :math:`j` (equation (21)'s loop),

.. math::

    A_s = \bar A_{0i} + \bar B_{0i} \mathcal K_j \bar C_i
        = \begin{bmatrix} A_i + B_i D_{c,j} M_i & B_i C_{c,j} \\ B_{c,j} M_i & A_{c,j} \end{bmatrix},
    \qquad \bar A_{1i} \Delta (\bar A_{2i} + \bar B_{2i} \mathcal K_j \bar C_i),

since :math:`(\bar A_{2i} + \bar B_{2i} \mathcal K_j \bar C_i) =
[[A2_i, 0], [B2_i D_{c,j} M_i, B2_i C_{c,j}]]`. The uncertainty term splits into two
channels with independent multipliers (no more conservative than the paper's single
block :math:`\Delta`): :math:`([A1_i; 0], [A2_i, 0])` and
:math:`([B1_i; 0], B2_i [D_{c,j} M_i, C_{c,j}])`. With :math:`n_c = 0` and :math:`M_i = I`
this is state feedback: :math:`A_s = A_i + B_i K_j`, channels :math:`(A1_i, A2_i)`,
:math:`(B1_i, B2_i K_j)`, :math:`B_{w,s} = D_i`, :math:`C_{z,s} = C_i` (eqs. (2), (13)).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ..controllers.controller import Controller
from ..errors import ValidationError
from ..model.names import SignalNames
from ..model.system import FTCSystem, JointChain, Matrix, Mode

__all__ = ["Channel", "ClosedLoop", "Barred", "barred", "closed_loop", "state_feedback_loop", "gain_loop"]


@dataclass(frozen=True, eq=False)
class Channel:
    """One norm-bounded uncertainty channel ``E Delta F`` with ``||Delta|| <= 1``."""

    E: Matrix
    F: Matrix
    name: str


@dataclass(frozen=True, eq=False)
class ClosedLoop:
    """Closed loop on the joint chain; one entry per joint state, in the order of
    :attr:`JointChain.states` (with the paper's FDI model ``s = true * m + fdi``).

    Attributes
    ----------
    chain : JointChain
        The joint (true, FDI, phase) chain and its rate bounds.
    A, Bw, Cz : tuple of arrays, one per joint state
        Closed-loop state matrix, disturbance input and performance output.
    channels : tuple of tuples of :class:`Channel`, one per joint state
        Uncertainty channels (empty for a nominal loop).
    controller : str
        What produced the loop (for reports).
    n_plant : int or None
        Plant states ``x`` at the top of the state (the rest is the controller's ``x_c``);
        ``None`` means all states are plant states.
    names : SignalNames or None
        The plant's mode and signal names (:attr:`FTCSystem.names
        <ftc_verify.model.system.FTCSystem>`), used only to label :meth:`to_statespace`;
        ``None``: the defaults.
    source : (FTCSystem, Controller) or None
        The system and controller the loop was formed from (set by :func:`closed_loop`):
        the proofs form the loop again from them in ball arithmetic
        (:func:`~ftc_verify.analysis.exact.exact_loop`). ``None`` for a loop built by
        hand or moved to other coordinates (its float matrices are then the data).
    """

    chain: JointChain
    A: tuple[Matrix, ...]
    Bw: tuple[Matrix, ...]
    Cz: tuple[Matrix, ...]
    channels: tuple[tuple[Channel, ...], ...]
    controller: str = "state feedback"
    n_plant: int | None = None
    names: SignalNames | None = None
    source: tuple[FTCSystem, Controller] | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        count = self.chain.n_states
        for name in ("A", "Bw", "Cz", "channels"):
            if len(getattr(self, name)) != count:
                raise ValidationError(
                    f"ClosedLoop.{name}: expected {count} joint states, got {len(getattr(self, name))}"
                )

    @property
    def n(self) -> int:
        """Closed-loop state dimension."""
        return int(self.A[0].shape[0])

    @property
    def modes(self) -> tuple[tuple[int, int], ...]:
        """The pair ``(true, fdi)`` of every joint state, 0-based, in index order (a pair
        repeats once per detection phase)."""
        return self.chain.joint_modes

    @property
    def uncertain(self) -> bool:
        """True when some joint mode has an uncertainty channel."""
        return any(self.channels)

    def nominal(self) -> ClosedLoop:
        """The loop with every uncertainty channel removed (``Delta = 0``)."""
        return replace(self, channels=tuple(() for _ in self.A))

    def with_chain(self, chain: JointChain) -> ClosedLoop:
        """The same loop on another chain with the same joint states (modes, phases)."""
        if chain.m != self.chain.m:
            raise ValidationError(f"with_chain: chain has {chain.m} modes, the loop {self.chain.m}")
        if chain.states != self.chain.states:
            raise ValidationError(f"with_chain: chain has {chain.n_states} joint states "
                                  f"({chain.delay_phases} phases), the loop {self.chain.n_states} "
                                  f"({self.chain.delay_phases} phases)")
        return replace(self, chain=chain)

    def scaled(self, d: Matrix) -> ClosedLoop:
        """The similar loop in the coordinates ``x = diag(d) x~``: ``A~ = D^-1 A D``,
        ``Bw~ = D^-1 Bw``, ``Cz~ = Cz D``, ``E~ = D^-1 E``, ``F~ = F D``. With ``d`` powers
        of two (:func:`ftc_verify.analysis.conditioning.balancing_scale`) every product is
        exact in floating point, so a certificate of the scaled loop is one of this loop."""
        d = np.asarray(d, dtype=float)
        inv = 1.0 / d
        return replace(
            self,
            source=None,
            A=tuple(inv[:, None] * A * d[None, :] for A in self.A),
            Bw=tuple(inv[:, None] * B for B in self.Bw),
            Cz=tuple(C * d[None, :] for C in self.Cz),
            channels=tuple(tuple(Channel(inv[:, None] * ch.E, ch.F * d[None, :], ch.name) for ch in chans)
                           for chans in self.channels),
        )

    def transformed(self, T: Matrix, T_inv: Matrix) -> ClosedLoop:
        """The similar loop in the coordinates ``x = T x~`` (``T_inv`` the inverse used):
        ``A~ = T^-1 A T``, ``Bw~ = T^-1 Bw``, ``Cz~ = Cz T``, ``E~ = T^-1 E``, ``F~ = F T``
        (:mod:`ftc_verify.analysis.conditioning`)."""
        return replace(
            self,
            source=None,
            A=tuple(T_inv @ A @ T for A in self.A),
            Bw=tuple(T_inv @ B for B in self.Bw),
            Cz=tuple(C @ T for C in self.Cz),
            channels=tuple(tuple(Channel(T_inv @ ch.E, ch.F @ T, ch.name) for ch in chans)
                           for chans in self.channels),
            names=None if self.names is None else replace(  # new coordinates: no state is the user's
                self.names, states=tuple(f"x~[{k}]" for k in range(len(self.names.states)))),
        )

    def perturbed(self, deltas: Mapping[str, Matrix]) -> tuple[Matrix, ...]:
        """State matrices ``A_s + sum_k E_k Delta_k F_k`` for given ``Delta`` per channel
        name (a channel missing from ``deltas`` stays at ``Delta = 0``).

        Raises
        ------
        ValidationError
            Naming the channel: a name that is no channel of the loop (with the names
            there are), a ``Delta`` that is not a finite real matrix, or one whose shape
            is not ``(columns of E, rows of F)``.
        """
        checked = self._checked_deltas(deltas)
        out = []
        for A, chans in zip(self.A, self.channels):
            M = A.copy()
            for ch in chans:
                if ch.name in checked:
                    M = M + ch.E @ checked[ch.name] @ ch.F
            out.append(M)
        return tuple(out)

    def _checked_deltas(self, deltas: Mapping[str, Matrix]) -> dict[str, Matrix]:
        """``deltas`` as finite real matrices of each channel's shape (:meth:`perturbed`)."""
        from ..model.matrices import as_matrix

        if not isinstance(deltas, Mapping):
            raise ValidationError(f"deltas: expected a mapping of channel name to matrix, got {type(deltas).__name__}")
        shapes: dict[str, tuple[int, int]] = {}
        for chans in self.channels:
            for ch in chans:
                shapes.setdefault(ch.name, (int(ch.E.shape[1]), int(ch.F.shape[0])))
        out: dict[str, Matrix] = {}
        for name, value in deltas.items():
            if name not in shapes:
                known = sorted(shapes) if shapes else "none: the loop is nominal"
                raise ValidationError(f"deltas: unknown uncertainty channel {name!r} (channels: {known})")
            if np.iscomplexobj(value):
                raise ValidationError(f"deltas[{name!r}]: Delta must be real, got a complex matrix")
            delta = as_matrix(value, f"deltas[{name!r}]")
            if delta.shape != shapes[name]:
                raise ValidationError(f"deltas[{name!r}]: Delta has shape {delta.shape}, channel {name!r} needs "
                                      f"{shapes[name]} (columns of E, rows of F)")
            out[name] = delta
        return out

    def to_statespace(self, *, deltas: Mapping[str, Matrix] | None = None) -> dict[tuple[int, int], Any]:
        r"""The frozen closed loop of every pair ``(true, fdi)`` as a ``control.StateSpace``.

        For the pair :math:`(i, j)` of joint state :math:`s`, the linear system from the
        disturbance :math:`w` to the performance output :math:`z`

        .. math::

            \dot\xi = \Bigl(A_s + \sum_k E_{s,k} \Delta_k F_{s,k}\Bigr)\xi + B_{w,s} w,
            \qquad z = C_{z,s} \xi + 0 \cdot w,

        the loop with the true mode and the FDI indication held at :math:`i` and
        :math:`j` (continuous time, ``dt = 0``). Its poles are the eigenvalues of the
        frozen :math:`A_s`, its :math:`H_\infty` norm the frozen mode's of
        :func:`ftc_verify.analysis.crossval.cross_validate`; the switching loop's
        mean-square stability and attenuation are not properties of any one of them.

        Parameters
        ----------
        deltas : mapping of channel name to array, optional
            Uncertainty values :math:`\Delta_k` per channel name (as in :meth:`perturbed`;
            a channel left out stays at 0). Default: the nominal loop, all
            :math:`\Delta_k = 0`.

        Returns
        -------
        dict
            ``{(true, fdi): control.StateSpace}``, the modes 1-based as in
            :attr:`AnalysisReport.per_mode <ftc_verify.analysis.analyze.AnalysisReport>`,
            the CLI and the reports (:attr:`modes` is 0-based), in the order the pairs first
            occur in :attr:`modes`; the detection phases of a pair share its matrices
            (module docstring) and give one entry. Labels are the user's (``names``,
            from :meth:`FTCSystem.from_statespace
            <ftc_verify.model.system.FTCSystem.from_statespace>`): the plant's state labels,
            then ``xc[k]`` for a dynamic controller's states, the disturbance labels as
            inputs and the performance-output labels as outputs, and the name
            ``"true nominal, FDI faulty"`` from the modes' names. Without names:
            ``x[k]``, ``xc[k]``, ``w[k]``, ``z[k]`` and ``"true mode 2, FDI mode 1"``.

        Raises
        ------
        ValidationError
            When two phases of one pair have different matrices (a loop built by hand),
            or a ``Delta`` is refused by :meth:`perturbed` (unknown channel, not a
            finite real matrix, wrong shape).

        Examples
        --------
        Build with :func:`closed_loop`; ``control.poles(loop.to_statespace()[(2, 1)])``
        are the poles while the FDI still shows mode 1 after a fault to mode 2.
        python-control is imported when this is called, not with the package.
        """
        import control

        A_all = self.A if deltas is None else self.perturbed(deltas)
        n_plant = self.n if self.n_plant is None else self.n_plant
        names = self.names
        plant_states = list(names.states) if names is not None else [f"x[{k}]" for k in range(n_plant)]
        states = plant_states + [f"xc[{k}]" for k in range(self.n - n_plant)]
        modes = names.modes if names is not None else tuple(f"mode {k}" for k in range(1, self.chain.m + 1))
        out: dict[tuple[int, int], Any] = {}
        first: dict[tuple[int, int], int] = {}
        for s, pair in enumerate(self.modes):
            f = first.setdefault(pair, s)
            if f != s:
                if not all(np.array_equal(M[f], M[s]) for M in (A_all, self.Bw, self.Cz)):
                    raise ValidationError(f"to_statespace: joint states {f} and {s} of the pair (true, fdi) = "
                                          f"{(pair[0] + 1, pair[1] + 1)} (1-based) have "
                                          "different matrices; one frozen loop per pair is undefined")
                continue
            B, C = self.Bw[s], self.Cz[s]
            true, fdi = pair
            out[(true + 1, fdi + 1)] = control.ss(
                A_all[s], B, C, np.zeros((C.shape[0], B.shape[1])), states=states,
                inputs=list(names.disturbances) if names else [f"w[{k}]" for k in range(B.shape[1])],
                outputs=list(names.performance) if names else [f"z[{k}]" for k in range(C.shape[0])],
                name=f"true {modes[true]}, FDI {modes[fdi]}")
        return out


@dataclass(frozen=True, eq=False)
class Barred:
    """The barred matrices of one true mode (module docstring; paper Section V, with the
    measurement ``M`` in place of ``C`` and ``n_c`` controller states). ``A1bar``,
    ``A2bar``, ``B2bar`` are ``None`` without uncertainty; ``split`` is the number of
    ``Delta1`` columns of ``A1bar`` (rows of ``A2bar``)."""

    A0bar: Matrix
    B0bar: Matrix
    Cbar: Matrix
    Dbar: Matrix
    C1bar: Matrix
    A1bar: Matrix | None
    A2bar: Matrix | None
    B2bar: Matrix | None
    split: int


def barred(mode: Mode, measurement: Matrix, n_c: int) -> Barred:
    """The barred matrices of ``mode`` for a controller reading ``v = measurement x``."""
    n, nu, _, nw = mode.dims
    nv = measurement.shape[0]
    A0 = np.zeros((n + n_c, n + n_c))
    A0[:n, :n] = mode.A
    B0 = np.zeros((n + n_c, n_c + nu))
    B0[:n, n_c:] = mode.B
    B0[n:, :n_c] = np.eye(n_c)
    Cb = np.zeros((n_c + nv, n + n_c))
    Cb[:n_c, n:] = np.eye(n_c)
    Cb[n_c:, :n] = measurement
    Db = np.vstack([mode.D, np.zeros((n_c, nw))])
    C1 = np.hstack([mode.C, np.zeros((mode.C.shape[0], n_c))])
    if not mode.uncertain:
        return Barred(A0, B0, Cb, Db, C1, None, None, None, 0)
    pa = 0 if mode.A1 is None else mode.A1.shape[1]
    qa = 0 if mode.A2 is None else mode.A2.shape[0]
    pb = 0 if mode.B1 is None else mode.B1.shape[1]
    qb = 0 if mode.B2 is None else mode.B2.shape[0]
    A1 = np.zeros((n + n_c, pa + pb))
    A2 = np.zeros((qa + qb, n + n_c))
    B2 = np.zeros((qa + qb, n_c + nu))
    if mode.A1 is not None and mode.A2 is not None:
        A1[:n, :pa] = mode.A1
        A2[:qa, :n] = mode.A2
    if mode.B1 is not None and mode.B2 is not None:
        A1[:n, pa:] = mode.B1
        B2[qa:, n_c:] = mode.B2
    return Barred(A0, B0, Cb, Db, C1, A1, A2, B2, pa)


def _assemble(system: FTCSystem, entry: Callable[[int, int], tuple[Any, Any, Any, Any]],
              measurement: Callable[[Mode], Matrix], n_c: int, label: str) -> ClosedLoop:
    """The loop of the module docstring from ``entry(i, j) = (Ac, Bc, Cc, Dc)``, one
    entry per joint state (``entry`` is called with the state's pair).

    With ``n_c = 0`` only ``Dc`` is used, so it may be a cvxpy expression (the synthesis
    LMIs); otherwise the entries are numbers and the barred form is used as written."""
    A, Bw, Cz, chans = [], [], [], []
    for i, j in system.chain.joint_modes:
        md = system.modes[i]
        M = measurement(md)
        Ac, Bc, Cc, Dc = entry(i, j)
        if n_c == 0:
            A.append(md.A + md.B @ Dc @ M)
            Bw.append(md.D)
            Cz.append(md.C)
            fb = None if md.B2 is None else md.B2 @ Dc @ M
            c = []
            if md.A1 is not None and md.A2 is not None:
                c.append(Channel(md.A1, md.A2, "Delta1 (A)"))
            if md.B1 is not None and fb is not None:
                c.append(Channel(md.B1, fb, "Delta2 (B)"))
            chans.append(tuple(c))
            continue
        bar = barred(md, M, n_c)
        K = np.block([[Ac, Bc], [Cc, Dc]])
        A.append(bar.A0bar + bar.B0bar @ K @ bar.Cbar)
        Bw.append(bar.Dbar)
        Cz.append(bar.C1bar)
        c = []
        if bar.A1bar is not None:
            F = bar.A2bar + bar.B2bar @ K @ bar.Cbar
            k = bar.split
            if md.A1 is not None and md.A2 is not None:
                c.append(Channel(bar.A1bar[:, :k], F[:md.A2.shape[0]], "Delta1 (A)"))
            if md.B1 is not None and md.B2 is not None:
                c.append(Channel(bar.A1bar[:, k:], F[F.shape[0] - md.B2.shape[0]:], "Delta2 (B)"))
        chans.append(tuple(c))
    n_plant = None if n_c == 0 else system.dims[0]
    return ClosedLoop(system.chain, tuple(A), tuple(Bw), tuple(Cz), tuple(chans), label, n_plant, system.names)


def closed_loop(system: FTCSystem, controller: Controller) -> ClosedLoop:
    """The closed loop of ``system`` under ``controller`` (module docstring), after
    :meth:`Controller.check` against the system."""
    controller.check(system)
    m = system.m

    def entry(i: int, j: int) -> tuple[Matrix, Matrix, Matrix, Matrix]:
        k = controller.index(i, j, m)
        return controller.Ac[k], controller.Bc[k], controller.Cc[k], controller.Dc[k]

    loop = _assemble(system, entry, controller.measurement, controller.n_c, controller.describe(m))
    return replace(loop, source=(system, controller))


def state_feedback_loop(system: FTCSystem, gains: Sequence[Matrix], *, controller: str | None = None) -> ClosedLoop:
    """:func:`closed_loop` of static state feedback: ``m`` FDI-mode gains or ``m * m``
    full-information gains, indexed ``true * m + fdi`` of a state's pair and shared by
    its phases (``controller`` overrides the label)."""
    loop = closed_loop(system, Controller.state_feedback(gains).check(system, source="gains"))
    return loop if controller is None else replace(loop, controller=controller)


def gain_loop(system: FTCSystem, gains: Sequence[Any], controller: str) -> ClosedLoop:
    """State-feedback loop from ``m`` FDI-mode gains or ``m * m`` full-information gains
    (index ``true * m + fdi`` of a state's pair, shared by its phases) without
    validation, so that the gains may be cvxpy expressions (the synthesis LMIs)."""
    m = system.m
    if len(gains) not in (m, m * m):
        raise ValidationError(f"gain_loop: expected {m} or {m * m} gains, got {len(gains)}")
    full_info = len(gains) == m * m

    def entry(i: int, j: int) -> tuple[Any, Any, Any, Any]:
        return None, None, None, gains[i * m + j] if full_info else gains[j]

    return _assemble(system, entry, lambda md: np.eye(md.n), 0, controller)
