"""The main job: synthesize, certify and check a controller three independent ways.

:func:`run_verify` runs these stages on a system and a controller (given, or synthesized),
all on the one closed loop :func:`~ftc_verify.analysis.closedloop.closed_loop` builds:

1. **synthesis** (:func:`ftc_verify.synthesis.synthesize`) unless a controller is given,
   then the core analysis: stability proved over the whole rate box, certified Theorem
   3.1 and robust gamma (Lemma 4.1), and a proved lower bound of the robust gain;
2. **cross-validation** of every frozen joint mode with python-control;
3. **exact expected energy** of the continuous-time loop for the paper's disturbance at
   every ``beta`` vertex (up to :data:`MAX_EXACT_VERTICES`) and for ``Delta`` in
   ``{0, +E, -E}`` (``E`` the rectangular identity, norm 1) when the plant is uncertain;
   then the **sampled loop** at ``step``, the loop the Monte Carlo runs
   (:mod:`ftc_verify.verification.sampled_stage`: mean-square stability proved over the
   rate box at the period, ``h_max``, and its exact expected energy with the input and
   the disturbance held, :mod:`ftc_verify.analysis.moments.sampled_energy`; the simulated
   loop's mean against its exact expectation, two-sided,
   :func:`~ftc_verify.verification.sampled_stage.sampled_mc_stage`), computed in a forked
   child beside stages 4-7 (:class:`~ftc_verify.verification.sampled_stage.SampledRun`;
   its checks keep their place, so the report is the one of a serial run);
4. **gamma bracket**: the proved lower bound of the analysis
   (:mod:`ftc_verify.analysis.lower_bound`) does not exceed the certified gamma, and
   their ratio says how far from the truth the certificate can be;
5. **Monte Carlo co-simulation** of the FMU plant under Markov faults and delayed FDI
   switching (sample-and-hold at ``step``), ``beta`` drawn per path from its box, a random
   ``Delta`` per chain segment when uncertain; the mean ratio's one-sided upper bound
   (:mod:`ftc_verify.verification.montecarlo`) is compared with gamma^2;
6. **backend agreement**: the first paths re-simulated by the numpy reference with the
   same ``Delta`` draws must match the FMU (plant and controller states) to
   :data:`AGREE_RTOL`.
   With a plant map instead (the user's FMU, ``system`` its linearisation), the **plant
   region** check: no path leaves ``[region]``; the Monte Carlo measures either the real
   paths (``measure="total"``) or, for plants whose faults move the equilibrium, each
   path's incremental response to ``w`` (``"incremental"``, :func:`incremental_records`);
7. **risk**, when the plant map declares ``[risk]`` and a risk stage is given (the CLI
   passes :func:`ftc_verify.risk.verify_stage.verify_risk_stage`; this package sits
   below :mod:`ftc_verify.risk` and cannot import it): the probability of leaving
   ``[region]`` within ``[0, T]``, its interval and proved upper bound, the FDI timing;
   a check against ``[risk].target`` when the map gives one (``_risk_check``).

Each stage becomes a named check; the verdict is ``pass`` only if all pass. Every random
draw comes from one :class:`numpy.random.Generator` whose seed is in the report. Each
stage's duration is in ``seconds`` and its start and end in ``spans`` (stages overlap).
"""

from __future__ import annotations

import functools
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any, Protocol

import numpy as np

from ..analysis.analyze import AnalysisReport, analyze, bracket, json_ready
from ..analysis.closedloop import ClosedLoop, closed_loop
from ..analysis.crossval import ModeCheck, cross_validate
from ..controllers.controller import Controller
from ..errors import PlantRunError, ValidationError
from ..jsonable import fields_dict
from ..model.system import FTCSystem
from ..simulation.delta import constant_delta_loops
from ..simulation.paths import ChainPath
from ..simulation.records import PathRecord, divergence_note
from ..simulation.spec import SimulationSpec, spec_from
from ..analysis.solvers import interruptible
from ..synthesis.state_feedback import SynthesisResult, synthesize
from ..analysis.moments.energy import exact_energy
from ..analysis.moments.sampled import SampledLoop
from ..claimtext import lower_text, upper_text
from .agreement import EarlyReference, against_reference
from .montecarlo import MCEstimate, estimate
from .sampled_stage import SampledRun

