"""The ``ftc-verify`` command line (thin: parses, calls the pipeline, prints, sets the exit code)."""

from __future__ import annotations

from .main import main, build_parser

__all__ = [
    "main",
    "build_parser",
]
