"""FMU co-simulation on Dask workers: every batch task is self-sufficient, every worker loads the FMU once.

:func:`run_fmu_batches` is the distributed form of calling
:meth:`~ftc_verify.simulation.supervisor.Supervisor.run` batch after batch (used by
:func:`~ftc_verify.simulation.batches.fmu_monte_carlo`). Each batch is one task that
carries an :class:`FmuJob` (the FMU's bytes, the map, the system; a run id), so workers on
other machines need neither the client's files nor its FMU cache, and nothing has to be
registered on the workers before the run. The first task of a run on a worker writes the
FMU into the worker's ``local_directory`` and opens one
:class:`~ftc_verify.simulation.supervisor.Supervisor`, kept in a per-worker cache (an
attribute of the Dask ``Worker``, keyed by the run id) that every later batch of the run
on that worker reuses (``fmi2Reset`` between paths, as on one machine). A worker lost at
any moment -- while it writes or opens the FMU or while it runs a batch -- costs its task
a re-run elsewhere; a replacement worker simply builds its own cache entry. At the end the
cached supervisors of the run are closed on every worker (best effort, bounded).

A batch whose worker died every time it ran it (``distributed.KilledWorker``: a crashing
plant FMU kills the process that runs it) is a :class:`~ftc_verify.errors.PlantRunError`
naming the FMU and the batch's path range; any other exception of a task comes back as
itself.

Same numbers as the serial run: every sampled path draws its ``Delta`` values from its
own stream (and a hand-built path from the generator state a serial run has at its
batch, :func:`~ftc_verify.simulation.streaming.batch_generators`), so the records are
identical wherever a batch runs.

This module imports ``dask.distributed`` at import time: import it only when a client
exists (:func:`~ftc_verify.simulation.cluster.open_client`).
"""

from __future__ import annotations

import dataclasses
import shutil
import tempfile
import threading
import time
import uuid
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NoReturn

import numpy as np
from distributed import KilledWorker, as_completed, get_worker, wait

from ..controllers.controller import Controller
from ..errors import PlantRunError
from ..model.system import FTCSystem
from .paths import ChainPath
from .records import SimulationResult
from .spec import SimulationSpec
from .streaming import TASK_RETRIES, batch_generators
from .supervisor import Supervisor

__all__ = ["FmuJob", "run_fmu_batches", "CACHED_RUNS", "RELEASE_TIMEOUT"]

#: Runs whose supervisor one worker keeps open at once; a further run closes the least
#: recently used idle one (bounds what a run that never released its entries leaves on a
#: long-lived remote worker).
CACHED_RUNS = 4
#: Seconds the client waits for the workers to close a finished run's supervisors.
RELEASE_TIMEOUT = 10.0
_RUNS = "_ftc_verify_fmu_runs"  # attribute of the dask Worker: run id -> _Entry
_RUNS_LOCK = "_ftc_verify_fmu_runs_lock"


@dataclass(frozen=True, eq=False)
class FmuJob:
    """What every batch task of one run carries besides its paths.

    Attributes
    ----------
    run : str
        The run id (the per-worker cache key).
    fmu_bytes : bytes
        The plant FMU archive.
    mapping : FaultInjectionMap
        The plant map's injection map.
    system : FTCSystem
        The system the loop is checked against.
    tolerance : float or None
        The ``fmi2SetupExperiment`` tolerance.
    fmu : str
        The FMU's file on the client: messages name it, not the worker's copy.
    """

    run: str
    fmu_bytes: bytes
    mapping: Any
    system: FTCSystem
    tolerance: float | None
    fmu: str


class _Entry:
    """One run's FMU copy and supervisor on one worker (guarded by :attr:`lock`)."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.folder: Path | None = None
        self.supervisor: Supervisor | None = None
        self.used = time.monotonic()
        self.released = False  # dropped from the cache: close after the batch that holds the lock

    def open(self, job: FmuJob, directory: str | None) -> Supervisor:
        """The supervisor of ``job`` (written to ``directory`` and opened on first use)."""
        if self.supervisor is None:
            self.folder = Path(tempfile.mkdtemp(prefix="ftc-verify-worker-fmu-", dir=directory))
            try:
                fmu = self.folder / "plant.fmu"
                fmu.write_bytes(job.fmu_bytes)
                self.supervisor = Supervisor(fmu, job.mapping, system=job.system, tolerance=job.tolerance)
            except BaseException:
                self.close()
                raise
        return self.supervisor

    def close(self) -> None:
        """Close the supervisor and remove the FMU copy (errors dropped: best effort)."""
        sup, self.supervisor = self.supervisor, None
        if sup is not None:
            try:
                sup.close()
            except Exception:
                pass
        if self.folder is not None:
            shutil.rmtree(self.folder, ignore_errors=True)
            self.folder = None


def _runs(worker: Any) -> tuple[threading.Lock, dict[str, _Entry]]:
    """The per-worker cache of ``worker`` and its lock (created on first use)."""
    state = vars(worker)
    return state.setdefault(_RUNS_LOCK, threading.Lock()), state.setdefault(_RUNS, {})


def _entry(worker: Any, run: str) -> _Entry:
    """The cache entry of ``run`` on ``worker``; a new run closes the least recently used
    idle entries beyond :data:`CACHED_RUNS`."""
    lock, runs = _runs(worker)
    with lock:
        if run not in runs:
            for _, old in sorted((e.used, k) for k, e in runs.items())[:max(0, len(runs) - CACHED_RUNS + 1)]:
                _release(runs.pop(old))
            runs[run] = _Entry()
        return runs[run]


def _release(entry: _Entry) -> None:
    """Close a dropped ``entry`` now, or after the batch that holds it."""
    entry.released = True
    if entry.lock.acquire(blocking=False):
        try:
            entry.close()
        finally:
            entry.lock.release()


def _batch_task(job: FmuJob, paths: list[ChainPath], controller: Controller, spec: SimulationSpec,
                gen: np.random.Generator) -> SimulationResult:
    """A Dask task: one batch on this worker's supervisor of ``job`` (opened by the run's
    first task here)."""
    worker = get_worker()
    while True:
        entry = _entry(worker, job.run)
        with entry.lock:
            if entry.released:  # dropped between the lookup and the lock: take the new one
                continue
            entry.used = time.monotonic()
            try:
                sup = entry.open(job, worker.local_directory)
                res = sup.run(paths, controller, spec=spec, rng=gen)
                copy = str(sup.path)
                return dataclasses.replace(res, records=tuple(
                    dataclasses.replace(r, failure=r.failure.replace(copy, job.fmu)) if r.failure else r
                    for r in res.records))
            finally:
                if entry.released:
                    entry.close()


def _close_run(run: str) -> None:
    """Drop ``run`` from this worker's cache and close its supervisor (a Dask task)."""
    lock, runs = _runs(get_worker())
    with lock:
        entry = runs.pop(run, None)
    if entry is not None:
        _release(entry)


