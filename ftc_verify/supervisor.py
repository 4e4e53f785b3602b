r"""Co-simulation supervisor: the sampled-data FTC loop around an FMI 2.0 co-simulation FMU.

The FMU is the plant; the supervisor is the rest of the loop of the reference paper. On
each path of the joint (fault, FDI) chain (:class:`~ftc_verify.paths.ChainPath`) it walks
the communication grid :func:`~ftc_verify.paths.communication_grid` ``t_0 < ... < t_N``
(the multiples of ``step`` and the jump times) and at every grid point ``t_k``

1. writes the fault mode ``r`` into the FMU when it changed (fault times),
2. writes ``Delta1, Delta2`` (:func:`~ftc_verify.uncertainty.delta_segments`) when the
   chain segment changed,
3. switches the gain when the FDI indication ``l`` changed (FDI times),
4. reads the state ``x`` (and the outputs ``y``), computes ``u = K[l] x`` and writes
   ``u`` and ``w(t_k)`` (:func:`~ftc_verify.paths.disturbance`),
5. calls ``fmi2DoStep(t_k, t_{k+1} - t_k)``: ``u, w, Delta`` and the mode are held over the
   step (sample-and-hold; the steps vary because jump times are grid points).

At ``t_N`` it records ``x_N, y_N`` and ``u = K[l_last] x_N``, ``w(t_N)``. Each path starts
at ``x = x0`` (default 0) in the path's start mode. This is exactly the loop of the numpy
reference simulator (``ftc_verify.reference_sim``), so on equal paths and equal ``Delta``
draws the two backends agree to rounding.

FDI model: the supervisor only follows the sampled path. The paper's model (the fault
does not jump while the FDI lags) is the default of :class:`~ftc_verify.model.JointChain`;
the named variant in which the fault keeps jumping during a detection delay comes from
``JointChain(..., fault_during_delay=True)`` and its sampled paths, nothing else changes.

Which FMU variables play which role is declared by a :class:`FaultInjectionMap`;
:meth:`FaultInjectionMap.for_linear_jump_plant` gives it for the project's
``LinearJumpPlant`` FMU (:mod:`ftc_verify.fmu_build`), and any other FMI 2.0
co-simulation FMU works by naming its variables (e.g. a Real ``actuatorEffectiveness``
input taking 1.0 or 0.2 per mode).

Safety and errors: the archive is checked before anything is extracted (no member may
leave the extraction folder: absolute names, ``..``, drive letters and backslashes are
refused), the model description must be FMI 2.0 with a co-simulation interface and a
binary for this platform, and every variable of the map must exist with a usable type
and causality. The FMU is extracted into a :class:`tempfile.TemporaryDirectory` owned by
the :class:`Supervisor` (removed on :meth:`Supervisor.close`), loaded once and
instantiated once; paths reuse the instance through ``fmi2Reset``. Every ``fmi2*`` status
other than OK or Warning raises :class:`~ftc_verify.fmu_build.FMUError` naming the FMU
file, the call, the variables and the time, with the FMU's own log messages.

The logger callback is a plain ctypes callback kept alive by the supervisor until the
instance is freed (fmpy's ``addLoggerProxy`` is deliberately not used: it keeps the last
callbacks in a process-wide global). Without the proxy the message arrives unformatted;
the LinearJumpPlant formats its messages itself (``%`` doubled), which is undone here.
"""

from __future__ import annotations

import ctypes
import difflib
import math
import os
import tempfile
import zipfile
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Any
from xml.etree import ElementTree as ET

import numpy as np

from .errors import ValidationError
from .fmu_build import FMUError, fmu_dims
from .model import FTCSystem, as_matrix
from .paths import ChainPath, communication_grid
from .paths import disturbance as disturbance_fn
from .simulation import PathRecord, SimulationResult
from .uncertainty import DeltaSchedule, delta_segments, delta_shapes

__all__ = ["FMUError", "FaultInjectionMap", "Supervisor", "simulate_fmu"]

_STATUS = ("OK", "Warning", "Discard", "Error", "Fatal", "Pending")
_FAULT_TYPES = ("Real", "Integer", "Boolean", "Enumeration")


def _status_label(status: int) -> str:
    return _STATUS[status] if 0 <= status < len(_STATUS) else f"illegal status {status}"


def _names(value: Any, field_name: str) -> tuple[str, ...]:
    if value is None:
        return ()
    if isinstance(value, str):
        value = (value,)
    try:
        out = tuple(value)
    except TypeError:
        raise ValidationError(f"FaultInjectionMap.{field_name}: expected variable names, got {value!r}") from None
    for name in out:
        if not isinstance(name, str) or not name:
            raise ValidationError(
                f"FaultInjectionMap.{field_name}: variable names must be non-empty strings, got {name!r}"
            )
    if len(set(out)) != len(out):
        dup = sorted({n for n in out if out.count(n) > 1})
        raise ValidationError(f"FaultInjectionMap.{field_name}: duplicate names {dup}")
    return out


def _scalar(value: Any, where: str) -> float | int | bool:
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)) and math.isfinite(float(value)):
        return float(value)
    raise ValidationError(f"{where}: expected a finite number or bool, got {value!r}")