__all__ = ["Check", "RiskStage", "VerifyReport", "run_verify", "incremental_records", "AGREE_RTOL",
           "MAX_EXACT_VERTICES", "LATER_STAGES"]

#: Relative agreement required between the FMU and the numpy reference on equal paths.
AGREE_RTOL = 1e-8
#: At most this many ``beta`` vertices get an exact energy (all of them for m <= 2..3).
MAX_EXACT_VERTICES = 64
#: Paths re-simulated by the reference backend for the agreement check.
AGREE_PATHS = 5


class RiskStage(Protocol):
    """The risk stage: :func:`ftc_verify.risk.verify_stage.verify_risk_stage` -- the JSON of
    the risk run and ``(ok, detail)``, ``ok`` ``None`` when there is nothing to check."""

    def __call__(self, system: FTCSystem, controller: Controller, plant: Any, spec: SimulationSpec,
                 client: Any = None) -> tuple[dict[str, Any], bool | None, str]: ...


@dataclass(frozen=True)
class Check:
    """One named check of the report."""

    name: str
    ok: bool
    detail: str


@dataclass(frozen=True, eq=False)
class VerifyReport:
    """Everything :func:`run_verify` computed (``controller`` is ``None`` only when
    synthesis found none)."""

    system: FTCSystem
    controller: Controller | None
    gamma_certified: float | None
    analysis: AnalysisReport | None
    synthesis: SynthesisResult | None
    per_mode: tuple[ModeCheck, ...]
    exact: tuple[dict[str, Any], ...]
    mc: MCEstimate | None
    records: tuple[PathRecord, ...]
    checks: tuple[Check, ...]
    seed: int
    options: dict[str, Any]
    seconds: dict[str, float] = field(default_factory=dict)
    plant: dict[str, Any] | None = None
    plant_failure: PlantRunError | None = None  # the plant FMU crashed or returned fmi2Fatal
    sampled: Any = None  # SampledResult of the loop at the simulation step (verification.sampled_stage)
    sampled_exact: tuple[dict[str, Any], ...] = ()  # its exact energies (sampled_stage.sampled_energy_stage)
    sampled_mc: dict[str, Any] | None = None  # simulated vs exact, two-sided (sampled_stage.sampled_mc_stage)
    risk: dict[str, Any] | None = None  # the risk stage's result when the plant map declares [risk]
    spans: dict[str, tuple[float, float]] = field(default_factory=dict)  # stage: (start, end), time.perf_counter

    @property
    def verdict(self) -> str:
        """``"pass"`` when every check passed."""
        return "pass" if self.checks and all(c.ok for c in self.checks) else "fail"

    @property
    def exact_energy_ratio(self) -> float | None:
        """Largest exact ``E||y||^2 / ||w||^2`` over the vertices and Deltas evaluated."""
        return max((e["ratio"] for e in self.exact), default=None)

    def __str__(self) -> str:
        """The summary ``ftc-verify verify`` prints (:func:`~ftc_verify.verification.summary.verify_summary`)."""
        from .summary import verify_summary

        return verify_summary(self)

    def to_dict(self) -> dict[str, Any]:
        """The ``report.json`` content."""
        an = self.analysis
        ctrl = self.controller
        return json_ready({
            "verdict": self.verdict,
            "system": self.system.name,
            "gamma_certified": self.gamma_certified,
            "gamma_nominal_certified": an.nominal.gamma if an is not None and an.nominal.certified else None,
            "spectral_abscissa": None if an is None else an.mss.spectral_abscissa,
            "exact_energy_ratio": self.exact_energy_ratio,
            "exact": list(self.exact),
            "mc": None if self.mc is None else self.mc.to_dict(),
            "gamma_lower_bound": None if an is None else bracket(an.robust, an.robust_lower),
            "checks": [fields_dict(c) for c in self.checks],
            "controller": None if ctrl is None else ctrl.to_dict(),
            "gains": [K.tolist() for K in ctrl.gains] if ctrl is not None and ctrl.is_state_feedback else None,
            "synthesis": None if self.synthesis is None else {
                k: v for k, v in self.synthesis.to_dict().items() if k != "analysis"},
            "analysis": None if an is None else an.to_dict() | {"per_mode": [m.to_dict() for m in self.per_mode]},
            "plant": self.plant,
            "plant_failure": None if self.plant_failure is None else {
                "fmu": self.plant_failure.fmu, "path": self.plant_failure.path, "time": self.plant_failure.time,
                "detail": self.plant_failure.detail},
            "sampled": None if self.sampled is None else self.sampled.to_dict(),
            "sampled_exact": list(self.sampled_exact),
            "sampled_mc": self.sampled_mc,
            "risk": self.risk,
            "seed": self.seed,
            "options": self.options,
            "seconds": self.seconds,
        })


