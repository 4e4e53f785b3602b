r"""A risk run: the probability that the loop leaves its safe envelope within ``[0, T]``.

Stages, in order (:func:`run_risk`):

1. the estimate (:mod:`ftc_verify.risk.estimate`): the chain's paths are drawn (tilted
   for importance sampling) and simulated by the project's simulators -- the numpy
   reference (:func:`~ftc_verify.simulation.reference.simulate_reference`) or the FMU
   Monte Carlo (:func:`~ftc_verify.simulation.batches.fmu_monte_carlo`, the same isolation
   and signal handling as ``simulate --backend fmu``) -- with sample-and-hold at the step;
   the envelope is checked at the grid points of each record (the multiples of the step and
   the jump times: :func:`~ftc_verify.simulation.paths.communication_grid`), so the
   estimate is the probability of leaving *on the simulation grid*, a lower estimate of
   leaving in continuous time;
2. optionally an upper bound (a callable ``bound(loop, constraints, x0=...,
   disturbance_energy=...)`` returning a frozen dataclass with ``value``, ``reason``, ...:
   :class:`BoundStage`), on the closed loop :func:`~ftc_verify.analysis.closedloop.closed_loop`
   with the envelope's constraints (:meth:`Envelope.constraints`): a bound of the
   *continuous-time* loop (none is claimed when the controller declares a sampling
   period), by the energy of ``w`` up to ``T`` (:func:`disturbance_energy`); none is
   claimed either for a plant map's FMU (``plant``), which the linear model need not
   describe (a fault that moves the equilibrium);
3. optionally the FDI timing view (a callable ``timing(chain, interval)``:
   :class:`TimingStage`) for a fault-tolerant time interval.

On the reference backend the paths of a batch are scored in chunks of ``SIM_BATCH`` (250),
one after the other or, with a Dask client (``workers`` / ``scheduler`` / ``client``), as
one task per chunk on the workers: the chain paths are drawn in this process from their
seeded streams, and a chunk's scores depend on its paths only, so serial and Dask runs give
the same numbers for a seed.

A plant FMU path that failed (``fmi2Error``) or diverged counts as leaving the envelope
(its score is infinite): the estimate errs towards danger, and ``failed_paths`` says how
often.
"""

from __future__ import annotations

import dataclasses
import importlib
import math
from pathlib import Path
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from ..analysis.closedloop import closed_loop
from ..controllers.controller import Controller
from ..errors import ValidationError
from ..jsonable import fields_dict
from ..model.system import FTCSystem, JointChain, Matrix
from ..simulation.batches import fmu_monte_carlo
from ..limits import CONNECT_TIMEOUT
from ..simulation.paths import ChainPath
from ..simulation.records import PathRecord
from ..simulation.reference import simulate_reference
from ..simulation.spec import SimulationSpec
from ..simulation.vectorised import output_peaks_reference
from .envelope import Envelope
from .estimate import Estimate, Settings, estimate_probability

__all__ = ["BoundStage", "TimingStage", "RiskResult", "available_stages", "disturbance_energy", "path_scores",
           "run_risk"]

#: Paths simulated per call of the reference simulator (their records are kept meanwhile);
#: also the chunk of a Dask task on the reference backend.
SIM_BATCH = 250


class BoundStage(Protocol):
    """The upper-bound stage: ``envelope_upper_bound`` of ``ftc_verify.risk.bound``."""

    def __call__(self, loop: Any, constraints: Sequence[tuple[Sequence[np.ndarray], float]], *, x0: np.ndarray,
                 disturbance_energy: float) -> Any: ...


class TimingStage(Protocol):
    """The FDI timing stage: ``delay_exceedance`` of ``ftc_verify.risk.timing``."""

    def __call__(self, chain: JointChain, interval: float) -> Any: ...


