"""FMI 3.0 co-simulation FMUs behind the calls the package makes on an FMI 2.0 slave.

:class:`~ftc_verify.plants.fmu_session.FMUSession` opens both versions with
:func:`load_slave`. For FMI 2.0 that is fmpy's ``FMU2Slave`` itself (the supervisor's inner
loop binds its ``fmi2GetReal``, ``fmi2SetReal``, ``fmi2DoStep`` to locals: nothing is added
there). For FMI 3.0 it is an :class:`FMU3Adapter`: fmpy's ``FMU3Slave`` with the methods of
``FMU2Slave`` the package calls (``fmi2GetReal``, ``fmi2SetReal``, ``fmi2SetInteger``,
``fmi2SetBoolean``, ``fmi2DoStep``, ``fmi2FreeInstance``, ``instantiate``,
``setupExperiment``, ``enterInitializationMode``, ``exitInitializationMode``, ``reset``,
``terminate``, ``doStep``, ``getRealStatus``, ``getDirectionalDerivative``,
``freeLibrary``), each forwarding to the FMI 3.0 call:

=========================  ===============================================================
``fmi2GetReal/SetReal``    ``fmi3GetFloat64/SetFloat64`` (``Float64`` scalars)
``fmi2SetInteger``         ``fmi3SetInt8`` .. ``fmi3SetUInt64`` by each variable's type
                           (``Enumeration``: ``fmi3SetInt64``)
``fmi2SetBoolean``         ``fmi3SetBoolean``
``setupExperiment``        kept, passed to ``fmi3EnterInitializationMode``
``fmi2DoStep``             ``fmi3DoStep`` (no event mode, no early return); its
                           ``lastSuccessfulTime`` answers ``getRealStatus``; an FMU that
                           sets ``terminateSimulation`` fails the step (status Discard)
=========================  ===============================================================

A status other than OK or Warning raises fmpy's ``FMICallException`` naming the FMI 3.0
function, exactly where the FMI 2.0 call would: errors name the FMU, the call and the time,
and an Error or Discard inside a path's loop ends that path as a failed record.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

__all__ = ["CALL_NAMES", "FAULT_KINDS", "INT_RANGES", "FMU3Adapter", "is_fmi3", "load_slave"]

#: The names of the calls :class:`~ftc_verify.plants.fmu_session.FMUSession` reports, per version.
CALL_NAMES = {
    "2.0": {"prefix": "fmi2", "setup": "fmi2SetupExperiment", "enter": "fmi2EnterInitializationMode",
            "exit": "fmi2ExitInitializationMode", "set_real": "fmi2SetReal", "instantiate": "fmi2Instantiate",
            "step": "fmi2DoStep", "fatal": "fmi2Fatal", "last_time": "fmi2LastSuccessfulTime"},
    "3.0": {"prefix": "fmi3", "setup": "fmi3EnterInitializationMode", "enter": "fmi3EnterInitializationMode",
            "exit": "fmi3ExitInitializationMode", "set_real": "fmi3SetFloat64",
            "instantiate": "fmi3InstantiateCoSimulation", "step": "fmi3DoStep", "fatal": "fmi3Fatal",
            "last_time": "lastSuccessfulTime"},
}

#: How a fault value is written, per variable type of both versions.
FAULT_KINDS = {"Real": "real", "Integer": "int", "Enumeration": "int", "Boolean": "bool", "Float64": "real",
               **{t: "int" for t in ("Int8", "UInt8", "Int16", "UInt16", "Int32", "UInt32", "Int64", "UInt64")}}

#: The value range of the FMI 3.0 integer types (FMI 2.0 ``Integer`` is 32 bits).
INT_RANGES = {"Integer": (-2**31, 2**31 - 1), "Int8": (-2**7, 2**7 - 1), "UInt8": (0, 2**8 - 1),
              "Int16": (-2**15, 2**15 - 1), "UInt16": (0, 2**16 - 1), "Int32": (-2**31, 2**31 - 1),
              "UInt32": (0, 2**32 - 1), "Int64": (-2**31, 2**31 - 1), "UInt64": (0, 2**31 - 1),
              "Enumeration": (-2**31, 2**31 - 1)}  # 64-bit types: written through a 32-bit buffer


def is_fmi3(md: Any) -> bool:
    """Whether fmpy's model description ``md`` is FMI 3.x."""
    return str(getattr(md, "fmiVersion", "") or "").startswith("3.")


