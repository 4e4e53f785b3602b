"""The full analysis of one closed loop: exact stability, certified LMIs, cross-validation.

:func:`analyze` runs, on any :class:`~ftc_verify.analysis.closedloop.ClosedLoop`:

1. the exact mean-square stability test (:mod:`ftc_verify.analysis.moments.stability`), worst over the
   vertices of the rate box (detection rates ``beta`` and, when given, false-alarm
   rates, :mod:`ftc_verify.model.chain`);
2. the smallest certified nominal gamma (Theorem 3.2) and robust gamma (Lemma 4.1,
   gains fixed), both over the rate box (each program in a forked child started before
   step 1, which neither needs, Lemma 4.1's solve once Theorem 3.2's has its answer;
   without uncertainty channels Lemma 4.1's program is Theorem 3.2's, solved once);
3. Theorem 3.1 over the rate box, certified (:func:`~ftc_verify.analysis.lmi_analysis.mes_lmi`),
   first with the ``P`` of step 2 (no solve), solved only when that check fails. When the
   box proof of step 1 would solve this LMI on the whole box (its centre's candidate
   misses a vertex), step 1 leaves it to this step (``root_lmi=False``,
   :data:`~ftc_verify.analysis.box.ROOT_LMI_DEFERRED`): the certified answer proves the
   verdict over the whole box (:meth:`~ftc_verify.analysis.moments.stability.MSSResult.proved_by`,
   one ``P`` for every rate); without one, step 1 runs again in full. Same proof, one
   SDP fewer;
4. beside each certified gamma, a proved lower bound of the same worst-case gain
   (:mod:`ftc_verify.analysis.lower_bound`): the bracket ``lower <= gain <= gamma``;
5. per-mode cross-validation with python-control (:mod:`ftc_verify.analysis.crossval`).

"Certified stable" means the verdict of stage 1 is "stable" over the whole box *and* the
Theorem 3.1 certificate passed (which covers the whole box, and time-varying rates in
it). At a missed-detection vertex (a ``beta_min`` of 0) both speak about an FDI that
never detects that fault (:mod:`ftc_verify.analysis.lmi`).
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass
from collections.abc import Callable
from typing import Any

from .box import ROOT_LMI_DEFERRED
from .closedloop import ClosedLoop
from ..jsonable import jsonable
from .crossval import ModeCheck, cross_validate
from ..limits import check_memory, dense_generator_estimate
from .lmi_analysis import LMIResult, hinf_gamma, mes_known, mes_lmi
from .lmi_size import check_lmi_memory
from .lower_bound import GainLowerBound, gain_lower_bound, within_solve_limit
from .worst_delta import robust_lower_bound
from .solvers import ForkedCall
from .moments.stability import MSSResult, mean_square_stability

__all__ = ["AnalysisReport", "analyze", "json_ready", "bracket", "LOOSE_RATIO"]


def json_ready(value: Any) -> Any:
    """JSON-ready built-ins, non-finite floats as ``None`` (:func:`ftc_verify.jsonable.jsonable`)."""
    return jsonable(value)


@dataclass(frozen=True, eq=False)
class AnalysisReport:
    """Everything :func:`analyze` found, with the time each stage took."""

    name: str
    controller: str
    mss: MSSResult
    mes_lmi: LMIResult
    nominal: LMIResult
    robust: LMIResult
    per_mode: tuple[ModeCheck, ...]
    seconds: dict[str, float]
    nominal_lower: GainLowerBound | None = None
    robust_lower: GainLowerBound | None = None

    @property
    def certificate_ok(self) -> bool:
        """Every LMI answer (Theorem 3.1, nominal and robust gamma) was certified."""
        return self.mes_lmi.certified and self.nominal.certified and self.robust.certified

    @property
    def certified_stable(self) -> bool:
        """Proved stable over the whole rate box and Theorem 3.1 certified."""
        return self.mss.stable and self.mes_lmi.certified

    @property
    def cross_validation_ok(self) -> bool:
        """python-control agreed on every joint mode."""
        return all(m.agree for m in self.per_mode)

    def __str__(self) -> str:
        """The summary ``ftc-verify analyze`` prints (:func:`~ftc_verify.analysis.summary.analysis_summary`)."""
        from .summary import analysis_summary

        return analysis_summary(self)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready report (the schema of :doc:`/reference/report-schema`)."""
        return json_ready({
            "name": self.name,
            "controller": self.controller,
            "mss": self.mss.to_dict(),
            "mes_lmi": {"feasible": self.mes_lmi.certified, **self.mes_lmi.to_dict()},
            "hinf": {
                "nominal_gamma": self.nominal.gamma if self.nominal.certified else None,
                "robust_gamma": self.robust.gamma if self.robust.certified else None,
                "nominal_lower_bound": bracket(self.nominal, self.nominal_lower),
                "robust_lower_bound": bracket(self.robust, self.robust_lower),
                "nominal": self.nominal.to_dict(),
                "robust": self.robust.to_dict(),
            },
            "certificate": {
                "ok": self.certificate_ok,
                "theorem_3_1": self.mes_lmi.certified,
                "theorem_3_2": self.nominal.certified,
                "lemma_4_1": self.robust.certified,
            },
            "certified_stable": self.certified_stable,
            "cross_validation_ok": self.cross_validation_ok,
            "per_mode": [m.to_dict() for m in self.per_mode],
            "seconds": self.seconds,
        })


