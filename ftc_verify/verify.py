"""The main job: synthesize, certify and check a controller three independent ways.

:func:`run_verify` runs these stages on a system (or on given gains):

1. **synthesis** (:func:`ftc_verify.synthesis.synthesize`) or loading gains, then the core
   analysis: exact spectral test, certified Theorem 3.1 and robust gamma (Lemma 4.1);
2. **cross-validation** of every frozen joint mode with python-control;
3. **exact expected energy** of the continuous-time loop for the paper's disturbance at
   every ``beta`` vertex (up to :data:`MAX_EXACT_VERTICES`) and for ``Delta`` in
   ``{0, +E, -E}`` (``E`` the rectangular identity, norm 1) when the plant is uncertain;
4. **worst-case disturbance** on a horizon at the worst of those vertices (a lower bound
   of the stochastic gain);
5. **Monte Carlo co-simulation** of the FMU plant under Markov faults and delayed FDI
   switching (sample-and-hold at ``step``), ``beta`` drawn per path from its box, a random
   ``Delta`` per chain segment when uncertain; the mean ratio's one-sided upper bound
   (:mod:`ftc_verify.montecarlo`) is compared with gamma^2;
6. **backend agreement**: the first paths re-simulated by the numpy reference with the
   same ``Delta`` draws must match the FMU to :data:`AGREE_RTOL`.

Each stage becomes a named check; the verdict is ``pass`` only if all pass. Every random
draw comes from one :class:`numpy.random.Generator` whose seed is in the report.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .analysis import AnalysisReport, analyze, json_ready
from .closedloop import state_feedback_loop
from .crossval import ModeCheck, cross_validate
from .model import FTCSystem, Matrix
from .montecarlo import MCEstimate, estimate
from .moments import WorstCase, exact_energy, worst_case_disturbance
from .paths import sample_paths
from .simulation import PathRecord
from .synthesis import SynthesisResult, synthesize
from .uncertainty import DeltaSchedule, constant_delta_loops

__all__ = ["Check", "VerifyReport", "run_verify", "AGREE_RTOL", "MAX_EXACT_VERTICES"]

#: Relative agreement required between the FMU and the numpy reference on equal paths.
AGREE_RTOL = 1e-8
#: At most this many ``beta`` vertices get an exact energy (all of them for m <= 2..3).
MAX_EXACT_VERTICES = 64
#: Paths re-simulated by the reference backend for the agreement check.
AGREE_PATHS = 5


@dataclass(frozen=True)
class Check:
    """One named check of the report."""

    name: str
    ok: bool
    detail: str


@dataclass(frozen=True, eq=False)
class VerifyReport:
    """Everything :func:`run_verify` computed."""

    system: FTCSystem
    gains: tuple[Matrix, ...]
    gamma_certified: float | None
    analysis: AnalysisReport
    synthesis: SynthesisResult | None
    per_mode: tuple[ModeCheck, ...]
    exact: tuple[dict[str, Any], ...]
    worst: WorstCase | None
    mc: MCEstimate | None
    records: tuple[PathRecord, ...]
    checks: tuple[Check, ...]
    seed: int
    options: dict[str, Any]
    seconds: dict[str, float] = field(default_factory=dict)

    @property
    def verdict(self) -> str:
        """``"pass"`` when every check passed."""
        return "pass" if self.checks and all(c.ok for c in self.checks) else "fail"

    @property
    def exact_energy_ratio(self) -> float | None:
        """Largest exact ``E||y||^2 / ||w||^2`` over the vertices and Deltas evaluated."""
        return max((e["ratio"] for e in self.exact), default=None)

    def to_dict(self) -> dict[str, Any]:
        """The ``report.json`` content."""
        return json_ready({
            "verdict": self.verdict,
            "system": self.system.name,
            "gamma_certified": self.gamma_certified,
            "gamma_nominal_certified": self.analysis.nominal.gamma if self.analysis.nominal.certified else None,
            "spectral_abscissa": self.analysis.mss.spectral_abscissa,
            "exact_energy_ratio": self.exact_energy_ratio,
            "exact": list(self.exact),
            "mc": None if self.mc is None else self.mc.to_dict(),
            "worst_case_gain": None if self.worst is None else self.worst.gain,
            "worst_case": None if self.worst is None else {
                "ratio": self.worst.ratio, "horizon": self.worst.horizon, "pieces": self.worst.pieces},
            "checks": [{"name": c.name, "ok": c.ok, "detail": c.detail} for c in self.checks],
            "gains": [K.tolist() for K in self.gains],
            "synthesis": None if self.synthesis is None else {
                k: v for k, v in self.synthesis.to_dict().items() if k != "analysis"},
            "analysis": self.analysis.to_dict() | {"per_mode": [m.to_dict() for m in self.per_mode]},
            "seed": self.seed,
            "options": self.options,
            "seconds": self.seconds,
        })


def _progress(total: int, enabled: bool) -> Any:
    if not enabled:
        return None
    from tqdm import tqdm

    return tqdm(total=total, desc="Monte Carlo (FMU)", unit="path", file=sys.stderr, leave=False)


def run_verify(
    system: FTCSystem,
    *,
    gamma: float | None = None,
    method: str = "iterative",
    k_max: float | None = 30.0,
    gains: Sequence[Matrix] | None = None,
    paths: int = 200,
    step: float = 0.01,
    horizon: float = 30.0,
    seed: int | None = None,
    solver: str | None = None,
    progress: bool = False,
) -> VerifyReport:
    """Run every stage of the module docstring and collect the checks."""
    seconds: dict[str, float] = {}
    if seed is None:
        seed = int(np.random.SeedSequence().entropy % 2**63)
    options = {"method": method if gains is None else "given gains", "gamma": gamma, "k_max": k_max, "paths": paths,
               "step": step, "horizon": horizon, "solver": solver or "auto", "disturbance": "paper"}
    checks: list[Check] = []
    t = time.perf_counter()
    synthesis = None
    if gains is None:
        synthesis = synthesize(system, method=method, gamma=gamma, k_max=k_max, solver=solver)
        K = list(synthesis.gains)
        checks.append(Check("synthesis", synthesis.feasible, synthesis.message))
    else:
        K = list(gains)
    seconds["synthesis"] = time.perf_counter() - t
    if not K:
        empty = analyze(state_feedback_loop(system, [np.zeros((system.dims[1], system.dims[0]))] * system.m),
                        solver=solver, name=system.name, cross_validation=False)
        return VerifyReport(system, (), None, empty, synthesis, (), (), None, None, (), tuple(checks), seed, options, seconds)
    loop = state_feedback_loop(system, K)
    t = time.perf_counter()
    analysis = synthesis.report if synthesis is not None and synthesis.report is not None else analyze(
        loop, solver=solver, name=system.name, cross_validation=False)
    gamma_cert = analysis.robust.gamma if analysis.robust.certified and analysis.certified_stable else None
    checks.append(Check("certified", gamma_cert is not None,
                        f"robust gamma {gamma_cert:.6g} (Lemma 4.1), spectral abscissa {analysis.mss.spectral_abscissa:.4g}"
                        if gamma_cert is not None else f"not certified: {analysis.robust.message}"))
    if gamma is not None and gamma_cert is not None:
        checks.append(Check("requested gamma", gamma_cert <= gamma, f"certified {gamma_cert:.6g} vs requested {gamma:.6g}"))
    seconds["analysis"] = time.perf_counter() - t
    t = time.perf_counter()
    per_mode = cross_validate(loop)
    bad = [f"({m.true_mode},{m.fdi_mode}): {m.detail}" for m in per_mode if not m.agree]
    checks.append(Check("python-control per mode", not bad, "all joint modes agree" if not bad else "; ".join(bad)))
    seconds["cross_validation"] = time.perf_counter() - t
    if gamma_cert is None:
        return VerifyReport(system, tuple(K), None, analysis, synthesis, per_mode, (), None, None, (), tuple(checks), seed, options, seconds)
    g2 = gamma_cert ** 2
    # exact expected energy at the vertices and Deltas
    t = time.perf_counter()
    exact = []
    vertices = list(system.chain.vertices())[:MAX_EXACT_VERTICES]
    for label, dl in constant_delta_loops(system, loop):
        for b in vertices:
            e = exact_energy(dl, beta=b)
            exact.append({"delta": label, "beta": b.tolist(), "y_energy": e.y_energy, "w_energy": e.w_energy, "ratio": e.ratio})
    worst_exact = max(exact, key=lambda e: e["ratio"])
    checks.append(Check("exact energy", worst_exact["ratio"] <= g2,
                        f"max E||y||^2/||w||^2 = {worst_exact['ratio']:.6g} ({worst_exact['delta']}, beta {worst_exact['beta']}) "
                        f"vs gamma^2 = {g2:.6g}, {len(exact)} cases, infinite horizon"))
    seconds["exact_energy"] = time.perf_counter() - t
    # worst-case disturbance at that vertex (nominal loop)
    t = time.perf_counter()
    worst = worst_case_disturbance(loop.nominal(), beta=np.array(worst_exact["beta"]), horizon=min(horizon, 30.0), pieces=40)
    checks.append(Check("worst-case disturbance", worst.gain <= gamma_cert,
                        f"lower bound of the stochastic gain {worst.gain:.6g} <= certified {gamma_cert:.6g} "
                        f"(gap {gamma_cert - worst.gain:.3g} = conservatism of the certificate)"))
    seconds["worst_case"] = time.perf_counter() - t
    # Monte Carlo on the FMU
    t = time.perf_counter()
    from .fmu_build import build_fmu
    from .reference_sim import simulate_reference
    from .supervisor import FaultInjectionMap, Supervisor

    rng = np.random.default_rng(seed)
    chain_paths = sample_paths(system.chain, horizon, paths, rng)
    delta = DeltaSchedule("random" if system.uncertain else "zero")
    delta_seed = int(rng.integers(2**63))
    records: list[PathRecord] = []
    bar = _progress(paths, progress)
    with Supervisor(build_fmu(system), FaultInjectionMap.for_linear_jump_plant(system), system=system) as sup:
        delta_rng = np.random.default_rng(delta_seed)
        for start in range(0, paths, 25):
            batch = chain_paths[start:start + 25]
            res = sup.run(batch, K, step=step, disturbance="paper", delta=delta, rng=delta_rng)
            records.extend(res.records)
            if bar is not None:
                bar.update(len(batch))
    if bar is not None:
        bar.close()
    y = np.array([r.y_norm ** 2 for r in records])
    w = np.array([r.w_norm ** 2 for r in records])
    mc = estimate(y, w, alpha=1e-6, gamma=gamma_cert, seed=seed)
    checks.append(Check("Monte Carlo (FMU)", mc.upper_bound <= g2,
                        f"mean ratio {mc.mean_ratio:.6g}, one-sided upper bound {mc.upper_bound:.6g} (alpha 1e-6, {paths} paths) "
                        f"vs gamma^2 = {g2:.6g}; sample-and-hold at h = {step:g}, horizon {horizon:g}"))
    seconds["monte_carlo"] = time.perf_counter() - t
    # the same first paths on the numpy reference, with the same Delta draws
    t = time.perf_counter()
    ref = simulate_reference(system, K, chain_paths[:AGREE_PATHS], step=step, disturbance="paper", delta=delta,
                             rng=np.random.default_rng(delta_seed))
    worst_diff = 0.0
    for a, b in zip(records[:AGREE_PATHS], ref.records):
        scale = max(1e-300, float(np.max(np.abs(b.x))))
        worst_diff = max(worst_diff, float(np.max(np.abs(a.x - b.x))) / scale)
    checks.append(Check("FMU vs reference", worst_diff <= AGREE_RTOL,
                        f"max relative state difference {worst_diff:.3g} on {min(AGREE_PATHS, paths)} paths (tolerance {AGREE_RTOL:g})"))
    seconds["reference"] = time.perf_counter() - t
    return VerifyReport(system, tuple(K), gamma_cert, analysis, synthesis, per_mode, tuple(exact), worst, mc,
                        tuple(records), tuple(checks), seed, options, seconds)