def _certify(analysis: AnalysisReport, gamma: float | None) -> tuple[float | None, list[Check]]:
    """The certified robust gamma (``None`` unless stable and certified) and its checks."""
    ok = analysis.robust.certified and analysis.certified_stable
    gamma_cert = analysis.robust.gamma if ok else None
    checks = [Check("certified", gamma_cert is not None,
                    f"robust gamma {upper_text(gamma_cert)} (Lemma 4.1), spectral abscissa {analysis.mss.spectral_abscissa:.4g}"
                    if gamma_cert is not None else
                    f"not certified: mean-square stability {analysis.mss.verdict}; {analysis.robust.message}")]
    if gamma is not None and gamma_cert is not None:
        checks.append(Check("requested gamma", gamma_cert <= gamma, f"certified {upper_text(gamma_cert)} vs requested {gamma:.6g}"))
    return gamma_cert, checks


def _join(sampled: list[Any], cross: dict[str, Any], cross_check: Any, checks: list[Check],
          seconds: dict[str, float], spans: dict[str, tuple[float, float]]) -> dict[str, Any]:
    """The findings of the children, collected at the end: the sampled stages (computed
    beside the Monte Carlo, :class:`~ftc_verify.verification.sampled_stage.SampledRun`),
    then, once the loop existed (``cross["at"]``, where its check goes), the per-mode
    cross-check (computed beside every stage). Their checks are put where they belong in
    ``checks``, their times into ``seconds`` and ``spans``."""
    found: dict[str, Any] = {}
    for run in sampled:
        found.update(run.join(checks, seconds, spans))
    sampled.clear()
    if cross:
        t0 = time.perf_counter()
        found["per_mode"], check = _cross_validation(cross_check)
        checks.insert(cross["at"], check)
        spans["cross_validation_wait"] = (t0, time.perf_counter())
        seconds["cross_validation_wait"] = spans["cross_validation_wait"][1] - t0
        seconds["cross_validation"] = cross_check.seconds.get("run", 0.0)
        spans.update({"cross_validation": cross_check.spans["run"]} if "run" in cross_check.spans else {})
        cross.clear()
    return found


def _cross_validation(cross_check: Any) -> tuple[tuple[ModeCheck, ...], Check]:
    """Every frozen joint mode against python-control (the answer of the running
    :class:`~ftc_verify.prestart.Prestarted`)."""
    per_mode = cross_check.result()
    bad = [f"({m.true_mode},{m.fdi_mode}): {m.detail}" for m in per_mode if not m.agree]
    return per_mode, Check("python-control per mode", not bad, "all joint modes agree" if not bad else "; ".join(bad))


