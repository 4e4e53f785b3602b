"""The sampled-loop stage of ``verify``: the loop it simulates, analysed at its period.

``verify --step h`` co-simulates the controller sampled every ``h`` with its output held
(:mod:`ftc_verify.simulation.reference`); this stage proves (or refutes) mean-square
stability of that sampled loop over the rate box at ``h`` and finds the proved ``h_max``
bracket (:func:`ftc_verify.analysis.moments.sampled.sampled_analysis`). The continuous-time
certificates of the other stages are its :math:`h \\to 0` limit.
"""

from __future__ import annotations

import contextlib
import dataclasses
import time
from typing import TYPE_CHECKING, Any

import numpy as np

from ..analysis.moments.sampled import SampledLoop, SampledResult, sampled_analysis
from ..analysis.solvers import interruptible
from ..claimtext import upper_text
from ..controllers.controller import Controller
from ..errors import FTCError, MemoryLimitError, ValidationError
from ..limits import check_memory, format_bytes
from ..model.system import FTCSystem

if TYPE_CHECKING:
    from .verify import Check

__all__ = ["SAMPLED_LIMIT", "MC_ALPHA", "MC_PERIODS", "MC_MIN_PATHS", "MC_MIN_JUMPED", "sampled_stage", "sampled_energy_stage", "sampled_mc_stage",
           "sampled_stages", "SampledRun"]

#: Largest second-moment generator (rows, joint states times ``d (d + 1) / 2`` with
#: ``d = n + n_u + n_c``) the stage analyses; its rigorous exponential is the cost.
SAMPLED_LIMIT = 400
#: Two-sided level of the interval of :func:`sampled_mc_stage` (its false-failure probability).
MC_ALPHA = 1e-6
#: Periods simulated by :func:`sampled_mc_stage` (at most; the verify horizon when shorter).
MC_PERIODS = 400
#: Fewest paths of the two-sided check (``--paths`` when larger): the numpy loop is cheap,
#: and the interval needs the paths' spread, which rare jumps make.
MC_MIN_PATHS = 1000
#: Fewest paths with a jump of the chain for the check to decide: below it the sample
#: spread misses the jumps' contribution and the interval would be too narrow.
MC_MIN_JUMPED = 10


def sampled_stage(system: FTCSystem, controller: Controller, step: float, here: bool = False,
                  h_max_work: float | None = None, reserved: float = 0.0,
                  loop: SampledLoop | None = None) -> tuple[SampledResult | None, Check]:
    """``(result, check)`` of the sampled loop at period ``step``: the check passes when
    mean-square stability over the whole rate box is proved; a loop above
    :data:`SAMPLED_LIMIT` is not analysed (said in the check, which then passes as
    before this stage existed and names what it does not cover). The analysis runs in a
    killable child (:func:`~ftc_verify.analysis.solvers.interruptible`) unless ``here``.
    ``h_max_work``: ``verify --h-max-work``, the bracket then refined
    (:func:`~ftc_verify.analysis.moments.sampled_refine.refine_result`) as by ``analyze``,
    unless its program's memory estimate plus ``reserved`` (bytes held meanwhile by the
    caller: ``verify``'s Monte Carlo records) is above the memory limit -- then the check
    says that the refinement was not run and why. ``loop``: :meth:`SampledLoop.build` of
    ``system, controller`` when the caller has it (built here otherwise)."""
    from .verify import Check

    loop = SampledLoop.of(system, controller, loop)
    d = loop.d
    rows = loop.states * d * (d + 1) // 2
    name = f"sampled loop (h = {step:g})"
    if rows > SAMPLED_LIMIT:
        return None, Check(name, True, f"NOT analysed: its moment generator has {rows} rows (limit {SAMPLED_LIMIT}); "
                                       "the certificates above are those of the continuous-time loop")
    from ..analysis.moments.sampled_cover import cubic_memory
    from ..analysis.moments.sampled_refine import check_refine, period_text, refinement_note, refine_result

    refused = ""
    if h_max_work is not None:  # a synthesized controller is checked here, a given one before any work too
        try:
            check_refine(system, controller, step, h_max_work, loop=loop)
            check_memory(cubic_memory(loop) + reserved, "the h_max refinement's clock program beside "
                         f"the Monte Carlo's records ({format_bytes(reserved)})", hint="lower --paths or drop --h-max-work")
        except (ValidationError, MemoryLimitError) as exc:
            refused, h_max_work = f"; refinement not run: {exc}", None

    def run() -> SampledResult:
        res = sampled_analysis(system, controller, step, max_seconds=30.0, loop=loop)
        if h_max_work is None:
            return res
        return refine_result(system, controller, res, h_max_work, loop=loop)

    res = run() if here else interruptible(run, "the sampled-data analysis")
    if refused:
        res = dataclasses.replace(res, h_max_note=res.h_max_note + refused)
    if res.h_max is None or res.h_max_unstable is None:
        bracket = "h_max not found: " + res.h_max_note
    else:
        bracket = (f"h_max {period_text(res.h_max, down=True)} (proved stable; unstable at "
                   f"{period_text(res.h_max_unstable, down=False)})")
        refined = refinement_note(res) or refused.lstrip("; ")
        bracket += f"; {refined}" if refined else ""
    word = {"stable": "mean-square stable", "not stable": "NOT mean-square stable",
            "undecided": "UNDECIDED"}[res.verdict]
    return res, Check(name, res.stable, f"{word}: spectral radius of the one-period map {res.spectral_radius:.6g}; "
                                        f"{res.proof}; {bracket}")


