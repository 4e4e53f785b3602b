"""ftc-verify: design and verify fault-tolerant controllers under random FDI delay.

The names most programs need, importable from the package itself; each is loaded from
its stage on first use (PEP 562), so ``import ftc_verify`` stays as cheap as before::

    import ftc_verify as fv

    system = fv.load_system("examples/paper.toml")
    loop = fv.closed_loop(system, fv.load_controller("examples/paper_gains.toml"))
    print(fv.analyze(loop, name=system.name))   # the summary ``ftc-verify analyze`` prints

The stages (:mod:`ftc_verify.model`, :mod:`ftc_verify.controllers`,
:mod:`ftc_verify.analysis`, :mod:`ftc_verify.synthesis`, :mod:`ftc_verify.verification`)
hold the rest.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # the names below are loaded on first use (see __getattr__)
    from .analysis import AnalysisReport, ClosedLoop, analyze, closed_loop
    from .controllers import Controller, load_controller, save_controller
    from .errors import FTCError
    from .model import FTCSystem, JointChain, SignalNames, load_system, save_system
    from .synthesis import SynthesisResult, synthesize
    from .verification import VerifyReport, run_verify, write_report

__version__ = "0.1.0"

#: Public name -> the subpackage that exports it.
_SOURCES = {
    **dict.fromkeys(("FTCSystem", "JointChain", "SignalNames", "load_system", "save_system"), "model"),
    **dict.fromkeys(("Controller", "load_controller", "save_controller"), "controllers"),
    **dict.fromkeys(("ClosedLoop", "closed_loop", "AnalysisReport", "analyze"), "analysis"),
    **dict.fromkeys(("SynthesisResult", "synthesize"), "synthesis"),
    **dict.fromkeys(("VerifyReport", "run_verify", "write_report"), "verification"),
    "FTCError": "errors",
}

__all__ = [
    "__version__",
    "FTCSystem",
    "JointChain",
    "SignalNames",
    "load_system",
    "save_system",
    "Controller",
    "load_controller",
    "save_controller",
    "ClosedLoop",
    "closed_loop",
    "AnalysisReport",
    "analyze",
    "SynthesisResult",
    "synthesize",
    "VerifyReport",
    "run_verify",
    "write_report",
    "FTCError",
]


def __getattr__(name: str) -> Any:
    """Import the stage exporting ``name`` on first use (PEP 562)."""
    source = _SOURCES.get(name)
    if source is None:
        raise AttributeError(f"module 'ftc_verify' has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{source}", __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