def _close_on_workers(client: Any, run: str) -> None:
    """Close ``run``'s cached supervisors on every worker, within :data:`RELEASE_TIMEOUT`
    (best effort: a worker that is gone has nothing to close, errors are dropped)."""
    futures: list[Any] = []
    try:
        futures = [client.submit(_close_run, run, workers=[w], allow_other_workers=False, pure=False,
                                 key=f"ftc-verify-fmu-close-{run}-{k}")
                   for k, w in enumerate(client.nthreads())]
        wait(futures, timeout=RELEASE_TIMEOUT)
    except Exception:
        pass
    finally:
        _cancel(client, futures)


def _cancel(client: Any, futures: list[Any]) -> None:
    """Cancel ``futures`` without waiting (best effort)."""
    try:
        if futures:
            client.cancel(futures, asynchronous=False)
    except Exception:
        pass


def _raise_failed(future: Any, span: tuple[int, int], fmu: str) -> NoReturn:
    """Raise what the task of ``future`` (the batch ``span`` of paths) failed with:
    :class:`PlantRunError` when its workers kept dying, else the task's own exception."""
    exc = future.exception()
    if isinstance(exc, KilledWorker):
        deaths = int(getattr(exc, "allowed_failures", 0)) + 1
        raise PlantRunError(fmu, f"the Dask worker running this batch died {deaths} times (a crashing plant FMU "
                                 "kills the process that runs it)", batch=span) from None
    future.result()  # re-raises the task's exception, with its traceback
    raise AssertionError(f"task of paths[{span[0]}:{span[1]}] failed without an exception")  # pragma: no cover


def run_fmu_batches(client: Any, system: FTCSystem, plant: Any, controller: Controller,
                    paths: Sequence[ChainPath], *, spec: SimulationSpec, rng: np.random.Generator,
                    done: Callable[[int], Any] | None = None) -> list[SimulationResult]:
    """What ``Supervisor(plant.fmu, ...).run(batch_k, controller, spec=spec, ...)``
    returns for each batch of ``spec.batch`` paths (default
    :data:`~ftc_verify.simulation.batches.FMU_TASK_PATHS`), computed on ``client``'s
    workers (one task per batch) and returned in order: the FMU of the (resolved and
    checked) plant map ``plant``; ``rng`` draws ``Delta`` as a serial run's would and ends
    in the same state. ``done(k)`` is called as each batch of ``k`` paths comes back.

    Raises
    ------
    PlantRunError
        A batch whose worker died every time it ran it (``batch=(first, stop)``).
    Exception
        Any other exception of a task, as it was raised there.
    """
    from .batches import FMU_TASK_PATHS

    plist = list(paths)
    batch = FMU_TASK_PATHS if spec.batch is None else spec.batch
    job = FmuJob(uuid.uuid4().hex, Path(plant.fmu).read_bytes(), plant.injection_map(), system, plant.tolerance,
                 str(plant.fmu))
    starts = range(0, len(plist), batch)
    futures = [client.submit(_batch_task, job, plist[b:b + batch], controller, spec, g,
                             retries=TASK_RETRIES, pure=False, key=f"ftc-verify-fmu-batch-{job.run}-{b}")
               for g, b in zip(batch_generators(system, plist, spec.schedule, rng, batch), starts)]
    span = {f.key: (b, min(b + batch, len(plist))) for f, b in zip(futures, starts)}
    try:
        for fut in as_completed(futures):
            if fut.status != "finished":
                _raise_failed(fut, span[fut.key], str(plant.fmu))
            if done is not None:
                done(span[fut.key][1] - span[fut.key][0])
        results = client.gather(futures)
    except Exception:
        _cancel(client, futures)
        _close_on_workers(client, job.run)
        raise
    except BaseException:  # SIGINT/SIGTERM: no waiting; a local cluster is torn down with its folder
        _cancel(client, futures)
        raise
    _close_on_workers(client, job.run)
    return results
