"""The last checks of ``verify``: the FMU against the numpy reference, or the plant region.

With the ``LinearJumpPlant`` FMU, :func:`backend_agreement` re-simulates the first
``AGREE_PATHS`` (5, :mod:`ftc_verify.verification.verify`) paths on the numpy reference with the
same ``Delta`` draws and requires the plant and controller states to agree to
:data:`~ftc_verify.verification.verify.AGREE_RTOL`; with the user's plant map,
:func:`plant_summary` reports the excursions, the paths that left ``[region]`` and the
measured linearisation error (:func:`against_reference` picks one). Stage 6 of
:mod:`ftc_verify.verification.verify`, moved here from that module unchanged.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from ..controllers.controller import Controller
from ..model.system import FTCSystem
from ..simulation.paths import ChainPath
from ..simulation.records import PathRecord
from ..simulation.spec import SimulationSpec
from .montecarlo import MCEstimate

if TYPE_CHECKING:
    from .verify import Check

__all__ = ["plant_summary", "backend_agreement", "against_reference", "EarlyReference"]


class EarlyReference:
    """The numpy reference of the paths the agreement checks, computed in a thread of this
    process while the FMU Monte Carlo runs in its plant processes (this process only
    waits for them then): :func:`~ftc_verify.simulation.reference.simulate_reference` of
    ``paths`` with ``spec``, the call :func:`backend_agreement` and
    :func:`against_reference` make after the Monte Carlo. They use it when the FMU ran
    the same paths (:meth:`result_for`: a plant FMU that cannot vary its step, or an
    exported controller, moves the jump times to the step grid; then they compute it
    themselves), so the check's numbers are those of the call made in turn.

    Parameters
    ----------
    system, controller, paths, spec
        The arguments of ``simulate_reference``.
    """

    def __init__(self, system: FTCSystem, controller: Controller, paths: list[ChainPath],
                 spec: SimulationSpec) -> None:
        import threading

        from ..simulation.reference import simulate_reference

        self.paths = list(paths)
        self._done = threading.Event()
        self._found: tuple[Any, BaseException | None] = (None, None)

        def work() -> None:
            try:
                self._found = (simulate_reference(system, controller, self.paths, spec=spec), None)
            except BaseException as exc:  # raised again by result_for, in the caller's thread
                self._found = (None, exc)
            finally:
                self._done.set()

        # a daemon: a command interrupted during the Monte Carlo exits without waiting for it
        threading.Thread(target=work, name="ftc-verify-reference", daemon=True).start()

    def result_for(self, paths: list[ChainPath]) -> Any:
        """The reference's :class:`~ftc_verify.simulation.records.SimulationResult` when
        ``paths`` are its paths (the same jump times, modes, rates and horizons), else
        ``None`` (the thread has ended either way); raises what the reference raised."""
        self.wait()
        if len(paths) != len(self.paths) or not all(_same_path(a, b) for a, b in zip(paths, self.paths)):
            return None
        result, error = self._found
        if error is not None:
            raise error
        return result

    def wait(self) -> None:
        """Wait for the thread (before this process forks; errors are left to :meth:`result_for`)."""
        self._done.wait()


def _same_path(a: ChainPath, b: ChainPath) -> bool:
    """The same path and the same ``Delta`` draws (its stream's seed: what ``delta_stream`` reads)."""
    seeds = [None if p.stream is None else (p.stream.entropy, tuple(p.stream.spawn_key), p.stream.pool_size)
             for p in (a, b)]
    return (a.horizon == b.horizon and seeds[0] == seeds[1] and np.array_equal(a.times, b.times)
            and np.array_equal(a.true, b.true) and np.array_equal(a.fdi, b.fdi) and np.array_equal(a.beta, b.beta))


def plant_summary(plant: Any, records: list[PathRecord], reference: list[PathRecord], mc: MCEstimate,
                   fmu: dict[str, Any], measured: list[PathRecord], fault_only: list[PathRecord] | None,
                   ) -> tuple[dict[str, Any], Check]:
    """The ``plant`` object of the report and the region check (issue: what "pass" means
    on a plant): excursions from the operating point and paths leaving ``[region]`` (on the
    real paths, ``records``), and the measured linearisation error: the paths the Monte
    Carlo measured (``measured``: the real ones, or their incremental responses) against the
    linear reference on the same chain and disturbance. ``fault_only``: the ``w = 0`` runs
    of the incremental measure, whose mean output energy is the fault response."""
    from .verify import Check

    ok = [r for r in records if r.diverged_at is None]
    excursion = np.max([np.max(np.abs(r.x), axis=0) for r in ok], axis=0) if ok else None
    left: list[int] = []
    x_op = plant.states_op if plant.states_op is not None else np.zeros(len(plant.states))
    limits = [(lo, hi, op, key) for lo, hi, op, key in ((plant.states_min, plant.states_max, x_op, "x"),
                                                       (plant.inputs_min, plant.inputs_max, plant.inputs_op, "u"))
              if lo is not None]
    failed = [k for k, r in enumerate(records, start=1) if r.failure is not None]  # stopped by the FMU, not the region
    for k, r in enumerate(records, start=1):
        outside = any(np.any(getattr(r, key) + op < lo) or np.any(getattr(r, key) + op > hi)
                      for lo, hi, op, key in limits)
        if outside or (r.diverged_at is not None and r.failure is None):
            left.append(k)
    u_range = [np.min([np.min(r.u, axis=0) for r in ok], axis=0) + plant.inputs_op,
               np.max([np.max(r.u, axis=0) for r in ok], axis=0) + plant.inputs_op] if ok else None
    err: float | None = None
    for a, b in zip(measured, reference):
        if a.diverged_at is None and b.diverged_at is None:
            diff = float(np.max(np.abs(a.x - b.x))) / max(1e-300, float(np.max(np.abs(b.x))))
            err = diff if err is None else max(err, diff)
    summary = fmu | {"mean_ratio": mc.mean_ratio, "upper_bound": mc.upper_bound,
                     "max_excursion": None if excursion is None else excursion.tolist(),
                     "input_range": None if u_range is None else [u_range[0].tolist(), u_range[1].tolist()],
                     "linearisation_error": err, "left_region": len(left), "left_region_paths": left[:20],
                     "failed_in_plant": len(failed), "failed_in_plant_paths": failed[:20],
                     "paths": len(records), "states": list(plant.states),
                     "states_op": None if plant.states_op is None else plant.states_op.tolist(), "measure": "total" if fault_only is None else "incremental",
                     "fault_response_energy": None if fault_only is None else
                     float(np.mean([r.y_norm ** 2 for r in fault_only]))}
    failed_text = (f"; {len(failed)} of {len(records)} paths failed in the plant FMU{_shown(failed)} (the region "
                   "is checked up to the failure)" if failed else "")
    excursion_text = (f"none measured (every path {_stopped(records)})" if excursion is None else
                      f"{summary['max_excursion']}; inputs within {summary['input_range']}")
    pairs = list(zip(measured, reference))
    detail = (f"{len(left)} of {len(records)} paths left [region]{_shown(left)}{failed_text}; largest excursion from "
              f"the operating point {excursion_text}; FMU vs linear reference: "
              + (f"every compared path {_stopped([a if a.diverged_at is not None else b for a, b in pairs])}"
                 if err is None else
                 f"largest relative state difference {err:.3g} on {min(len(records), len(reference))} paths "
                 "(the measured linearisation error)"))
    return summary, Check("plant region", not left and not failed, detail)


def _shown(paths: list[int]) -> str:
    """`` (paths [1, 2, ...])``: the first ten of the 1-based ``paths``; empty when none."""
    return f" (paths {paths[:10]}{' ...' if len(paths) > 10 else ''})" if paths else ""


def _stopped(records: list[PathRecord]) -> str:
    """How ``records`` (each diverged or failed) ended: "diverged", "failed in the plant
    FMU", or "diverged or failed in the plant FMU" when some of each."""
    failed = sum(r.failure is not None for r in records)
    if failed and failed == len(records):
        return "failed in the plant FMU"
    return "diverged" if not failed else "diverged or failed in the plant FMU"


def backend_agreement(system: FTCSystem, controller: Controller, chain_paths: list[ChainPath],
                       records: list[PathRecord], spec: SimulationSpec, early: EarlyReference | None = None) -> Check:
    """The first paths again on the numpy reference, with the same Delta draws
    (``early``'s when it simulated them)."""
    from ..simulation.reference import simulate_reference
    from .verify import AGREE_PATHS, AGREE_RTOL, Check

    # the paths the FMU ran (jump times on its step grid when it or the controller FMU has a fixed step)
    ran = [r.path for r in records[:AGREE_PATHS]]
    ref = early.result_for(ran) if early is not None else None
    if ref is None:
        ref = simulate_reference(system, controller, ran, spec=spec)
    worst = 0.0
    for k, (a, b) in enumerate(zip(records[:AGREE_PATHS], ref.records), start=1):
        if a.diverged_at != b.diverged_at:
            return Check("FMU vs reference", False, f"path {k} diverged at t = {a.diverged_at} on the FMU and at "
                                                    f"t = {b.diverged_at} on the reference")
        za, zb = np.hstack([a.x, a.xc]), np.hstack([b.x, b.xc])
        worst = max(worst, float(np.max(np.abs(za - zb))) / max(1e-300, float(np.max(np.abs(zb)))))
    return Check("FMU vs reference", worst <= AGREE_RTOL,
                 f"max relative state difference (plant and controller) {worst:.3g} on "
                 f"{min(AGREE_PATHS, len(records))} paths (tolerance {AGREE_RTOL:g})")


def against_reference(system: FTCSystem, controller: Controller, chain_paths: list[ChainPath],
                       records: list[PathRecord], spec: SimulationSpec, plant: Any,
                       mc: MCEstimate, fmu: dict[str, Any], measured: list[PathRecord],
                       fault_only: list[PathRecord] | None,
                       early: EarlyReference | None = None) -> tuple[dict[str, Any] | None, Check]:
    """The backend agreement (LinearJumpPlant), or the plant summary and region check;
    ``early``: the reference computed during the Monte Carlo (:class:`EarlyReference`)."""
    if plant is None:
        return None, backend_agreement(system, controller, chain_paths, records, spec, early)
    from ..simulation.reference import simulate_reference
    from .verify import AGREE_PATHS

    first = chain_paths[:AGREE_PATHS]
    ref = early.result_for(first) if early is not None else None
    if ref is None:
        ref = simulate_reference(system, controller, first, spec=spec)
    return plant_summary(plant, records, list(ref.records), mc, fmu, measured, fault_only)