# ------------------------------------------------------------------------------------------
# The map
# ------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class FaultInjectionMap:
    """Which FMU variables carry what (declarative; names as in ``modelDescription.xml``).

    Parameters
    ----------
    fault
        Variable(s) carrying the fault mode: inputs or tunable parameters of type
        Integer, Enumeration, Boolean or Real.
    inputs
        The control inputs ``u`` (Real), in the order of the gains' rows.
    states
        What the controller reads, ``x`` (Real: states or a state estimate), in the order
        of the gains' columns.
    disturbances
        The disturbance inputs ``w`` (Real); every channel gets the same shape
        (:func:`ftc_verify.paths.disturbance`).
    outputs
        The outputs ``y`` (Real) recorded at every grid point.
    fault_values
        ``fault_values[k]`` is written when the true mode is ``k`` (0-based, the paths'
        index; the paper's mode ``k + 1``): a scalar when there is one fault variable,
        else one value per fault variable. Default: the 1-based mode number ``k + 1``
        into every fault variable (the LinearJumpPlant convention). Example: a Real
        ``actuatorEffectiveness`` with ``fault_values=(1.0, 0.2)``.
    initial_states
        Real parameters (or variables with ``initial`` exact/approx) set to ``x0`` in
        initialization mode; empty: the FMU's own initial state (``x0`` must be None).
    delta1, delta2
        Real inputs carrying ``Delta1`` and ``Delta2`` row-major
        (:mod:`ftc_verify.uncertainty`); empty: the FMU has no such channel.
    """

    fault: tuple[str, ...]
    inputs: tuple[str, ...]
    states: tuple[str, ...]
    disturbances: tuple[str, ...] = ()
    outputs: tuple[str, ...] = ()
    fault_values: tuple[tuple[float | int | bool, ...], ...] | None = None
    initial_states: tuple[str, ...] = ()
    delta1: tuple[str, ...] = ()
    delta2: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        for name in ("fault", "inputs", "states", "disturbances", "outputs", "initial_states", "delta1", "delta2"):
            object.__setattr__(self, name, _names(getattr(self, name), name))
        for name in ("fault", "inputs", "states"):
            if not getattr(self, name):
                raise ValidationError(f"FaultInjectionMap.{name}: at least one variable is needed")
        written = self.fault + self.inputs + self.disturbances + self.delta1 + self.delta2
        clash = sorted({n for n in written if written.count(n) > 1})
        if clash:
            raise ValidationError(f"FaultInjectionMap: variables {clash} are given more than one role to write")
        if self.fault_values is not None:
            vals = self.fault_values
            if isinstance(vals, (str, bytes, Mapping)) or not isinstance(vals, Sequence | np.ndarray):
                raise ValidationError(
                    "FaultInjectionMap.fault_values: expected a sequence indexed by the 0-based mode, "
                    f"got {vals!r}"
                )
            if len(vals) < 1:
                raise ValidationError("FaultInjectionMap.fault_values: empty")
            out = []
            for k, v in enumerate(vals):
                where = f"FaultInjectionMap.fault_values[{k}]"
                row = tuple(v) if isinstance(v, Sequence | np.ndarray) and not isinstance(v, str) else (v,)
                if len(row) != len(self.fault):
                    raise ValidationError(
                        f"{where}: expected {len(self.fault)} value(s), one per fault variable "
                        f"{list(self.fault)}, got {v!r}"
                    )
                out.append(tuple(_scalar(x, where) for x in row))
            object.__setattr__(self, "fault_values", tuple(out))

    def values_for(self, mode: int) -> tuple[float | int | bool, ...]:
        """Values written into :attr:`fault` in the 0-based true mode ``mode``."""
        if self.fault_values is None:
            return (mode + 1,) * len(self.fault)
        if not 0 <= mode < len(self.fault_values):
            raise ValidationError(
                f"FaultInjectionMap.fault_values: no value for mode {mode} (0-based); "
                f"{len(self.fault_values)} mode(s) are mapped"
            )
        return self.fault_values[mode]

    @classmethod
    def for_linear_jump_plant(cls, system: FTCSystem) -> "FaultInjectionMap":
        """The map of the ``LinearJumpPlant`` FMU of ``system`` (:func:`ftc_verify.fmu_build.build_fmu`):
        Integer ``mode`` (1-based), ``u[k]``, ``w[k]``, ``x[k]``, ``y[k]``, ``x0[k]`` and the
        ``Delta1[i,j]``, ``Delta2[i,j]`` inputs its uncertainty channels imply."""
        d = fmu_dims(system)
        return cls(
            fault=("mode",),
            inputs=tuple(f"u[{k}]" for k in range(1, d.nu + 1)),
            states=tuple(f"x[{k}]" for k in range(1, d.n + 1)),
            disturbances=tuple(f"w[{k}]" for k in range(1, d.nw + 1)),
            outputs=tuple(f"y[{k}]" for k in range(1, d.ny + 1)),
            initial_states=tuple(f"x0[{k}]" for k in range(1, d.n + 1)),
            delta1=tuple(f"Delta1[{i},{j}]" for i in range(1, d.q1 + 1) for j in range(1, d.p1 + 1)),
            delta2=tuple(f"Delta2[{i},{j}]" for i in range(1, d.q2 + 1) for j in range(1, d.p2 + 1)),
        )


# ------------------------------------------------------------------------------------------
# Opening and checking the FMU
# ------------------------------------------------------------------------------------------


def _unsafe_member(name: str) -> str | None:
    """Why the archive member ``name`` could land outside the extraction folder (or None)."""
    if "\\" in name:
        return "contains a backslash"
    if name.startswith("/"):
        return "is an absolute path"
    if ":" in name:
        return "contains a drive or device letter (':')"
    if "\0" in name:
        return "contains a NUL character"
    if ".." in PurePosixPath(name).parts:
        return "contains a '..' component"
    root = os.path.join(os.sep, "extract-root")
    if os.path.commonpath([root, os.path.normpath(os.path.join(root, name))]) != root:
        return "resolves outside the extraction folder"
    return None


