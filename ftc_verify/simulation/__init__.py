"""Stage 4: sample paths of the joint chain, Delta schedules, the exact numpy reference simulator
and the FMU co-simulation supervisor (both on the same sampled-data loop).

Each name below is loaded from its module on first use (PEP 562, as :mod:`ftc_verify`
does), so that a process needing one module -- the plant process of an isolated Monte
Carlo (:mod:`ftc_verify.simulation.isolated`) needs the supervisor only -- imports only
what that module imports."""

from __future__ import annotations

import importlib
import importlib.util
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # the names below are loaded on first use (see __getattr__)
    from .continuous import simulate_continuous
    from .delta import DELTA_KINDS, DeltaSchedule, constant_delta_loops, delta_segments, delta_shapes
    from .discretise import phi_gamma, zoh_matrices
    from .paths import DISTURBANCES, ChainPath, Disturbance, communication_grid, disturbance, sample_paths
    from .records import PathRecord, SimulationResult, l2_norm
    from .reference import simulate_reference
    from .spec import SimulationSpec
    from .supervisor import FaultInjectionMap, FMUError, Supervisor, simulate_fmu
    from .vectorised import energies_reference

#: Public name -> the module of this package that defines it.
_SOURCES = {
    **dict.fromkeys(("DELTA_KINDS", "DeltaSchedule", "delta_shapes", "delta_segments", "constant_delta_loops"),
                    "delta"),
    **dict.fromkeys(("ChainPath", "sample_paths", "communication_grid", "Disturbance", "disturbance",
                     "DISTURBANCES"), "paths"),
    **dict.fromkeys(("PathRecord", "SimulationResult", "l2_norm"), "records"),
    **dict.fromkeys(("FMUError", "FaultInjectionMap", "Supervisor", "simulate_fmu"), "supervisor"),
    "SimulationSpec": "spec",
    "simulate_continuous": "continuous",
    "phi_gamma": "discretise",
    "zoh_matrices": "discretise",
    "energies_reference": "vectorised",
    "simulate_reference": "reference",
}

__all__ = [
    "DELTA_KINDS",
    "DeltaSchedule",
    "delta_shapes",
    "delta_segments",
    "constant_delta_loops",
    "ChainPath",
    "sample_paths",
    "communication_grid",
    "Disturbance",
    "disturbance",
    "DISTURBANCES",
    "SimulationSpec",
    "PathRecord",
    "SimulationResult",
    "l2_norm",
    "simulate_reference",
    "energies_reference",
    "simulate_continuous",
    "zoh_matrices",
    "phi_gamma",
    "FMUError",
    "FaultInjectionMap",
    "Supervisor",
    "simulate_fmu",
]


def __getattr__(name: str) -> Any:
    """Import the module defining ``name`` on first use (PEP 562); a submodule's name
    imports it (``ftc_verify.simulation.supervisor`` as an attribute, as when this package
    imported every module)."""
    source = _SOURCES.get(name)
    if source is None:
        if name.startswith("_") or importlib.util.find_spec(f"{__name__}.{name}") is None:
            raise AttributeError(f"module 'ftc_verify.simulation' has no attribute {name!r}")
        return importlib.import_module(f".{name}", __name__)
    value = getattr(importlib.import_module(f".{source}", __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
