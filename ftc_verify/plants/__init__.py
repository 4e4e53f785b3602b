"""FMU plants: building, caching and validating the project's ``LinearJumpPlant`` FMU
(:mod:`.linear_jump`), its resource file (:mod:`.system_text`) and model description
(:mod:`.model_description`), and the build toolchain of every FMU the package compiles
(:mod:`.build`)."""

from __future__ import annotations

from .build import build_lock, cache_dir, fmi2_include_dir, run_compiler
from .linear_jump import FMUError, MODEL_IDENTIFIER, FORMAT_VERSION, FMUDims, source_dir, build_binary, build_fmu, validate, fmu_dims, system_text, parse_system_text, model_description, variable_names

__all__ = [
    "FMUError",
    "MODEL_IDENTIFIER",
    "FORMAT_VERSION",
    "FMUDims",
    "source_dir",
    "fmi2_include_dir",
    "cache_dir",
    "build_lock",
    "run_compiler",
    "build_binary",
    "build_fmu",
    "validate",
    "fmu_dims",
    "system_text",
    "parse_system_text",
    "model_description",
    "variable_names",
]
