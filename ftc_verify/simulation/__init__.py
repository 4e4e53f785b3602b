"""Stage 4: sample paths of the joint chain, Delta schedules, the exact numpy reference simulator
and the FMU co-simulation supervisor (both on the same sampled-data loop)."""

from __future__ import annotations

from .delta import DELTA_KINDS, DeltaSchedule, delta_shapes, delta_segments, constant_delta_loops
from .paths import ChainPath, sample_paths, communication_grid, Disturbance, disturbance, DISTURBANCES
from .records import PathRecord, SimulationResult, l2_norm
from .spec import SimulationSpec
from .continuous import simulate_continuous
from .discretise import phi_gamma, zoh_matrices
from .vectorised import energies_reference
from .reference import simulate_reference
from .supervisor import FMUError, FaultInjectionMap, Supervisor, simulate_fmu

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
