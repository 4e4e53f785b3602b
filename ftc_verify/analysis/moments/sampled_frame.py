r"""The coordinates the sampled gain certificate is solved and proved in.

The program of :mod:`~ftc_verify.analysis.moments.sampled_gamma` is invariant, in exact
arithmetic, under a similarity of the augmented state :math:`\zeta = T\tilde\zeta`
(:math:`\tilde P_s = T^T P_s T`, each instance congruent to the original one by
:math:`\operatorname{diag}(T, I)`, the jump condition by :math:`T`) and under scaling the
disturbance input and the output by :math:`s_w, s_z` (the gain times :math:`s_w s_z`).
The solver and its margin are not: on the paper loop moved by a similarity of condition
1e3 in units of condition 1e4 the bound was 7 % above the paper loop's and at condition
1e4 none was found; a gain of 1e-12 came out as :math:`\sqrt{10^{-7}}` (the margin
:math:`t` of every block, the :math:`-\gamma^2 I` one included) and one of 1e12 stopped
the solver (measured, ``tests/test_sampled_scaling_h31s.py``).

:func:`coordinates` chooses :math:`(s_w, s_z)` (:func:`io_scales`) and :math:`T`: the
:func:`~ftc_verify.analysis.conditioning.conditioning_transform` of the scaled augmented
loop (the one the continuous analysis uses: a balanced realisation of the mode-averaged
loop) when it is :func:`usable` -- condition above :data:`CONDITION` (the loop's
coordinates were badly chosen) and the condition of its non-diagonal part
(:func:`essential_condition`) below :data:`LIMIT` -- else none (a well-conditioned loop
is solved as written). The same rule moves the loop of the stability proofs
(:mod:`~ftc_verify.analysis.moments.sampled_conditioned`) and the coordinates its speed
is measured in (:attr:`SampledLoop.speed`). **Soundness does not
depend on** :math:`T`: the proof builds the transformed loop and jumps in ball arithmetic
from the balls of the numbers as written, with :math:`T` an exact float matrix and
:math:`T^{-1}` a ball that contains the exact inverse (Arb's ``arb_mat.inv``), so what is
proved is the program for a loop congruent to the written one: the same gain. The proved
lower bound (:mod:`~ftc_verify.analysis.moments.sampled_lower`) is searched and proved in
the same similarity (without the scales).

Both stages start from the same float64 work -- the augmented loop
(:func:`~ftc_verify.analysis.moments.sampled_gamma.augmented_loop`), the sample jumps
(:func:`~ftc_verify.analysis.moments.sampled_gamma.sample_jumps`) and :func:`coordinates`
of them -- which :func:`float_frame` computes once per loop and period.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.linalg

from ...controllers.controller import Controller
from ...errors import FTCError
from ...model.system import FTCSystem, Matrix
from ..closedloop import ClosedLoop
from .sampled import SampledLoop

__all__ = ["CONDITION", "LIMIT", "BAND", "io_scales", "essential_condition", "usable", "loop_similarity", "Coordinates", "coordinates", "FloatFrame", "float_frame"]

#: A similarity is used only when the conditioning transform has a larger condition number.
CONDITION = 100.0
#: ... and only when its :func:`essential_condition` is smaller.
LIMIT = 1e12
#: A disturbance input or output whose largest norm is outside ``[1/BAND, BAND]`` is scaled.
BAND = 8.0


def io_scales(aug: ClosedLoop) -> tuple[float, float]:
    r"""Powers of two :math:`(s_w, s_z)`. With :math:`b = \max_i\|\bar B_{w,i}\|`,
    :math:`c = \max_i\|\bar C_i\|`: each side whose norm is outside
    :math:`[1/\text{BAND}, \text{BAND}]` scaled to norm about 1
    (:math:`2^{-\operatorname{round}\log_2}`); then :math:`s_w` times the power of two
    nearest :math:`s_z c / (s_w b)` when that is above 1 (a disturbance input 1e4 times
    smaller than the output left the three-tank certificate 27 % above the gain, 1.8 %
    after; scaling an input *down* by 2 loosened a dynamic controller's quadratic storage
    on the paper plant by 3 % -- hence the band; measured, not derived)."""
    def norm(Ms: tuple[Matrix, ...]) -> float:
        return max(float(np.linalg.norm(M, 2)) if M.size else 0.0 for M in Ms)

    def unit(v: float) -> float:
        return float(2.0 ** -round(math.log2(v))) if 0 < v < math.inf and not 1 / BAND <= v <= BAND else 1.0

    b, c = norm(aug.Bw), norm(aug.Cz)
    sw, sz = unit(b), unit(c)
    if b > 0 and c * sz > b * sw and math.isfinite(c):
        sw *= float(2.0 ** round(math.log2(c * sz / (b * sw))))
    return sw, sz


@dataclass(frozen=True, eq=False)
class Coordinates:
    """``Bw`` times ``w_scale``, ``Cz`` times ``z_scale`` (powers of two), and
    :math:`\\zeta = T \\tilde\\zeta` when ``T`` is given (``T_inv`` its float inverse, for the
    solver). The solved loop's gain is ``w_scale * z_scale`` times the loop's."""

    w_scale: float = 1.0
    z_scale: float = 1.0
    T: Matrix | None = None
    T_inv: Matrix | None = None

    @property
    def gain_factor(self) -> float:
        return self.w_scale * self.z_scale

    def _pair(self, balls: bool) -> tuple[Any, Any]:
        from ..rigorous import Ball, ball

        assert self.T is not None and self.T_inv is not None
        if not balls:
            return self.T, self.T_inv
        return ball(self.T), Ball(ball(self.T).value.inv())  # raises when T is not proved invertible

    def loop(self, aug: ClosedLoop, balls: bool = False) -> ClosedLoop:
        """``aug`` (already scaled by ``w_scale``, ``z_scale``) in the coordinates
        :math:`\\tilde\\zeta`; its ``source`` (the written rates) kept."""
        from dataclasses import replace

        if self.T is None:
            return aug
        T, T_inv = self._pair(balls)
        return replace(aug.transformed(T, T_inv), source=aug.source, names=aug.names)

    def jumps(self, jumps: list[Any], balls: bool = False) -> list[Any]:
        """:math:`T^{-1} J_s T` for each jump."""
        if self.T is None:
            return jumps
        T, T_inv = self._pair(balls)
        return [T_inv @ J @ T for J in jumps]


def essential_condition(T: Matrix) -> float:
    r"""The 2-norm condition number of ``T`` with each row scaled by the power of two nearest
    its inverse 2-norm: a diagonal factor of powers of two (:math:`T = D T_0`, the first
    step of :func:`~ftc_verify.analysis.conditioning.conditioning_transform`, a change of
    units) is exact and moves no rounding -- :math:`|D^{-1} A D| = |D^{-1}||A||D|`, so the
    rounding of :math:`T^{-1} A T` is that of :math:`T_0^{-1} (D^{-1} A D) T_0` -- only
    :math:`T_0` does. ``inf`` when ``T`` has a zero or non-finite row."""
    norms = np.linalg.norm(T, axis=1)
    if not (np.all(np.isfinite(norms)) and np.all(norms > 0)):
        return math.inf
    rows = 2.0 ** -np.round(np.log2(norms))
    return float(np.linalg.cond(T * rows[:, None]))


def usable(sim: Any) -> bool:
    """The rule for moving a loop by the
    :func:`~ftc_verify.analysis.conditioning.conditioning_transform` ``sim``: its condition
    number above :data:`CONDITION` (the loop as written is badly conditioned; else the
    loop is kept, bit for bit) and its :func:`essential_condition` below :data:`LIMIT` (a
    similarity the float64 data can carry). The whole condition number was held against
    ``LIMIT`` before: states in units ``1e-6`` and ``1e6`` (a transform of condition
    ``1e12``, nearly all of it the exact diagonal) were left as written, the speed
    (:attr:`SampledLoop.speed`) was ``1e12`` times the loop's and the clock certificates'
    time unit (:func:`~ftc_verify.analysis.moments.sampled_clock.time_unit`) and the
    ``h_max`` scan followed it (``benchmarks/results/frame11.md``)."""
    return CONDITION < float(sim.condition) and essential_condition(np.asarray(sim.T, dtype=float)) < LIMIT


def loop_similarity(system: FTCSystem, controller: Controller) -> Any | None:
    """The :func:`~ftc_verify.analysis.conditioning.conditioning_transform` of the continuous
    closed loop of ``system`` and ``controller`` when it is :func:`usable`; ``None``
    otherwise (no transform can be formed, or the loop as written is as well conditioned)."""
    from ..closedloop import closed_loop
    from ..conditioning import conditioning_transform

    try:
        sim = conditioning_transform(closed_loop(system, controller))
    except (np.linalg.LinAlgError, ValueError, FTCError):  # no transform: the loop as written
        return None
    return sim if usable(sim) else None


def coordinates(aug: ClosedLoop, jumps: list[Matrix], loop: SampledLoop, system: FTCSystem) -> Coordinates:
    """:class:`Coordinates` of the module docstring for the float augmented loop ``aug`` of
    ``loop`` (balanced coordinates, :attr:`SampledLoop.scale`): ``T`` acts on the plant and
    controller states as the conditioning transform of the continuous closed loop, the held
    input stays; then :func:`io_scales` of the transformed loop."""
    plain = Coordinates()
    sim = loop_similarity(system, loop.controller)
    if sim is not None:
        idx = np.r_[0:loop.n, loop.n + loop.nu:loop.d]
        sc = loop.scale[idx]
        T, T_inv = np.eye(loop.d), np.eye(loop.d)
        T[np.ix_(idx, idx)] = np.asarray(sim.T, dtype=float) / sc[:, None]
        T_inv[np.ix_(idx, idx)] = np.asarray(sim.T_inv, dtype=float) * sc[None, :]
        moved = Coordinates(1.0, 1.0, T, T_inv)
        pattern = sum(np.abs(A) for A in moved.loop(aug).A) + sum(np.abs(J) for J in moved.jumps(jumps))
        if np.all(np.isfinite(pattern)):  # powers of two: the held input against the new states
            _, (found, _) = scipy.linalg.matrix_balance(pattern + np.eye(loop.d), permute=False, separate=True)
            T, T_inv = T * found[None, :], T_inv / found[:, None]
        plain = Coordinates(1.0, 1.0, T, T_inv)
    sw, sz = io_scales(plain.loop(aug))
    return Coordinates(sw, sz, plain.T, plain.T_inv)


@dataclass(frozen=True, eq=False)
class FloatFrame:
    """The float64 augmented loop ``aug`` (balanced coordinates, ``Bw`` and ``Cz`` as
    written), its sample jumps ``jumps`` (:math:`J_s = R_s P`) and :func:`coordinates` of
    them, of one loop at one period (:func:`float_frame`)."""

    aug: ClosedLoop
    jumps: tuple[Matrix, ...]
    coords: Coordinates


def float_frame(loop: SampledLoop, system: FTCSystem, h: float) -> FloatFrame:
    """:class:`FloatFrame` of ``loop`` (built from ``system``) at period ``h``: computed on
    the first call and kept in ``loop.memo`` (the gain certificate and the lower bound of
    :mod:`~ftc_verify.analysis.moments.sampled_gains` share it; the same float64
    operations as computing it afresh, so the same bits)."""
    from .sampled_gamma import augmented_loop, sample_jumps

    key = ("float_frame", float(h), id(system))
    found = loop.memo.get(key)
    if found is not None and found[0] is system:
        return found[1]
    aug = augmented_loop(loop, system)
    jumps = sample_jumps(loop, h)
    frame = FloatFrame(aug, tuple(jumps), coordinates(aug, jumps, loop, system))
    loop.memo[key] = (system, frame)
    return frame