def _c_buffer(ctype: Any, values: Sequence[Any]) -> Any:
    return (ctype * len(values))(*values)


class _Group:
    """Value references of a list of variables of one FMI type, with a ctypes buffer."""

    __slots__ = ("names", "vr", "buf", "n")

    def __init__(self, names: Sequence[str], vrs: Sequence[int], ctype: Any) -> None:
        from fmpy.fmi2 import fmi2ValueReference

        self.names = tuple(names)
        self.n = len(vrs)
        self.vr = _c_buffer(fmi2ValueReference, list(vrs))
        self.buf = (ctype * max(self.n, 1))()


class Supervisor:
    """Sampled-data FTC loop around one FMI 2.0 co-simulation FMU (a context manager).

    Parameters
    ----------
    fmu
        Path of the ``.fmu`` archive.
    mapping
        The :class:`FaultInjectionMap`; default: :meth:`FaultInjectionMap.for_linear_jump_plant`
        of ``system``.
    system
        The :class:`~ftc_verify.model.FTCSystem` the FMU simulates; needed for ``Delta``
        (shapes and draws) and to check the gains; optional for other FMUs.
    instance_name
        ``instanceName`` passed to ``fmi2Instantiate``.

    The archive is checked, extracted and loaded, and one instance is created, when the
    supervisor is constructed; :meth:`run` reuses it for every path (``fmi2Reset``).
    :attr:`stats` counts library loads, instantiations, resets, paths and steps.
    """

    def __init__(
        self,
        fmu: str | os.PathLike[str],
        mapping: FaultInjectionMap | None = None,
        *,
        system: FTCSystem | None = None,
        instance_name: str = "ftc-verify-supervisor",
    ) -> None:
        if mapping is None:
            if system is None:
                raise ValidationError("Supervisor: give a FaultInjectionMap, or the system of a LinearJumpPlant FMU")
            mapping = FaultInjectionMap.for_linear_jump_plant(system)
        if not isinstance(mapping, FaultInjectionMap):
            raise ValidationError(f"Supervisor: mapping must be a FaultInjectionMap, got {type(mapping).__name__}")
        if system is not None and not isinstance(system, FTCSystem):
            raise ValidationError(f"Supervisor: system must be an FTCSystem, got {type(system).__name__}")
        self.path = Path(fmu)
        self.mapping = mapping
        self.system = system
        self.instance_name = str(instance_name)
        self.stats = {"library_loads": 0, "instantiations": 0, "resets": 0, "paths": 0, "steps": 0}
        self.messages: deque[tuple[str, str, str]] = deque(maxlen=200)  # (status, category, text)
        self.log_counts: dict[str, int] = {}  # messages logged by the FMU, per status
        self._tmp: tempfile.TemporaryDirectory[str] | None = None
        self._slave: Any = None
        self._component_live = False
        self._dirty = False  # the instance has been initialised since the last reset
        self._dead = False  # fmi2Fatal seen: no further calls into the FMU
        self._closed = False
        self._callbacks: Any = None
        self._logger_ref: Any = None
        try:
            self._open()
        except BaseException:
            self.close()
            raise

    # -------------------------------------------------------------------- context manager
    def __enter__(self) -> "Supervisor":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def slave(self) -> Any:
        """The one :class:`fmpy.fmi2.FMU2Slave` of this supervisor (None once closed)."""
        return self._slave

    @property
    def closed(self) -> bool:
        return self._closed

    @property
    def extraction_dir(self) -> Path | None:
        """The temporary folder the FMU is extracted into (None once closed)."""
        return None if self._tmp is None else Path(self._tmp.name)

    # -------------------------------------------------------------------- opening
    def _err(self, what: str) -> FMUError:
        return FMUError(f"{self.path}: {what}")

    def _open(self) -> None:
        import fmpy
        from fmpy import read_model_description

        p = self.path
        if not p.is_file():
            raise self._err("no such FMU file")
        if not zipfile.is_zipfile(p):
            raise self._err("not an FMU (not a zip archive)")
        try:
            with zipfile.ZipFile(p) as zf:
                infos = zf.infolist()
                for info in infos:
                    why = _unsafe_member(info.filename)
                    if why is not None:
                        raise self._err(
                            f"archive member {info.filename!r} {why}: it would be extracted outside the "
                            "extraction folder (zip-slip); refusing to extract the FMU"
                        )
                names = {info.filename for info in infos}
                if "modelDescription.xml" not in names:
                    raise self._err("modelDescription.xml is missing from the archive (not an FMU)")
                xml = zf.read("modelDescription.xml")
        except FMUError:
            raise
        except (zipfile.BadZipFile, OSError, RuntimeError) as exc:
            raise self._err(f"cannot read the archive: {exc}") from None

        try:
            root = ET.fromstring(xml)
        except ET.ParseError as exc:
            raise self._err(f"modelDescription.xml is not well-formed XML: {exc}") from None
        if root.tag != "fmiModelDescription":
            raise self._err(f"modelDescription.xml: root element is <{root.tag}>, not <fmiModelDescription>")
        version = root.get("fmiVersion")
        if version != "2.0":
            raise self._err(
                f"modelDescription.xml declares fmiVersion {version!r}; the supervisor needs an "
                "FMI 2.0 co-simulation FMU (fmiVersion \"2.0\")"
            )
        try:
            md = read_model_description(str(p), validate=True)
        except Exception as exc:  # fmpy raises plain Exceptions with the schema problems
            raise self._err(f"invalid modelDescription.xml: {exc}") from None
        cs = md.coSimulation
        if cs is None:
            raise self._err("modelDescription.xml has no <CoSimulation> element (Model Exchange only?)")
        self.model_description = md
        self.model_identifier = cs.modelIdentifier
        self.can_vary_step = bool(cs.canHandleVariableCommunicationStepSize)
        lib = f"binaries/{fmpy.platform}/{cs.modelIdentifier}{fmpy.sharedLibraryExtension}"
        if lib not in names:
            found = sorted({n.split("/")[1] for n in names if n.startswith("binaries/") and n.count("/") >= 2})
            hint = f"it has binaries for {found}" if found else "it has no binaries"
            if any(n.startswith("sources/") for n in names):
                hint += " (C sources are included: rebuild it for this platform)"
            raise self._err(f"no binary for this platform: {lib} is missing; {hint}")

        self._resolve_variables(md)

        self._tmp = tempfile.TemporaryDirectory(prefix="ftc-verify-fmu-")
        unzip = self._tmp.name
        try:
            with zipfile.ZipFile(p) as zf:
                zf.extractall(unzip)
        except (zipfile.BadZipFile, OSError, RuntimeError) as exc:
            raise self._err(f"cannot extract the archive: {exc}") from None
        self._load(md, unzip)

    def _resolve_variables(self, md: Any) -> None:
        by_name = {v.name: v for v in md.modelVariables}
        m = self.mapping

        def lookup(name: str, role: str) -> Any:
            v = by_name.get(name)
            if v is None:
                close = difflib.get_close_matches(name, list(by_name), n=3)
                hint = f"; did you mean {close}?" if close else ""
                raise self._err(
                    f"variable {name!r} ({role} in the fault-injection map) is not declared in "
                    f"modelDescription.xml{hint}"
                )
            return v

        def settable(v: Any, role: str, types: Sequence[str]) -> Any:
            if v.type not in types:
                raise self._err(f"variable {v.name!r} ({role}) has type {v.type}; expected {' or '.join(types)}")
            if v.causality == "input":
                return v
            if v.causality == "parameter" and v.variability == "tunable":
                return v
            raise self._err(
                f"variable {v.name!r} ({role}) has causality {v.causality!r}"
                + (f" and variability {v.variability!r}" if v.causality == "parameter" else "")
                + "; it must be an input or a tunable parameter to be set during the simulation"
            )

        def readable(v: Any, role: str) -> Any:
            if v.type != "Real":
                raise self._err(f"variable {v.name!r} ({role}) has type {v.type}; expected Real")
            return v

        fault = [settable(lookup(n, "fault mode"), "fault mode", _FAULT_TYPES) for n in m.fault]
        inputs = [settable(lookup(n, "control input u"), "control input u", ("Real",)) for n in m.inputs]
        dist = [settable(lookup(n, "disturbance input w"), "disturbance input w", ("Real",)) for n in m.disturbances]
        delta = [settable(lookup(n, "Delta input"), "Delta input", ("Real",)) for n in m.delta1 + m.delta2]
        states = [readable(lookup(n, "state x"), "state x") for n in m.states]
        outputs = [readable(lookup(n, "output y"), "output y") for n in m.outputs]
        init = []
        for n in m.initial_states:
            v = readable(lookup(n, "initial state x0"), "initial state x0")
            if not (v.causality in ("parameter", "input") or v.initial in ("exact", "approx")):
                raise self._err(
                    f"variable {v.name!r} (initial state x0) has causality {v.causality!r} and initial "
                    f"{v.initial!r}; it cannot be set before initialisation"
                )
            init.append(v)

        from fmpy.fmi2 import fmi2Boolean, fmi2Integer, fmi2Real

        self._fault_vars = fault
        self._fault_kind = {"Real": "real", "Integer": "int", "Enumeration": "int", "Boolean": "bool"}
        self._fault_groups = {
            kind: _Group([v.name for v in fault if self._fault_kind[v.type] == kind],
                         [v.valueReference for v in fault if self._fault_kind[v.type] == kind], ctype)
            for kind, ctype in (("real", fmi2Real), ("int", fmi2Integer), ("bool", fmi2Boolean))
        }
        self._fault_cache: dict[int, list[tuple[str, Any]]] = {}
        self._nu, self._nw, self._n, self._ny = len(inputs), len(dist), len(states), len(outputs)
        self._uw = _Group([v.name for v in inputs + dist], [v.valueReference for v in inputs + dist], fmi2Real)
        self._delta = _Group([v.name for v in delta], [v.valueReference for v in delta], fmi2Real)
        self._init = _Group([v.name for v in init], [v.valueReference for v in init], fmi2Real)
        # Outputs y that depend directly on u or w (declared, or undeclared = all inputs)
        # are read after u, w are written; otherwise x and y are read in one call.
        uw_vrs = {v.valueReference for v in inputs + dist}
        deps = {u.variable.name: u.dependencies for u in md.outputs if u.variable is not None}
        self._feedthrough = any(
            deps.get(v.name, None) is None and v.causality == "output"
            or any(d.valueReference in uw_vrs for d in (deps.get(v.name) or ()))
            for v in outputs
        )
        if self._feedthrough:
            self._x = _Group([v.name for v in states], [v.valueReference for v in states], fmi2Real)
            self._y = _Group([v.name for v in outputs], [v.valueReference for v in outputs], fmi2Real)
        else:
            self._x = _Group([v.name for v in states + outputs],
                             [v.valueReference for v in states + outputs], fmi2Real)
            self._y = _Group([], [], fmi2Real)

    def _load(self, md: Any, unzip: str) -> None:
        from fmpy.fmi2 import (
            FMU2Slave,
            fmi2CallbackAllocateMemoryTYPE,
            fmi2CallbackFreeMemoryTYPE,
            fmi2CallbackFunctions,
            fmi2CallbackLoggerTYPE,
        )
        from fmpy import calloc, free

        cwd = os.getcwd()
        try:
            slave = FMU2Slave(
                guid=md.guid, unzipDirectory=unzip, modelIdentifier=self.model_identifier,
                instanceName=self.instance_name,
            )
        except Exception as exc:  # missing library, unloadable binary, missing fmi2 functions
            lib = f"binaries/<platform>/{self.model_identifier}"
            raise self._err(f"cannot load the FMU binary ({lib}): {exc}") from None
        finally:
            if os.getcwd() != cwd:  # fmpy does not restore the directory when loading fails
                os.chdir(cwd)
        self._slave = slave
        self.stats["library_loads"] += 1

        messages, counts = self.messages, self.log_counts

        def logger(env: Any, instance: bytes | None, status: int, category: bytes | None,
                   message: bytes | None) -> None:
            try:
                text = (message or b"").decode("utf-8", "replace").replace("%%", "%")
                label = _status_label(status)
                counts[label] = counts.get(label, 0) + 1
                messages.append((label, (category or b"").decode("utf-8", "replace"), text))
            except Exception:  # never let an exception cross the C boundary
                pass

        cb = fmi2CallbackFunctions()
        self._logger_ref = fmi2CallbackLoggerTYPE(logger)
        cb.logger = self._logger_ref
        cb.allocateMemory = ctypes.cast(calloc, fmi2CallbackAllocateMemoryTYPE)
        cb.freeMemory = ctypes.cast(free, fmi2CallbackFreeMemoryTYPE)
        cb.componentEnvironment = None
        self._callbacks = cb
        try:
            slave.instantiate(callbacks=cb, loggingOn=False)
        except Exception:
            raise self._err(f"fmi2Instantiate failed{self._said()}") from None
        self._component_live = True
        self.stats["instantiations"] += 1

    # -------------------------------------------------------------------- closing
    def close(self) -> None:
        """Terminate and free the instance, unload the library, remove the extracted files."""
        if self._closed:
            return
        self._closed = True
        slave, self._slave = self._slave, None
        if slave is not None:
            try:
                if self._component_live and not self._dead:
                    try:
                        if self._dirty:
                            slave.terminate()
                    except Exception:
                        pass
                    slave.fmi2FreeInstance(slave.component)
                self._component_live = False
            finally:
                try:
                    slave.freeLibrary()
                except Exception:
                    pass
        self._callbacks = None
        self._logger_ref = None
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None

    # -------------------------------------------------------------------- errors
    def _said(self, count: int = 4) -> str:
        bad = [f"[{s}] {t}" for s, _, t in self.messages if s != "OK"]
        return ("; the FMU reported: " + " | ".join(bad[-count:])) if bad else ""

    def _call_error(self, exc: Any, when: str, names: Sequence[str]) -> FMUError:
        status = getattr(exc, "status", None)
        function = getattr(exc, "function", "an fmi2 function")
        if status == 4:  # fmi2Fatal: the instance must not be called any more
            self._dead = True
        label = _status_label(status) if status is not None else "an error"
        var = f" ({', '.join(names)})" if names else ""
        return self._err(f"{function}{var} returned {label} {when}{self._said()}")

    def _check_open(self) -> None:
        if self._closed or self._slave is None:
            raise self._err("the supervisor is closed")
        if self._dead:
            raise self._err("the FMU returned fmi2Fatal earlier; the instance cannot be used any more")

    # -------------------------------------------------------------------- per-path setup
    def _fault_writes(self, mode: int) -> list[tuple[str, Any]]:
        """``[(kind, ctypes values)]`` for the 0-based true mode (validated once per mode)."""
        cached = self._fault_cache.get(mode)
        if cached is not None:
            return cached
        values = self.mapping.values_for(mode)
        per_kind: dict[str, list[Any]] = {"real": [], "int": [], "bool": []}
        for v, val in zip(self._fault_vars, values):
            kind = self._fault_kind[v.type]
            if kind == "int":
                if isinstance(val, float) and not val.is_integer():
                    raise self._err(f"fault variable {v.name!r} is {v.type}; mode {mode} maps to non-integer {val!r}")
                val = int(val)
                lo = int(v.min) if v.min is not None else None
                hi = int(v.max) if v.max is not None else None
                if (lo is not None and val < lo) or (hi is not None and val > hi):
                    raise self._err(
                        f"fault variable {v.name!r}: mode {mode} (0-based) maps to {val}, outside its declared "
                        f"range [{v.min}, {v.max}]"
                    )
            elif kind == "bool":
                if val not in (0, 1):
                    raise self._err(f"fault variable {v.name!r} is Boolean; mode {mode} maps to {val!r}")
                val = int(bool(val))
            else:
                val = float(val)
                lo = float(v.min) if v.min is not None else -math.inf
                hi = float(v.max) if v.max is not None else math.inf
                if not lo <= val <= hi:
                    raise self._err(
                        f"fault variable {v.name!r}: mode {mode} (0-based) maps to {val}, outside its declared "
                        f"range [{v.min}, {v.max}]"
                    )
            per_kind[kind].append(val)
        out = []
        for kind, vals in per_kind.items():
            if vals:
                grp = self._fault_groups[kind]
                out.append((kind, _c_buffer(grp.buf._type_, vals)))
        self._fault_cache[mode] = out
        return out

    def _set_fault(self, mode: int, when: str) -> None:
        from fmpy.fmi1 import FMICallException

        s = self._slave
        for kind, vals in self._fault_writes(mode):
            grp = self._fault_groups[kind]
            try:
                if kind == "real":
                    s.fmi2SetReal(s.component, grp.vr, grp.n, vals)
                elif kind == "int":
                    s.fmi2SetInteger(s.component, grp.vr, grp.n, vals)
                else:
                    s.fmi2SetBoolean(s.component, grp.vr, grp.n, vals)
            except FMICallException as exc:
                shown = [f"{n} = {v}" for n, v in zip(grp.names, list(vals))]
                raise self._call_error(exc, f"{when} (setting fault mode {mode}, 0-based)", shown) from None

    def _set_delta(self, values: Any, when: str) -> None:
        if values is None or self._delta.n == 0:
            return
        from fmpy.fmi1 import FMICallException

        s = self._slave
        try:
            s.fmi2SetReal(s.component, self._delta.vr, self._delta.n, values)
        except FMICallException as exc:
            raise self._call_error(exc, f"{when} (setting Delta)", self._delta.names) from None

    def _start_path(self, x0: Any, mode0: int, delta0: Any) -> None:
        from fmpy.fmi1 import FMICallException

        s = self._slave
        stage, names = "fmi2Reset", ()
        try:
            if self._dirty:
                s.reset()
                self.stats["resets"] += 1
            self._dirty = True
            stage = "fmi2SetupExperiment"
            s.setupExperiment(startTime=0.0)
            stage = "fmi2EnterInitializationMode"
            s.enterInitializationMode()
            if self._init.n:
                stage, names = "fmi2SetReal", self._init.names
                s.fmi2SetReal(s.component, self._init.vr, self._init.n, x0)
            self._set_fault(mode0, "in initialization mode")
            self._set_delta(delta0, "in initialization mode")
            stage, names = "fmi2ExitInitializationMode", ()
            s.exitInitializationMode()
        except FMICallException as exc:
            raise self._call_error(exc, f"in {stage} while initialising a path at t = 0", names) from None

    # -------------------------------------------------------------------- the loop
    def _check_gains(self, gains: Any) -> tuple[list[np.ndarray], bool, int | None]:
        n, nu = self._n, self._nu
        if isinstance(gains, np.ndarray) and gains.ndim == 2:
            gains = [gains]
        try:
            gl = list(gains)
        except TypeError:
            raise ValidationError(
                f"gains: expected a sequence of {nu} x {n} matrices, got {type(gains).__name__}"
            ) from None
        m = self.system.m if self.system is not None else (
            len(self.mapping.fault_values) if self.mapping.fault_values is not None else None)
        if m is not None and len(gl) not in (m, m * m):
            raise ValidationError(
                f"gains: {len(gl)} gains given, the plant has {m} modes "
                f"(expected {m}, or {m * m} for full-information gains)"
            )
        if not gl:
            raise ValidationError("gains: no gain given")
        out = []
        for k, K in enumerate(gl, start=1):
            Km = as_matrix(K, f"gains: gain[{k}].K")
            if Km.shape != (nu, n):
                raise ValidationError(
                    f"gains: gain[{k}].K: expected shape {(nu, n)} ({nu} inputs x {n} states of the map), "
                    f"got {Km.shape}"
                )
            out.append(np.ascontiguousarray(Km, dtype=np.float64))
        full = m is not None and len(gl) == m * m and m * m != m
        return out, full, m

    def run(
        self,
        paths: ChainPath | Sequence[ChainPath],
        gains: Sequence[Any],
        *,
        step: float,
        disturbance: str = "paper",
        delta: DeltaSchedule | str | None = None,
        x0: Any = None,
        rng: np.random.Generator | None = None,
        seed: int | None = None,
    ) -> SimulationResult:
        """Co-simulate every path; returns a :class:`~ftc_verify.simulation.SimulationResult`
        with ``backend="fmu"``.

        ``gains``: one ``nu x n`` matrix per FDI mode (``u = K[l] x``), or ``m * m``
        full-information gains ``K[r * m + l]``. ``disturbance``: a kind of
        :data:`ftc_verify.paths.DISTURBANCES`. ``delta``: a
        :class:`~ftc_verify.uncertainty.DeltaSchedule` or its kind (None: zero); the
        values come from :func:`~ftc_verify.uncertainty.delta_segments` per path in
        order, drawing from ``rng`` (default ``numpy.random.default_rng(seed)``).
        ``x0``: the initial state (default 0; needs :attr:`FaultInjectionMap.initial_states`).
        """
        self._check_open()
        if isinstance(paths, ChainPath):
            paths = [paths]
        paths = list(paths)
        if not paths or not all(isinstance(p, ChainPath) for p in paths):
            raise ValidationError("paths: expected a non-empty sequence of ChainPath")
        K, full_info, m = self._check_gains(gains)
        if not (isinstance(step, (int, float)) and math.isfinite(step) and step > 0):
            raise ValidationError(f"step: must be a positive finite number, got {step!r}")
        step = float(step)
        wfun = disturbance_fn(disturbance, self._nw)

        # x0
        if x0 is None:
            x0_arr = np.zeros(self._init.n)
        else:
            if not self._init.n:
                raise ValidationError(
                    "x0: the fault-injection map names no initial_states, so the initial state cannot be set"
                )
            x0_arr = np.asarray(x0, dtype=float).reshape(-1)
            if x0_arr.size != self._init.n or not np.all(np.isfinite(x0_arr)):
                raise ValidationError(f"x0: expected {self._init.n} finite numbers, got {x0!r}")
        from fmpy.fmi2 import fmi2Real

        x0_c = _c_buffer(fmi2Real, x0_arr.tolist())

        # Delta
        if delta is None:
            schedule = DeltaSchedule("zero")
        elif isinstance(delta, str):
            schedule = DeltaSchedule(delta)
        elif isinstance(delta, DeltaSchedule):
            schedule = delta
        else:
            raise ValidationError(f"delta: expected a DeltaSchedule, a kind or None, got {type(delta).__name__}")
        use_delta = self.system is not None
        if not use_delta and (schedule.kind != "zero"):
            raise ValidationError(f"delta: kind {schedule.kind!r} needs the system (Supervisor(..., system=...))")
        if use_delta:
            s1, s2 = delta_shapes(self.system)
            for shape, names, label in ((s1, self.mapping.delta1, "delta1"), (s2, self.mapping.delta2, "delta2")):
                size = 0 if shape is None else shape[0] * shape[1]
                if names and len(names) != size:
                    raise ValidationError(
                        f"FaultInjectionMap.{label}: {len(names)} names, but the system's "
                        f"{'Delta1' if label == 'delta1' else 'Delta2'} has {size} entries ({shape})"
                    )
                if size and not names and schedule.kind != "zero":
                    raise ValidationError(
                        f"delta: kind {schedule.kind!r} needs FaultInjectionMap.{label} (the FMU's "
                        f"{'Delta1' if label == 'delta1' else 'Delta2'} inputs)"
                    )
        if rng is None:
            rng = np.random.default_rng(seed)

        # checks over all paths before any simulation
        for i, p in enumerate(paths):
            top_true, top_fdi = int(np.max(p.true)), int(np.max(p.fdi))
            if m is not None and max(top_true, top_fdi) >= m:
                raise ValidationError(
                    f"paths[{i}]: mode {max(top_true, top_fdi)} (0-based) but the plant has {m} modes"
                )
            if not full_info and top_fdi >= len(K):
                raise ValidationError(f"paths[{i}]: FDI mode {top_fdi} (0-based) but only {len(K)} gains")
            for mode in np.unique(p.true):
                self._fault_writes(int(mode))

        warnings_before = self.log_counts.get("Warning", 0)
        records = []
        for i, p in enumerate(paths):
            segs = None
            if use_delta:
                segs = delta_segments(self.system, p, schedule, rng)
            records.append(self._run_path(i, p, K, full_info, m, step, wfun, x0_c, segs))
        options: dict[str, Any] = {
            "fmu": str(self.path),
            "delta": schedule.kind,
            "x0": x0_arr.tolist(),
            "gains": "full-information" if full_info else "fdi",
            "fmu_warnings": self.log_counts.get("Warning", 0) - warnings_before,
        }
        if self.system is not None:
            options["fault_during_delay"] = bool(self.system.chain.fault_during_delay)
        return SimulationResult(
            backend="fmu",
            seed=seed,
            step=step,
            horizon=float(max(p.horizon for p in paths)),
            disturbance=disturbance,
            records=tuple(records),
            options=options,
        )

    def _delta_values(self, seg: tuple[Any, Any]) -> Any:
        if self._delta.n == 0:
            return None
        from fmpy.fmi2 import fmi2Real

        parts = []
        if self.mapping.delta1:
            parts.append(np.asarray(seg[0], dtype=float).ravel())
        if self.mapping.delta2:
            parts.append(np.asarray(seg[1], dtype=float).ravel())
        return _c_buffer(fmi2Real, np.concatenate(parts).tolist())

    def _run_path(self, index: int, path: ChainPath, K: list[np.ndarray], full_info: bool, m: int | None,
                  step: float, wfun: Any, x0_c: Any, segs: Any) -> PathRecord:
        from fmpy.fmi1 import FMICallException

        t, true, fdi = communication_grid(path, step)
        N = len(t) - 1
        h = np.diff(t)
        if not self.can_vary_step and N > 1 and np.ptp(h) > 1e-9 * step:
            raise self._err(
                "the FMU does not declare canHandleVariableCommunicationStepSize, but the grid of "
                f"paths[{index}] has steps from {h.min():.6g} to {h.max():.6g} (jump times are grid points)"
            )
        seg = np.searchsorted(path.times, t[:-1], side="right") - 1
        W = wfun(t)
        n, nu, nw, ny = self._n, self._nu, self._nw, self._ny
        nuw = nu + nw
        feed = self._feedthrough

        delta_c = None
        if segs is not None:
            delta_c = [None] * len(segs)
            for j in set(seg.tolist()):
                delta_c[j] = self._delta_values(segs[j])

        # events: grid points (k >= 1) where the true mode, the FDI mode or the segment changes
        change = np.zeros(N, dtype=bool)
        if N > 1:
            change[1:] = (true[1:] != true[:-1]) | (fdi[1:] != fdi[:-1]) | (seg[1:] != seg[:-1])
        events = np.flatnonzero(change).tolist()
        events.append(-1)

        tl = t.tolist()
        hl = h.tolist()
        true_l = true.tolist()
        fdi_l = fdi.tolist()
        seg_l = seg.tolist()

        self._start_path(x0_c, true_l[0], None if delta_c is None else delta_c[seg_l[0]])

        s = self._slave
        c = s.component
        gr, sr, ds = s.fmi2GetReal, s.fmi2SetReal, s.fmi2DoStep
        xg, yg, uwg = self._x, self._y, self._uw
        vr_x, buf_x, nx_read = xg.vr, xg.buf, xg.n
        vr_y, buf_y = yg.vr, yg.buf
        vr_uw, buf_uw = uwg.vr, uwg.buf
        np_xr = np.frombuffer(buf_x, dtype=np.float64, count=nx_read)
        np_x = np_xr[:n]
        np_y = np.frombuffer(buf_y, dtype=np.float64, count=ny) if feed else None
        np_uw = np.frombuffer(buf_uw, dtype=np.float64, count=nuw)
        np_u = np_uw[:nu]
        np_w = np_uw[nu:]
        XR = np.empty((N + 1, nx_read))
        Y = np.empty((N + 1, ny)) if feed else None
        U = np.empty((N + 1, nu))
        dot = np.dot

        def gain(r: int, l: int) -> np.ndarray:
            return K[r * m + l] if full_info else K[l]

        r, l, sg = true_l[0], fdi_l[0], seg_l[0]
        Kl = gain(r, l)
        k = 0
        nxt = events[0]
        ev = 0
        stage = ""
        try:
            for k in range(N):
                if k == nxt:
                    when = f"at t = {tl[k]!r} (paths[{index}], grid point {k})"
                    if true_l[k] != r:
                        r = true_l[k]
                        self._set_fault(r, when)
                    if seg_l[k] != sg:
                        sg = seg_l[k]
                        if delta_c is not None:
                            self._set_delta(delta_c[sg], when)
                    l = fdi_l[k]
                    Kl = gain(r, l)
                    ev += 1
                    nxt = events[ev]
                stage = "x"
                gr(c, vr_x, nx_read, buf_x)
                XR[k] = np_xr
                dot(Kl, np_x, out=np_u)
                if nw:
                    np_w[:] = W[k]
                stage = "uw"
                sr(c, vr_uw, nuw, buf_uw)
                U[k] = np_u
                if feed:
                    stage = "y"
                    gr(c, vr_y, ny, buf_y)
                    Y[k] = np_y
                stage = "step"
                ds(c, tl[k], hl[k], 1)
            # the last grid point: record x_N, y_N and u = K[l_last] x_N, w(t_N)
            k = N
            stage = "x"
            gr(c, vr_x, nx_read, buf_x)
            XR[N] = np_xr
            dot(Kl, np_x, out=np_u)
            if nw:
                np_w[:] = W[N]
            stage = "uw"
            sr(c, vr_uw, nuw, buf_uw)
            U[N] = np_u
            if feed:
                stage = "y"
                gr(c, vr_y, ny, buf_y)
                Y[N] = np_y
        except FMICallException as exc:
            if stage == "step":
                when = (f"at t = {tl[k]!r} with step size {hl[k]!r} (paths[{index}], grid point {k} of {N}, "
                        f"true mode {true_l[k]}, FDI mode {fdi_l[k]}, 0-based)")
                names: Sequence[str] = ()
            else:
                when = f"at t = {tl[k]!r} (paths[{index}], grid point {k} of {N})"
                names = {"x": xg.names, "y": yg.names, "uw": [
                    f"{name} = {v!r}" for name, v in zip(uwg.names, np_uw.tolist())]}[stage]
            raise self._call_error(exc, when, names) from None
        finally:
            self.stats["steps"] += k
        self.stats["paths"] += 1

        X = XR[:, :n]
        if not feed:
            Y = XR[:, n:]
        return PathRecord(
            path=path, t=t, true=true, fdi=fdi,
            x=np.ascontiguousarray(X), u=U, w=W, y=np.ascontiguousarray(Y),
        )


# ------------------------------------------------------------------------------------------
# Convenience
# ------------------------------------------------------------------------------------------


def simulate_fmu(
    system: FTCSystem,
    gains: Sequence[Any],
    paths: ChainPath | Sequence[ChainPath],
    *,
    step: float,
    disturbance: str = "paper",
    delta: DeltaSchedule | str | None = None,
    x0: Any = None,
    rng: np.random.Generator | None = None,
    seed: int | None = None,
) -> SimulationResult:
    """Build the ``LinearJumpPlant`` FMU of ``system`` (:func:`ftc_verify.fmu_build.build_fmu`,
    compiled once and cached) and co-simulate ``paths`` with a :class:`Supervisor`; the
    arguments are those of :meth:`Supervisor.run`."""
    from .fmu_build import build_fmu

    if not isinstance(system, FTCSystem):
        raise ValidationError(f"simulate_fmu: expected an FTCSystem, got {type(system).__name__}")
    fmu = build_fmu(system)
    with Supervisor(fmu, FaultInjectionMap.for_linear_jump_plant(system), system=system) as sup:
        return sup.run(paths, gains, step=step, disturbance=disturbance, delta=delta, x0=x0, rng=rng, seed=seed)