def _exact_energies(system: FTCSystem, loop: ClosedLoop, g2: float) -> tuple[list[dict[str, Any]], Check]:
    """Exact expected energy at the ``beta`` vertices and the constant Deltas."""
    exact = []
    vertices = list(system.chain.vertices())[:MAX_EXACT_VERTICES]
    for label, dl in constant_delta_loops(system, loop):
        for b in vertices:
            e = exact_energy(dl, beta=b)
            exact.append({"delta": label, "beta": b.tolist(), "y_energy": e.y_energy, "w_energy": e.w_energy,
                          "ratio": e.ratio})
    worst = max(exact, key=lambda e: e["ratio"])
    return exact, Check("exact energy", worst["ratio"] <= g2,
                        f"max E||y||^2/||w||^2 = {worst['ratio']:.6g} ({worst['delta']}, "
                        f"{system.chain.rate_text(worst['beta'])}) "
                        f"vs gamma^2 = {upper_text(g2)}, {len(exact)} cases, infinite horizon")


def _fmu_monte_carlo(system: FTCSystem, controller: Controller, chain_paths: list[ChainPath], spec: SimulationSpec,
                     progress: bool, plant: Any = None, log: Any = None, client: Any = None,
                     processes: list[Any] | None = None) -> tuple[list[PathRecord], dict[str, Any]]:
    """Every path co-simulated on the plant map's FMU (default: the ``LinearJumpPlant`` of
    ``system``) as ``spec`` says, in batches (:data:`~ftc_verify.simulation.batches.FMU_TASK_PATHS`), on
    ``client``'s Dask workers if given (:func:`~ftc_verify.simulation.batches.fmu_monte_carlo`;
    same records); also the FMU's file and model identifier. Every path draws ``Delta`` from
    its own stream, so two calls see the same ``Delta``."""
    from ..simulation.batches import fmu_monte_carlo, progress_bar

    bar = progress_bar(len(chain_paths), "Monte Carlo (FMU)", progress)
    try:
        res = fmu_monte_carlo(system, controller, chain_paths, spec=spec, plant=plant, client=client, log=log,
                              done=None if bar is None else bar.update, processes=processes or None)
    finally:
        if bar is not None:
            bar.close()
    extra = {"controller_fmu": res.options["controller_fmu"]} if "controller_fmu" in res.options else {}
    return list(res.records), {"fmu": res.options["fmu"], "model_identifier": res.options["model_identifier"], **extra}


def incremental_records(with_w: list[PathRecord], without_w: list[PathRecord]) -> list[PathRecord]:
    """Each path's response to the disturbance alone: the path with ``w`` minus the same
    path (same chain, FDI switches, ``Delta``) run with ``w = 0``,

    .. math::  y_{inc}(t) = y(t; w) - y(t; 0),

    and likewise for ``x, u, y_m, x_c``; ``w`` is kept. On a linear plant this is the path
    itself (superposition); on a nonlinear plant whose faults move the equilibrium it
    removes the fault response ``y(t; 0)``, which the linear model cannot carry, and
    leaves the incremental ``w -> y`` response that the certified gamma bounds. A path
    that diverged in either run counts as diverged at the earlier time."""
    out = []
    for a, b in zip(with_w, without_w, strict=True):
        k = min(len(a.t), len(b.t))
        times = [d for d in (a.diverged_at, b.diverged_at) if d is not None]
        out.append(PathRecord(a.path, a.t[:k], a.true[:k - 1], a.fdi[:k - 1], a.x[:k] - b.x[:k], a.u[:k] - b.u[:k],
                              a.w[:k], a.y[:k] - b.y[:k], a.xc[:k] - b.xc[:k], a.ym[:k] - b.ym[:k],
                              diverged_at=min(times) if times else None))
    return out


def _measured(records: list[PathRecord], measure: str,
              run_without_w: Any) -> tuple[list[PathRecord], list[PathRecord] | None]:
    """The records the Monte Carlo measures, and the ``w = 0`` runs when ``measure`` is
    ``"incremental"`` (``run_without_w()`` simulates them)."""
    if measure == "total":
        return records, None
    fault_only = run_without_w()
    return incremental_records(records, fault_only), fault_only


