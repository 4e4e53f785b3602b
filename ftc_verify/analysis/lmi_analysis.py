r"""LMI analysis of a fixed closed loop, with independently checked certificates.

* :func:`mes_lmi` -- Theorem 3.1 over the whole rate box: find :math:`P_s > 0` (one per
  joint state of :mod:`ftc_verify.model.chain`) with :math:`\Pi_s < 0` at every vertex of
  the rates of row :math:`s` (:func:`~ftc_verify.analysis.lmi.block_specs`; what a
  certificate means at a missed-detection vertex, :math:`\beta = 0`, is stated in
  :mod:`ftc_verify.analysis.lmi`). The conditions are homogeneous in
  :math:`P`, so the solver is asked for :math:`P_s \succeq I`, :math:`\Pi_s \preceq -I`
  (equivalent to strict feasibility) while minimising :math:`\max_s \lambda_{max}(P_s)`
  for conditioning.
* :func:`hinf_gamma` -- the smallest certified :math:`\gamma` of Theorem 3.2 (nominal,
  ``robust=False``) or of Lemma 4.1 with the gains fixed (``robust=True``; the
  S-procedure multipliers are free, so the problem is convex).

The minimal-:math:`\gamma` optimum lies on the boundary of the feasible set (singular Lyapunov matrices), where
no certificate can pass. With Clarabel, :func:`hinf_gamma` first solves *one* program with the margin built in
(``_margin_gamma``): minimise :math:`g` with every block :math:`\preceq -\tau I` and :math:`P_s \succeq \tau I`
(``MARGIN_TAU``, on the blocks with :math:`B_w/\hat\gamma`, :math:`\hat\gamma` a hint from below or 1); its
optimum is interior, so its certificate passes, and the dual point bounds the :math:`\tau = 0` minimum from
below, which says how far above the minimum the certified gamma is (re-solved, at most ``MARGIN_SOLVES`` times,
when more than ``MARGIN_GAP``): one solve per certified gamma where the ladder below needs two. When that path
gives no certificate, and with the other solvers, the two-step ladder runs: minimise :math:`g = \gamma^2`, then
re-solve at :math:`\gamma_1 = \gamma^*(1+\rho)` for :math:`\rho` in :data:`GAMMA_LADDER`, maximising a common
margin :math:`t` with :math:`M_s \preceq -t I`, :math:`P_s \succeq t I` -- on the blocks congruent by
:math:`\operatorname{diag}(I, \gamma_1^{-1} I, I)`, i.e. with :math:`B_w/\gamma_1` and :math:`g = 1`, so that a
large :math:`\gamma` does not make the :math:`-gI` row dwarf the margin (the same :math:`P` certifies both) --
and reports the first :math:`\gamma_1` whose certificate passes -- after ``REFINE_STEPS`` geometric bisections
of :math:`\rho` between that step and the one before it when the one before failed, so that a coarse ladder does
not cost up to a factor 10 in :math:`\rho`.

Conditioning: before any LMI is built the loop is moved to the coordinates of
:func:`~ftc_verify.analysis.conditioning.conditioning_transform` (one similarity
:math:`x = T\tilde x` common to every joint state: power-of-two balancing, then the
balanced realisation of the mode-averaged loop), where the solver sees well-scaled data.
The certificate is not trusted to the transform: it is the original-coordinate
:math:`P_s = T^{-T}\tilde P_s T^{-1}`, formed and checked in ball arithmetic on the
original loop (:func:`~ftc_verify.analysis.lmi.check_certificate`); the returned ``P``
are that product rounded to float, ``P_conditioned`` and ``similarity`` the exact
certificate.

The programs are written by :mod:`ftc_verify.analysis.conic` from the blocks of
:mod:`ftc_verify.analysis.lmi` and solved by :func:`~ftc_verify.analysis.solvers.solve_conic`
(Clarabel directly; SDPA and SCS through cvxpy). A variable ``P_s`` is its ``svec``
coordinates, so ``P_s`` is symmetric by construction.

Outcomes: ``certified`` (the numpy check of :mod:`ftc_verify.analysis.lmi` passed),
``candidate`` (a solver returned numbers that failed the check), ``infeasible`` (the
solver and a second, independent solver both claimed infeasibility) and ``error``.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..claimtext import upper_text
from ..jsonable import fields_dict
from ..model.system import Matrix
from .closedloop import ClosedLoop
from .conditioning import Similarity, conditioning_transform
from .conic import ConicProblem, Rows, affine_bmat, scalar_variable, svec_index, sym_variable
from .lmi import Certificate, block_specs, check_certificate, lyapunov_block
from .bounded_real import lyapunov_candidate, riccati_candidate
from .robust_riccati import robust_riccati_candidate
from .shared_channels import ChannelGroup, group_cones, merged_first, merged_loop, shared_input_groups
from .lmi_size import (RICCATI_FIRST_SIZE, RICCATI_FIRST_STATES, SDP_FALLBACK_LIMIT, check_size, decision_size,
                       sdp_fallback_refusal)
from .solvers import LEAN_SETTINGS, SETTINGS, SolveOutcome, choose_solver, second_solver, solve_conic, solve_conic_dual

__all__ = ["GAMMA_LADDER", "ROUTES", "LMIResult", "mes_lmi", "mes_known", "hinf_gamma"]

#: Relative increases of gamma tried, in order, when re-solving for a certificate.
GAMMA_LADDER = (1e-5, 1e-4, 1e-3, 1e-2, 5e-2, 0.2, 1.0)
#: Geometric bisections between the last failing and the first certifying ladder step.
REFINE_STEPS = 3
#: Margin of the one-solve program (``_margin_gamma``): blocks <= -tau I, P >= tau I, in the coordinates where
#: the output row is -I and ``g`` is about 1. Measured on random n = 8, 3 modes and n = 12, 4 modes: certified at
#: 1e-7 already, gamma 1e-6 relative above the dual bound at 1e-6.
MARGIN_TAU = 1e-6
#: Routes of :func:`hinf_gamma`.
ROUTES = ("auto", "sdp", "riccati")
#: The one-solve path re-solves when its gamma is more than this above the dual bound.
MARGIN_GAP = 1e-4
#: At most this many solves on the one-solve path before the two-step ladder.
MARGIN_SOLVES = 3


@dataclass(frozen=True, eq=False)
class LMIResult:
    """Outcome of one LMI analysis, with the certificate and the matrices found."""

    condition: str
    outcome: str
    gamma: float | None
    solver: str
    solver_status: str
    build_seconds: float
    solve_seconds: float
    certificate: Certificate | None
    P: tuple[Matrix, ...] | None = None
    multipliers: tuple[tuple[float, ...], ...] | None = None
    message: str = ""
    attempts: tuple[SolveOutcome, ...] = field(default=())
    similarity: Similarity | None = None
    P_conditioned: tuple[Matrix, ...] | None = None

    @property
    def certified(self) -> bool:
        """True only when the independent certificate passed."""
        return self.outcome == "certified" and self.certificate is not None and self.certificate.ok

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (matrices omitted)."""
        return {
            "condition": self.condition,
            "outcome": self.outcome,
            "certified": self.certified,
            "gamma": self.gamma,
            "solver": self.solver,
            "solver_settings": SETTINGS.get(self.solver, {}),
            "solver_status": self.solver_status,
            "build_seconds": self.build_seconds,
            "solve_seconds": self.solve_seconds,
            "message": self.message,
            "certificate": None if self.certificate is None else self.certificate.to_dict(),
            "attempts": [fields_dict(a) for a in self.attempts],
            "conditioning": None if self.similarity is None else self.similarity.to_dict(),
        }


