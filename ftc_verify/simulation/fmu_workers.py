"""FMU co-simulation on Dask workers: every worker loads the FMU once.

:func:`run_fmu_batches` is the distributed form of calling
:meth:`~ftc_verify.simulation.supervisor.Supervisor.run` batch after batch (used by
:func:`~ftc_verify.simulation.batches.fmu_monte_carlo`). A
:class:`SupervisorPlugin` (a ``dask.distributed`` worker plugin) carries the FMU's bytes,
so workers on other machines need neither the client's files nor its FMU cache; on each
worker it writes them to a temporary folder once and opens one
:class:`~ftc_verify.simulation.supervisor.Supervisor` on first use, which every batch
then reuses (``fmi2Reset`` between paths, as on one machine). A worker that replaces a
lost one gets the plugin from the scheduler, and its tasks are retried
(:data:`~ftc_verify.simulation.streaming.TASK_RETRIES`).

Same numbers as the serial run: every sampled path draws its ``Delta`` values from its
own stream (and a hand-built path from the generator state a serial run has at its
batch, :func:`~ftc_verify.simulation.streaming.batch_generators`), so the records are
identical wherever a batch runs.

This module imports ``dask.distributed`` at import time: import it only when a client
exists (:func:`~ftc_verify.simulation.cluster.open_client`).
"""

from __future__ import annotations

import shutil
import tempfile
import threading
import uuid
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from distributed import as_completed, get_worker
from distributed.diagnostics.plugin import WorkerPlugin

from ..controllers.controller import Controller
from ..model.system import FTCSystem
from .delta import DeltaSchedule
from .paths import ChainPath
from .records import SimulationResult
from .streaming import TASK_RETRIES, batch_generators
from .supervisor import Supervisor

__all__ = ["SupervisorPlugin", "run_fmu_batches"]


class SupervisorPlugin(WorkerPlugin):
    """One :class:`Supervisor` per worker for the FMU whose bytes it carries.

    The FMU is written to a temporary folder in :meth:`setup` and opened by the first task
    that needs it (in the task's thread); :meth:`teardown` closes it and removes the
    folder. Tasks on a worker with several threads take turns on the one instance."""

    def __init__(self, name: str, fmu_bytes: bytes, mapping: Any, system: FTCSystem,
                 tolerance: float | None) -> None:
        self.name = name
        self.fmu_bytes = fmu_bytes
        self.mapping = mapping
        self.system = system
        self.tolerance = tolerance
        self._folder: Path | None = None
        self._supervisor: Supervisor | None = None
        self._lock: threading.Lock | None = None

    def __getstate__(self) -> dict[str, Any]:  # what is shipped: never a worker's open instance
        return {k: v for k, v in self.__dict__.items() if k not in ("_folder", "_supervisor", "_lock")}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state, _folder=None, _supervisor=None, _lock=None)

    def setup(self, worker: Any) -> None:
        self._folder = Path(tempfile.mkdtemp(prefix="ftc-verify-worker-fmu-"))
        (self._folder / "plant.fmu").write_bytes(self.fmu_bytes)
        self._lock = threading.Lock()

    def teardown(self, worker: Any) -> None:
        if self._supervisor is not None:
            self._supervisor.close()
            self._supervisor = None
        if self._folder is not None:
            shutil.rmtree(self._folder, ignore_errors=True)

    def run(self, paths: list[ChainPath], controller: Controller, step: float, disturbance: str,
            delta: DeltaSchedule, gen: np.random.Generator) -> SimulationResult:
        """One batch on this worker's supervisor (opened on first use)."""
        assert self._lock is not None and self._folder is not None, "SupervisorPlugin.setup did not run"
        with self._lock:
            if self._supervisor is None:
                self._supervisor = Supervisor(self._folder / "plant.fmu", self.mapping, system=self.system,
                                              tolerance=self.tolerance)
            return self._supervisor.run(paths, controller, step=step, disturbance=disturbance, delta=delta, rng=gen)


def _batch_task(name: str, paths: list[ChainPath], controller: Controller, step: float, disturbance: str,
                delta: DeltaSchedule, gen: np.random.Generator) -> SimulationResult:
    """A Dask task: one batch on the worker's :class:`SupervisorPlugin` ``name``."""
    return get_worker().plugins[name].run(paths, controller, step, disturbance, delta, gen)


def run_fmu_batches(client: Any, system: FTCSystem, plant: Any, controller: Controller,
                    paths: Sequence[ChainPath], *, step: float, delta: DeltaSchedule, rng: np.random.Generator,
                    batch: int, disturbance: str = "paper",
                    done: Callable[[int], Any] | None = None) -> list[SimulationResult]:
    """What ``Supervisor(plant.fmu, ...).run(batch_k, ...)`` returns for each batch of
    ``batch`` paths, computed on ``client``'s workers (one task per batch) and returned in
    order: the FMU of the (resolved and checked) plant map ``plant``; ``rng`` draws
    ``Delta`` as a serial run's would and ends in the same state. ``done(k)`` is called as
    each batch of ``k`` paths comes back."""
    plist = list(paths)
    name = f"ftc-verify-fmu-{uuid.uuid4().hex}"
    client.register_plugin(SupervisorPlugin(name, Path(plant.fmu).read_bytes(), plant.injection_map(), system,
                                            plant.tolerance), name=name)
    try:
        chunks = [plist[b:b + batch] for b in range(0, len(plist), batch)]
        futures = [client.submit(_batch_task, name, c, controller, step, disturbance, delta, g, retries=TASK_RETRIES,
                                 pure=False)
                   for g, c in zip(batch_generators(system, plist, delta, rng, batch), chunks)]
        size = {f.key: len(c) for f, c in zip(futures, chunks)}
        for fut in as_completed(futures):
            if done is not None:
                done(size[fut.key])
        return client.gather(futures)
    finally:
        client.unregister_worker_plugin(name)
