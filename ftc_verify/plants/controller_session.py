"""An exported controller FMU run by the supervisor (``simulate``/``verify --controller-fmu``).

:class:`ControllerFMU` opens a co-simulation FMU written by ``ftc-verify export-controller``
(:mod:`ftc_verify.export.controller_fmu`), FMI 2.0 or 3.0, checks its variables
(``v[i]``, ``u[i]``, ``xc[i]``, ``samplePeriod``, ``fdi_mode``), and offers what one
sampled controller does per grid point: :meth:`ControllerFMU.output` (``v`` and the FDI mode
written, ``u`` read) and :meth:`ControllerFMU.step` (``doStep`` over the period, ``xc``
read back). :func:`controller_of_fmu` reads the controller file the FMU carries in
``resources/controller.toml`` (the matrices the analysis and the checks use), and
:func:`fmu_problems` is FMPy's validation of any FMU file.
"""

from __future__ import annotations

import os
import tempfile
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..controllers.controller import Controller
from ..errors import FMUError, ValidationError
from .fmu_archive import read_archive, read_model_description, require_binary

__all__ = ["ExportedController", "ControllerFMU", "controller_of_fmu", "check_period", "fmu_problems",
           "fmu_variable_types"]


def fmu_problems(path: str | os.PathLike[str]) -> list[str]:
    """The problems :func:`fmpy.validation.validate_fmu` finds in the FMU ``path`` (empty: none)."""
    from fmpy.validation import validate_fmu

    return [str(p) for p in validate_fmu(str(path))]


def fmu_variable_types(path: str | os.PathLike[str]) -> dict[str, str]:
    """The FMI 2.0 type name (``Real``, ``Integer``, ``Boolean``, ``String``,
    ``Enumeration``) of every variable of the FMU ``path``, by name."""
    from fmpy import read_model_description

    md = read_model_description(str(path), validate=False)
    names = {"Float64": "Real", "Float32": "Real", "Int32": "Integer"}
    return {v.name: names.get(v.type, v.type) for v in md.modelVariables}


@dataclass(frozen=True, eq=False)
class ExportedController(Controller):
    """A :class:`~ftc_verify.controllers.controller.Controller` whose loop runs the exported
    FMU ``fmu`` (:class:`ControllerFMU`) instead of the matrices: the matrices (read from the
    FMU's ``resources/controller.toml``) serve the checks and the analysis."""

    fmu: str = ""


def controller_of_fmu(path: str | os.PathLike[str]) -> ExportedController:
    """The controller an exported FMU carries (``resources/controller.toml``), bound to the FMU.

    Raises
    ------
    FMUError
        When the file is not an FMU written by ``export-controller``.
    """
    from ..controllers.files import load_controller

    p = Path(path)
    err = _err(p)
    names, _ = read_archive(p, err)
    if "resources/controller.toml" not in names:
        raise err("not a controller FMU of ftc-verify export-controller (no resources/controller.toml)")
    with tempfile.TemporaryDirectory(prefix="ftc-verify-ctrl-") as tmp:
        with zipfile.ZipFile(p) as zf:
            target = Path(tmp) / "controller.toml"
            target.write_bytes(zf.read("resources/controller.toml"))
        c = load_controller(target)
    return ExportedController(c.Ac, c.Bc, c.Cc, c.Dc, c.measures, c.name, fmu=str(p))


def _err(path: Path) -> Any:
    return lambda what: FMUError(f"{path}: {what}")