def _conditioned(loop: ClosedLoop) -> tuple[ClosedLoop, Similarity]:
    return (sim := conditioning_transform(loop)).apply(loop), sim


def _map_back(result: LMIResult, sim: Similarity) -> LMIResult:
    """Record the conditioned ``P`` (the certificate, with ``sim``) and map ``P`` back
    to the original coordinates (rounded: the exact certificate is the product)."""
    if result.P is None:
        return dataclasses.replace(result, similarity=sim)
    return dataclasses.replace(result, P=tuple(sim.lyapunov_back(P) for P in result.P), P_conditioned=result.P,
                               similarity=sim)


@dataclass(frozen=True)
class _Layout:
    """Where each decision variable of the analysis programs lives in ``x``:
    ``svec(P_s)`` for every joint state, the multipliers ``lambda`` (robust only; with
    each group's ``mu`` after the state's own, :mod:`~ftc_verify.analysis.shared_channels`),
    then ``g``, ``t`` and the groups' ``sigma``."""

    n: int
    modes: int
    channels: tuple[int, ...]  # multipliers per joint state (all 0 when not robust), the groups' mu included
    groups: tuple[ChannelGroup, ...] = ()
    checked: tuple[int, ...] = ()  # the loop's own channels per joint state (without the mu)

    @property
    def per_p(self) -> int:
        return self.n * (self.n + 1) // 2

    @property
    def lam_start(self) -> tuple[int, ...]:
        first = self.modes * self.per_p
        return tuple(first + sum(self.channels[:s]) for s in range(self.modes))

    @property
    def g(self) -> int:
        return self.modes * self.per_p + sum(self.channels)

    @property
    def t(self) -> int:
        return self.g + 1

    @property
    def K(self) -> int:
        return self.g + 2 + sum(len(group.members) for group in self.groups)

    def values(self, x: Matrix, robust: bool) -> tuple[tuple[Matrix, ...], tuple[tuple[float, ...], ...] | None]:
        """``(P, lambda)`` at the point ``x`` (``P`` rebuilt from its ``svec``)."""
        r, c, w = svec_index(self.n)
        P = []
        for s in range(self.modes):
            M = np.zeros((self.n, self.n))
            M[r, c] = x[s * self.per_p:(s + 1) * self.per_p] / w
            M[c, r] = M[r, c]
            P.append(M)
        lam = None
        if robust:
            lam = tuple(tuple(float(v) for v in x[a:a + k]) for a, k in zip(self.lam_start, self.checked or self.channels))
        return tuple(P), lam