def load_slave(md: Any, unzip: str, model_identifier: str, instance_name: str,
               logger: Callable[..., None]) -> tuple[Any, Any]:
    """``(slave, callbacks)``: the loaded (not yet instantiated) slave of ``md`` extracted in
    ``unzip`` and the object to pass to its ``instantiate(callbacks=...)`` (kept alive by the
    caller). ``logger(*args)`` receives the FMU's messages, ``(env, instance, status,
    category, message)`` from FMI 2.0 and ``(env, status, category, message)`` from FMI 3.0."""
    if is_fmi3(md):
        return FMU3Adapter(md, unzip, model_identifier, instance_name, logger), None
    import ctypes

    from fmpy import calloc, free
    from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                           fmi2CallbackFunctions, fmi2CallbackLoggerTYPE)

    slave = FMU2Slave(guid=md.guid, unzipDirectory=unzip, modelIdentifier=model_identifier,
                      instanceName=instance_name)
    cb = fmi2CallbackFunctions()
    cb.logger = fmi2CallbackLoggerTYPE(logger)
    cb.allocateMemory = ctypes.cast(calloc, fmi2CallbackAllocateMemoryTYPE)
    cb.freeMemory = ctypes.cast(free, fmi2CallbackFreeMemoryTYPE)
    cb.componentEnvironment = None
    return slave, cb


def _checked(fun: Any, name: str) -> Callable[..., int]:
    """The ctypes function ``fun`` raising fmpy's ``FMICallException`` above Warning."""
    from fmpy.fmi1 import FMICallException

    def call(*args: Any) -> int:
        status = fun(*args)
        if status > 1:
            raise FMICallException(function=name, status=status)
        return status

    return call


