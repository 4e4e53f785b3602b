"""Monte Carlo on an FMU in batches: serially on one supervisor or on Dask workers, with progress.

:func:`fmu_monte_carlo` is the one FMU Monte Carlo of ``simulate --backend fmu`` and of
``verify``: the paths in batches of ``batch``, run on one
:class:`~ftc_verify.simulation.supervisor.Supervisor` in this process, or with a
``dask.distributed`` client on its workers
(:func:`~ftc_verify.simulation.fmu_workers.run_fmu_batches`), reporting each finished
batch to ``done`` (a progress bar). Either way the result is what one
:meth:`Supervisor.run <ftc_verify.simulation.supervisor.Supervisor.run>` over all paths
returns: every path draws its ``Delta`` values from its own stream.
"""

from __future__ import annotations

import copy
import dataclasses
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..controllers.controller import Controller
from ..errors import PlantRunError
from ..model.system import FTCSystem
from .delta import DeltaSchedule
from .paths import ChainPath
from .records import SimulationResult
from .spec import SimulationSpec, spec_from
from .streaming import batch_generators
from .supervisor import Supervisor, resolve_plant

__all__ = ["FMU_TASK_PATHS", "fmu_monte_carlo", "merge_results", "progress_bar"]

#: Paths per batch (one Dask task; a batch of the paper's plant at horizon 30 takes about 1 s).
FMU_TASK_PATHS = 25


def progress_bar(total: int, desc: str, enabled: bool) -> Any:
    """A tqdm bar on stderr (``None`` unless ``enabled``, e.g. ``sys.stderr.isatty()``)."""
    if not enabled:
        return None
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit="path", file=sys.stderr, leave=False)


def merge_results(parts: Sequence[SimulationResult], fmu: str | Path, seed: int | None) -> SimulationResult:
    """Batches of one run as one result: records in order, the first batch's options with
    the FMU's file ``fmu``, the FMU's warnings summed and the largest timing error."""
    options = parts[0].options | {"fmu": str(fmu), "fmu_warnings": sum(p.options["fmu_warnings"] for p in parts),
                                  "timing_error": max(p.options["timing_error"] for p in parts)}
    return dataclasses.replace(parts[0], seed=seed, horizon=max(p.horizon for p in parts),
                               records=tuple(r for p in parts for r in p.records), options=options)


