"""FMU plants: building, caching and validating the project's ``LinearJumpPlant`` FMU
(:mod:`.linear_jump`), its resource file (:mod:`.system_text`) and model description
(:mod:`.model_description`), and the build toolchain of every FMU the package compiles
(:mod:`.build`). The package exports the public names of :mod:`.linear_jump` and four of
:mod:`.build`."""

from __future__ import annotations

from . import linear_jump
from .build import build_lock, cache_dir, fmi2_include_dir, run_compiler
from .linear_jump import *  # noqa: F403 -- exactly linear_jump.__all__, listed once there

__all__ = ["fmi2_include_dir", "cache_dir", "build_lock", "run_compiler"]
__all__ += linear_jump.__all__
