"""The FMI calls of a co-simulation FMU, for FMI 2.0 and FMI 3.0.

:class:`~ftc_verify.plants.fmu_session.FMUSession` opens both versions with
:func:`load_slave`: fmpy's ``FMU2Slave`` or ``FMU3Slave``, and the :class:`SlaveCalls`
its :meth:`~ftc_verify.plants.fmu_session.FMUSession.read`,
:meth:`~ftc_verify.plants.fmu_session.FMUSession.write`,
:meth:`~ftc_verify.plants.fmu_session.FMUSession.step` and life-cycle methods make, each
the function of the FMU's version:

========================  =================================  ===================================
:class:`SlaveCalls`       FMI 2.0                            FMI 3.0
========================  =================================  ===================================
``get_real, set_real``    ``fmi2GetReal, fmi2SetReal``       ``fmi3GetFloat64, fmi3SetFloat64``
                                                             (``Float64`` scalars)
``set_integer``           ``fmi2SetInteger``                 ``fmi3SetInt8`` .. ``fmi3SetUInt64``
                                                             by each variable's type
                                                             (``Enumeration``: ``fmi3SetInt64``)
``set_boolean``           ``fmi2SetBoolean``                 ``fmi3SetBoolean``
``do_step``               ``fmi2DoStep``                     ``fmi3DoStep`` (no event mode, no
                                                             early return; an FMU that sets
                                                             ``terminateSimulation`` fails the
                                                             step, status Discard)
``instantiate``           ``fmi2Instantiate``                ``fmi3InstantiateCoSimulation``
``setup_experiment``      ``fmi2SetupExperiment``            kept for the next call
``enter_initialization``  ``fmi2EnterInitializationMode``    ``fmi3EnterInitializationMode``
``free_instance``         ``fmi2FreeInstance``               ``fmi3FreeInstance``
``last_successful_time``  ``fmi2GetRealStatus``              ``lastSuccessfulTime`` of the last
                          (``fmi2LastSuccessfulTime``)       ``fmi3DoStep``
========================  =================================  ===================================

The calls both fmpy classes name alike (``exitInitializationMode``, ``reset``,
``terminate``, ``getDirectionalDerivative``, ``freeLibrary``) are made on the slave itself.
A status other than OK or Warning raises fmpy's ``FMICallException`` naming the function
of the FMU's version; the session turns it into its own error
(:class:`~ftc_verify.plants.fmu_session.FMICallError`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

__all__ = ["CALL_NAMES", "FAULT_KINDS", "INT_RANGES", "LOADER_MODULES", "SlaveCalls", "is_fmi3", "load_slave",
           "preload", "typed_value"]

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
               **dict.fromkeys(("Int8", "UInt8", "Int16", "UInt16", "Int32", "UInt32", "Int64", "UInt64"), "int")}

#: The value range of the FMI 3.0 integer types (FMI 2.0 ``Integer`` is 32 bits).
INT_RANGES = {"Integer": (-2**31, 2**31 - 1), "Int8": (-2**7, 2**7 - 1), "UInt8": (0, 2**8 - 1),
              "Int16": (-2**15, 2**15 - 1), "UInt16": (0, 2**16 - 1), "Int32": (-2**31, 2**31 - 1),
              "UInt32": (0, 2**32 - 1), "Int64": (-2**31, 2**31 - 1), "UInt64": (0, 2**31 - 1),
              "Enumeration": (-2**31, 2**31 - 1)}  # 64-bit types: written through a 32-bit buffer


def is_fmi3(md: Any) -> bool:
    """Whether fmpy's model description ``md`` is FMI 3.x."""
    return str(getattr(md, "fmiVersion", "") or "").startswith("3.")


def typed_value(v: Any, val: Any, what: str, label: str, err: Callable[[str], Exception]) -> Any:
    """``val`` converted for the FMI type of the variable ``v`` and checked against its range.

    Parameters
    ----------
    v
        fmpy's model variable (its ``type``, ``min``, ``max``, ``name``).
    val
        The value to write.
    what, label
        Where the value comes from (e.g. ``"mode 1 (0-based) maps to"``) and what the
        variable is (e.g. ``"fault variable"``), for the messages.
    err
        Makes the exception raised for a value the variable cannot take.

    Returns
    -------
    float or int
        The value for the variable's kind (:data:`FAULT_KINDS`; a Boolean as 0 or 1).
    """
    kind = FAULT_KINDS[v.type]
    if kind == "int":
        if isinstance(val, float) and not val.is_integer():
            raise err(f"{label} {v.name!r} is {v.type}; {what} non-integer {val!r}")
        val = int(val)
        lo, hi = INT_RANGES.get(v.type, (None, None))
        lo, hi = (int(v.min) if v.min is not None else lo), (int(v.max) if v.max is not None else hi)
        if (lo is not None and val < lo) or (hi is not None and val > hi):
            raise err(f"{label} {v.name!r}: {what} {val}, outside its range [{lo}, {hi}] ({v.type})")
        return val
    if kind == "bool":
        if val not in (0, 1):
            raise err(f"{label} {v.name!r} is Boolean; {what} {val!r}")
        return int(bool(val))
    val = float(val)
    low = float(v.min) if v.min is not None else -math.inf
    high = float(v.max) if v.max is not None else math.inf
    if not low <= val <= high:
        raise err(f"{label} {v.name!r}: {what} {val}, outside its declared range [{v.min}, {v.max}]")
    return val