def fmu_monte_carlo(system: FTCSystem, controller: Controller, paths: Sequence[ChainPath], *,
                    spec: SimulationSpec | None = None, step: float | None = None,
                    delta: DeltaSchedule | str | None = None, rng: np.random.Generator | None = None,
                    disturbance: str | None = None, seed: int | None = None, plant: Any = None,
                    batch: int | None = None, client: Any = None, log: Callable[[str, str, str], None] | None = None,
                    done: Callable[[int], Any] | None = None, isolate: bool | None = None,
                    processes: Sequence[Any] | None = None) -> SimulationResult:
    """Co-simulate ``paths`` on the FMU of the plant map ``plant`` (default: the
    ``LinearJumpPlant`` of ``system``; :func:`~ftc_verify.simulation.supervisor.resolve_plant`)
    in batches (module docstring).

    ``spec`` (:class:`~ftc_verify.simulation.spec.SimulationSpec`; the keywords ``step``,
    ``delta``, ``disturbance``, ``seed``, ``batch``, ``isolate`` are its shorthand,
    :func:`~ftc_verify.simulation.spec.spec_from`): ``step``, ``disturbance`` and
    ``delta`` of the loop; ``seed``, recorded; ``batch``, paths per batch (default
    :data:`FMU_TASK_PATHS`); ``workers``/``scheduler``, the Dask cluster opened for the
    run when no ``client`` is given. The kept records are checked against the memory limit
    first (:meth:`~ftc_verify.simulation.spec.SimulationSpec.check_memory`). ``client``:
    run the batches on its workers (``log`` is then not available: the messages stay
    there). ``done(k)`` is called after each batch of ``k`` paths. ``rng`` (default
    :meth:`~ftc_verify.simulation.spec.SimulationSpec.generator`) draws ``Delta`` only for
    paths without their own stream.

    ``spec.isolate`` (default): without a client, run the FMU in a watched child process
    (:func:`~ftc_verify.simulation.isolated.run_isolated`), so that a plant whose code
    crashes raises :class:`~ftc_verify.errors.PlantRunError` naming the path and the time
    instead of ending this process, on one child per core (at most
    :data:`~ftc_verify.simulation.isolated.MAX_PROCESSES`; ``processes``: children started
    earlier, :func:`~ftc_verify.simulation.isolated.plant_processes`, closed here whatever
    happens), the same records; ``False`` runs it in this process. With a client, a
    batch whose worker died repeatedly is run again in a watched child to find where the
    plant crashed.

    Paths on which the FMU returned ``fmi2Error`` or ``fmi2Discard`` come back as failed
    records (:meth:`~ftc_verify.simulation.records.PathRecord.failed`); ``fmi2Fatal`` and
    crashes raise :class:`~ftc_verify.errors.PlantRunError`.
    """
    spec = spec_from(spec, {"step": step, "delta": delta, "disturbance": disturbance, "seed": seed, "batch": batch,
                            "isolate": isolate})
    if spec.batch is None:
        spec = dataclasses.replace(spec, batch=FMU_TASK_PATHS)
    plant = resolve_plant(system, plant)
    rng = spec.generator(rng)
    plist = list(paths)
    if plist and isinstance(controller, Controller):
        spec.check_memory(system, controller, len(plist), max(p.horizon for p in plist))
    try:
        with spec.client(client) as client:
            if client is not None:
                return _on_cluster(client, system, plant, controller, plist, spec, rng, done)
            if spec.isolate:
                from .isolated import run_isolated

                parts = run_isolated(system, plant, controller, plist, spec=spec, rng=rng, log=log, done=done,
                                     processes=processes)
                processes = None  # closed by run_isolated
                return merge_results(parts, plant.fmu, spec.seed)
    finally:
        for proc in processes or ():
            proc.close()
    parts = []
    batch = FMU_TASK_PATHS if spec.batch is None else spec.batch
    with Supervisor(plant.fmu, plant.injection_map(), system=system, tolerance=plant.tolerance, log=log) as sup:
        for b in range(0, len(plist), batch):
            parts.append(sup.run(plist[b:b + batch], controller, spec=spec, rng=rng))
            if done is not None:
                done(len(parts[-1].records))
    return merge_results(parts, plant.fmu, spec.seed)


def _on_cluster(client: Any, system: FTCSystem, plant: Any, controller: Controller, plist: list[ChainPath],
                spec: SimulationSpec, rng: np.random.Generator, done: Callable[[int], Any] | None) -> SimulationResult:
    """:func:`fmu_monte_carlo` on ``client``'s workers; a batch that killed its workers
    is run again in a watched child to name the path and time of the crash."""
    from .fmu_workers import run_fmu_batches

    batch = int(spec.batch)  # type: ignore[arg-type]
    starts = list(batch_generators(system, plist, spec.schedule, copy.deepcopy(rng), batch))
    try:
        parts = run_fmu_batches(client, system, plant, controller, plist, spec=spec, rng=rng, done=done)
    except PlantRunError as exc:
        if exc.batch is None:
            raise
        _locate_crash(exc, system, plant, controller, plist, starts[exc.batch[0] // batch], spec)
        raise
    return merge_results(parts, plant.fmu, spec.seed)


def _locate_crash(exc: PlantRunError, system: FTCSystem, plant: Any, controller: Controller,
                  paths: list[ChainPath], rng: np.random.Generator, spec: SimulationSpec) -> None:
    """The batch ``exc.batch`` that killed its Dask workers, run again in a watched child:
    raises the :class:`PlantRunError` naming the path and time where the plant crashes;
    returns when it does not crash there (the workers died of something else)."""
    from .isolated import plant_processes, run_isolated

    first, stop = exc.batch  # type: ignore[misc]
    try:
        run_isolated(system, plant, controller, paths[first:stop], spec=dataclasses.replace(spec, batch=stop - first),
                     rng=rng, processes=plant_processes(1))
    except PlantRunError as found:
        raise PlantRunError(found.fmu, found.detail + f" (the Dask workers running paths[{first}:{stop}] died "
                            "the same way)", path=None if found.path is None else first + found.path,
                            time=found.time) from None