def _layout(loop: ClosedLoop, robust: bool, merge: bool = False) -> _Layout:
    groups = shared_input_groups(loop) if robust and merge else ()
    own = tuple(len(c) if robust else 0 for c in loop.channels)
    mus = tuple(sum(1 for group in groups if group.s == s) for s in range(len(loop.A)))
    return _Layout(loop.n, len(loop.A), tuple(a + b for a, b in zip(own, mus)), groups, own)


def _block_rows(loop: ClosedLoop, lay: _Layout, *, with_g: bool, margin: float | None) -> Rows:
    """The rows of every block of :func:`~ftc_verify.analysis.lmi.block_specs`:
    ``block(P, lambda, g) + t I <= 0`` (``margin`` a number instead of the variable
    ``t`` when given; ``with_g=False`` gives Theorem 3.1's blocks). Each block is built
    on its own variables only (``P_s``, the ``P`` it couples to, its multipliers, ``g``,
    ``t``) and placed into the global columns."""
    rows = Rows(lay.K)
    robust = any(lay.channels)
    loop = merged_loop(loop, lay.groups)  # the channels sharing an E: one border (shared_channels)
    for spec in block_specs(loop):
        coupled = [spec.s] + [t for t, q in enumerate(spec.q_row) if q != 0.0 and t != spec.s]
        columns = np.concatenate([np.arange(t * lay.per_p, (t + 1) * lay.per_p) for t in coupled]
                                 + [np.arange(lay.lam_start[spec.s], lay.lam_start[spec.s] + lay.channels[spec.s]),
                                    [lay.g, lay.t]]).astype(int)
        k_loc = len(columns)
        P: list[Any] = [None] * lay.modes
        for pos, t in enumerate(coupled):
            P[t] = sym_variable(lay.n, pos * lay.per_p, k_loc)
        base = len(coupled) * lay.per_p
        lam = [scalar_variable(base + k, k_loc) for k in range(lay.channels[spec.s])] if robust else None
        g = scalar_variable(k_loc - 2, k_loc) if with_g else None
        M = lyapunov_block(loop, spec, P, lam, g, affine_bmat)
        eye = np.eye(M.shape[0])
        M = M + (margin * eye if margin is not None else scalar_variable(k_loc - 1, k_loc) * eye)
        rows.lmi(M, columns)
    return rows