def _mc_check(records: list[PathRecord], gamma_cert: float, seed: int, step: float,
              horizon: float, incremental: bool = False) -> tuple[MCEstimate, Check]:
    """The Monte Carlo estimate of ``E||y||^2/||w||^2`` on the FMU paths against gamma^2
    (``incremental``: the records are :func:`incremental_records`)."""
    g2 = gamma_cert ** 2
    y = np.array([r.y_norm ** 2 for r in records])
    w = np.array([r.w_norm ** 2 for r in records])
    mc = estimate(y, w, alpha=1e-6, gamma=gamma_cert, seed=seed)
    return mc, Check("Monte Carlo (FMU)", mc.upper_bound <= g2, divergence_note(records) or
                     f"mean ratio {mc.mean_ratio:.6g}, one-sided upper bound {mc.upper_bound:.6g} (alpha 1e-6, "
                     f"{len(records)} paths) vs gamma^2 = {upper_text(g2)}; sample-and-hold at h = {step:g}, horizon {horizon:g}"
                     + ("; incremental: y(w) - y(w = 0) on the same paths" if incremental else ""))


def _bracket(analysis: AnalysisReport, gamma_cert: float) -> tuple[None, Check]:
    """The proved lower bound beside the certified robust gamma (computed by the
    analysis): it must not exceed the certificate."""
    low = bracket(analysis.robust, analysis.robust_lower)
    if low is None or low["value"] is None:
        why = "no candidate loop was stable" if low is None else low["method"]
        return None, Check("gamma bracket", True, f"certified {upper_text(gamma_cert)}; no lower bound proved ({why})")
    return None, Check("gamma bracket", low["value"] <= gamma_cert,
                       f"proved lower bound {lower_text(low['value'])} <= certified {upper_text(gamma_cert)} (ratio "
                       f"{gamma_cert / low['value']:.6g}{', LOOSE' if low['loose'] else ''}; {low['delta']}, "
                       f"rates {low['rates']}, w = F x + e cos({low['frequency']:.4g} t))")


def _monte_carlo_stage(system: FTCSystem, controller: Controller, spec: SimulationSpec, plant: Any, fmu_log: Any,
                       measure: str, progress: bool, client: Any, procs: list[Any],
                       early: list[EarlyReference]) -> tuple[Any, ...]:
    """The paths of ``spec``, their FMU records and the records the Monte Carlo measures
    (:func:`_measured`); the ``w = 0`` runs of the incremental measure (else ``None``).
    ``procs``: plant processes started earlier (used by the first run, closed there).
    Meanwhile a thread computes the reference of the agreement's paths
    (:class:`~ftc_verify.verification.agreement.EarlyReference`, put into ``early``)."""
    chain_paths = spec.sample_paths(system.chain)
    early.append(EarlyReference(system, controller, chain_paths[:AGREE_PATHS], spec))
    try:
        with spec.client(client) as client:
            records, fmu = _fmu_monte_carlo(system, controller, chain_paths, spec, progress, plant, fmu_log,
                                            client=client, processes=list(procs))
            procs.clear()
            measured, fault_only = _measured(records, measure, lambda: _fmu_monte_carlo(
                system, controller, chain_paths, replace(spec, disturbance="zero"), progress, plant, fmu_log,
                client=client)[0])
    except PlantRunError:  # reported by the caller, whose figures fork: the thread ends first
        early[-1].wait()
        raise
    return chain_paths, records, fmu, measured, fault_only