class FMU3Adapter:
    """fmpy's ``FMU3Slave`` of an FMI 3.0 co-simulation FMU, called as an ``FMU2Slave``
    (module docstring). ``md`` is fmpy's model description (the variables' types choose the
    integer setters); ``logger`` gets ``(env, status, category, message)``."""

    fmi_version = "3.0"

    def __init__(self, md: Any, unzip: str, model_identifier: str, instance_name: str,
                 logger: Callable[..., None]) -> None:
        from fmpy.fmi3 import FMU3Slave

        self.fmu = FMU3Slave(guid=md.guid, unzipDirectory=unzip, modelIdentifier=model_identifier,
                             instanceName=instance_name)
        self._logger = logger
        self._types = {v.valueReference: v.type for v in md.modelVariables}
        self.component: Any = None
        self._tolerance: float | None = None
        self._start = 0.0
        self._bind()

    def _bind(self) -> None:
        """The FMI 2.0-named calls of the inner loop, as closures over the ctypes functions."""
        import ctypes

        from fmpy.fmi1 import FMICallException
        from fmpy.fmi3 import fmi3Boolean, fmi3Float64

        f = self.fmu._functions
        get64, set64 = _checked(f["fmi3GetFloat64"], "fmi3GetFloat64"), _checked(f["fmi3SetFloat64"], "fmi3SetFloat64")
        step = f["fmi3DoStep"]
        event, term, early, last = fmi3Boolean(), fmi3Boolean(), fmi3Boolean(), fmi3Float64(math.nan)
        refs = ctypes.byref(event), ctypes.byref(term), ctypes.byref(early), ctypes.byref(last)
        self._last = last

        def fmi2GetReal(c: Any, vr: Any, n: int, buf: Any) -> int:
            return get64(c, vr, n, buf, n)

        def fmi2SetReal(c: Any, vr: Any, n: int, buf: Any) -> int:
            return set64(c, vr, n, buf, n)

        def fmi2DoStep(c: Any, t: float, h: float, no_set: Any) -> int:
            last.value = math.nan
            status = step(c, t, h, bool(no_set), *refs)
            if status > 1:
                raise FMICallException(function="fmi3DoStep", status=status)
            if term.value:
                raise FMICallException(function="fmi3DoStep (the FMU set terminateSimulation)", status=2)
            return status

        self.fmi2GetReal, self.fmi2SetReal, self.fmi2DoStep = fmi2GetReal, fmi2SetReal, fmi2DoStep

    # ------------------------------------------------------------------ typed writes
    def fmi2SetInteger(self, c: Any, vr: Any, n: int, values: Any) -> None:
        """Each variable through the setter of its FMI 3.0 type."""
        from fmpy import fmi3

        groups: dict[str, list[tuple[int, int]]] = {}
        for ref, value in zip(list(vr)[:n], list(values)[:n]):
            kind = self._types.get(ref, "Int32")
            groups.setdefault("Int64" if kind == "Enumeration" else kind, []).append((ref, int(value)))
        for kind, pairs in groups.items():
            ctype = getattr(fmi3, f"fmi3{kind}")
            refs = (fmi3.fmi3ValueReference * len(pairs))(*[r for r, _ in pairs])
            vals = (ctype * len(pairs))(*[v for _, v in pairs])
            self.fmu._call(f"fmi3Set{kind}", c, refs, len(pairs), vals, len(pairs))

    def fmi2SetBoolean(self, c: Any, vr: Any, n: int, values: Any) -> None:
        from fmpy.fmi3 import fmi3Boolean

        vals = (fmi3Boolean * max(n, 1))(*[bool(v) for v in list(values)[:n]])
        self.fmu.fmi3SetBoolean(c, vr, n, vals, n)

    # ------------------------------------------------------------------ life cycle
    def instantiate(self, callbacks: Any = None, loggingOn: bool = True) -> None:
        """``fmi3InstantiateCoSimulation`` (no event mode, no early return); ``callbacks`` is unused."""
        self.fmu.instantiate(loggingOn=loggingOn, logMessage=self._logger)
        self.component = self.fmu.component

    def setupExperiment(self, tolerance: float | None = None, startTime: float = 0.0,
                        stopTime: float | None = None) -> None:
        self._tolerance, self._start = tolerance, float(startTime)

    def enterInitializationMode(self) -> None:
        self.fmu.enterInitializationMode(tolerance=self._tolerance, startTime=self._start)

    def exitInitializationMode(self) -> None:
        self.fmu.exitInitializationMode()

    def reset(self) -> int:
        return self.fmu.reset()

    def terminate(self) -> int:
        return self.fmu.terminate()

    def fmi2FreeInstance(self, c: Any) -> None:
        self.fmu.fmi3FreeInstance(c)
        self.component = None

    def freeLibrary(self) -> None:
        self.fmu.freeLibrary()

    # ------------------------------------------------------------------ stepping, queries
    def doStep(self, currentCommunicationPoint: float, communicationStepSize: float,
               noSetFMUStatePriorToCurrentPoint: bool = True) -> int:
        return self.fmi2DoStep(self.component, currentCommunicationPoint, communicationStepSize,
                               noSetFMUStatePriorToCurrentPoint)

    def getRealStatus(self, kind: int) -> float:
        """``lastSuccessfulTime`` of the last ``fmi3DoStep`` (``kind`` 2, as FMI 2.0's
        ``fmi2LastSuccessfulTime``); raises when there is none."""
        if kind != 2 or not math.isfinite(self._last.value):
            raise ValueError("no lastSuccessfulTime")
        return float(self._last.value)

    def getDirectionalDerivative(self, vUnknown_ref: Any, vKnown_ref: Any, dvKnown: Any) -> list[float]:
        return self.fmu.getDirectionalDerivative(list(vUnknown_ref), list(vKnown_ref), list(dvKnown))