def _p_rows(rows: Rows, lay: _Layout, *, low: float | None, high: bool) -> None:
    """``P_s >= low I`` (``t I`` when ``low`` is None) and, with ``high``, ``P_s <= t I``."""
    for s in range(lay.modes):
        P = sym_variable(lay.n, 0, lay.per_p + 1)
        eye = np.eye(lay.n)
        t = scalar_variable(lay.per_p, lay.per_p + 1)
        columns = np.concatenate([np.arange(s * lay.per_p, (s + 1) * lay.per_p), [lay.t]]).astype(int)
        rows.lmi(-P + (low * eye if low is not None else t * eye), columns)
        if high:
            rows.lmi(P - t * eye, columns)


def _nonneg(rows: Rows, lay: _Layout, index: Sequence[int]) -> None:
    """``x_k >= 0`` for each ``k`` in ``index``."""
    A = np.zeros((len(index), lay.K))
    A[np.arange(len(index)), list(index)] = -1.0
    rows.nonneg(A, np.zeros(len(index)))


def _solver_order(loop: ClosedLoop, solver: str | None, robust: bool) -> list[str]:
    first = choose_solver(solver, decision_size(loop, robust=robust))
    second = second_solver(first)
    return [first] + ([second] if second else [])


def _conclude(condition: str, attempts: list[SolveOutcome], best: LMIResult | None, t_build: float) -> LMIResult:
    """Candidate if some solver returned numbers, infeasible if every solver claimed so
    (at least two different solvers), error otherwise."""
    if best is not None:
        return best
    seconds = sum(a.seconds for a in attempts)
    last = attempts[-1]
    if len({a.solver for a in attempts}) >= 2 and all(a.infeasible for a in attempts):
        msg = "infeasible: " + ", ".join(f"{a.solver} says {a.status}" for a in attempts)
        return LMIResult(condition, "infeasible", None, attempts[0].solver, attempts[0].status, t_build, seconds, None, message=msg, attempts=tuple(attempts))
    msg = "; ".join(f"{a.solver}: {a.status}{' (' + a.message + ')' if a.message else ''}" for a in attempts)
    if all(a.infeasible for a in attempts):
        msg = "infeasibility claimed but not confirmed by a second solver: " + msg
    return LMIResult(condition, "error", None, last.solver, last.status, t_build, seconds, None, message=msg, attempts=tuple(attempts))


def mes_lmi(loop: ClosedLoop, *, solver: str | None = None, known: Sequence[LMIResult] = (),
            second_opinion: bool = True) -> LMIResult:
    r"""Theorem 3.1 (eq. (4)) on the nominal loop over the rate box, certified, on
    the balanced loop (module docstring).

    ``known``: certified :math:`H_\infty` results of the same loop (Theorem 3.2, Lemma
    4.1). Their :math:`P` is tried first, without a solve: :math:`\Pi_s` is the leading
    principal block of Theorem 3.2's block, and :math:`\Pi_s + \sum_k \lambda_k F_k^T
    F_k` (with :math:`\lambda_k \ge 0`) that of Lemma 4.1's, so by eigenvalue
    interlacing :math:`\Pi_s` is negative definite with at least the same margin. The
    numpy check of Theorem 3.1 is still run on that :math:`P`; only if it fails (or no
    result is certified) is the LMI solved. ``second_opinion=False`` skips the second
    solver that confirms an infeasibility (the branch and bound of
    :mod:`ftc_verify.analysis.box` needs a certificate or nothing).
    """
    passed = mes_known(loop, known)
    if passed is not None:
        return passed
    nominal, sim = _conditioned(loop.nominal())
    if decision_size(loop.nominal(), robust=False) > SDP_FALLBACK_LIMIT:  # no SDP at this size (lmi_size)
        found = lyapunov_candidate(loop.nominal(), nominal, sim)
        why = "" if found.certificate is not None else sdp_fallback_refusal(loop.nominal(), False, "Theorem 3.1")
        return _map_back(LMIResult("theorem-3.1", "error" if why else "certified", None, "riccati", "failed" if why else
                                   "optimal", 0.0, 0.0, found.certificate, found.P, message=found.message + why), sim)
    check_size(loop, False, "Theorem 3.1")
    return _map_back(_mes_lmi(loop.nominal(), nominal, sim, solver, second_opinion), sim)