def _risk_check(stage: RiskStage | None, system: FTCSystem, controller: Controller, plant: Any,
                spec: SimulationSpec, client: Any, checks: list[Check], seconds: dict[str, float]) -> dict[str, Any] | None:
    """The risk stage (module docstring, 7) when ``plant`` declares ``[risk]``: its JSON,
    its check appended to ``checks`` when the map gives a target (a crashed plant FMU fails
    the check), its time in ``seconds["risk"]``."""
    if stage is None or plant is None or getattr(plant, "risk", None) is None:
        return None
    t = time.perf_counter()
    with spec.client(client) as client:
        try:
            found, ok, detail = stage(system, controller, plant, spec, client)
        except PlantRunError as exc:
            found, ok, detail = {"plant_failure": str(exc)}, False, f"the plant FMU failed: {exc}"
    if ok is not None:
        checks.append(Check("risk", ok, detail))
    seconds["risk"] = time.perf_counter() - t
    return found | {"detail": detail}


#: Modules of the stages after the synthesis, imported while it runs in its child process
#: (fmpy: the plant FMU's build check, ``plants.build.fmi2_include_dir``, imports it).
LATER_STAGES = ("ftc_verify.verification.plots", "ftc_verify.simulation.reference", "ftc_verify.simulation.batches",
                "ftc_verify.simulation.isolated", "ftc_verify.verification.report", "ftc_verify.verification.summary",
                "fmpy.model_description")


def _import_later_stages() -> None:
    """Import :data:`LATER_STAGES` (and so matplotlib): work this process would do later
    anyway, done while it would only wait for the synthesis."""
    import importlib

    for name in LATER_STAGES:
        importlib.import_module(name)


def _verify_spec(spec: SimulationSpec | None, given: dict[str, Any]) -> SimulationSpec:
    """The spec of :func:`run_verify`: ``n_paths``, ``step``, ``horizon``, ``seed`` (drawn
    and reported when ``None``), ``delta`` as
    :meth:`~ftc_verify.simulation.spec.SimulationSpec.resolve_delta` decides on the plant
    (from the keywords: kind ``random`` wherever the plant carries it), the paper's
    disturbance, ``workers``/``scheduler`` for the cluster."""
    if spec is None:
        given = given | {"delta": "random", "delta_explicit": False}
    spec = spec_from(spec, given).with_seed()
    if spec.disturbance != "paper":
        raise ValidationError(f"spec.disturbance: {spec.disturbance!r}; verify measures the paper's disturbance "
                              "(its exact energies are compared), give 'paper'")
    return spec