class ControllerFMU:
    """One loaded and instantiated controller FMU (a context manager; module docstring).

    Parameters
    ----------
    path
        The ``.fmu`` written by ``export-controller``.
    workdir
        Where the temporary extraction folder is made (default: the system's), e.g. the
        folder a watching parent process removes if this one is killed.
    """

    def __init__(self, path: str | os.PathLike[str], workdir: str | os.PathLike[str] | None = None) -> None:
        self.path = Path(path)
        self.err = _err(self.path)
        names, xml = read_archive(self.path, self.err)
        md, self.fmi_version = read_model_description(self.path, xml, self.err)
        require_binary(names, md.coSimulation.modelIdentifier, self.fmi_version, self.err)
        refs = {v.name: v.valueReference for v in md.modelVariables}
        self.v_refs = self._refs(refs, "v")
        self.u_refs = self._refs(refs, "u")
        self.xc_refs = self._refs(refs, "xc")
        for name in ("samplePeriod", "fdi_mode"):
            if name not in refs:
                raise self.err(f"no variable {name!r}: not a controller FMU of ftc-verify export-controller")
        self.mode_ref = refs["fdi_mode"]
        period = next(v for v in md.modelVariables if v.name == "samplePeriod")
        self.period = float(period.start)
        self.modes = int(next(v for v in md.modelVariables if v.name == "fdi_mode").max)
        self.messages: list[str] = []
        self._tmp = tempfile.TemporaryDirectory(prefix="ftc-verify-ctrl-fmu-",
                                                dir=None if workdir is None else str(workdir))
        self.slave: Any = None
        try:
            with zipfile.ZipFile(self.path) as zf:
                zf.extractall(self._tmp.name)
            self._instantiate(md)
        except BaseException:
            self.close()
            raise

    def _refs(self, refs: dict[str, int], base: str) -> list[int]:
        out: list[int] = []
        while f"{base}[{len(out) + 1}]" in refs:
            out.append(refs[f"{base}[{len(out) + 1}]"])
        if base != "xc" and not out:
            raise self.err(f"no variable {base}[1]: not a controller FMU of ftc-verify export-controller")
        return out

    def _instantiate(self, md: Any) -> None:
        kwargs = {"guid": md.guid, "unzipDirectory": self._tmp.name,
                  "modelIdentifier": md.coSimulation.modelIdentifier, "instanceName": "ftc-verify-controller"}
        if self.fmi_version == "3.0":
            from fmpy.fmi3 import FMU3Slave

            self.slave = FMU3Slave(**kwargs)
            self.slave.instantiate(loggingOn=False, logMessage=self._log3)
            self._set_real, self._get_real, self._set_int = (self.slave.setFloat64, self.slave.getFloat64,
                                                             self.slave.setInt32)
        else:
            from fmpy.fmi2 import FMU2Slave

            self.slave = FMU2Slave(**kwargs)
            self.slave.instantiate(loggingOn=False, callbacks=self._callbacks2())
            self._set_real, self._get_real, self._set_int = (self.slave.setReal, self.slave.getReal,
                                                             self.slave.setInteger)
        self._live = True
        self.reset()

    def _callbacks2(self) -> Any:
        """FMI 2.0 callbacks whose logger keeps the messages (nothing printed)."""
        import ctypes

        from fmpy import calloc, free
        from fmpy.fmi2 import (fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE, fmi2CallbackFunctions,
                               fmi2CallbackLoggerTYPE)

        cb = fmi2CallbackFunctions()
        cb.logger = fmi2CallbackLoggerTYPE(self._log2)
        cb.allocateMemory = ctypes.cast(calloc, fmi2CallbackAllocateMemoryTYPE)
        cb.freeMemory = ctypes.cast(free, fmi2CallbackFreeMemoryTYPE)
        self._keep = cb  # the C side holds pointers into it
        return cb

    def _log2(self, env: Any, name: Any, status: int, category: Any, message: bytes | None) -> None:
        self.messages.append((message or b"").decode("utf-8", "replace"))

    def _log3(self, env: Any, status: int, category: Any, message: bytes | None) -> None:
        self.messages.append((message or b"").decode("utf-8", "replace"))

    def _call(self, what: str, fun: Any, *args: Any) -> Any:
        try:
            return fun(*args)
        except Exception as exc:
            detail = self.messages[-1] if self.messages else str(exc)
            raise self.err(f"{what} failed: {detail}") from None

    def reset(self) -> None:
        """Start values (``xc = 0``, FDI mode 1), initialised at ``t = 0``: ready for a path."""
        s = self.slave
        if self.fmi_version == "3.0":
            self._call("fmi3Reset", s.reset)
            self._call("fmi3EnterInitializationMode", s.enterInitializationMode, None, 0.0, None)
        else:
            self._call("fmi2Reset", s.reset)
            self._call("fmi2SetupExperiment", s.setupExperiment, None, 0.0, None)
            self._call("fmi2EnterInitializationMode", s.enterInitializationMode)
        self._call("exitInitializationMode", s.exitInitializationMode)

    def output(self, fdi_mode: int, v: np.ndarray) -> np.ndarray:
        """``u`` for the FDI mode ``fdi_mode`` (1-based) and the measured vector ``v``
        (both written into the FMU, held until the next call)."""
        self._call("setting fdi_mode", self._set_int, [self.mode_ref], [int(fdi_mode)])
        self._call("setting v", self._set_real, self.v_refs, [float(x) for x in v])
        return np.asarray(self._call("getting u", self._get_real, self.u_refs), dtype=float)

    def step(self, t: float, h: float) -> np.ndarray:
        """``doStep(t, h)`` (``v``, FDI mode held); returns the new ``xc``."""
        self._call(f"doStep at t = {t!r} with step {h!r}", self.slave.doStep, t, h)
        if not self.xc_refs:
            return np.zeros(0)
        return np.asarray(self._call("getting xc", self._get_real, self.xc_refs), dtype=float)

    def __enter__(self) -> ControllerFMU:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Terminate and free the instance, unload the library, remove the extracted files."""
        if self.slave is not None:
            try:
                if getattr(self, "_live", False):
                    self.slave.terminate()
                    self.slave.freeInstance()
            except Exception:
                pass
            try:
                from fmpy import freeLibrary

                freeLibrary(self.slave.dll._handle)
            except Exception:
                pass
            self.slave = None
        self._tmp.cleanup()


def check_period(fmu: ControllerFMU, step: float) -> None:
    """Refuse a run whose ``step`` is not the FMU's sampling period."""
    if abs(step - fmu.period) > 1e-9 * fmu.period:
        raise ValidationError(f"--controller-fmu {fmu.path}: sampling period {fmu.period!r} s, but --step is "
                              f"{step!r} (export the controller with --step {step!r}, or run with --step {fmu.period!r})")