def mes_known(loop: ClosedLoop, known: Sequence[LMIResult]) -> LMIResult | None:
    """The first step of :func:`mes_lmi` alone: Theorem 3.1 certified with the ``P`` of
    the first certified result of ``known`` whose check passes (no solve), ``None``
    when none passes. :func:`~ftc_verify.analysis.analyze.analyze` runs it on Theorem
    3.2's answer while Lemma 4.1's program is still running."""
    for result in known:
        if result.certified and result.P is not None:
            P = result.P if result.P_conditioned is None else result.P_conditioned
            cert = check_certificate(loop.nominal(), "theorem-3.1", P, None, None, similarity=result.similarity)
            if cert.ok:
                note = f"certificate passed with the P of the certified {result.condition} answer (no solve)"
                return LMIResult("theorem-3.1", "certified", None, result.solver, result.solver_status, 0.0, 0.0,
                                 cert, result.P, message=note, similarity=result.similarity,
                                 P_conditioned=result.P_conditioned)
    return None


def _mes_lmi(original: ClosedLoop, nominal: ClosedLoop, sim: Similarity, solver: str | None,
             second_opinion: bool = True) -> LMIResult:
    """Theorem 3.1 solved on the conditioned ``nominal``, certified on ``original``."""
    condition = "theorem-3.1"
    t0 = time.perf_counter()
    lay = _layout(nominal, robust=False)
    rows = _block_rows(nominal, lay, with_g=False, margin=1.0)
    _p_rows(rows, lay, low=1.0, high=True)
    objective = np.zeros(lay.K)
    objective[lay.t] = 1.0
    problem = rows.problem(objective).fix(lay.g, 0.0)
    t_build = time.perf_counter() - t0
    attempts: list[SolveOutcome] = []
    best: LMIResult | None = None
    for name in _solver_order(nominal, solver, robust=False)[:None if second_opinion else 1]:
        out, x = solve_conic(problem, name)
        attempts.append(out)
        if x is None:
            continue
        Pv, _ = lay.values(x, robust=False)
        cert = check_certificate(original, condition, Pv, None, None, similarity=sim)
        outcome = "certified" if cert.ok else "candidate"
        note = "" if out.status == "optimal" else f"solver status {out.status}; "
        res = LMIResult(condition, outcome, None, name, out.status, t_build, sum(a.seconds for a in attempts), cert, Pv,
                        message=note + ("certificate passed" if cert.ok else cert.reason), attempts=tuple(attempts))
        if cert.ok:
            return res
        best = best or res
    return _conclude(condition, attempts, best, t_build)