def sampled_energy_stage(system: FTCSystem, controller: Controller, step: float, g2: float,
                         sampled: SampledResult | None, max_vertices: int) -> tuple[list[dict[str, Any]], Check]:
    """The exact expected energy of the sampled loop at ``step`` for the paper's
    disturbance (:func:`ftc_verify.analysis.moments.sampled_energy.sampled_energies`, infinite
    horizon) at the rate vertices (up to ``max_vertices``) and the constant
    ``Delta in {0, +E, -E}``, against ``g2`` (gamma^2 of the continuous certificate: the
    loop that runs must keep it). Not run when the sampled loop was not analysed or not
    proved stable (its check says why)."""
    from ..simulation.delta import delta_shapes
    from ..analysis.moments.sampled_energy import perturbed_system, sampled_energies
    from .verify import Check

    name = f"exact energy (sampled loop, h = {step:g})"
    if sampled is None or not sampled.stable:
        why = "not analysed" if sampled is None else f"not proved stable ({sampled.verdict})"
        return [], Check(name, sampled is None, f"not computed: the sampled loop was {why}")
    s1, s2 = delta_shapes(system)
    cases: list[tuple[str, Any, Any]] = [("Delta=0", None, None)]
    if system.uncertain:
        cases += [(label, None if s1 is None else sign * np.eye(*s1), None if s2 is None else sign * np.eye(*s2))
                  for sign, label in ((1.0, "Delta=+E"), (-1.0, "Delta=-E"))]
    out: list[dict[str, Any]] = []
    betas = list(system.chain.vertices())[:max_vertices]
    for label, d1, d2 in cases:
        try:  # the rate-independent parts once per Delta (sampled_energies)
            found = sampled_energies(perturbed_system(system, d1, d2), controller, step, betas)
        except FTCError:
            found = [None] * len(betas)
        for b, e in zip(betas, found):  # None: the perturbed sampled loop is not stable at this vertex
            out.append({"delta": label, "beta": b.tolist(), "ratio": float("inf") if e is None else e.ratio})
    worst = max(out, key=lambda e: e["ratio"])
    return out, Check(name, worst["ratio"] <= g2,
                      f"max E||y||^2/||w||^2 = {worst['ratio']:.6g} ({worst['delta']}, "
                      f"{system.chain.rate_text(worst['beta'])}) vs gamma^2 = {upper_text(g2)}, {len(out)} cases, "
                      "infinite horizon, u and w held over each period")