#: A certified gamma more than this factor above its proved lower bound is flagged ``loose``.
LOOSE_RATIO = 1.05


def bracket(certified: LMIResult, lower: GainLowerBound | None) -> dict[str, Any] | None:
    """The JSON of a lower bound beside its certified gamma: the bound, the ratio
    certified / lower, ``loose`` above :data:`LOOSE_RATIO`, and what attains it."""
    if lower is None:
        return None
    ratio = (certified.gamma / lower.value if certified.certified and certified.gamma is not None
             and lower.value is not None and lower.value > 0 else None)
    return lower.to_dict() | {"ratio": ratio, "loose": ratio is not None and ratio > LOOSE_RATIO}


def analyze(loop: ClosedLoop, *, solver: str | None = None, name: str = "", cross_validation: bool = True,
            lmi: bool = True, lower_bounds: bool = True, lean: bool = False) -> AnalysisReport:
    """Run every analysis of the module docstring on ``loop``.

    ``solver`` is ``None``/``"auto"`` (by size), ``"clarabel"``, ``"sdpa"`` or ``"scs"``.
    Without uncertainty channels the robust gamma is the nominal one (Lemma 4.1
    reduces to Theorem 3.2) and is not solved twice. Stage 5 runs in a child process
    started first (:class:`~ftc_verify.prestart.Prestarted`: python-control's import and
    checks beside every other stage; ``seconds["cross_validation_wait"]`` is what was left
    to wait for at the end); ``cross_validation=False`` skips it (synthesis loops, where
    python-control's start-up cost would dominate).
    ``lmi=False`` runs only the exact spectral test and the cross-check (large loops);
    otherwise the LMI stage's memory is checked first, before any work
    (:func:`~ftc_verify.analysis.lmi_size.check_lmi_memory`), and so is the lower
    bounds' dense second-moment generator
    (:func:`~ftc_verify.limits.dense_generator_estimate`). ``lower_bounds=False``
    skips stage 4 (synthesis loops). ``lean``: the gamma programs first with Clarabel's
    :data:`~ftc_verify.analysis.solvers.LEAN_SETTINGS` (``hinf_gamma(..., lean=lean)``; the
    ``analyze`` and ``verify`` commands' own analysis; the synthesis certifies with the full
    settings, whose answers steer its choices). A loop the spectral test proves NOT stable gets no
    LMI solve (outcome ``"skipped"``: no certificate of stability or of a finite gamma
    exists for it).
    """
    if lmi:
        check_lmi_memory(loop)
    if lmi and lower_bounds:  # dense second-moment solves and eigenvalues (analysis.lower_bound)
        check_memory(dense_generator_estimate(loop.n, len(loop.A)),
                     f"the gamma lower bounds of a loop with n = {loop.n} and {len(loop.A)} joint states",
                     hint="reduce the problem, or run the exact spectral test alone (analyze --no-lmi)")
    seconds: dict[str, float] = {}
    check = None
    if cross_validation:  # python-control's import and checks in a child, beside every stage below
        from ..prestart import cross_check as start_cross_check

        check = start_cross_check()
        check.submit(cross_validate, loop)
    try:
        return _analyze(loop, solver, name, lmi, lower_bounds, check, seconds, lean)
    finally:
        if check is not None:
            check.cancel()