def hinf_gamma(loop: ClosedLoop, *, robust: bool, solver: str | None = None,
               gamma_hint: float | None = None, route: str = "auto", lean: bool = False) -> LMIResult:
    """Smallest certified gamma: Theorem 3.2 (``robust=False``, eq. (12), Delta = 0) or
    Lemma 4.1 with the gains fixed (``robust=True``, eq. (16) in LMI form), on the
    balanced loop (module docstring).

    ``gamma_hint``: an estimate of the answer, preferably from below (the certified
    nominal gamma for Lemma 4.1, whose blocks contain Theorem 3.2's as leading blocks);
    it only scales the one-solve program (``_margin_gamma``), never the answer.

    ``lean``: the one-solve program first with :data:`~ftc_verify.analysis.solvers.LEAN_SETTINGS` (``analyze``'s
    calls; the synthesis certifies its iterates with the full settings, whose answers steer its path).

    ``route``: ``"auto"`` tries, above :data:`~ftc_verify.analysis.lmi_size.RICCATI_FIRST_SIZE` decision variables
    (with at least :data:`~ftc_verify.analysis.lmi_size.RICCATI_FIRST_STATES` states), the
    coupled-Riccati candidate (:func:`~ftc_verify.analysis.bounded_real.riccati_candidate`:
    no SDP, proved at every vertex like an SDP answer) first (Theorem 3.2, or Lemma 4.1
    without uncertainty channels; with them, the augmented loop's candidate of
    :func:`~ftc_verify.analysis.robust_riccati.robust_riccati_candidate`), the SDP when
    none passes (below: the SDP alone, faster and up to about 1 % tighter); ``"sdp"``,
    ``"riccati"``: only that one."""
    if route not in ROUTES:
        raise ValueError(f"route must be one of {', '.join(ROUTES)}, got {route!r}")
    original = loop if robust else loop.nominal()
    conditioned, sim = _conditioned(original)
    fallback, t0 = "", time.perf_counter()
    first = route == "riccati" or (route == "auto" and decision_size(original, robust=False) > RICCATI_FIRST_SIZE
                                   and original.n >= RICCATI_FIRST_STATES)
    if first:
        augmented = robust and loop.uncertain
        found = (robust_riccati_candidate if augmented else riccati_candidate)(original, conditioned, sim)
        refused = "" if found.certificate is not None or route == "riccati" else \
            sdp_fallback_refusal(original, robust, "Lemma 4.1" if robust else "Theorem 3.2")
        if found.certificate is not None or route == "riccati" or refused:
            return _map_back(LMIResult("lemma-4.1" if robust else "theorem-3.2",
                                       "certified" if found.certificate is not None else "error", found.gamma, "riccati",
                                       "optimal" if found.gamma else "failed", 0.0, time.perf_counter() - t0,
                                       found.certificate, found.P, found.multipliers, found.message + refused), sim)
        fallback = f"; the Riccati candidate was not used ({found.message}), SDP fallback"
    check_size(loop, robust, "Lemma 4.1" if robust else "Theorem 3.2")
    result = _hinf_gamma(original, conditioned, sim, robust, solver, gamma_hint, lean)
    return _map_back(dataclasses.replace(result, message=result.message + fallback), sim)


def _two_step_status(step1: SolveOutcome, step2: SolveOutcome) -> str:
    """The status of a two-step answer: step 2's, or step 1's when step 2 was ``optimal`` (none hidden)."""
    return step2.status if step2.status != "optimal" else step1.status


def _gamma_rows(target: ClosedLoop, lay: _Layout, robust: bool) -> Rows:
    """Every block with the variables ``g`` and ``t`` (``block + t I <= 0``),
    ``P_s >= t I`` and, robust, ``lambda >= 0``."""
    rows = _block_rows(target, lay, with_g=True, margin=None)
    _p_rows(rows, lay, low=None, high=False)
    if robust:
        _nonneg(rows, lay, range(lay.lam_start[0], lay.g))
        group_cones(rows, lay.groups, lay.lam_start, lay.checked, lay.t, lay.t + 1)
    return rows


def _margin_problem(target: ClosedLoop, lay: _Layout, robust: bool, gamma_hat: float) -> ConicProblem:
    r"""``min g`` s.t. every block ``+ t I <= 0``, ``P_s >= t I``, ``g >= 0``, on the loop
    with ``Bw / gamma_hat`` (the congruence ``diag(I, I / gamma_hat, I)``: ``gamma =
    gamma_hat sqrt(g)``, the same ``P``); ``t`` still a column, fixed by the caller."""
    scaled = dataclasses.replace(target, Bw=tuple(B / gamma_hat for B in target.Bw))
    g_row = np.zeros((1, lay.K))
    g_row[0, lay.g] = -1.0
    objective = np.zeros(lay.K)
    objective[lay.g] = 1.0
    return _gamma_rows(scaled, lay, robust).extended(g_row, [0.0]).problem(objective)