def sampled_mc_stage(system: FTCSystem, controller: Controller, step: float, horizon: float, n_paths: int,
                     seed: int, sampled: SampledResult | None) -> tuple[dict[str, Any] | None, Check]:
    r"""The simulated loop against the exact expectation of the sampled loop, two-sided.

    ``max(n_paths, MC_MIN_PATHS)`` paths of the numpy loop (:func:`ftc_verify.simulation.vectorised.energies_reference`,
    the loop the FMU Monte Carlo runs, purely periodic at ``step``) of the nominal plant
    (:math:`\Delta = 0`) at the rate box's midpoint, from :math:`x = 0` with the paper's
    disturbance, over :math:`H = \min(\text{horizon}, \text{MC\_PERIODS}\cdot h)`; their
    streams are children of ``SeedSequence([seed, 31])``. Per path the trapezoidal sum of
    :math:`|y|^2` over its samples (``quadrature="samples"``);
    its exact expectation is :func:`~ftc_verify.analysis.moments.sampled_energy.sample_trapezoid`
    (the same quadrature, so no quadrature bias). The check passes when the exact value lies
    in the Student-t interval :math:`\bar Y \pm t_{1-\alpha/2, n-1} s/\sqrt n`
    (``alpha`` = :data:`MC_ALPHA`; by the central limit theorem a correct simulator fails it
    with probability about ``alpha``), widened by ``1e-9`` relative for rounding. Not run
    when the sampled loop was not analysed or is proved not mean-square stable (the check
    fails: no finite expectation; at ``--step 1e4`` its 1000 paths over 10 periods held
    1e8 jumps of the chain, 2.6 GB, and the run reached 7 GB); not decided (reported,
    passed) when fewer than
    :data:`MC_MIN_JUMPED` paths saw a jump of the chain: the paths without one all have
    the same energy, so the sample spread would miss the jumps' share of the mean and the
    interval's stated false-failure probability would not hold."""
    import scipy.stats

    from ..analysis.moments.sampled_energy import sample_trapezoid
    from ..simulation.paths import sample_paths
    from ..simulation.vectorised import energies_reference
    from .verify import Check

    name = f"Monte Carlo vs exact (sampled loop, h = {step:g})"
    if sampled is None:
        return None, Check(name, True, "not compared: the sampled loop was not analysed")
    if getattr(sampled, "verdict", None) == "not stable":  # no finite expectation to compare with (and the paths diverge)
        return None, Check(name, False, "not compared: the sampled loop is proved NOT mean-square stable")
    H = min(horizon, MC_PERIODS * step)
    nominal = system.nominal()
    rates = system.chain.midpoint()
    paths = sample_paths(system.chain, H, max(n_paths, MC_MIN_PATHS), np.random.SeedSequence([seed, 31]),
                         beta=rates)
    jumped = sum(1 for p in paths if len(p.times) > 1)
    Y, _ = energies_reference(nominal, controller, paths, step=step, disturbance="paper", quadrature="samples")
    if not np.all(np.isfinite(Y)):
        return None, Check(name, False, f"{int(np.sum(~np.isfinite(Y)))} simulated paths diverged: no mean")
    exact = sample_trapezoid(nominal, controller, step, beta=rates, horizon=H)
    n = Y.size
    half = (float(scipy.stats.t.ppf(1 - MC_ALPHA / 2, n - 1)) * float(Y.std(ddof=1)) / np.sqrt(n) if n > 1 else np.inf)
    half += 1e-9 * abs(exact)
    mean = float(Y.mean())
    found = {"paths": n, "jumped": jumped, "horizon": H, "rates": rates.tolist(), "seed": [seed, 31], "mean": mean,
             "interval": [mean - half, mean + half], "exact": exact, "alpha": MC_ALPHA,
             "decided": jumped >= MC_MIN_JUMPED}
    if jumped < MC_MIN_JUMPED:
        return found, Check(name, True, f"not compared: {jumped} of {n} paths saw a jump of the chain within "
                                        f"{H:g} (at least {MC_MIN_JUMPED} needed); exact {exact:.6g}, "
                                        f"Monte Carlo {mean:.6g}")
    return found, Check(name, abs(mean - exact) <= half,
                        f"E sum_k w_k |y(t_k)|^2 over the samples: exact {exact:.6g}, Monte Carlo {mean:.6g} "
                        f"+- {half:.3g} ({n} paths, nominal, rates at the box midpoint, horizon {H:g}, "
                        f"two-sided, false failure {MC_ALPHA:g})")