def _analyze(loop: ClosedLoop, solver: str | None, name: str, lmi: bool, lower_bounds: bool,
             check: Any, seconds: dict[str, float], lean: bool = False) -> AnalysisReport:
    """The stages of :func:`analyze`; ``check``: the running
    :class:`~ftc_verify.prestart.Prestarted` (``None``: no cross-validation)."""
    ahead, nominal_ahead = _gamma_ahead(loop, solver, lower_bounds and within_solve_limit(loop), lean) if lmi else (None, None)
    try:
        return _stages(loop, solver, name, lmi, lower_bounds, check, seconds, ahead, nominal_ahead, lean)
    finally:
        for call in (ahead, nominal_ahead):
            if call is not None:
                call.cancel()


def _gamma_ahead(loop: ClosedLoop, solver: str | None, gated: bool = True,
                 lean: bool = False) -> tuple[ForkedCall | None, ForkedCall | None]:
    """The gamma programs that need nothing of the spectral stage, each in a forked child
    started before it: Theorem 3.2 without uncertainty channels (``(Theorem 3.2, None)``);
    with them Lemma 4.1 and Theorem 3.2 in a second child (``(Lemma 4.1, Theorem 3.2)``:
    this process then goes from the spectral stage straight to the lower bounds, which
    wait only for Theorem 3.2's answer, instead of solving it after the spectral stage:
    the longest chain of stages one solve shorter, issue 37). ``gated``: Lemma 4.1's solve
    starts when Theorem 3.2's child has its answer (:func:`_after`); ``analyze`` gates it
    when the lower bounds run, which are then the longest chain (n = 8, m = 3), not
    without them, when Lemma 4.1's solve is (n = 12, m = 4). Cancelled when the loop is
    proved unstable. FLINT and Clarabel are imported first so that no process imports
    them twice; ``(None, None)`` without ``fork``. Each child solves the same program as a
    call here would (no hint, no shared state), so its answer is the same to the last bit."""
    if not hasattr(os, "fork"):
        return None, None
    import clarabel  # noqa: F401
    import flint  # noqa: F401

    if loop.uncertain:
        gate, opener = os.pipe()  # Lemma 4.1's child starts when Theorem 3.2's has its answer (_after)
        try:
            robust = ForkedCall(_after(gate if gated else None, opener, lambda: hinf_gamma(loop, robust=True, solver=solver, lean=lean)),
                                "Lemma 4.1")
            try:
                return robust, ForkedCall(_after(None, gate, lambda: hinf_gamma(loop, robust=False, solver=solver, lean=lean),
                                                 opener), "Theorem 3.2")
            except BaseException:
                robust.cancel()
                raise
        finally:
            os.close(gate)
            os.close(opener)
    return ForkedCall(lambda: hinf_gamma(loop, robust=False, solver=solver, lean=lean), "Theorem 3.2"), None


def _after(gate: int | None, unused: int, fn: Callable[[], Any], opens: int | None = None) -> Callable[[], Any]:
    """``fn`` for a forked child of :func:`_gamma_ahead`: the pipe end ``unused`` closed
    first; with ``gate`` (a read end), ``fn`` starts at its end of file, i.e. once every
    write end is closed; ``opens`` (a write end) is closed as soon as ``fn`` returns.
    Lemma 4.1's child waits so for Theorem 3.2's: one core solves Theorem 3.2, then Lemma
    4.1, while the other runs the spectral stage and the lower bounds alone, which wait
    for Theorem 3.2's answer only (the longest chain of stages, issue 37: on two cores the
    four processes started at once shared them, and that chain got half a core at first).
    Lemma 4.1's answer is not needed before the end of that chain; a Theorem 3.2 child
    that dies or is cancelled opens the gate too."""
    def run() -> Any:
        os.close(unused)
        if gate is not None:
            while os.read(gate, 1):
                pass
        try:
            return fn()
        finally:
            if opens is not None:
                os.close(opens)
    return run


