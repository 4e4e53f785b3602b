r"""Streaming Monte Carlo on the reference backend: every path's energies, few trajectories.

:func:`simulate_streaming` gives what ``simulate --backend reference`` reports -- per path
:math:`\|y\|_2`, :math:`\|w\|_2`, switch counts, ``beta`` and divergences -- without keeping
trajectories: the energies come from the vectorised engine
:func:`~ftc_verify.simulation.energies.energies_reference` (all paths of a batch advance
together), in batches of ``batch`` paths so that memory is bounded by the batch, not by
paths x steps. Full trajectories (:class:`~ftc_verify.simulation.records.PathRecord`) are
computed only for the first ``record`` paths, by
:func:`~ftc_verify.simulation.reference.simulate_reference` with the same ``Delta`` draws.

Same numbers as the per-path code: both draw ``Delta`` per path in path order from one
generator (:func:`~ftc_verify.simulation.delta.delta_segments`), and the engine uses the
same grid and trapezoidal rule as ``record.y_norm``; a diverged path (``Ey = inf``) gets
its divergence time by re-simulating that path alone after replaying the draws of the
paths before it.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..controllers.controller import Controller
from ..errors import ValidationError
from ..model.system import FTCSystem
from ._common import generator, schedule_of
from .delta import DeltaSchedule, delta_segments
from .energies import energies_reference
from .paths import ChainPath
from .records import PathRecord, divergence_line
from .reference import simulate_reference

__all__ = ["StreamedResult", "simulate_streaming", "STREAM_BATCH"]

#: Paths per batch of the vectorised engine (memory is linear in it).
STREAM_BATCH = 2000


@dataclass(frozen=True, eq=False)
class StreamedResult:
    """Per-path summaries of a streamed run and the recorded trajectories (the first
    ``len(records)`` paths); ``to_dict`` has the keys of
    :meth:`~ftc_verify.simulation.records.SimulationResult.to_dict`."""

    backend: str
    seed: int | None
    step: float
    horizon: float
    disturbance: str
    y_norm: np.ndarray
    w_norm: np.ndarray
    paths: tuple[ChainPath, ...]
    diverged_at: dict[int, float]
    records: tuple[PathRecord, ...]
    options: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (per-path norms and switch counts, not the trajectories)."""
        diverged = sorted(self.diverged_at)
        note = divergence_line([(k + 1, self.diverged_at[k]) for k in diverged], len(self.paths))
        return {
            "backend": self.backend, "seed": self.seed, "paths": len(self.paths), "step": self.step,
            "horizon": self.horizon, "disturbance": self.disturbance,
            "y_norm": [float(v) for v in self.y_norm], "w_norm": [float(v) for v in self.w_norm],
            "switches": [{"fault": p.fault_switches, "fdi": p.fdi_switches} for p in self.paths],
            "diverged": [{"path": k + 1, "t": self.diverged_at[k]} for k in diverged],
            "divergence": note, "beta": [p.beta.tolist() for p in self.paths], "options": self.options,
        }


def simulate_streaming(
    system: FTCSystem,
    controller: Controller,
    paths: Sequence[ChainPath],
    *,
    step: float,
    disturbance: str = "paper",
    delta: DeltaSchedule | str | None = None,
    rng: np.random.Generator | None = None,
    seed: int | None = None,
    record: int = 0,
    batch: int = STREAM_BATCH,
) -> StreamedResult:
    """The paths of ``simulate_reference`` (same arguments, same numbers) summarised per
    path, with trajectories for the first ``record`` paths only (module docstring)."""
    plist = list(paths)
    if not plist:
        raise ValidationError("paths: at least one path is needed")
    gen = generator(rng, seed)
    start = copy.deepcopy(gen)  # the draws before any path, to replay
    schedule = schedule_of(delta)
    Ey, Ew = np.empty(len(plist)), np.empty(len(plist))
    for b in range(0, len(plist), max(1, batch)):
        Ey[b:b + batch], Ew[b:b + batch] = energies_reference(system, controller, plist[b:b + batch], step=step,
                                                              disturbance=disturbance, delta=schedule, rng=gen)
    records = ()
    if record > 0:
        records = simulate_reference(system, controller, plist[:record], step=step, disturbance=disturbance,
                                     delta=schedule, rng=copy.deepcopy(start), seed=seed).records
    diverged: dict[int, float] = {}
    for k in np.flatnonzero(~np.isfinite(Ey)).tolist():
        if k < len(records):
            t = records[k].diverged_at
        else:
            replay = copy.deepcopy(start)
            for p in plist[:k]:
                delta_segments(system, p, schedule, replay)
            t = simulate_reference(system, controller, [plist[k]], step=step, disturbance=disturbance,
                                   delta=schedule, rng=replay).records[0].diverged_at
        diverged[k] = math.inf if t is None else float(t)
    return StreamedResult("reference", seed, step, float(max(p.horizon for p in plist)), disturbance,
                          np.sqrt(Ey), np.sqrt(Ew), tuple(plist), diverged, tuple(records),
                          {"streamed": True, "batch": batch, "recorded": len(records)})
