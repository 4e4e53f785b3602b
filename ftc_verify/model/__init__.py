"""Stage 1 of the pipeline: the FTC plant (modes, uncertainty weights, the joint (true, FDI) chain) and its TOML files."""

from __future__ import annotations

from .files import dump_system, load_system, save_system, write_atomic
from .names import SignalNames
from .system import GENERATOR_RTOL, Mode, JointChain, FTCSystem, as_matrix

__all__ = [
    "load_system",
    "dump_system",
    "save_system",
    "write_atomic",
    "GENERATOR_RTOL",
    "Mode",
    "JointChain",
    "FTCSystem",
    "SignalNames",
    "as_matrix",
]