def _stages(loop: ClosedLoop, solver: str | None, name: str, lmi: bool, lower_bounds: bool, check: Any,
            seconds: dict[str, float], ahead: ForkedCall | None,
            nominal_ahead: ForkedCall | None = None, lean: bool = False) -> AnalysisReport:
    """The stages of :func:`_analyze`; ``ahead``, ``nominal_ahead``: the gamma programs
    running beside (:func:`_gamma_ahead`)."""
    t = time.perf_counter()
    mss = mean_square_stability(loop, root_lmi=not lmi)  # with LMIs the whole box's is stage 3's (ROOT_LMI_DEFERRED)
    seconds["spectral"] = time.perf_counter() - t
    if lmi and mss.unstable:  # proved not stable: no certificate can exist, no solve is spent on one
        mes, nominal, robust = (_not_requested(c, "not solved: the loop is proved NOT mean-square stable, so no "
                                               "certificate exists") for c in ("Theorem 3.1", "Theorem 3.2", "Lemma 4.1"))
    elif lmi:
        nominal, robust, early, mes_first = _gammas(loop, solver, seconds, mss if lower_bounds else None, ahead,
                                                     nominal_ahead, lean)
        t = time.perf_counter()
        mes = mes_first or mes_lmi(loop, solver=solver, known=(nominal, robust))
        seconds["theorem_3_1"] = seconds.get("theorem_3_1", 0.0) + time.perf_counter() - t
        if mss.undecided and mes.certified:
            mss = mss.proved_by("the certified Theorem 3.1 LMI over the whole box (one P for every rate)", loop.chain)
        elif mss.reason == ROOT_LMI_DEFERRED:  # no certificate from stage 3: the branch and bound in full
            t = time.perf_counter()
            mss = mean_square_stability(loop)
            seconds["spectral"] += time.perf_counter() - t
    else:
        mes, nominal, robust = (_not_requested(c) for c in ("Theorem 3.1", "Theorem 3.2", "Lemma 4.1"))
    nominal_lower = robust_lower = None
    t = time.perf_counter()
    if lmi and lower_bounds and not mss.unstable:
        nominal_lower, robust_lower = _lower_bounds(loop, mss, nominal, robust, early)
        seconds["lower_bounds"] = time.perf_counter() - t
    per_mode: tuple[ModeCheck, ...] = ()
    if check is not None:
        try:
            per_mode = check.result()
        finally:
            check.cancel()
        seconds["cross_validation_wait"] = check.seconds.get("wait", 0.0)
        seconds["cross_validation"] = check.seconds.get("run", 0.0)
    return AnalysisReport(name, loop.controller, mss, mes, nominal, robust, per_mode, seconds, nominal_lower,
                          robust_lower)


#: The nominal lower bound and the robust one at a constant ``Delta``, computed
#: beside Lemma 4.1's program (:func:`_nominal_side`); ``None`` when not computed there.
Early = tuple[GainLowerBound, GainLowerBound | None] | None


def _lower_bounds(loop: ClosedLoop, mss: MSSResult, nominal: LMIResult, robust: LMIResult,
                  early: Early = None) -> tuple[GainLowerBound | None, GainLowerBound | None]:
    """The nominal lower bound and the robust one (the best of the nominal and the
    bound at the constant ``Delta`` of :func:`~ftc_verify.analysis.worst_delta.robust_lower_bound`
    at the nominal bound's rates); ``early``: those two already found beside Lemma 4.1."""
    top = robust.gamma if robust.certified else None
    if early is not None:
        low, high = early
    else:
        upper = nominal.gamma if nominal.certified else None
        low = gain_lower_bound(loop, worst_rates=mss.worst_beta, upper=upper)
        high = robust_lower_bound(loop, low.rates, worst_rates=mss.worst_beta, upper=top)[1] if loop.uncertain else None
    if not loop.uncertain:
        return low, low
    candidates = [b for b in (low, high) if b is not None]
    best = max(candidates, key=lambda b: (b.value is not None, b.value if b.value is not None else
                                          (b.estimate if math.isfinite(b.estimate) else -math.inf)))
    return low, best


