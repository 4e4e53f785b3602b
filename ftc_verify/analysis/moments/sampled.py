r"""The sampled-data loop: its exact one-period second-moment map, stability and ``h_max``.

A digital controller with period :math:`h` reads :math:`v_k = M_i x(t_k)` and the FDI
report :math:`l(t_k)` at :math:`t_k = k h` and holds its output until :math:`t_{k+1}`,
while faults and detections keep happening between samples. With the controller entry
:math:`e` of the joint state at the sample (:meth:`Controller.index`: the FDI mode) and
the exact discretisation :math:`\Phi_c = e^{A_{c,e} h}`,
:math:`\Gamma_c = \int_0^h e^{A_{c,e} s} ds\, B_{c,e}` of a dynamic controller
(:meth:`Controller.discretise`, as in the simulators),

.. math::

    u_k = C_{c,e} x_{c,k} + D_{c,e} M_i x(t_k), \qquad
    x_{c,k+1} = \Phi_c x_{c,k} + \Gamma_c M_i x(t_k), \qquad
    \dot x = A_{\theta(t)} x + B_{\theta(t)} u_k \ \ (t_k \le t < t_{k+1}),

with :math:`\theta` the joint chain (true mode, FDI mode, phase) of
:mod:`ftc_verify.model.chain`, jumping freely inside the period.

**One-period map** (derived here). Take the augmented state
:math:`z = (x, u, x_c^+)` of dimension :math:`d = n + n_u + n_c`, constant in its last
two parts inside a period: :math:`\dot z = \bar A_i z`,
:math:`\bar A_i = \bigl[\begin{smallmatrix} A_i & B_i & 0 \\ 0 & 0 & 0 \\ 0 & 0 & 0
\end{smallmatrix}\bigr]` in true mode :math:`i`. Its second moments per joint state,
:math:`Z_s(t) = E[z z^T 1\{\theta_t = s\}]`, obey the moment equation of
:mod:`ftc_verify.analysis.moments.stability` with :math:`A_s = \bar A_i`,
:math:`\dot{\operatorname{vech}} Z = \mathcal L\, \operatorname{vech} Z`, so over one
period they move by :math:`e^{\mathcal L h}` -- every jump inside the period
included exactly. At the sample the controller resets :math:`z` from the sampled
:math:`\zeta = (x, x_c)` (dimension :math:`r = n + n_c`) of the same joint state:
:math:`z = R_s \zeta`,

.. math::

    R_s = \begin{bmatrix} I_n & 0 \\ D_{c,e} M_i & C_{c,e} \\ \Gamma_c M_i & \Phi_c
    \end{bmatrix}, \qquad \zeta_{k+1} = P z(t_{k+1}^-), \quad
    P = \begin{bmatrix} I_n & 0 & 0 \\ 0 & 0 & I_{n_c} \end{bmatrix}.

The chain does not jump at the sample instant (probability 0), so the moments
:math:`Y_{s,k} = E[\zeta_k \zeta_k^T 1\{\theta_{t_k} = s\}]` obey
:math:`\operatorname{vech} Y_{k+1} = T \operatorname{vech} Y_k` with

.. math::

    T = \mathcal P\, e^{\mathcal L h}\, \mathcal R, \quad
    \mathcal R = \operatorname{blockdiag}_s\bigl(L_d (R_s \otimes R_s) D_r\bigr), \quad
    \mathcal P = \operatorname{blockdiag}_s\bigl(L_r (P \otimes P) D_d\bigr),

(:math:`D, L` the duplication and elimination matrices). :math:`T` maps positive
semidefinite stacks to positive semidefinite stacks, and the loop (nominal,
:math:`\Delta = 0`) is mean-square stable iff its spectral radius
:math:`\rho(T) < 1`: between samples the moments are bounded by a constant times
those at the last sample. The map of the post-reset moments,
:math:`\mathcal R \mathcal P e^{\mathcal L h}`, has the same non-zero spectrum
(:math:`\rho(AB) = \rho(BA)`). As :math:`h \to 0`, :math:`T \approx I + h \mathcal
L_{cl}` with the continuous loop's generator, so :math:`\rho(T) < 1` for small
:math:`h` when the continuous loop is mean-square stable.

The proofs (ball arithmetic, over the rate box by sub-boxes) are in
:mod:`ftc_verify.analysis.moments.sampled_proof`; this module holds the float64 map, the scan
over periods and :func:`sampled_analysis`, which reports the verdict at the period and
``h_max``.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.linalg

from ...controllers.controller import Controller, check_period
from ...errors import ValidationError
from ...limits import check_memory, dense_generator_estimate
from ...model.chain import JointChain
from ...model.system import FTCSystem, Matrix
from ..closedloop import closed_loop
from .stability import duplication_matrix, second_moment_matrix, vech_order

__all__ = ["SampledLoop", "SampledResult", "one_period_map", "assemble_map", "spectral_radius", "rate_points",
           "worst_radius", "crossing", "scan_periods", "stability_intervals", "h_max_bracket", "sampled_analysis",
           "H_MAX_RTOL", "SCAN_PER_OCTAVE", "SCAN_WIDEN"]

#: Relative width of the proved ``h_max`` bracket (proved stable, proved unstable).
H_MAX_RTOL = 1e-3


@dataclass(frozen=True, eq=False)
class SampledLoop:
    """The sampled loop of the module docstring, before a period is chosen.

    Attributes
    ----------
    chain : JointChain
        The joint chain and its rate box.
    flow : tuple of (d, d) arrays, one per joint state
        :math:`\\bar A_i` of the state's true mode.
    measurement : tuple of arrays, one per joint state
        :math:`M_i` (``I`` or ``Cy`` of the true mode).
    entry : tuple of int, one per joint state
        The controller entry used at a sample in that state.
    controller : Controller
    n, nu : int
        Plant states and inputs.
    modes_part : array
        The rate-independent part of :math:`\\mathcal L` (its block diagonal).
    scale : (d,) array
        Powers of two: ``flow``, :meth:`resets` and the maps with ``scaled=True`` are in
        the balanced coordinates :math:`z = \\operatorname{diag}(scale)\\, \\tilde z`
        (a similarity, exact in floating point; the spectrum is the same).
    speed : float
        The largest closed-loop rate (for the range of periods scanned): 2-norms of the
        continuous loop's matrices in the coordinates of
        :func:`~ftc_verify.analysis.moments.sampled_frame.loop_similarity` when it applies
        (in the user's, a similarity of condition 1e3 made it 1e6 times larger and the scan
        start at ``3e-11``; condition 1e4 in units of condition 1e6 at ``3e-14``, where
        float64 rounding put the radius above 1).
    literals : mapping or None
        The numbers of the system and controller files as written (float -> decimal
        texts, :func:`ftc_verify.model.files.read_toml`); the proofs enclose those
        decimals (:func:`ftc_verify.analysis.exact.enclose`). ``None``: the floats are the
        data.
    written : tuple of float
        Periods the user wrote (:func:`sampled_analysis`'s ``period``): the proofs take
        such a period as its decimal text when the controller file has it, else as the
        ball of every decimal read as that float; the periods the analysis chooses (the
        scan, the ``h_max`` bracket) are exact.
    memo : dict
        Float64 work derived from the loop and a period, computed once
        (:func:`~ftc_verify.analysis.moments.sampled_frame.float_frame`); empty in a copy
        made by ``dataclasses.replace``.
    system : FTCSystem or None
        The system it was built from (:meth:`build`), checked by :meth:`of`.
    """

    chain: JointChain
    flow: tuple[Matrix, ...]
    measurement: tuple[Matrix, ...]
    entry: tuple[int, ...]
    controller: Controller
    n: int
    nu: int
    modes_part: Matrix
    scale: Matrix
    speed: float
    literals: Mapping[float, tuple[str, ...]] | None = None
    written: tuple[float, ...] = ()
    memo: dict[Any, Any] = dataclasses.field(default_factory=dict, init=False, repr=False, compare=False)
    system: FTCSystem | None = dataclasses.field(default=None, repr=False, compare=False)

    @classmethod
    def of(cls, system: FTCSystem, controller: Controller, loop: SampledLoop | None) -> SampledLoop:
        """``loop`` when it was built for ``system`` and ``controller`` (the same objects), a
        new :meth:`build` when ``None``; a loop built for another system or controller is
        refused (:class:`~ftc_verify.errors.ValidationError`): a stage given it would prove
        that loop and report it for this one."""
        if loop is None:
            return cls.build(system, controller)
        if loop.controller is not controller or loop.system is not system:
            raise ValidationError(f"loop: built for {getattr(loop.system, 'name', None)!r} under "
                                  f"{loop.controller.name!r}, not for {system.name!r} under {controller.name!r}")
        return loop

    @classmethod
    def build(cls, system: FTCSystem, controller: Controller) -> SampledLoop:
        """The sampled loop of ``system`` under ``controller`` (checked against it)."""
        controller.check(system)
        n, nu, _, _ = system.dims
        nc = controller.n_c
        d = n + nu + nc
        S = system.chain.n_states
        check_memory(dense_generator_estimate(d, S),
                     f"the sampled-data analysis (one-period map on {S} joint states x {d * (d + 1) // 2} "
                     f"second moments of (x, u, x_c), d = {d})",
                     hint="analyse without --period, or a smaller loop")
        flows, meas, entries = [], [], []
        pattern = np.zeros((d, d))  # |flow| + |reset pattern| over the states, to balance
        for i, j in system.chain.joint_modes:
            mode = system.modes[i]
            Ab = np.zeros((d, d))
            Ab[:n, :n] = mode.A
            Ab[:n, n:n + nu] = mode.B
            M = controller.measurement(mode)
            e = controller.index(i, j, system.m)
            flows.append(Ab)
            meas.append(M)
            entries.append(e)
            pattern += np.abs(Ab)
            pattern[n:n + nu, :n] += np.abs(controller.Dc[e] @ M)
            pattern[n:n + nu, n + nu:] += np.abs(controller.Cc[e])
            pattern[n + nu:, :n] += np.abs(controller.Bc[e] @ M)
            pattern[n + nu:, n + nu:] += np.abs(controller.Ac[e])
        scale = np.ones(d)
        if np.all(np.isfinite(pattern)):
            _, (found, _) = scipy.linalg.matrix_balance(pattern + np.eye(d), permute=False, separate=True)
            scale = np.asarray(found, dtype=float)
        flows = [Ab / scale[:, None] * scale[None, :] for Ab in flows]
        modes_part = second_moment_matrix(flows, np.zeros((S, S)))
        loop = closed_loop(system, controller)
        from .sampled_frame import loop_similarity  # the one rule for the loop's coordinates

        if (sim := loop_similarity(system, controller)) is not None:  # a similarity does not change the speed
            loop = sim.apply(loop)
        rates = [float(np.linalg.norm(A, 2)) for A in loop.A]
        rates.append(float(np.max(np.abs(system.chain.generator(system.chain.rate_max)))))
        literals: dict[float, tuple[str, ...]] | None = None
        if system.literals is not None or controller.literals is not None:
            literals = {}
            for source in (system.literals or {}, controller.literals or {}):
                for value, texts in source.items():
                    literals[value] = literals.get(value, ()) + tuple(texts)
        return cls(system.chain, tuple(flows), tuple(meas), tuple(entries), controller, n, nu, modes_part, scale,
                   max(*rates, 1e-9), literals, system=system)

    def period_ball(self, h: float) -> Any:
        """The period ``h`` as a ball (``flint.arb``): exact for a period the analysis
        chose; for one the user wrote (``written``) its decimal text from the
        controller file, else every decimal read as ``h`` (:func:`ftc_verify.analysis.exact.enclose`)."""
        import flint

        from ..exact import enclose

        h = float(h)
        return enclose(h, self.literals or {}) if h in self.written else flint.arb(h)

    @property
    def nc(self) -> int:
        """Controller states."""
        return self.controller.n_c

    @property
    def d(self) -> int:
        """Dimension of the augmented state ``(x, u, x_c)`` inside a period."""
        return self.n + self.nu + self.nc

    @property
    def r(self) -> int:
        """Dimension of the sampled state ``(x, x_c)``."""
        return self.n + self.nc

    @property
    def states(self) -> int:
        """Joint states."""
        return len(self.flow)

    @property
    def size(self) -> int:
        """Rows of the one-period map :math:`T`: joint states times ``r (r + 1) / 2``."""
        return self.states * self.r * (self.r + 1) // 2

    def restriction(self) -> Matrix:
        """:math:`P` (``r x d``), selecting ``(x, x_c)`` from ``(x, u, x_c)``."""
        P = np.zeros((self.r, self.d))
        P[:self.n, :self.n] = np.eye(self.n)
        P[self.n:, self.n + self.nu:] = np.eye(self.nc)
        return P

    @property
    def scale_r(self) -> Matrix:
        """The scale of the sampled state ``(x, x_c)``."""
        return np.concatenate([self.scale[:self.n], self.scale[self.n + self.nu:]])

    def vech_weights(self) -> Matrix:
        """``vech`` of :math:`\\operatorname{diag}(s) X \\operatorname{diag}(s)` is ``weights *
        vech(X)`` (``s`` = :attr:`scale_r`), tiled over the joint states."""
        rows, cols = vech_order(self.r)
        c = self.scale_r
        return np.tile(c[rows] * c[cols], self.states)

    @functools.cached_property
    def restrict_map(self) -> Matrix:
        """:math:`L_r (P \\otimes P) D_d` (``vr x vd``), the same in every joint state."""
        Dd, _ = duplication_matrix(self.d)
        _, Lr = duplication_matrix(self.r)
        P = self.restriction()
        return np.asarray(Lr @ np.kron(P, P) @ Dd)

    @functools.cached_property
    def _static_lifts(self) -> Matrix:
        return self._lifts(0.0)

    def _lifts(self, h: float) -> Matrix:
        _, Ld = duplication_matrix(self.d)
        Dr, _ = duplication_matrix(self.r)
        return np.stack([Ld @ np.kron(R, R) @ Dr for R in self.resets(h)])

    def lifts(self, h: float) -> Matrix:
        """:math:`L_d (R_s \\otimes R_s) D_r` per joint state (``(S, vd, vr)``); computed
        once for a static controller (its resets do not depend on ``h``)."""
        return self._static_lifts if self.nc == 0 else self._lifts(h)

    def resets(self, h: float) -> tuple[Matrix, ...]:
        """:math:`R_s` (``d x r``) of every joint state at period ``h`` (float64), in the
        balanced coordinates."""
        n, nu, nc = self.n, self.nu, self.nc
        out = []
        for M, e in zip(self.measurement, self.entry):
            R = np.zeros((self.d, self.r))
            R[:n, :n] = np.eye(n)
            R[n:n + nu, :n] = self.controller.Dc[e] @ M
            if nc:
                Phic, Gamc = self.controller.discretise(e, h)
                R[n:n + nu, n:] = self.controller.Cc[e]
                R[n + nu:, :n] = Gamc @ M
                R[n + nu:, n:] = Phic
            out.append(R / self.scale[:, None] * self.scale_r[None, :])
        return tuple(out)


def one_period_map(loop: SampledLoop, h: float, rates: Matrix, *, scaled: bool = False) -> Matrix:
    """:math:`T` of the module docstring at period ``h`` and rate array ``rates`` (float64),
    computed in the balanced coordinates (:attr:`SampledLoop.scale`) and returned in the
    loop's own (``scaled=False``) or in those (``scaled=True``)."""
    Q = loop.chain.generator(rates)
    vd = loop.d * (loop.d + 1) // 2
    with np.errstate(over="ignore", invalid="ignore"):  # an overflow is a result: inf (spectral_radius)
        F = scipy.linalg.expm((loop.modes_part + np.kron(Q.T, np.eye(vd))) * float(h))
        T = assemble_map(loop, F, h)
    if scaled:
        return T
    w = loop.vech_weights()
    return T * w[:, None] / w[None, :]


def spectral_radius(loop: SampledLoop, h: float, rates: Matrix) -> float:
    """:math:`\\rho(T)` at period ``h`` and ``rates`` (float64 eigenvalues); ``inf`` when
    :math:`T` overflows float64 (a period so long that the moments leave its range). Kept
    in ``loop.memo``: the bisections and the ``h_max`` bracket ask for some again."""
    key = ("rho", float(h), np.asarray(rates, dtype=float).tobytes())
    if (found := loop.memo.get(key)) is None:
        T = one_period_map(loop, h, rates, scaled=True)
        found = math.inf if not np.all(np.isfinite(T)) else float(np.max(np.abs(scipy.linalg.eigvals(T, check_finite=False))))
        loop.memo[key] = found
    return float(found)


def rate_points(chain: JointChain, limit: int = 16) -> tuple[Matrix, ...]:
    """Rate arrays the float64 scan evaluates: every vertex of the box (up to ``limit``
    of them, else the two corners) and the midpoint. The proofs cover the whole box."""
    pts = list(chain.vertices()) if chain.vertex_count() <= limit else [chain.rate_min, chain.rate_max]
    return tuple(pts) + (chain.midpoint(),)


def worst_radius(loop: SampledLoop, h: float, points: Sequence[Matrix]) -> tuple[float, Matrix]:
    """The largest float64 :math:`\\rho(T)` over ``points`` and where it is attained."""
    best, where = -1.0, points[0]
    for p in points:
        rho = spectral_radius(loop, h, p)
        if not math.isfinite(rho):
            return math.inf, p
        if rho > best:
            best, where = rho, p
    return best, where


#: Periods per octave of the scan (:func:`scan_periods`).
SCAN_PER_OCTAVE = 8
#: The range of ``period * speed`` where ``scan_range`` widens the scan to the period.
SCAN_WIDEN = (1e-9, 1e9)


def assemble_map(loop: SampledLoop, F: Matrix, h: float) -> Matrix:
    """:math:`T` in the balanced coordinates from the flow :math:`F = e^{\\mathcal L h}`:
    block :math:`(t, s)` is :math:`\\mathcal P_0 F_{ts} \\mathcal R_s`, two batched
    products (the restriction and, for a static controller, the lifts computed once per
    loop, :meth:`SampledLoop.lifts`)."""
    restrict, lifts = loop.restrict_map, loop.lifts(h)
    S, vd, vr = loop.states, restrict.shape[1], restrict.shape[0]
    FL = np.matmul(F.reshape(S * vd, S, vd).transpose(1, 0, 2), lifts)  # (s, t vd + b, vr): F_ts R_s
    X = FL.transpose(1, 0, 2).reshape(S, vd, S * vr)  # (t, b, s vr + d)
    return np.matmul(restrict, X).reshape(S * vr, S * vr)


def scan_periods(loop: SampledLoop, lo: float, hi: float) -> tuple[Matrix, Matrix]:
    r"""``(hs, rho)``: periods from ``lo`` to at least ``hi``, :data:`SCAN_PER_OCTAVE` per
    octave (``h_k = lo 2^{k/8}``), and a worst float64 :math:`\rho(T)` over
    :func:`rate_points` at each as far as :func:`stability_intervals` reads it (``< 1``
    exactly where every point has :math:`\rho < 1`; once some point has
    :math:`\rho \ge 1` the others are not evaluated there). The flows are products of a
    ladder of squares (one exponential per rate point) applied to vectors, and most
    periods are decided by a Collatz--Wielandt cone test instead of eigenvalues
    (:mod:`~ftc_verify.analysis.moments.sampled_scan`, where the float error relied on is
    stated): the same periods and verdicts as the eigenvalues of the map."""
    from .sampled_scan import scan

    return scan(loop, lo, hi)


def crossing(loop: SampledLoop, a: float, b: float, stable_at_a: bool, rtol: float,
             points: Sequence[Matrix] | None = None) -> float:
    """Float64 bisection of the change of ``rho < 1`` (worst over ``points``, default
    :func:`rate_points`) between ``a`` and ``b``; returns the end on the side of ``a``'s
    verdict, within ``rtol`` relative. A step stops at its first point with ``rho >= 1``
    (tried first at the next step): the same verdicts, fewer exponentials."""
    pts = list(rate_points(loop.chain) if points is None else points)
    while (b - a) > rtol * max(abs(a), abs(b)):
        mid = 0.5 * (a + b)
        bad = next((k for k, p in enumerate(pts) if not spectral_radius(loop, mid, p) < 1.0), None)
        if bad is not None:
            pts.insert(0, pts.pop(bad))
        if (bad is None) == stable_at_a:
            a = mid
        else:
            b = mid
    return a


def stability_intervals(loop: SampledLoop, hs: Matrix, rho: Matrix, rtol: float = 1e-4) -> tuple[tuple[float, float], ...]:
    """Maximal runs of the scan with :math:`\\rho < 1`, their inner ends refined by
    float64 bisection (the scan's ends stay as they are)."""
    stable = rho < 1.0
    out = []
    k = 0
    while k < hs.size:
        if not stable[k]:
            k += 1
            continue
        start = k
        while k + 1 < hs.size and stable[k + 1]:
            k += 1
        lo = float(hs[0]) if start == 0 else crossing(loop, float(hs[start]), float(hs[start - 1]), True, rtol)
        hi = float(hs[-1]) if k == hs.size - 1 else crossing(loop, float(hs[k]), float(hs[k + 1]), True, rtol)
        out.append((lo, hi))
        k += 1
    return tuple(out)


def h_max_bracket(loop: SampledLoop, stable_h: float, unstable_h: float, *, rtol: float = H_MAX_RTOL,
                  max_boxes: int = 512, work: float | None = None,
                  deadline: float = math.inf) -> tuple[float | None, float | None, str]:
    """``(h_max, h_max_unstable, note)`` from a float64 bracket ``stable_h < unstable_h``
    of the crossing: :func:`ftc_verify.analysis.moments.sampled_bracket.h_max_bracket`
    (``work``: its budget per attempt, default
    :data:`~ftc_verify.analysis.moments.sampled_bracket.BRACKET_WORK`)."""
    from .sampled_bracket import BRACKET_WORK
    from .sampled_bracket import h_max_bracket as bracket

    return bracket(loop, stable_h, unstable_h, rtol=rtol, max_boxes=max_boxes,
                   work=BRACKET_WORK if work is None else work, deadline=deadline)


@dataclass(frozen=True, eq=False)
class SampledResult:
    """What :func:`sampled_analysis` found (JSON: :meth:`to_dict`, the ``sampled`` object).

    Attributes
    ----------
    period : float
    verdict : {"stable", "not stable", "undecided"}
        Mean-square stability of the nominal sampled loop over the whole rate box at
        ``period``, proved in ball arithmetic (:mod:`ftc_verify.analysis.moments.sampled_proof`).
    spectral_radius : float
        The worst float64 :math:`\\rho(T)` over :func:`rate_points`, and ``worst_rates``
        where.
    proof : str
        How the verdict was proved (or why it is undecided).
    h_max, h_max_unstable : float or None
        The proved bracket: stable over the box at ``h_max``, unstable at a rate point at
        ``h_max_unstable``, within :data:`H_MAX_RTOL` relative (``None`` if not found).
    stability_intervals : tuple of (float, float)
        Runs of periods with float64 :math:`\\rho < 1` at the scan's rate points in the
        scanned range; the first ends no later than ``h_max_unstable`` (where the bracket
        found a worse vertex, the loop is proved unstable there).
    scan : (float, float)
        The scanned range of periods.
    performance : SampledPerformance or None
        The proved gains at the period and their lower estimates
        (:mod:`ftc_verify.analysis.moments.sampled_gamma`), when computed; merged into
        :meth:`to_dict`.
    """

    period: float
    verdict: str
    spectral_radius: float
    worst_rates: Matrix
    proof: str
    boxes: int
    h_max: float | None
    h_max_unstable: float | None
    h_max_note: str
    stability_intervals: tuple[tuple[float, float], ...]
    scan: tuple[float, float]
    seconds: float
    performance: Any = None

    @property
    def stable(self) -> bool:
        """Proved mean-square stable at the period over the whole rate box."""
        return self.verdict == "stable"

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (``sampled`` in the report schema)."""
        return {
            "period": self.period, "verdict": self.verdict, "spectral_radius": self.spectral_radius,
            "worst_rates": np.asarray(self.worst_rates).tolist(), "proof": self.proof, "sub_boxes": self.boxes,
            "h_max": self.h_max, "h_max_unstable": self.h_max_unstable, "h_max_note": self.h_max_note,
            "stability_intervals": [list(iv) for iv in self.stability_intervals], "scan": list(self.scan),
            "seconds": self.seconds, **({} if self.performance is None else self.performance.to_dict()),
        }


def scan_range(loop: SampledLoop, period: float | None = None) -> tuple[float, float]:
    """Periods scanned for ``h_max``: from ``1e-3 / c`` to ``20 / c`` with ``c`` the
    largest closed-loop rate (:attr:`SampledLoop.speed`: the 2-norms of the continuous
    loop's matrices and the largest generator entry), widened to contain ``period`` when
    ``period c`` is within :data:`SCAN_WIDEN` (``1e308`` overflowed; the result names the range)."""
    c = loop.speed
    if period is not None and SCAN_WIDEN[0] <= period * c <= SCAN_WIDEN[1]:
        return min(1e-3 / c, period / 2), max(20.0 / c, period * 2)
    return 1e-3 / c, 20.0 / c


def sampled_analysis(system: FTCSystem, controller: Controller, period: float, *, max_boxes: int = 64,
                     h_max: bool = True, max_seconds: float = 60.0, loop: SampledLoop | None = None) -> SampledResult:
    """Mean-square stability of the sampled loop at ``period`` over the rate box (sub-box
    proofs, at most ``max_boxes``, and a clock-dependent certificate of the whole box:
    :func:`~ftc_verify.analysis.moments.sampled_clock.period_verdict`), and the proved
    ``h_max`` bracket (module docstring): the end of the stability interval that starts at
    the smallest scanned period, ``None`` when the loop is unstable there or stable over
    the whole scanned range (``h_max_note`` says which). Its proofs' budget is fixed by the
    problem's sizes (:func:`~ftc_verify.analysis.moments.sampled_bracket.box_work`); ``max_seconds``
    (wall) is a safety valve: the sub-box proofs at the period get a third of it. ``loop``:
    the sampled loop of ``system`` and ``controller`` when the caller has built it
    (:meth:`SampledLoop.build`; built here otherwise)."""
    from .sampled_bracket import period_worst
    from .sampled_clock import period_verdict
    from .sampled_conditioned import conditioned

    period = check_period(period, "period")
    t0 = time.perf_counter()
    loop = dataclasses.replace(SampledLoop.of(system, controller, loop), written=(float(period),))
    rho, where = period_worst(loop, period)
    verdict = period_verdict(loop, period, rho, max_boxes=max_boxes, max_seconds=max_seconds / 3, where=where)
    if verdict.verdict == "undecided" and not math.isfinite(rho):  # the map overflows float64: decide it in Arb
        from .sampled_overflow import overflow_verdict
        verdict = overflow_verdict(loop, period, where) or verdict
    lo, hi = scan_range(loop, period)
    intervals: tuple[tuple[float, float], ...] = ()
    hm, hu, note = None, None, "not requested"
    if h_max:
        loop = conditioned(loop)  # the scan and bracket in the proofs' coordinates (same spectrum)
        hs, rhos = scan_periods(loop, lo, hi)
        intervals = stability_intervals(loop, hs, rhos)
        if not intervals or intervals[0][0] > hs[0]:
            note = f"the sampled loop is not stable at the smallest scanned period {hs[0]:.3g} (float64)"
        elif intervals[0][1] >= hs[-1]:
            note = f"stable at every scanned period up to {hs[-1]:.6g} (float64 scan); no h_max below it"
        else:
            k = int(np.searchsorted(hs, intervals[0][1], side="right"))
            hm, hu, note = h_max_bracket(loop, float(hs[k - 1]), float(hs[k]), deadline=t0 + max_seconds)
            if hu is not None and intervals[0][1] > hu:  # a worse vertex than the scan's points
                intervals = ((intervals[0][0], hu),) + intervals[1:]
    return SampledResult(period, verdict.verdict, rho, where, verdict.detail, verdict.boxes, hm, hu, note,
                         intervals, (lo, hi), time.perf_counter() - t0)
