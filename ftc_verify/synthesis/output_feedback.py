r"""Output-feedback synthesis: full-order dynamic controllers that switch with the FDI mode.

The controller of FDI mode ``j`` reads the measured output :math:`y_m = C_{y,i} x` (``Cy``
of the true mode ``i``; ``C`` when the system gives none) and is

.. math::  \dot x_c = \hat A_j x_c + \hat B_j y_m, \qquad u = \hat C_j x_c + \hat D_j y_m,
           \qquad \mathcal K_j = \begin{bmatrix} \hat A_j & \hat B_j \\ \hat C_j & \hat D_j \end{bmatrix},

with :math:`n_c = n`. With the barred matrices of :mod:`ftc_verify.analysis.closedloop`
(the paper's Section V definitions, ``Cy`` in place of ``C`` in :math:`\bar C_i`) the loop
is :math:`\bar A_{0i} + \bar B_{0i} \mathcal K_j \bar C_i`: static output feedback of the
**augmented plant** :func:`~ftc_verify.synthesis.of_blocks.augmented_system` (state :math:`(x, x_c)`, input
:math:`(\dot x_c, u)`) through :math:`\bar C_i`. So every tool of state feedback applies to
the augmented plant, and the closed loop is the one :func:`closed_loop` builds for the
dynamic controller (same state order, same two uncertainty channels), on which the core
analysis certifies every result.

Methods:

``observer`` (baseline)
    Per FDI mode, certified state-feedback gains :math:`K_j` (``synthesize(method=
    "iterative")`` under ``k_max``, or unbounded and under 30 when none is given) and
    observer gains :math:`L_j = -X C_{y,j}^T R^{-1}` from the dual Riccati equation of
    :math:`(A_j^T, C_{y,j}^T)` with :math:`Q = D_j D_j^T + 10^{-2} I`, :math:`R = \rho I`,
    :math:`\rho \in \{10^{-2}, 1, 10^2\}` (Kalman-like): the controller
    :math:`\hat A_j = A_j + B_j K_j + L_j C_{y,j}`, :math:`\hat B_j = -L_j`,
    :math:`\hat C_j = K_j`, :math:`\hat D_j = 0`; the best certified of them.
``ccl`` (the paper's Theorem 5.1)
    At a fixed gamma: find :math:`P_s`, :math:`X_s = P_s^{-1}`, multipliers
    :math:`\lambda_{s,k}` and :math:`\varepsilon_{s,k} = \lambda_{s,k}^{-1}` satisfying the two
    projected conditions (:func:`~ftc_verify.synthesis.ccl.ccl_blocks`), by cone complementarity
    linearisation; then, with ``P`` and the multipliers fixed, the controller of each FDI
    mode from the LMI in :math:`\mathcal K_j` over all true modes and ``beta`` ends
    (:func:`~ftc_verify.synthesis.state_feedback.gain_step` on the augmented plant).
    ``gamma=None`` tries a decreasing ladder from the observer design's certified gamma.
``vk`` (beyond the paper)
    The V-K iteration: from the best certified observer design, alternate the core's
    certified robust gamma with the controller fixed (the V-step, giving ``P`` and the
    multipliers) and the controller step with them fixed (the K-step); every iterate is
    certified and the best kept (:func:`~ftc_verify.synthesis.state_feedback.descend`).
``hinf`` (beyond the paper; any order)
    Nonsmooth BFGS on the certified quantity itself, the bounded-real level of the loop
    over the rate box (:mod:`ftc_verify.synthesis.hinf_descent`), from the certified
    controllers of the other routes (alone: from the ``descent`` route's, the route to a
    first stabilising controller); its answer certified by the core. ``auto`` runs it last,
    and runs the ``descent`` before it only when no LMI route certified a controller
    within the gain bound.

Every controller returned honours ``k_max`` in :math:`\|\mathcal K_j\|_2`: observer designs
above it are scaled onto it before certification, any other answer above it is scaled
and certified again (``_honour_bound``).
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass
from typing import Any


from ..analysis.closedloop import closed_loop
from ..analysis.lmi_analysis import hinf_gamma
from ..controllers.controller import Controller
from ..claimtext import upper_text
from ..errors import ValidationError
from ..limits import check_memory, dense_generator_estimate
from ..model.system import FTCSystem, Matrix
from .descent import accepted_gamma, descent_route
from .hinf_descent import hinf_route, within_bound
from .of_blocks import augmented_system, bounded_blocks, controller_blocks, controller_from_blocks, observer_designs
from .starts import certify_start
from .results import SolverCalls, SynthesisResult, check_levels, verify_controller
from .state_feedback import descend, gain_step, synthesize
from .ccl import CCL_MAX_ITER, CCL_TOL, ccl, ccl_blocks

__all__ = ["OF_METHODS", "ccl_blocks", "ccl", "synthesize_output_feedback", "CCL_MAX_ITER", "CCL_TOL"]

OF_METHODS = ("ccl", "observer", "vk", "descent", "hinf")
#: Gain bound of the baseline's second state-feedback design when none is given.
OBSERVER_K_MAX = 30.0


def _observer_rows(system: FTCSystem, k_max: float | None, solver: str, calls: SolverCalls) -> list[dict[str, Any]]:
    r"""The certified-or-not observer designs (the baseline and the start of ``vk``): the
    state-feedback gains of ``synthesize(method="iterative")`` under ``k_max``, and, when
    no bound is given, also under :data:`OBSERVER_K_MAX` (unbounded state-feedback gains
    reach norms of 1e4 on the paper's plant, and the observer's model mismatch during a
    detection delay, ``(B_j - B_i) K_j``, then destabilises the loop). With ``k_max`` a
    design whose blocks :math:`[[\hat A_j, \hat B_j], [\hat C_j, \hat D_j]]` exceed it
    (the observer part is not bounded by the state-feedback design) is scaled onto it
    (:func:`bounded_blocks`) before it is certified."""
    rows: list[dict[str, Any]] = []
    for bound in ([k_max] if k_max is not None else [None, OBSERVER_K_MAX]):
        sf = synthesize(system, method="iterative", k_max=bound, solver=solver)
        calls.absorb(sf)
        tag = "" if bound is None else f", k_max {bound:g}"
        if not sf.certified:
            rows.append({"name": f"observer{tag}", "gamma_certified": None, "spectral_abscissa": None, "note": "",
                         "reason": f"no certified state-feedback gains: {sf.message}"})
            continue
        for label, ctrl in observer_designs(system, list(sf.gains)):
            blocks, scaled = bounded_blocks(controller_blocks(ctrl), k_max)
            note = f"blocks scaled onto --k-max {k_max:g}" if scaled and k_max is not None else ""
            ctrl = controller_from_blocks(system, blocks, label) if scaled else ctrl
            rows.append(certify_start(system, label + tag, blocks, solver, note, loop=closed_loop(system, ctrl))
                        | {"controller": ctrl})
    for r in rows:
        calls.outcomes.extend(r.get("attempts", ()))
    return rows or [{"name": "observer", "gamma_certified": None, "spectral_abscissa": None, "note": "",
                     "reason": "no stabilising observer Riccati solution"}]


def _ccl_ladder(system: FTCSystem, gamma: float | None, start: float | None, calls: SolverCalls,
                k_max: float | None, warm: Any = None) -> tuple[list[Matrix] | None, float | None, list[float], str]:
    """CCL at ``gamma``, or (``gamma=None``) down a ladder of levels from ``start`` (the
    observer design's certified gamma, else 10), each 0.7 times the certified robust gamma
    of the previous level's controller, while it succeeds (at most six levels). ``warm``:
    the observer design's certificate: where CCL from its own first point fails at a
    level, it is run again from this point (a design known to work at a higher level);
    each later level warm-starts from the certificate of the previous level's controller."""
    point = None if warm is None or warm.P is None else (warm.P, warm.multipliers or [()] * len(warm.P))

    def attempt(level: float) -> tuple[list[Matrix] | None, list[float], str, float | None]:
        """Cold start first; from the warm point only when that fails."""
        found = ccl(system, level, calls, k_max)
        if found[0] is None and point is not None:
            warm_found = ccl(system, level, calls, k_max, start=point)
            if warm_found[0] is not None:
                return warm_found[0], found[1] + warm_found[1], warm_found[2] + " (warm start)", warm_found[3]
        return found

    if gamma is not None:
        blocks, history, msg, reached = attempt(gamma)
        return blocks, reached, history, msg
    level = 10.0 if start is None else start
    best: tuple[list[Matrix] | None, float | None, list[float], str] = (None, None, [], "")
    for _ in range(6):
        blocks, history, msg, reached = attempt(level)
        if blocks is None or reached is None:
            return best if best[0] is not None else (None, None, history, msg)
        cert = hinf_gamma(closed_loop(system, controller_from_blocks(system, blocks, "ccl")), robust=True,
                          solver=calls.solver)
        calls.outcomes.extend(cert.attempts)
        certified = cert.gamma if cert.certified and cert.gamma is not None else reached
        if cert.certified and cert.P is not None:
            point = (cert.P, cert.multipliers or [()] * len(cert.P))
        best = (blocks, reached, history, f"{msg}; last level that succeeded {level:.6g} (ladder: 0.7 times the "
                                            "certified gamma of the previous level)")
        level = 0.7 * min(level, certified)
    return best


@dataclass(frozen=True, eq=False)
class _Outcome:
    """What one route produced (the controller is accepted only with ``gamma``)."""

    route: str
    controller: Controller | None
    report: Any
    synthesis_gamma: float | None
    history: list[float]
    ccl_history: list[float]
    message: str

    @property
    def gamma(self) -> float | None:
        return accepted_gamma(self.report, self.route in ("descent", "hinf"))

    @property
    def rank(self) -> tuple[int, float]:
        """Robust-certified before nominal-only, then by gamma."""
        robust = self.report is not None and self.report.robust.certified
        return (0 if robust else 1, math.inf if self.gamma is None else self.gamma)


def synthesize_output_feedback(
    system: FTCSystem,
    *,
    method: str = "auto",
    gamma: float | None = None,
    k_max: float | None = None,
    solver: str | None = None,
    max_iter: int = 10,
    tol: float = 1e-3,
    order: int | None = None,
    seed: int = 0,
) -> SynthesisResult:
    """A dynamic output-feedback controller by ``method`` (module docstring), certified by
    the core analysis of its closed loop; the result's ``controller`` is it, ``gains`` its
    blocks ``K_j``. ``k_max`` bounds ``||K_j||_2`` in the controller steps (``ccl``, ``vk``),
    the descent, and the state-feedback gains of the observer baseline. ``gamma``: the
    level CCL works at, and for every method a requirement on the certified gamma.
    ``order``: the controller order (default ``n``; other orders only by ``descent``, 0 is
    static output feedback). ``method="auto"`` runs every route (observer, V-K, CCL at full
    order, the descent when none of them certified one within ``k_max``, then ``hinf`` from the
    certified ones) and
    keeps the best certified controller, each route's outcome in ``starts``. A controller counts as certified when the core proves it stable and
    certifies Lemma 4.1's robust gamma -- or, for the descent, Theorem 3.2's nominal gamma
    when Lemma 4.1 finds no certificate (the result says which)."""
    from ..analysis.solvers import choose_solver
    from .starts import diagnose

    if method not in OF_METHODS + ("auto",):
        raise ValidationError(f"method: {method!r} is not an output-feedback method; choose from "
                              f"{list(OF_METHODS + ('auto',))}")
    check_levels(gamma, k_max)
    n0 = system.dims[0]
    order = n0 if order is None else order
    if not isinstance(order, int) or order < 0:
        raise ValidationError(f"order: must be a whole number >= 0, got {order!r}")
    if order != n0 and method not in ("descent", "hinf", "auto"):
        raise ValidationError(f"order: {order} needs the descent (method descent, hinf or auto); {method} designs order "
                              f"n = {n0} only")
    t0 = time.perf_counter()
    n = n0 + order
    check_memory(dense_generator_estimate(n, system.chain.n_states),
                 f"order {order}: the second-moment generator of the closed loop of order {n}",
                 hint="choose a smaller order")
    name = choose_solver(solver, system.chain.n_states * (n * (n + 1) + 1))
    calls = SolverCalls(name)
    full = order == n0
    rows = _observer_rows(system, k_max, name, calls) if full else []
    outcomes, descent_rows, took = _routes(system, method, order, rows, gamma, k_max, name, calls, max_iter, tol,
                                           seed)
    if gamma is not None:  # --gamma is a requirement for every method
        outcomes = [o if o.gamma is None or o.gamma <= gamma * (1 + 1e-9) else
                    _Outcome(o.route, None, None, o.synthesis_gamma, o.history, o.ccl_history,
                             f"{o.message}; certified gamma {upper_text(o.gamma)} is above the requested {gamma:.6g}")
                    for o in outcomes]
    certified = [o for o in outcomes if o.gamma is not None]
    chosen = min(certified, key=lambda o: o.rank) if certified else outcomes[-1]
    msg = chosen.message
    if method == "auto":
        msg = f"best of {len(outcomes)} routes: {chosen.route}; {msg}" if certified else f"no route certified; {msg}"
    ctrl, report = (chosen.controller, chosen.report) if certified else (None, chosen.report)
    diagnosis = None
    if not certified:
        seen = rows + descent_rows + ([{"spectral_abscissa": report.mss.spectral_abscissa}] if report is not None
                                      else [])
        diagnosis = diagnose(system, seen, [o.status for o in calls.outcomes], k_max, output_feedback=True)
        scan = next((r for r in descent_rows if r["name"] == "descent gain scan"), None)
        if scan is not None:
            diagnosis = diagnosis | {"descent": {k: v for k, v in scan.items() if k != "name"}}
        msg = f"{msg}; {diagnosis['message']}"
    public = tuple({k: r.get(k) for k in ("name", "gamma_certified", "spectral_abscissa", "note", "reason", "seconds")}
                   for r in rows + descent_rows if r["name"] != "descent gain scan")
    if method == "auto":
        public += tuple({"name": f"route {o.route}", "gamma_certified": o.gamma,
                         "spectral_abscissa": None if o.report is None else o.report.mss.spectral_abscissa,
                         "note": "", "reason": "" if o.gamma is not None else o.message,
                         "seconds": took.get(o.route)} for o in outcomes)
    blocks = [] if ctrl is None else controller_blocks(ctrl)
    return SynthesisResult(chosen.route if method == "auto" else method, ctrl is not None, tuple(blocks),
                           chosen.synthesis_gamma, name, calls.seconds, time.perf_counter() - t0, calls.count, report,
                           msg, k_max, tuple(chosen.history), (_best_row(rows) or {}).get("name"), public, diagnosis, ctrl,
                           tuple(chosen.ccl_history), nominal_accepted=chosen.route in ("descent", "hinf"),
                           iterations=len(chosen.ccl_history) if chosen.route == "ccl" else None)


def _routes(system: FTCSystem, method: str, order: int, rows: list[dict[str, Any]], gamma: float | None,
            k_max: float | None, name: str, calls: SolverCalls, max_iter: int, tol: float, seed: int,
            ) -> tuple[list[_Outcome], list[dict[str, Any]], dict[str, float]]:
    """Run the routes of ``method`` in order (the LMI routes at full order, the descent,
    then ``hinf`` from the certified ones; module docstring): their outcomes, the rows of
    the descent and ``hinf``, and each route's seconds."""
    full = order == system.dims[0]
    routes = [r for r in (("observer", "vk", "ccl") if full else ()) if method in (r, "auto")]
    if method in ("descent", "hinf", "auto"):
        routes.append("descent")
    outcomes: list[_Outcome] = []
    descent_rows: list[dict[str, Any]] = []
    took: dict[str, float] = {}
    for route in routes:
        t_route = time.perf_counter()
        if route == "descent" and method == "auto" and any(
                o.gamma is not None and o.controller is not None and within_bound(o.controller, k_max) for o in outcomes):
            continue  # an LMI route certified a start for hinf: the descent is the route to a first stabilising one
        if route == "descent":
            ctrl, report, history, msg, descent_rows = descent_route(system, order, rows, k_max, name, calls, seed)
            outcomes.append(_Outcome(route, ctrl, report, history[-1] if history else None, history, [], msg))
        else:
            outcomes.append(_Outcome(route, *_run_route(route, system, rows, gamma, k_max, name, calls, max_iter, tol)))
        outcomes[-1] = _honour_bound(system, outcomes[-1], k_max, name)
        took[route] = time.perf_counter() - t_route
    if method in ("hinf", "auto"):
        t_route = time.perf_counter()
        ranked = [(o.route, o.controller) for o in sorted(outcomes, key=lambda o: o.rank)
                  if o.gamma is not None and o.controller is not None]
        ctrl, report, history, msg, hinf_rows = hinf_route(system, order, ranked, calls, name, k_max=k_max, seed=seed)
        outcomes.append(_honour_bound(system, _Outcome("hinf", ctrl, report, history[-1] if history else None,
                                                       history, [], msg), k_max, name))
        descent_rows += hinf_rows
        took["hinf"] = time.perf_counter() - t_route
    return outcomes, descent_rows, took


def _honour_bound(system: FTCSystem, outcome: _Outcome, k_max: float | None, solver: str) -> _Outcome:
    """``outcome`` with its controller within ``k_max`` (:func:`within_bound`): a controller
    above it (an LMI's bound met only to the solver's tolerance, a projection's rounding)
    is scaled onto it (:func:`bounded_blocks`) and certified again, so every returned
    controller honours ``--k-max`` and is the one certified."""
    ctrl = outcome.controller
    if ctrl is None or within_bound(ctrl, k_max):
        return outcome
    blocks, _ = bounded_blocks(controller_blocks(ctrl), k_max)
    ctrl = controller_from_blocks(system, blocks, ctrl.name)
    return dataclasses.replace(outcome, controller=ctrl, report=verify_controller(system, ctrl, solver),
                               message=f"{outcome.message}; blocks scaled onto --k-max {k_max:g} and certified again")


def _best_row(rows: list[dict[str, Any]]) -> dict[str, Any] | None:
    """The observer design with the smallest certified gamma (``None`` when none is)."""
    certified = [r for r in rows if r["gamma_certified"] is not None]
    return min(certified, key=lambda r: r["gamma_certified"]) if certified else None


def _run_route(route: str, system: FTCSystem, rows: list[dict[str, Any]], gamma: float | None, k_max: float | None,
               name: str, calls: SolverCalls, max_iter: int, tol: float) -> tuple[Any, Any, Any, list[float], list[float], str]:
    """One LMI route at full order: ``(controller, report, synthesis gamma, history, CCL
    history, message)``; the controller is certified by the core (``report``)."""
    best = _best_row(rows)
    blocks: list[Matrix] | None = None
    history: list[float] = []
    ccl_history: list[float] = []
    gsyn = None
    if route == "observer":
        blocks = None if best is None else list(best["gains"])
        gsyn = None if best is None else best["gamma_certified"]
        msg = f"observer baseline: best of {len(rows)} ({best['name']})" if best else "no certified observer design"
    elif route == "vk":
        if best is None:
            msg = "no certified observer design to start the V-K iteration from"
        else:
            aug, cbars = augmented_system(system)
            found = descend(
                lambda B: closed_loop(system, controller_from_blocks(system, B, "vk")),
                lambda P, lam, j: gain_step(aug, P, lam, j, calls, k_max, measurement=cbars), system.m,
                list(best["gains"]), calls, name, max_iter, tol, best.get("lmi"))
            blocks, history, msg = found.gains, found.history, found.message
            gsyn = history[-1] if history else None
            msg = f"V-K iteration from {best['name']} (certified gamma {upper_text(best['gamma_certified'])}); {msg}"
    else:
        blocks, gsyn, ccl_history, msg = _ccl_ladder(system, gamma, None if best is None else best["gamma_certified"],
                                                     calls, k_max, None if best is None else best.get("lmi"))
    ctrl = None if blocks is None else controller_from_blocks(system, blocks, f"{system.name} {route}")
    report = None if ctrl is None else verify_controller(system, ctrl, name)
    return ctrl, report, gsyn, history, ccl_history, msg