def _gammas(loop: ClosedLoop, solver: str | None, seconds: dict[str, float],
            mss: MSSResult | None = None, ahead: ForkedCall | None = None,
            nominal_ahead: ForkedCall | None = None,
            lean: bool = False) -> tuple[LMIResult, LMIResult, Early, LMIResult | None]:
    """The nominal (Theorem 3.2) and robust (Lemma 4.1) gamma programs. ``ahead``: the
    one already running in a forked child since before the spectral stage
    (:func:`_gamma_ahead`; ``None`` without ``fork``: both solved here, the certified
    nominal gamma as the robust program's scale hint). Without uncertainty the robust
    gamma is the nominal one. With it, Theorem 3.2 comes from ``nominal_ahead`` (its own
    child, started with Lemma 4.1's; solved here when ``None``) while Lemma 4.1 runs in
    its child (single-threaded solves on two cores), and, given ``mss`` (lower
    bounds requested), this process goes on with the nominal lower bound and the
    robust one at a constant ``Delta`` (:func:`_nominal_side`), which need only
    the nominal gamma, and with Theorem 3.1 on Theorem 3.2's ``P``
    (:func:`~ftc_verify.analysis.lmi_analysis.mes_known`); when that fails, Theorem 3.1
    (:func:`~ftc_verify.analysis.lmi_analysis.mes_lmi`) on Lemma 4.1's answer once it
    arrives: the same answer as ``mes_lmi(known=(nominal, robust))``, returned last
    (``None`` in the other cases: the caller runs that). ``seconds`` gets each stage's
    wall time after the spectral stage (``lemma_4_1``: until the child's answer arrived;
    the lower-bound part of :func:`_nominal_side` as ``lower_bounds_beside``)."""
    t = time.perf_counter()
    if not loop.uncertain:
        nominal = ahead.result() if ahead is not None else hinf_gamma(loop, robust=False, solver=solver, lean=lean)
        seconds["theorem_3_2"] = seconds["lemma_4_1"] = time.perf_counter() - t
        return nominal, nominal, None, None
    if ahead is None:
        nominal = hinf_gamma(loop, robust=False, solver=solver, lean=lean)
        seconds["theorem_3_2"] = time.perf_counter() - t
        hint = nominal.gamma if nominal.certified else None  # Lemma 4.1's gamma is at least this
        robust = hinf_gamma(loop, robust=True, solver=solver, gamma_hint=hint, lean=lean)
        seconds["lemma_4_1"] = time.perf_counter() - t - seconds["theorem_3_2"]
        return nominal, robust, None, None
    nominal, early, beside = _nominal_side(loop, solver, mss, nominal_ahead, lean)
    seconds["theorem_3_2"] = time.perf_counter() - t
    if early is not None:
        seconds["lower_bounds_beside"] = beside
    t31 = time.perf_counter()
    mes = mes_known(loop, (nominal,))
    seconds["theorem_3_1"] = time.perf_counter() - t31
    robust = ahead.result()
    seconds["lemma_4_1"] = seconds["gammas_wall"] = time.perf_counter() - t
    if mes is None:  # Theorem 3.2's P did not pass: Lemma 4.1's, else the solve (mes_lmi)
        t31 = time.perf_counter()
        mes = mes_lmi(loop, solver=solver, known=(robust,))
        seconds["theorem_3_1"] += time.perf_counter() - t31
    return nominal, robust, early, mes


def _nominal_side(loop: ClosedLoop, solver: str | None, mss: MSSResult | None,
                  nominal_ahead: ForkedCall | None = None, lean: bool = False) -> tuple[LMIResult, Early, float]:
    """Beside Lemma 4.1's child (:func:`_gammas`): Theorem 3.2 (``nominal_ahead``'s answer,
    or solved here without it), then (given ``mss``, the
    nominal gamma certified) the nominal lower bound and the robust one at a constant
    ``Delta`` (``None`` in their place when not computed or when they fail:
    :func:`_lower_bounds` then computes them), and the seconds those took."""
    nominal = nominal_ahead.result() if nominal_ahead is not None else hinf_gamma(loop, robust=False, solver=solver, lean=lean)
    if mss is None or mss.unstable or not nominal.certified:
        return nominal, None, 0.0
    t = time.perf_counter()
    try:
        low = gain_lower_bound(loop, worst_rates=mss.worst_beta, upper=nominal.gamma)
        high = robust_lower_bound(loop, low.rates, worst_rates=mss.worst_beta, upper=nominal.gamma)[1]
    except Exception:  # a float search: _lower_bounds runs it again and decides
        return nominal, None, 0.0
    return nominal, (low, high), time.perf_counter() - t


def _not_requested(condition: str, why: str = "") -> LMIResult:
    """The placeholder of an LMI analysis that was not run: ``lmi=False`` (outcome
    ``"not requested"``), or ``why`` it was skipped (outcome ``"skipped"``)."""
    if why:
        return LMIResult(condition, "skipped", None, "", "", 0.0, 0.0, None, message=why)
    return LMIResult(condition, "not requested", None, "", "", 0.0, 0.0, None,
                     message="LMIs not requested (exact spectral test only)")