@dataclass(frozen=True)
class SlaveCalls:
    """The FMI calls of one loaded slave (module docstring), each raising fmpy's
    ``FMICallException`` on a status above Warning.

    ``get_real``, ``set_real``, ``set_integer`` and ``set_boolean`` take ``(component,
    value references, count, values)`` (ctypes arrays); ``do_step`` takes ``(component,
    t, h)``; ``setup_experiment`` takes the tolerance (None: the FMU's default) and the
    start time; ``instantiate``, ``enter_initialization`` and ``free_instance`` act on the
    slave's current instance; ``last_successful_time`` raises where the FMU gives none.
    ``keep`` holds the ctypes callbacks the FMU calls, alive as long as these calls.
    ``raw`` (FMI 2.0 only, else ``None``): the unchecked ctypes functions ``fmi2GetReal``,
    ``fmi2SetReal`` and ``fmi2DoStep`` themselves, returning the status, for a loop that
    checks the status inline (:class:`~ftc_verify.simulation.loop_parts.StaticLoop`).
    """

    get_real: Callable[[Any, Any, int, Any], Any]
    set_real: Callable[[Any, Any, int, Any], Any]
    set_integer: Callable[[Any, Any, int, Any], Any]
    set_boolean: Callable[[Any, Any, int, Any], Any]
    do_step: Callable[[Any, float, float], Any]
    instantiate: Callable[[], None]
    setup_experiment: Callable[[float | None, float], None]
    enter_initialization: Callable[[], None]
    free_instance: Callable[[], None]
    last_successful_time: Callable[[], float]
    keep: Any = None
    raw: tuple[Any, Any, Any] | None = None


def _checked(fun: Any, name: str) -> Callable[..., int]:
    """The ctypes function ``fun`` raising fmpy's ``FMICallException`` above Warning."""
    from fmpy.fmi1 import FMICallException

    def call(*args: Any) -> int:
        status = fun(*args)
        if status > 1:
            raise FMICallException(function=name, status=status)
        return status

    return call


#: fmpy's modules that open an FMU (:func:`load_slave`, the model description's reader).
LOADER_MODULES = ("fmpy.fmi2", "fmpy.fmi3", "fmpy.model_description")


def preload() -> None:
    """Import :data:`LOADER_MODULES` now (a plant process waiting for its job,
    :mod:`ftc_verify.simulation.isolated`); one that fails to import is left to the code
    that needs it, which reports it as before."""
    import contextlib
    import importlib

    for name in LOADER_MODULES:
        with contextlib.suppress(Exception):
            importlib.import_module(name)


def load_slave(md: Any, unzip: str, model_identifier: str, instance_name: str,
               logger: Callable[..., None]) -> tuple[Any, SlaveCalls]:
    """The loaded (not yet instantiated) slave of the FMU extracted in ``unzip`` and its calls.

    Parameters
    ----------
    md
        fmpy's model description of the FMU (its version chooses the slave class).
    unzip
        The folder the FMU is extracted in.
    model_identifier, instance_name
        The co-simulation model identifier and the ``instanceName`` to instantiate with.
    logger
        Receives the FMU's messages: ``(env, instance, status, category, message)`` from
        FMI 2.0, ``(env, status, category, message)`` from FMI 3.0.

    Returns
    -------
    tuple
        ``(slave, calls)``: fmpy's ``FMU2Slave`` or ``FMU3Slave``, and its :class:`SlaveCalls`.
    """
    if is_fmi3(md):
        from fmpy.fmi3 import FMU3Slave

        slave = FMU3Slave(guid=md.guid, unzipDirectory=unzip, modelIdentifier=model_identifier,
                          instanceName=instance_name)
        return slave, _fmi3_calls(slave, md, logger)
    from fmpy.fmi2 import FMU2Slave

    slave = FMU2Slave(guid=md.guid, unzipDirectory=unzip, modelIdentifier=model_identifier,
                      instanceName=instance_name)
    return slave, _fmi2_calls(slave, logger)