def run_verify(
    system: FTCSystem, *, gamma: float | None = None, method: str = "iterative", k_max: float | None = 30.0,
    controller: Controller | None = None, spec: SimulationSpec | None = None,
    paths: int | None = None, step: float | None = None, horizon: float | None = None, seed: int | None = None,
    solver: str | None = None, progress: bool = False, plant: Any = None, fmu_log: Any = None,
    measure: str = "total", client: Any = None, cross_check: Any = None, risk: RiskStage | None = None,
    meanwhile: Callable[[VerifyReport], Any] | None = None, processes: list[Any] | None = None,
    h_max_work: float | None = None, sampled_loop: SampledLoop | None = None,
) -> VerifyReport:
    """Run every stage of the module docstring and collect the checks.

    ``controller=None`` synthesizes state feedback by ``method``; a given controller (static or dynamic,
    :class:`~ftc_verify.controllers.Controller`) is verified as is. ``spec``: the
    :class:`~ftc_verify.simulation.spec.SimulationSpec` of the Monte Carlo (seed drawn when ``None``; ``Delta`` resolved
    on the plant; records' memory checked first); the keywords ``paths``, ``step``, ``horizon``, ``seed`` are its
    shorthand. ``plant``: a :class:`~ftc_verify.plants.plant_map.PlantMap` whose FMU replaces the ``LinearJumpPlant`` in
    the Monte Carlo (``system`` is then its linearisation); the report gains a ``plant`` object and the region check
    replaces the backend agreement. ``measure``: ``"total"`` or ``"incremental"`` (:func:`incremental_records`; the
    fault response's energy is reported). ``client``: a ``dask.distributed.Client`` whose workers co-simulate the Monte
    Carlo batches (same numbers); else ``fmu_log`` gets the FMU's messages. ``cross_check``: a
    :class:`~ftc_verify.prestart.Prestarted` started by the caller (the CLI starts it
    right after its numerical imports, before loading anything); by default one is started here, first. It gets the loop as
    soon as it exists and is waited for only at the end, so python-control's import and
    checks overlap every other stage. ``risk``: the risk stage
    (stage 7). ``meanwhile``: called with the report so far (every stage but the
    sampled loop's and the python-control check, which run in child processes) before
    waiting for those children, when the sampled stages ran; the CLI draws the report's
    figures there (:class:`~ftc_verify.verification.report.EarlyFigures`). ``processes``: the
    Monte Carlo's plant processes (:func:`~ftc_verify.simulation.isolated.plant_processes`)
    started by the caller (the CLI starts them first, so their interpreters start beside its
    own imports); by default started here, before the synthesis, when the Monte Carlo runs
    isolated in this machine (no cluster); closed here either way. ``h_max_work``: the
    sampled loop's ``h_max`` bracket refined within that many work units (``verify
    --h-max-work``, :func:`~ftc_verify.analysis.moments.sampled_refine.refine_result`).
    ``sampled_loop``: the :class:`~ftc_verify.analysis.moments.sampled.SampledLoop` of the
    given ``controller`` when the caller built it (the CLI, for ``--h-max-work``'s memory
    check); the sampled stages build it otherwise."""
    if measure not in ("total", "incremental"):
        raise ValidationError(f"measure: {measure!r} is not 'total' or 'incremental'")
    spec = _verify_spec(spec, {"n_paths": paths, "step": step, "horizon": horizon, "seed": seed})
    if cross_check is None:
        from ..prestart import cross_check as start_cross_check

        cross_check = start_cross_check()
    procs: list[Any] = list(processes or ())
    sampled: list[Any] = []  # the SampledRun child while it runs
    try:
        if not (client is None and spec.workers is None and spec.scheduler is None and spec.isolate):
            for proc in procs:  # the Monte Carlo runs elsewhere
                proc.close()
            procs = []
        elif not procs:
            from ..simulation.isolated import plant_processes

            procs = plant_processes()  # their interpreters start beside the synthesis and analysis
        return _run_verify(system, gamma, method, k_max, controller, spec, solver, progress, plant, fmu_log,
                           measure, client, cross_check, procs, sampled, risk, meanwhile, h_max_work, sampled_loop)
    finally:
        cross_check.cancel()
        for run in sampled:
            run.cancel()
        for proc in procs:
            proc.close()


