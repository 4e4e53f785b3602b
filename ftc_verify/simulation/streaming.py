r"""Streaming Monte Carlo on the reference backend: every path's energies, few trajectories.

:func:`simulate_streaming` gives what ``simulate --backend reference`` reports -- per path
:math:`\|y\|_2`, :math:`\|w\|_2`, switch counts, ``beta`` and divergences -- without keeping
trajectories: the energies come from the vectorised engine
:func:`~ftc_verify.simulation.vectorised.energies_reference` (all paths of a batch advance
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

Paths as a recipe: given a :class:`~ftc_verify.simulation.paths.PathSpec` instead of a
list, nothing is sampled in the client: a task gets the recipe and its range of path
indices ``[first, stop)``, samples those paths on the worker from their own streams
(:func:`~ftc_verify.simulation.paths.sample_path_range`, the very paths of
:func:`~ftc_verify.simulation.paths.sample_paths`) and sends back only their summaries
(energies, switch counts, rate arrays), in tasks of :data:`DASK_BATCH` paths. Serially the
batches are sampled one at a time, so the paths are never all held at once. The recorded
paths and a diverged path are sampled again in the client, alone.
"""

from __future__ import annotations

import copy
import ctypes
import math
import os
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..controllers.controller import Controller
from ..errors import ValidationError
from ..model.system import FTCSystem
from .delta import DeltaSchedule, delta_segments
from .vectorised import energies_reference
from .paths import ChainPath, PathSpec
from .records import PathRecord, divergence_line
from .reference import simulate_reference
from .spec import SimulationSpec, spec_from

__all__ = ["StreamedResult", "simulate_streaming", "batch_generators", "STREAM_BATCH", "DASK_BATCH",
           "TASK_RETRIES"]

#: Paths per batch of the vectorised engine (memory is linear in it).
STREAM_BATCH = 2000
#: Paths per Dask task when the workers sample their own paths (a ``PathSpec``). Equal to
#: :data:`STREAM_BATCH` on purpose: the engine's rounding depends on a batch's size (its
#: matrix products), so only the batches of a serial run give its numbers bitwise. 2000 is
#: also the fastest of 1000, 2000, 2500 and 4000 measured on 2 workers (20,000 paths: 10
#: tasks of about 0.3 s, shared evenly; a task costs a few ms, its results 2 x 16 kB
#: plus the rate arrays; ``benchmarks/reference_cluster.py``).
DASK_BATCH = STREAM_BATCH
#: Retries of a batch whose Dask worker was lost.
TASK_RETRIES = 3


def batch_generators(system: FTCSystem, paths: list[ChainPath], schedule: DeltaSchedule,
                     gen: np.random.Generator, batch: int) -> Iterator[np.random.Generator]:
    """One generator per batch of ``batch`` paths, yielded in turn: the state ``gen`` would
    have after the ``Delta`` draws of every earlier path, so that batches computed
    anywhere, in any order, draw what a serial run draws. Only paths without their own
    stream (``ChainPath.stream`` is None: built by hand) draw
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


#: glibc's ``mallopt`` parameters and the mmap threshold a Dask task runs with (below).
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3
_TASK_MMAP_THRESHOLD = 16 * 1024 ** 2


@contextmanager
def _task_malloc() -> Iterator[None]:
    """On a Dask worker, glibc's heap kept for the batch's arrays, given back after it.

    Dask's nanny starts workers with ``MALLOC_TRIM_THRESHOLD_=65536``, which also freezes
    glibc's mmap threshold at 128 KiB: every temporary array of the vectorised engine is
    then a fresh ``mmap`` whose pages fault in again, and a batch ran 30 % slower than in
    a plain process (1.84 s against 1.43 s for 10,000 paths of the paper example). For
    the batch the threshold is raised to 16 MiB; afterwards the worker's settings are
    restored and the free heap trimmed. Elsewhere (no such variable, not glibc) nothing
    is changed."""
    trim = os.environ.get("MALLOC_TRIM_THRESHOLD_")
    libc = None
    if trim is not None and trim.isdigit():
        try:
            libc = ctypes.CDLL(None)
            if not (libc.mallopt(_M_MMAP_THRESHOLD, _TASK_MMAP_THRESHOLD)
                    and libc.mallopt(_M_TRIM_THRESHOLD, 2 * _TASK_MMAP_THRESHOLD)):
                libc = None
        except (OSError, AttributeError):
            libc = None
    try:
        yield
    finally:
        if libc is not None and trim is not None:
            libc.mallopt(_M_MMAP_THRESHOLD, 128 * 1024)  # glibc's default, which the variable froze
            libc.mallopt(_M_TRIM_THRESHOLD, int(trim))
            libc.malloc_trim(0)


def _energies_task(system: FTCSystem, controller: Controller, paths: list[ChainPath], step: float,
                   disturbance: str, schedule: DeltaSchedule,
                   gen: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_energies_batch` as a Dask task (:func:`_task_malloc`)."""
    with _task_malloc():
        return _energies_batch(system, controller, paths, step, disturbance, schedule, gen)


