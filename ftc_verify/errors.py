"""Exception hierarchy of ftc-verify.

Every error the package raises on purpose derives from :class:`FTCError`, and each
subclass also inherits the built-in exception it refines, so callers may catch either
``FTCError`` or the familiar built-in (``ValueError``, ``RuntimeError``, ``OSError``).
Messages name the offending field, file or solver together with the value seen.
"""

from __future__ import annotations

__all__ = [
    "FTCError",
    "ValidationError",
    "ProblemFileError",
    "SolverError",
    "FMUError",
    "MemoryLimitError",
]


class FTCError(Exception):
    """Root of every error raised deliberately by ftc-verify."""


class ValidationError(FTCError, ValueError):
    """A model, controller or option has an invalid value (names the field and value)."""


class ProblemFileError(ValidationError):
    """A system or gains file is unreadable, malformed or inconsistent.

    The message starts with the file name and, where it applies, the table index and key.
    """


class SolverError(FTCError, RuntimeError):
    """A convex solver failed or raised; the message names the solver."""


class FMUError(FTCError, RuntimeError):
    """Building, locating, validating or running an FMU failed (names the file and the problem)."""


class MemoryLimitError(FTCError, MemoryError):
    """A problem would need more memory than allowed (names the estimate and the limit)."""