def sampled_stages(system: FTCSystem, controller: Controller, step: float, g2: float, checks: list[Check],
                   seconds: dict[str, float], mc: tuple[float, int, int] | None = None,
                   spans: dict[str, tuple[float, float]] | None = None, here: bool = False,
                   h_max_work: float | None = None, reserved: float = 0.0,
                   loop: SampledLoop | None = None) -> dict[str, Any]:
    """Both stages of ``verify`` on the sampled loop (:func:`sampled_stage`, then
    :func:`sampled_energy_stage` at the rate vertices up to
    :data:`~ftc_verify.verification.verify.MAX_EXACT_VERTICES`): their checks appended
    to ``checks``, their times to ``seconds`` (``sampled``, ``sampled_energy``) and their
    ``(start, end)`` (:func:`time.perf_counter`) to ``spans``; with
    ``mc = (horizon, paths, seed)`` also :func:`sampled_mc_stage` (``sampled_mc``). Returns
    the report's ``sampled``, ``sampled_exact`` (and ``sampled_mc``). ``here``: the
    analysis runs in this process (already a child, :class:`SampledRun`), not in a child
    of its own. ``h_max_work``, ``reserved``: passed to :func:`sampled_stage`. ``loop``:
    :meth:`SampledLoop.build` of ``system, controller`` (built here when ``None``), the one
    loop of the analysis, its refinement and the gains."""
    from .verify import MAX_EXACT_VERTICES

    spans = {} if spans is None else spans

    def done(name: str, t0: float) -> None:
        spans[name] = (t0, time.perf_counter())
        seconds[name] = spans[name][1] - t0

    t = time.perf_counter()
    loop = SampledLoop.of(system, controller, loop)
    res, check = sampled_stage(system, controller, step, here, h_max_work, reserved, loop)
    checks.append(check)
    done("sampled", t)
    # after the analysis, so that it runs alone as before (its h_max bracket has a wall-time valve)
    gains = _gains_child(system, controller, step, loop) if here and res is not None and _has_gains(res) else None
    try:
        t = time.perf_counter()
        exact, check = sampled_energy_stage(system, controller, step, g2, res, MAX_EXACT_VERTICES)
        checks.append(check)
        done("sampled_energy", t)
        found: dict[str, Any] = {"sampled_exact": tuple(exact)}
        if mc is not None:
            t = time.perf_counter()
            found["sampled_mc"], check = sampled_mc_stage(system, controller, step, mc[0], mc[1], mc[2], res)
            checks.append(check)
            done("sampled_mc", t)
        t = time.perf_counter()
        if res is not None:  # its proved gains, JSON sampled.nominal_gamma / robust_gamma (+ lower estimates)
            res = _attach_gains(res, system, controller, gains, loop)
        done("sampled_gains_wait", t)
    finally:
        if gains is not None:
            gains.cancel()
    found["sampled"] = res
    return found


def _has_gains(res: SampledResult) -> bool:
    """Whether :func:`~ftc_verify.analysis.moments.sampled_gamma.attach_performance` seeks
    gains for ``res``: not proved unstable and its float64 radius below 1."""
    return res.verdict != "not stable" and res.spectral_radius < 1.0


def _gains_child(system: FTCSystem, controller: Controller, step: float, loop: SampledLoop) -> Any:
    """The sampled loop's gains at ``step`` (:func:`~ftc_verify.analysis.moments.sampled_gamma.sampled_performance`:
    the proved lower bounds and certificates, which need nothing of the exact energies or the
    Monte Carlo check) started in a forked child (:class:`~ftc_verify.analysis.solvers.ForkedCall`)
    beside them; ``None`` (computed afterwards, in turn) without ``fork``. The child stays
    in this process's group, which :class:`SampledRun` leads, so that
    :meth:`SampledRun.cancel` kills it with its group on every POSIX system. On the
    three-tank example the gains are about 9 s of CPU, the energies 5.5 s."""
    import os

    from ..analysis.moments.sampled_gamma import sampled_performance
    from ..analysis.solvers import ForkedCall

    if not hasattr(os, "fork"):
        return None
    return ForkedCall(lambda: sampled_performance(system, controller, step, loop=loop), "the sampled loop's gains")