@dataclass(frozen=True)
class RiskResult:
    """The answer of :func:`run_risk`; ``to_dict()`` is the JSON of ``ftc-verify risk``.

    ``estimate``: the :class:`~ftc_verify.risk.estimate.Estimate`; ``upper_bound`` and
    ``timing``: the stages' results as JSON-ready dicts (``None`` when not run);
    ``failed_paths``: paths of the estimate whose plant failed or diverged (counted as
    leaving); ``evaluated``: where the envelope is checked."""

    system: str
    envelope: str
    horizon: float
    step: float
    backend: str
    disturbance: str
    x0: tuple[float, ...]
    beta: list[Any]
    estimate: Estimate
    upper_bound: dict[str, Any] | None
    timing: dict[str, Any] | None
    failed_paths: int
    evaluated: str = "at the grid points of each simulated path (multiples of the step and the jump times)"

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: the estimate's fields at the top level (``probability``, ``ci``,
        ``paths``, ``method``, ``seed``, ``relative_error``, ``tilt``, ...)."""
        d = fields_dict(self)
        est = d.pop("estimate")
        return {**{k: d[k] for k in ("system", "envelope", "horizon", "step", "backend", "disturbance")}, **est,
                **{k: d[k] for k in ("x0", "beta", "failed_paths", "evaluated", "upper_bound", "timing")}}


def _stage(module: str, name: str) -> Any:
    """``name`` of ``ftc_verify.risk.<module>``, or ``None`` when that module is not installed
    (any other import error propagates)."""
    full = f"{__package__}.{module}"
    try:
        return getattr(importlib.import_module(full), name)
    except ModuleNotFoundError as exc:
        if exc.name != full:
            raise
        return None


def available_stages() -> tuple[BoundStage | None, TimingStage | None]:
    """The optional stages of :func:`run_risk` this installation has: the upper bound
    (``ftc_verify.risk.bound.envelope_upper_bound``) and the FDI timing view
    (``ftc_verify.risk.timing.delay_exceedance``), each ``None`` when its module is absent."""
    return _stage("bound", "envelope_upper_bound"), _stage("timing", "delay_exceedance")


def disturbance_energy(kind: str, nw: int, horizon: float) -> float:
    r""":math:`\int_0^T |w|^2 dt` of a disturbance kind of
    :data:`~ftc_verify.simulation.paths.DISTURBANCES` on ``nw`` channels, in closed form:
    ``paper`` (:math:`e^{-0.1t}\sin t`) :math:`\int_0^\infty e^{-0.2t}\sin^2 t\,dt =
    \tfrac12(1/0.2 - 0.2/(0.2^2 + 4))` (an upper bound of the integral to ``T``), ``zero``
    0, ``step`` :math:`T`, ``pulse`` :math:`\min(T, 1)`, ``sine`` :math:`T/2 - \sin(2T)/4`;
    times ``nw``. The energy up to ``T`` suffices for leaving within ``[0, T]``: the path on
    ``[0, T]`` is the same under ``w`` cut off at ``T``, whose whole energy this is."""
    per = {"paper": 0.5 * (1 / 0.2 - 0.2 / (0.04 + 4.0)), "zero": 0.0, "step": horizon, "pulse": min(horizon, 1.0),
           "sine": horizon / 2 - math.sin(2 * horizon) / 4}[kind]
    return nw * per


def _record_score(envelope: Envelope, rec: PathRecord) -> float:
    if rec.diverged_at is not None or rec.failure is not None:
        return math.inf
    return envelope.score(rec.x, rec.y)


def _peak_scores(scored: FTCSystem, controller: Controller, envelope: Envelope, paths: Sequence[ChainPath],
                 spec: SimulationSpec) -> np.ndarray:
    """Scores of one chunk on the vectorised reference (a Dask task of :func:`path_scores`)."""
    peak_sq, peak = output_peaks_reference(scored, controller, paths, spec=spec)
    return envelope.peak_score(peak_sq, peak)


def path_scores(system: FTCSystem, controller: Controller, envelope: Envelope, spec: SimulationSpec,
                backend: str, plant: Any = None, client: Any = None) -> Callable[[Sequence[ChainPath]], np.ndarray]:
    """The scorer of the estimator: simulate the paths on ``backend`` and return every
    path's largest envelope score. ``fmu``: one FMU Monte Carlo over them, the plant of the
    plant map ``plant`` or the system's ``LinearJumpPlant``, on the Dask ``client`` when
    given (:func:`~ftc_verify.simulation.batches.fmu_monte_carlo`). ``reference`` takes the output peaks of the vectorised
    reference (:func:`~ftc_verify.simulation.vectorised.output_peaks_reference` on
    :meth:`Envelope.score_system`) in chunks of ``SIM_BATCH`` (250) paths, each a task on
    ``client``'s workers when given (the same numbers); ``records`` scores the records of
    :func:`~ftc_verify.simulation.reference.simulate_reference` (the same numbers, one path
    at a time: the check of the fast path)."""
    scored = envelope.score_system(system)

    def score(paths: Sequence[ChainPath]) -> np.ndarray:
        records: list[PathRecord] = []
        if backend == "records":
            for b in range(0, len(paths), SIM_BATCH):
                records.extend(simulate_reference(system, controller, list(paths[b:b + SIM_BATCH]), spec=spec).records)
        elif backend == "fmu":
            records.extend(fmu_monte_carlo(system, controller, list(paths), spec=spec, plant=plant,
                                           client=client).records)
        else:
            chunks = [list(paths[b:b + SIM_BATCH]) for b in range(0, len(paths), SIM_BATCH)]
            if client is None:
                parts = [_peak_scores(scored, controller, envelope, c, spec) for c in chunks]
            else:
                parts = client.gather([client.submit(_peak_scores, scored, controller, envelope, c, spec, pure=False)
                                       for c in chunks])
            return np.concatenate(parts) if parts else np.zeros(0)
        return np.array([_record_score(envelope, r) for r in records])

    return score


def run_risk(system: FTCSystem, controller: Controller, envelope: Envelope, *, horizon: float, step: float,
             settings: Settings, x0: Sequence[float] | None = None, disturbance: str = "paper",
             beta: Matrix | None = None, backend: str = "reference", plant: Any = None,
             bound: BoundStage | None = None, timing: TimingStage | None = None,
             interval: float | None = None, done: Callable[[int], object] | None = None,
             workers: int | None = None, scheduler: str | None = None, client: Any = None,
             connect_timeout: float = CONNECT_TIMEOUT) -> RiskResult:
    """The risk run of the module docstring. ``beta``: the rate array (default: the centre
    of the box, :meth:`JointChain.midpoint`); the paths start in the joint mode ``(0, 0)``
    (no fault, FDI agrees); ``x0`` default 0; ``workers`` / ``scheduler``: the batches (FMU)
    or chunks (reference) on a local Dask cluster of that many processes or on the
    scheduler at that address (:meth:`SimulationSpec.client
    <ftc_verify.simulation.spec.SimulationSpec.client>`, opened once for the run; connecting
    to ``scheduler`` time-boxed to ``connect_timeout`` seconds), or on
    the given Dask ``client`` (``verify``'s); the same numbers as serially."""
    if backend not in ("reference", "records", "fmu"):
        raise ValidationError(f"backend: {backend!r} is not one of reference, records, fmu")
    chain = system.chain
    rates = chain.midpoint() if beta is None else chain.check_beta(beta)
    n = system.dims[0]
    x0v = np.zeros(n) if x0 is None else np.asarray(x0, dtype=float)
    spec = SimulationSpec(step=step, horizon=horizon, seed=settings.seed, beta=rates, disturbance=disturbance,
                          x0=tuple(float(v) for v in x0v), workers=workers,
                          scheduler=scheduler, connect_timeout=connect_timeout)
    failed = [0]
    with spec.client(client) as client:
        scorer = path_scores(system, controller, envelope, spec, backend, plant, client)

        def counted(paths: Sequence[ChainPath]) -> np.ndarray:
            s = scorer(paths)
            failed[0] += int(np.count_nonzero(np.isinf(s)))
            return s

        est = estimate_probability(chain, rates, horizon, counted, settings, start=chain.start_state((0, 0)),
                                   done=done)
    upper = None
    if bound is not None and plant is not None:  # the certificate speaks of the linear model, not of the FMU
        upper = {"value": None, "reason": f"not claimed for the plant map's FMU ({Path(str(getattr(plant, 'fmu', plant))).name}): the "
                 "certificate is of the linear model, whose equilibrium the plant's faults may move"}
    elif bound is not None:
        loop = closed_loop(system, controller)
        xi0 = np.concatenate((x0v, np.zeros(loop.n - n)))
        res = bound(loop, envelope.constraints(system, loop.n, chain.states), x0=xi0,
                    disturbance_energy=disturbance_energy(disturbance, system.dims[3], horizon))
        upper = fields_dict(res) if dataclasses.is_dataclass(res) else dict(res)
    view = None
    if timing is not None and interval is not None:
        res = timing(chain, interval)
        view = fields_dict(res) if dataclasses.is_dataclass(res) else dict(res)
    return RiskResult(system.name, envelope.description, float(horizon), float(step), backend, disturbance,
                      tuple(float(v) for v in x0v), rates.tolist(), est, upper, view, failed[0])