def _margin_gamma(original: ClosedLoop, target: ClosedLoop, sim: Similarity, robust: bool, gamma_hint: float | None,
                  attempts: list[SolveOutcome], merge: bool = False, ended: list[bool] | None = None,
                  lean: bool = False) -> LMIResult | None:
    r"""The certified gamma in (usually) one Clarabel solve, ``None`` when this path gives no certificate (then
    the two-step ladder); ``merge``: the program of :func:`_layout` with ``merge``; ``True`` appended to ``ended``
    when it ended cleanly.

    Minimise ``g`` with every block :math:`\preceq -\tau I` and :math:`P_s \succeq \tau I` (``MARGIN_TAU``;
    ``Bw / gamma_hat`` as in step 2 of the ladder, ``gamma_hat`` the hint, else 1): the optimum is interior by
    :math:`\tau`, so its certificate passes where the plain minimum's cannot, and ``-b' z`` at the dual point
    ``z`` bounds the :math:`\tau = 0` minimum from below (the dual constraints do not depend on :math:`\tau`).
    When the certified gamma is more than ``MARGIN_GAP`` above that bound, the program is re-solved scaled by
    the certified gamma with :math:`\tau` cut in proportion; when the certificate fails, with :math:`100\tau`.
    At most ``MARGIN_SOLVES`` solves (``lean``: each with Clarabel's :data:`~ftc_verify.analysis.solvers.LEAN_SETTINGS`,
    again with the full settings when that gives no point or no certificate); the smallest certified gamma is
    kept; clean: the last one ``optimal`` within ``MARGIN_GAP``. The certificate is the proof; the bound is
    only the reported minimum (as step 1's)."""
    condition = "lemma-4.1" if robust else "theorem-3.2"
    lay = _layout(target, robust, merge)
    gamma_hat = gamma_hint if gamma_hint is not None and math.isfinite(gamma_hint) and gamma_hint > 0 else 1.0
    tau = MARGIN_TAU
    best: LMIResult | None = None
    for _ in range(MARGIN_SOLVES):
        problem = _margin_problem(target, lay, robust, gamma_hat)
        for settings in (LEAN_SETTINGS, None) if lean else (None,):  # lean first; full when no certificate
            out, x, z = solve_conic_dual(problem.fix(lay.t, tau), settings)
            attempts.append(out)
            if x is not None and z is not None:
                x = np.insert(x, lay.t, tau)
                gamma, bound = (gamma_hat * math.sqrt(max(v, 0.0)) for v in (float(x[lay.g]), -float(problem.b @ z)))
                Pv, lv = lay.values(x, robust)
                cert = check_certificate(original, condition, Pv, lv, gamma ** 2, similarity=sim)
                if cert.ok:
                    break
        if x is None or z is None:
            break
        if not cert.ok:
            if best is not None:
                break
            tau *= 100.0
            continue
        gap = gamma / bound - 1.0 if bound > 0 else math.inf
        if best is None or best.gamma is None or gamma < best.gamma:
            note = (f"minimum {bound:.6g} (dual bound of the margin program); certified at {upper_text(gamma)} "
                    f"(+{max(gap, 0.0):.3g} relative), margin {tau:.3g}, one-solve path")
            if out.status != "optimal":
                note += f"; solver status {out.status}, accepted only because the certificate passed"
            best = LMIResult(condition, "certified", gamma, "clarabel", out.status, 0.0, 0.0, cert, Pv, lv, note)
        if out.status == "optimal" and gap <= MARGIN_GAP:
            (ended if ended is not None else []).append(True)
            break
        gamma_hat, tau = gamma, max(tau * min(1.0, 0.1 * MARGIN_GAP / max(gap, 1e-300)), 1e-9)
    return best


def _hinf_gamma(original: ClosedLoop, target: ClosedLoop, sim: Similarity, robust: bool,
                solver: str | None, gamma_hint: float | None = None, lean: bool = False) -> LMIResult:
    """The one-solve path (Clarabel; the shared channels merged first,
    :func:`~ftc_verify.analysis.shared_channels.merged_first`), else the two steps, on the
    conditioned ``target``; every certificate checked on ``original``."""
    condition = "lemma-4.1" if robust else "theorem-3.2"
    lay = _layout(target, robust)  # the ladder: the full program
    attempts: list[SolveOutcome] = []
    best: LMIResult | None = None
    t_build = 0.0
    for name in _solver_order(target, solver, robust):
        t0, before = time.perf_counter(), len(attempts)
        fast = merged_first(lambda merge, ended: _margin_gamma(original, target, sim, robust, gamma_hint, attempts, merge,
                                                               ended, lean),
                            robust and bool(shared_input_groups(target))) if name == "clarabel" else None
        t_build += time.perf_counter() - t0 - sum(a.seconds for a in attempts[before:])
        if fast is not None:
            return dataclasses.replace(fast, build_seconds=t_build, attempts=tuple(attempts),
                                       solve_seconds=sum(a.seconds for a in attempts))
        found = _ladder(original, target, sim, robust, name, lay, attempts, t_build)
        if found is not None and found.certified:
            return found
        best = best or found
    if best is not None:
        best = dataclasses.replace(best, solve_seconds=sum(a.seconds for a in attempts), attempts=tuple(attempts))
    return _conclude(condition, attempts, best, t_build)