def _attach_gains(res: SampledResult, system: FTCSystem, controller: Controller, gains: Any,
                  loop: SampledLoop) -> SampledResult:
    """``res`` with its gains (:func:`~ftc_verify.analysis.moments.sampled_gamma.attach_performance`):
    the child's answer when one was started (:func:`_has_gains`: what ``attach_performance``
    computes then), else ``attach_performance`` in turn."""
    from ..analysis.moments.sampled_gamma import attach_performance

    if gains is None:
        return attach_performance(res, system, controller, loop=loop)
    return dataclasses.replace(res, performance=gains.result())


class SampledRun:
    """:func:`sampled_stages` in a forked child started now
    (:class:`~ftc_verify.analysis.solvers.ForkedCall`, leading its own process group),
    beside what this process does next: ``verify`` runs the FMU Monte Carlo meanwhile,
    which needs nothing of this stage. :meth:`join` waits for the answer and puts its
    checks at the place they had when computed in turn (``at``, an index into the
    report's checks), so the report is the same; :meth:`cancel` (in a ``finally``) kills
    a child still running. Without ``fork`` the stages run in :meth:`join`. ``loop``: as
    for :func:`sampled_stages` (``verify --h-max-work`` with a given controller: the one
    the CLI built for its memory check)."""

    def __init__(self, system: FTCSystem, controller: Controller, step: float, g2: float,
                 mc: tuple[float, int, int] | None, at: int, h_max_work: float | None = None,
                 reserved: float = 0.0, loop: SampledLoop | None = None) -> None:
        import os

        from ..analysis.solvers import ForkedCall

        self.at = at
        self._args = (system, controller, step, g2, mc)
        self._h_max_work, self._reserved, self._loop = h_max_work, reserved, loop
        self._child = ForkedCall(self._run, "the sampled-loop stages", group=True) if hasattr(os, "fork") else None

    def _run(self, here: bool = True) -> tuple[dict[str, Any], list[Check], dict[str, float],
                                              dict[str, tuple[float, float]]]:
        checks: list[Check] = []
        seconds: dict[str, float] = {}
        spans: dict[str, tuple[float, float]] = {}
        system, controller, step, g2, mc = self._args
        found = sampled_stages(system, controller, step, g2, checks, seconds, mc, spans, here=here,
                               h_max_work=self._h_max_work, reserved=self._reserved, loop=self._loop)
        return found, checks, seconds, spans

    def join(self, checks: list[Check], seconds: dict[str, float],
             spans: dict[str, tuple[float, float]]) -> dict[str, Any]:
        """The report's ``sampled`` fields; the stages' checks inserted into ``checks`` at
        ``at``, their times into ``seconds`` and ``spans``, and ``sampled_wait`` (what
        was left to wait for)."""
        t0 = time.perf_counter()
        if self._child is None:
            found, mine, times, marks = self._run(here=False)
        else:
            try:
                found, mine, times, marks = self._child.result()
            finally:
                self.cancel()
        checks[self.at:self.at] = mine
        seconds.update(times)
        spans.update(marks)
        spans["sampled_wait"] = (t0, time.perf_counter())
        seconds["sampled_wait"] = spans["sampled_wait"][1] - t0
        return found

    def cancel(self) -> None:
        """Kill the child (and its group) if it still runs. The child itself is killed
        first: a child cancelled right after the fork may not lead its group yet."""
        import os
        import signal

        if self._child is not None:
            if self._child.pid:
                with contextlib.suppress(ProcessLookupError, PermissionError):
                    os.kill(self._child.pid, signal.SIGKILL)
            self._child.cancel()
