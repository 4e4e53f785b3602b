r"""Streaming Monte Carlo on the reference backend: every path's energies, few trajectories.

:func:`simulate_streaming` gives what ``simulate --backend reference`` reports -- per path
:math:`\|y\|_2`, :math:`\|w\|_2`, switch counts, ``beta`` and divergences -- without keeping
trajectories: the energies come from the vectorised engine
:func:`~ftc_verify.simulation.energies.energies_reference` (all paths of a batch advance
together), in batches of ``batch`` paths so that memory is bounded by the batch, not by
paths x steps. Full trajectories (:class:`~ftc_verify.simulation.records.PathRecord`) are
computed only for the first ``record`` paths, by
:func:`~ftc_verify.simulation.reference.simulate_reference` with the same ``Delta`` draws.

Same numbers as the per-path code: both take each path's ``Delta`` values from
:func:`~ftc_verify.simulation.delta.delta_segments` (the path's own stream), and the
engine uses the same grid and trapezoidal rule as ``record.y_norm``; a diverged path
(``Ey = inf``) gets its divergence time by re-simulating that path alone.

Scale-out: with a ``dask.distributed`` client every batch is one task; sampled paths
carry their own streams (hand-built paths the generator state a serial run would have at
the batch's first path, :func:`batch_generators`), so serial, local-cluster and
remote-cluster runs give identical numbers for a seed.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable, Iterator, Sequence
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

__all__ = ["StreamedResult", "simulate_streaming", "batch_generators", "STREAM_BATCH", "TASK_RETRIES"]

#: Paths per batch of the vectorised engine (memory is linear in it).
STREAM_BATCH = 2000
#: Retries of a batch whose Dask worker was lost.
TASK_RETRIES = 3


def batch_generators(system: FTCSystem, paths: list[ChainPath], schedule: DeltaSchedule,
                     gen: np.random.Generator, batch: int) -> Iterator[np.random.Generator]:
    """One generator per batch of ``batch`` paths, yielded in turn: the state ``gen`` would
    have after the ``Delta`` draws of every earlier path, so that batches computed
    anywhere, in any order, draw what a serial run draws. Only paths without their own
    stream (:attr:`~ftc_verify.simulation.paths.ChainPath.stream`, built by hand) draw
    from ``gen``; paths from :func:`~ftc_verify.simulation.paths.sample_paths` draw from
    their stream, so for them nothing is replayed. A batch can be submitted as soon as its
    state is yielded. ``gen`` ends where a serial run leaves it once the iterator is
    exhausted."""
    for b in range(0, len(paths), batch):
        yield copy.deepcopy(gen)
        if schedule.kind == "random":  # the only kind that draws
            for p in paths[b:b + batch]:
                if p.stream is None:
                    delta_segments(system, p, schedule, gen)


def _energies_batch(system: FTCSystem, controller: Controller, paths: list[ChainPath], step: float,
                    disturbance: str, schedule: DeltaSchedule,
                    gen: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """One batch on the vectorised engine (a Dask task; module-level so that it pickles)."""
    return energies_reference(system, controller, paths, step=step, disturbance=disturbance, delta=schedule, rng=gen)


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
    client: Any = None,
    done: Callable[[int], Any] | None = None,
) -> StreamedResult:
    """The paths of ``simulate_reference`` (same arguments, same numbers) summarised per
    path, with trajectories for the first ``record`` paths only (module docstring).
    ``client``: a ``dask.distributed.Client``; the batches then run on its workers, with
    the same numbers as serially (each batch carries its own generator state).
    ``done(k)``: called as each batch of ``k`` paths is finished (a progress bar)."""
    plist = list(paths)
    if not plist:
        raise ValidationError("paths: at least one path is needed")
    gen = generator(rng, seed)
    start = copy.deepcopy(gen)  # the draws before any path, to replay
    schedule = schedule_of(delta)
    batch = max(1, batch)
    starts = range(0, len(plist), batch)
    report = done if done is not None else (lambda k: None)
    if client is None:  # serially the batches draw from ``gen`` in turn: no replay needed
        parts = []
        for b in starts:
            parts.append(_energies_batch(system, controller, plist[b:b + batch], step, disturbance, schedule, gen))
            report(len(parts[-1][0]))
    else:  # Dask: one task per batch, each with its own generator state; lost workers' tasks are retried
        from dask.distributed import as_completed

        futures = [client.submit(_energies_batch, system, controller, plist[b:b + batch], step, disturbance, schedule,
                                 g, retries=TASK_RETRIES, pure=False)
                   for g, b in zip(batch_generators(system, plist, schedule, gen, batch), starts)]
        size = {f.key: len(plist[b:b + batch]) for f, b in zip(futures, starts)}
        for fut in as_completed(futures):  # progress as batches finish; the results are gathered once, below
            report(size[fut.key])
        parts = client.gather(futures)
    Ey = np.concatenate([p[0] for p in parts])
    Ew = np.concatenate([p[1] for p in parts])
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
                if p.stream is None and schedule.kind == "random":
                    delta_segments(system, p, schedule, replay)
            t = simulate_reference(system, controller, [plist[k]], step=step, disturbance=disturbance,
                                   delta=schedule, rng=replay).records[0].diverged_at
        diverged[k] = math.inf if t is None else float(t)
    return StreamedResult("reference", seed, step, float(max(p.horizon for p in plist)), disturbance,
                          np.sqrt(Ey), np.sqrt(Ew), tuple(plist), diverged, tuple(records),
                          {"streamed": True, "batch": batch, "recorded": len(records)})
