"""Stage 2: the controller type (static gains or dynamic output feedback, one entry per FDI
mode) and its TOML files. Every later stage consumes a :class:`Controller`."""

from __future__ import annotations

from .controller import MEASURES, Controller
from .files import check_gains, dump_controller, dump_gains, load_controller, load_gains, save_controller, save_gains

__all__ = [
    "MEASURES",
    "Controller",
    "load_controller",
    "dump_controller",
    "save_controller",
    "load_gains",
    "dump_gains",
    "save_gains",
    "check_gains",
]