def _run_verify(system: FTCSystem, gamma: float | None, method: str, k_max: float | None,
                controller: Controller | None, spec: SimulationSpec, solver: str | None, progress: bool,
                plant: Any, fmu_log: Any, measure: str, client: Any, cross_check: Any, procs: list[Any],
                sampled: list[Any], risk: RiskStage | None = None, meanwhile: Callable[[VerifyReport], Any] | None = None,
                h_max_work: float | None = None, sampled_loop: SampledLoop | None = None) -> VerifyReport:
    """The stages of :func:`run_verify`, with its running ``cross_check`` and the plant processes
    ``procs`` started for the Monte Carlo (:func:`~ftc_verify.simulation.isolated.plant_processes`;
    none on a cluster); ``sampled`` holds the :class:`~ftc_verify.verification.sampled_stage.SampledRun`
    started here until it is joined (the caller cancels what is left)."""
    seconds: dict[str, float] = {}
    spans: dict[str, tuple[float, float]] = {}  # each stage's start and end: stages overlap
    seed = int(spec.seed)  # type: ignore[arg-type]
    options = {"fdi_model": system.chain.describe(), "method": method if controller is None else "given controller",
               "gamma": gamma, "k_max": k_max, "paths": spec.n_paths, "step": spec.step, "horizon": spec.horizon,
               "solver": solver or "auto", "disturbance": spec.disturbance, "measure": measure}
    checks: list[Check] = []

    def stage(name: str, t0: float) -> None:
        spans[name] = (t0, time.perf_counter())
        seconds[name] = spans[name][1] - t0

    def timed(name: str, run: Callable[[], tuple[Any, Check]]) -> Any:
        """``run()``'s finding; its check appended and its time recorded as ``name``."""
        t0 = time.perf_counter()
        found, check = run()
        checks.append(check)
        stage(name, t0)
        return found

    t = time.perf_counter()
    synthesis = None
    if controller is None:
        synthesis = interruptible(lambda: synthesize(system, method=method, gamma=gamma, k_max=k_max,
                                                     solver=solver), "the synthesis", _import_later_stages)
        checks.append(Check("synthesis", synthesis.feasible, synthesis.message))
        controller = synthesis.controller
    stage("synthesis", t)
    extra: dict[str, Any] = {}  # the sampled loop's findings (verification.sampled_stage)
    cross: dict[str, Any] = {}  # where the python-control check goes among the checks, once the loop exists

    def report(**found: Any) -> VerifyReport:
        def made() -> VerifyReport:
            parts: dict[str, Any] = {"gamma_certified": None, "analysis": None, "per_mode": (), "exact": (),
                                     "mc": None, "records": ()} | extra | found
            return VerifyReport(system, controller, synthesis=synthesis, checks=tuple(checks), seed=seed,
                                options=options, seconds=dict(seconds), spans=dict(spans), **parts)

        if meanwhile is not None and sampled:  # the report so far, while the sampled stages may still run
            meanwhile(made())
        extra.update(_join(sampled, cross, cross_check, checks, seconds, spans))
        return made()

    if controller is None:
        return report()
    loop = closed_loop(system, controller.check(system))
    cross_check.submit(cross_validate, loop)
    spec.check_memory(system, controller, spec.n_paths)
    t = time.perf_counter()
    analysis = synthesis.report if synthesis is not None and synthesis.report is not None else interruptible(
        lambda: analyze(loop, solver=solver, name=system.name, cross_validation=False, lean=True), "the analysis")
    gamma_cert, found = _certify(analysis, gamma)
    checks.extend(found)
    stage("analysis", t)
    cross["at"] = len(checks)
    if gamma_cert is None:
        return report(analysis=analysis)
    g2 = gamma_cert ** 2
    exact = timed("exact_energy", lambda: _exact_energies(system, loop, g2))
    sampled.append(SampledRun(system, controller, spec.step, g2, (spec.horizon, spec.n_paths, seed), len(checks),
                              h_max_work, spec.records_memory(system, controller, spec.n_paths)[0],
                              sampled_loop))  # beside the MC
    timed("gamma_bracket", functools.partial(_bracket, analysis, gamma_cert))
    t = time.perf_counter()
    spec, options["delta"] = spec.resolve_delta(system, plant)
    early: list[EarlyReference] = []
    try:
        chain_paths, records, fmu, measured, fault_only = _monte_carlo_stage(
            system, controller, spec, plant, fmu_log, measure, progress, client, procs, early)
    except PlantRunError as exc:  # the plant crashed: a result, reported
        checks.append(Check("Monte Carlo (FMU)", False, str(exc)))
        stage("monte_carlo", t)
        return report(gamma_certified=gamma_cert, analysis=analysis, exact=tuple(exact), plant_failure=exc)
    options.update(fmu)
    mc, check = _mc_check(measured, gamma_cert, seed, spec.step, spec.horizon, incremental=measure == "incremental")
    checks.append(check)
    stage("monte_carlo", t)
    found_plant = timed("reference", lambda: against_reference(system, controller, chain_paths, records, spec,
                                                                 plant, mc, fmu, measured, fault_only, early[0]))
    return report(gamma_certified=gamma_cert, analysis=analysis, exact=tuple(exact), mc=mc, records=tuple(records),
                  plant=found_plant, risk=_risk_check(risk, system, controller, plant, spec, client, checks, seconds))