def _fmi2_calls(slave: Any, logger: Callable[..., None]) -> SlaveCalls:
    import ctypes

    from fmpy import calloc, free
    from fmpy.fmi2 import (fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE, fmi2CallbackFunctions,
                           fmi2CallbackLoggerTYPE)

    cb = fmi2CallbackFunctions()
    cb.logger = fmi2CallbackLoggerTYPE(logger)
    cb.allocateMemory = ctypes.cast(calloc, fmi2CallbackAllocateMemoryTYPE)
    cb.freeMemory = ctypes.cast(free, fmi2CallbackFreeMemoryTYPE)
    cb.componentEnvironment = None
    f = slave._functions
    step = _checked(f["fmi2DoStep"], "fmi2DoStep")

    def do_step(c: Any, t: float, h: float) -> int:
        return step(c, t, h, 1)

    return SlaveCalls(
        get_real=_checked(f["fmi2GetReal"], "fmi2GetReal"), set_real=_checked(f["fmi2SetReal"], "fmi2SetReal"),
        set_integer=_checked(f["fmi2SetInteger"], "fmi2SetInteger"),
        set_boolean=_checked(f["fmi2SetBoolean"], "fmi2SetBoolean"), do_step=do_step,
        instantiate=lambda: slave.instantiate(callbacks=cb, loggingOn=True),
        setup_experiment=lambda tolerance, start: slave.setupExperiment(tolerance=tolerance, startTime=start),
        enter_initialization=lambda: slave.enterInitializationMode(),
        free_instance=lambda: slave.fmi2FreeInstance(slave.component),
        last_successful_time=lambda: slave.getRealStatus(2),  # fmi2LastSuccessfulTime = 2
        keep=cb, raw=(f["fmi2GetReal"], f["fmi2SetReal"], f["fmi2DoStep"]))


def _fmi3_calls(slave: Any, md: Any, logger: Callable[..., None]) -> SlaveCalls:
    import ctypes

    from fmpy import fmi3
    from fmpy.fmi1 import FMICallException

    f = slave._functions
    get64, set64 = _checked(f["fmi3GetFloat64"], "fmi3GetFloat64"), _checked(f["fmi3SetFloat64"], "fmi3SetFloat64")
    step = f["fmi3DoStep"]
    event, term, early, last = fmi3.fmi3Boolean(), fmi3.fmi3Boolean(), fmi3.fmi3Boolean(), fmi3.fmi3Float64(math.nan)
    outs = ctypes.byref(event), ctypes.byref(term), ctypes.byref(early), ctypes.byref(last)
    types = {v.valueReference: v.type for v in md.modelVariables}
    experiment: dict[str, Any] = {"tolerance": None, "start": 0.0}

    def do_step(c: Any, t: float, h: float) -> int:
        last.value = math.nan
        status = step(c, t, h, True, *outs)
        if status > 1:
            raise FMICallException(function="fmi3DoStep", status=status)
        if term.value:
            raise FMICallException(function="fmi3DoStep (the FMU set terminateSimulation)", status=2)
        return status

    def set_integer(c: Any, vr: Any, n: int, values: Any) -> None:
        """Each variable through the setter of its FMI 3.0 type."""
        groups: dict[str, list[tuple[int, int]]] = {}
        for ref, value in zip(list(vr)[:n], list(values)[:n]):
            kind = types.get(ref, "Int32")
            groups.setdefault("Int64" if kind == "Enumeration" else kind, []).append((ref, int(value)))
        for kind, pairs in groups.items():
            ctype = getattr(fmi3, f"fmi3{kind}")
            refs = (fmi3.fmi3ValueReference * len(pairs))(*[r for r, _ in pairs])
            vals = (ctype * len(pairs))(*[v for _, v in pairs])
            slave._call(f"fmi3Set{kind}", c, refs, len(pairs), vals, len(pairs))

    def set_boolean(c: Any, vr: Any, n: int, values: Any) -> None:
        vals = (fmi3.fmi3Boolean * max(n, 1))(*[bool(v) for v in list(values)[:n]])
        slave.fmi3SetBoolean(c, vr, n, vals, n)

    def setup_experiment(tolerance: float | None, start: float) -> None:
        experiment.update(tolerance=tolerance, start=float(start))

    def free_instance() -> None:
        slave.fmi3FreeInstance(slave.component)
        slave.component = None

    def last_successful_time() -> float:
        if not math.isfinite(last.value):
            raise ValueError("no lastSuccessfulTime")
        return float(last.value)

    return SlaveCalls(
        get_real=lambda c, vr, n, buf: get64(c, vr, n, buf, n), set_real=lambda c, vr, n, buf: set64(c, vr, n, buf, n),
        set_integer=set_integer, set_boolean=set_boolean, do_step=do_step,
        instantiate=lambda: slave.instantiate(loggingOn=True, logMessage=logger),
        setup_experiment=setup_experiment,
        enter_initialization=lambda: slave.enterInitializationMode(tolerance=experiment["tolerance"],
                                                                   startTime=experiment["start"]),
        free_instance=free_instance, last_successful_time=last_successful_time)