def _ladder(original: ClosedLoop, target: ClosedLoop, sim: Similarity, robust: bool, name: str,
            lay: _Layout, attempts: list[SolveOutcome], t_build: float) -> LMIResult | None:
    """The two steps with solver ``name`` (module docstring): the certified result, else
    a candidate, else ``None`` (no point returned)."""
    condition = "lemma-4.1" if robust else "theorem-3.2"
    minimise_g, g_row = np.zeros(lay.K), np.zeros((1, lay.K))
    minimise_g[lay.g], g_row[0, lay.g] = 1.0, -1.0
    step1 = _gamma_rows(target, lay, robust).extended(g_row, [0.0]).problem(minimise_g).fix(lay.t, 0.0)
    out, x = solve_conic(step1, name)  # min g: blocks <= 0, P >= 0
    attempts.append(out)
    if x is None:
        return None
    gamma_star = math.sqrt(max(float(x[lay.g]), 0.0))
    maximise_t, t_row = np.zeros(lay.K), np.zeros((1, lay.K))
    maximise_t[lay.t], t_row[0, lay.t] = -1.0, 1.0

    def attempt(rho: float) -> tuple[float, SolveOutcome, Any, Any, Any] | None:
        """Step 2 at ``gamma_star (1 + rho)``: max t <= 1 on the loop with ``Bw / gamma1``
        and ``g = 1`` (the congruence ``diag(I, I / gamma1, I)`` of the same block, so the
        same ``P``); ``(gamma1, outcome, P, lambda, numpy check)``."""
        gamma1 = max(gamma_star, 1e-7) * (1.0 + rho)
        scaled = dataclasses.replace(target, Bw=tuple(B / gamma1 for B in target.Bw))
        step2 = _gamma_rows(scaled, lay, robust).extended(t_row, [1.0]).problem(maximise_t).fix(lay.g, 1.0)
        out2, x2 = solve_conic(step2, name)
        attempts.append(out2)
        if x2 is None:
            return None
        Pv, lv = lay.values(x2, robust)
        return gamma1, out2, Pv, lv, check_certificate(original, condition, Pv, lv, gamma1 ** 2, similarity=sim)

    failed, candidate = 0.0, None  # the largest rho tried that gave no certificate
    for rho in GAMMA_LADDER:
        found = attempt(rho)
        if found is not None and found[4].ok:
            for _ in range(REFINE_STEPS if failed > 0 else 0):  # bisect (geometrically) towards gamma_star
                mid = math.sqrt(failed * rho)
                closer = attempt(mid)
                if closer is not None and closer[4].ok:
                    rho, found = mid, closer
                else:
                    failed = mid
            gamma1, out2, Pv, lv, cert = found
            status = _two_step_status(out, out2)
            note = f"minimum {gamma_star:.6g} from step 1; certified at {upper_text(gamma1)} (+{rho:.3g} relative)"
            if status != "optimal":
                note += f"; solver status {status}, accepted only because the certificate passed"
            return LMIResult(condition, "certified", gamma1, name, status, t_build,
                             sum(a.seconds for a in attempts), cert, Pv, lv, note, tuple(attempts))
        failed = rho
        if found is not None and candidate is None:
            gamma1, out2, Pv, lv, cert = found
            candidate = LMIResult(condition, "candidate", gamma_star, name, _two_step_status(out, out2), t_build,
                                  sum(a.seconds for a in attempts), cert, Pv, lv,
                                  f"no certificate up to gamma {gamma1:.6g}: {cert.reason}", tuple(attempts))
    return candidate