def _sampled_task(*args: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_sampled_batch` as a Dask task (:func:`_task_malloc`)."""
    with _task_malloc():
        return _sampled_batch(*args)


def _summaries(paths: Sequence[ChainPath]) -> tuple[np.ndarray, np.ndarray]:
    """Per path its ``(fault, fdi)`` switch counts (``(P, 2)``) and its rate array (stacked)."""
    switches = np.array([(p.fault_switches, p.fdi_switches) for p in paths], dtype=np.int64).reshape(-1, 2)
    return switches, np.stack([np.asarray(p.beta, dtype=float) for p in paths])


def _sampled_batch(system: FTCSystem, controller: Controller, spec: PathSpec, first: int, stop: int, step: float,
                   disturbance: str, schedule: DeltaSchedule,
                   gen: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Paths ``first .. stop - 1`` of ``spec``, sampled here (on a worker: nothing but the
    recipe is shipped), through the vectorised engine: ``(Ey, Ew, switches, betas)``."""
    paths = spec.sample(first, stop)
    Ey, Ew = _energies_batch(system, controller, paths, step, disturbance, schedule, gen)
    return (Ey, Ew, *_summaries(paths))


@dataclass(frozen=True, eq=False)
class StreamedResult:
    """Per-path summaries of a streamed run and the recorded trajectories (the first
    ``len(records)`` paths); ``to_dict`` has the keys of
    :meth:`~ftc_verify.simulation.records.SimulationResult.to_dict`. ``paths``: the paths
    given, or their :class:`~ftc_verify.simulation.paths.PathSpec` (sampled when read);
    ``switches`` (``(P, 2)``: fault, FDI) and ``betas`` summarise them (from ``paths``
    when left out)."""

    backend: str
    seed: int | None
    step: float
    horizon: float
    disturbance: str
    y_norm: np.ndarray
    w_norm: np.ndarray
    paths: Sequence[ChainPath]
    diverged_at: dict[int, float]
    records: tuple[PathRecord, ...]
    options: dict[str, Any] = field(default_factory=dict)
    switches: np.ndarray | None = None
    betas: np.ndarray | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (per-path norms and switch counts, not the trajectories)."""
        diverged = sorted(self.diverged_at)
        note = divergence_line([(k + 1, self.diverged_at[k]) for k in diverged], len(self.paths))
        switches, betas = ((self.switches, self.betas) if self.switches is not None and self.betas is not None
                           else _summaries(self.paths))
        return {
            "backend": self.backend, "seed": self.seed, "paths": len(self.paths), "step": self.step,
            "horizon": self.horizon, "disturbance": self.disturbance,
            "y_norm": [float(v) for v in self.y_norm], "w_norm": [float(v) for v in self.w_norm],
            "switches": [{"fault": int(f), "fdi": int(d)} for f, d in switches.tolist()],
            "diverged": [{"path": k + 1, "t": self.diverged_at[k]} for k in diverged],
            "divergence": note, "beta": [b.tolist() for b in betas], "options": self.options,
        }


def simulate_streaming(
    system: FTCSystem,
    controller: Controller,
    paths: Sequence[ChainPath] | PathSpec,
    *,
    spec: SimulationSpec | None = None,
    step: float | None = None,
    disturbance: str | None = None,
    delta: DeltaSchedule | str | None = None,
    rng: np.random.Generator | None = None,
    seed: int | None = None,
    record: int | None = None,
    batch: int | None = None,
    client: Any = None,
    done: Callable[[int], Any] | None = None,
) -> StreamedResult:
    """The paths of ``simulate_reference`` (same arguments, same numbers) summarised per
    path, with trajectories for the first ``spec.record`` paths only (module docstring).

    ``paths``: sampled paths, or a :class:`~ftc_verify.simulation.paths.PathSpec` to have
    each batch sampled where it runs (on a Dask worker with a client), with the same
    numbers. ``spec`` (:class:`~ftc_verify.simulation.spec.SimulationSpec`): ``step``,
    ``disturbance``, ``delta``, ``seed`` as for ``simulate_reference``; ``record``;
    ``batch``, paths per batch, default :data:`STREAM_BATCH` (:data:`DASK_BATCH` for a
    ``PathSpec`` on a client); ``workers``/``scheduler``, the Dask cluster opened for the
    run when no ``client`` is given. The keywords ``step`` ... ``batch`` are its shorthand
    (:func:`~ftc_verify.simulation.spec.spec_from`).
    ``client``: a ``dask.distributed.Client``; the batches then run on its workers, with
    the same numbers as serially (each batch carries its own generator state).
    ``done(k)``: called as each batch of ``k`` paths is finished (a progress bar)."""
    spec = spec_from(spec, {"step": step, "disturbance": disturbance, "delta": delta, "seed": seed,
                            "record": record, "batch": batch})
    with spec.client(client) as client:
        return _stream(system, controller, paths, spec, rng, client, done)


def _stream(system: FTCSystem, controller: Controller, paths: Sequence[ChainPath] | PathSpec, spec: SimulationSpec,
            rng: np.random.Generator | None, client: Any, done: Callable[[int], Any] | None) -> StreamedResult:
    """:func:`simulate_streaming` once the spec and the client are settled."""
    if spec.x0 is not None:
        raise ValidationError("x0: a streamed run starts every path at x = 0; use simulate_reference for another x0")
    pspec = paths if isinstance(paths, PathSpec) else None
    if pspec is None and hasattr(client, "ready"):  # a starting cluster: sampled paths wait for it
        client = client.client()
    plist: Sequence[ChainPath] = pspec if pspec is not None else list(paths)
    if not len(plist):
        raise ValidationError("paths: at least one path is needed")
    gen = spec.generator(rng)
    start = copy.deepcopy(gen)  # the draws before any path, to replay
    schedule, step, disturbance, record = spec.schedule, spec.step, spec.disturbance, spec.record
    batch = spec.batch
    if batch is None:
        batch = DASK_BATCH if pspec is not None and client is not None else STREAM_BATCH
    report = done if done is not None else (lambda k: None)
    job = (system, controller, step, disturbance, schedule)
    if pspec is not None:
        parts = _spec_parts(job, pspec, gen, batch, client, report)
        switches, betas = np.concatenate([p[2] for p in parts]), np.concatenate([p[3] for p in parts])
    else:
        parts = _list_parts(job, list(plist), gen, batch, client, report)
        switches, betas = _summaries(plist)
    Ey = np.concatenate([p[0] for p in parts])
    Ew = np.concatenate([p[1] for p in parts])
    records: tuple[PathRecord, ...] = ()
    if record > 0:
        records = simulate_reference(system, controller, plist[:record], spec=spec,
                                     rng=copy.deepcopy(start)).records
    diverged = _divergence_times(job, plist, Ey, records, start)
    horizon = pspec.horizon if pspec is not None else float(max(p.horizon for p in plist))
    return StreamedResult("reference", spec.seed, step, horizon, disturbance, np.sqrt(Ey), np.sqrt(Ew),
                          pspec if pspec is not None else tuple(plist), diverged, tuple(records),
                          {"streamed": True, "batch": batch, "recorded": len(records)}, switches, betas)


def _list_parts(job: tuple[Any, ...], plist: list[ChainPath], gen: np.random.Generator, batch: int, client: Any,
                report: Callable[[int], Any]) -> list[tuple[np.ndarray, ...]]:
    """``(Ey, Ew)`` per batch of sampled paths, serially or one Dask task per batch."""
    system, controller, step, disturbance, schedule = job
    starts = range(0, len(plist), batch)
    if client is None:  # serially the batches draw from ``gen`` in turn: no replay needed
        parts: list[tuple[np.ndarray, ...]] = []
        for b in starts:
            parts.append(_energies_batch(system, controller, plist[b:b + batch], step, disturbance, schedule, gen))
            report(len(parts[-1][0]))
        return parts
    # Dask: one task per batch, each with its own generator state; lost workers' tasks are retried
    futures = [client.submit(_energies_task, system, controller, plist[b:b + batch], step, disturbance, schedule,
                             g, retries=TASK_RETRIES, pure=False)
               for g, b in zip(batch_generators(system, plist, schedule, gen, batch), starts)]
    return _gather(client, futures, [len(plist[b:b + batch]) for b in starts], report)


def _spec_parts(job: tuple[Any, ...], spec: PathSpec, gen: np.random.Generator, batch: int, client: Any,
                report: Callable[[int], Any]) -> list[tuple[np.ndarray, ...]]:
    """``(Ey, Ew, switches, betas)`` per range of path indices, each range sampled where
    it runs: serially here, one batch at a time, or one Dask task per range (only the
    recipe and the range are shipped; the paths' own streams leave ``gen`` untouched).
    ``client`` may be a :class:`~ftc_verify.simulation.cluster.ClusterStart` still
    starting: the first ranges are then sampled and simulated here, in order, until the
    cluster is up, and the rest go to its workers (the same numbers: a range's draws come
    from its paths' streams wherever it runs)."""
    system, controller, step, disturbance, schedule = job
    ranges = [(b, min(b + batch, spec.n_paths)) for b in range(0, spec.n_paths, batch)]
    if client is None:
        parts: list[tuple[np.ndarray, ...]] = []
        for first, stop in ranges:
            parts.append(_sampled_batch(system, controller, spec, first, stop, step, disturbance, schedule, gen))
            report(stop - first)
        return parts
    here: list[tuple[np.ndarray, ...]] = []
    if hasattr(client, "ready"):  # a local cluster still starting: the first ranges run here meanwhile
        while len(here) < len(ranges) and not client.ready():
            first, stop = ranges[len(here)]
            here.append(_sampled_batch(system, controller, spec, first, stop, step, disturbance, schedule, gen))
            report(stop - first)
        ranges = ranges[len(here):]
        if not ranges:
            return here
        client = client.client()
    futures = [client.submit(_sampled_task, system, controller, spec, first, stop, step, disturbance, schedule, gen,
                             retries=TASK_RETRIES, pure=False) for first, stop in ranges]
    return here + _gather(client, futures, [stop - first for first, stop in ranges], report)


def _gather(client: Any, futures: list[Any], sizes: list[int], report: Callable[[int], Any]) -> list[Any]:
    """The futures' results in order, ``report(size)`` as each finishes."""
    from dask.distributed import as_completed

    size = {f.key: n for f, n in zip(futures, sizes)}
    for fut in as_completed(futures):  # progress as batches finish; the results are gathered once, below
        report(size[fut.key])
    return client.gather(futures)


def _divergence_times(job: tuple[Any, ...], plist: Sequence[ChainPath], Ey: np.ndarray,
                      records: Sequence[PathRecord], start: np.random.Generator) -> dict[int, float]:
    """Divergence time per diverged path (``Ey = inf``): from its record, else by
    simulating that path alone with the generator state a serial run has at it."""
    system, controller, step, disturbance, schedule = job
    diverged: dict[int, float] = {}
    for k in np.flatnonzero(~np.isfinite(Ey)).tolist():
        if k < len(records):
            t = records[k].diverged_at
        else:
            path = plist[k]
            replay = copy.deepcopy(start)
            if path.stream is None and schedule.kind == "random":
                for p in plist[:k]:
                    if p.stream is None:
                        delta_segments(system, p, schedule, replay)
            t = simulate_reference(system, controller, [path], step=step, disturbance=disturbance,
                                   delta=schedule, rng=replay).records[0].diverged_at
        diverged[k] = math.inf if t is None else float(t)
    return diverged
