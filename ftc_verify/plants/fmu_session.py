"""One opened FMI 2.0 or 3.0 co-simulation FMU: checks, variables, FMI calls, logging and cleanup.

This module implements :class:`FMUSession`, the FMU side of the co-simulation supervisor
(:mod:`ftc_verify.simulation.supervisor`):

* the archive is checked before anything is extracted (no member may leave the
  extraction folder: absolute names, ``..``, drive letters and backslashes are refused),
  the model description must be FMI 2.0 or 3.0 with a co-simulation interface and a binary
  for this platform (an FMI 3.0 FMU is called through :mod:`ftc_verify.plants.fmi3`);
* every variable of the :class:`~ftc_verify.plants.fault_map.FaultInjectionMap` must
  exist with a usable type and causality
  (:func:`~ftc_verify.plants.fault_map.resolve_variables`);
* the FMU is extracted into a :class:`tempfile.TemporaryDirectory` owned by the session
  (removed on :meth:`FMUSession.close`), loaded once and instantiated once; paths reuse
  the instance through ``fmi2Reset`` (:meth:`FMUSession.start_path`);
* every ``fmi2*`` status other than OK or Warning raises
  :class:`~ftc_verify.errors.FMUError` naming the FMU file, the call, the variables and the
  time, with the FMU's own log messages (:meth:`FMUSession.call_error`).

Call names in errors are those of the FMU's version (``fmi3DoStep``...). A signal handler's exception (Ctrl-C, the CLI's SIGTERM) raised inside the logger
callback, where ctypes would drop it, is kept as :attr:`FMUSession.pending` and raised
after the FMI call returns (:meth:`FMUSession.raise_pending`).

The logger callback is a plain ctypes callback kept alive by the session until the
instance is freed (fmpy's ``addLoggerProxy`` is deliberately not used: it keeps the last
callbacks in a process-wide global). Without the proxy the message arrives unformatted;
the LinearJumpPlant formats its messages itself (``%`` doubled), which is undone here.
"""

from __future__ import annotations

import math
import os
import tempfile
import zipfile
from collections import deque
from collections.abc import Callable, Sequence
from pathlib import Path, PurePosixPath
from typing import Any
from xml.etree import ElementTree as ET

import numpy as np

from ..errors import FMUError
from .fault_map import FaultInjectionMap, ResolvedVariables, resolve_variables
from .fmi3 import CALL_NAMES, FAULT_KINDS as _FAULT_KIND, INT_RANGES, is_fmi3, load_slave

__all__ = ["FMUError", "FMUSession", "VarGroup", "c_buffer"]

_STATUS = ("OK", "Warning", "Discard", "Error", "Fatal", "Pending")


def _status_label(status: int) -> str:
    return _STATUS[status] if 0 <= status < len(_STATUS) else f"illegal status {status}"


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


def c_buffer(ctype: Any, values: Sequence[Any]) -> Any:
    """A ctypes array of ``ctype`` holding ``values``."""
    return (ctype * len(values))(*values)


class VarGroup:
    """Value references of a list of variables of one FMI type, with a ctypes buffer."""

    __slots__ = ("names", "vr", "buf", "n")

    def __init__(self, variables: Sequence[Any], ctype: Any = None) -> None:
        from fmpy.fmi2 import fmi2Real, fmi2ValueReference

        self.names = tuple(v.name for v in variables)
        self.n = len(variables)
        self.vr = c_buffer(fmi2ValueReference, [v.valueReference for v in variables])
        self.buf = ((ctype or fmi2Real) * max(self.n, 1))()


# ------------------------------------------------------------------------------------------
# The session
# ------------------------------------------------------------------------------------------


class FMUSession:
    """One checked, extracted, loaded and instantiated FMU (module docstring).

    Parameters
    ----------
    fmu
        Path of the ``.fmu`` archive.
    mapping
        The :class:`~ftc_verify.plants.fault_map.FaultInjectionMap` whose variables
        are resolved (and checked) when the session opens.
    instance_name
        ``instanceName`` passed to ``fmi2Instantiate`` (``fmi3InstantiateCoSimulation``).
    tolerance
        Relative tolerance passed to ``fmi2SetupExperiment`` (``fmi3EnterInitializationMode``;
        None: the FMU's default).
    log
        Called with ``(status, category, message)`` for every message the FMU logs
        (``loggingOn`` is always true; the messages are also kept for error messages).
    workdir
        Where the FMU's temporary extraction folder is made (default: the system's).

    :attr:`stats` counts library loads, instantiations (and re-instantiations after a
    failed ``fmi2Reset``), resets, paths and steps;
    :attr:`messages` keeps the FMU's last 200 log messages of the current path, :attr:`log_counts` counts them
    per status. On any error while opening, everything opened so far is released.
    """

    def __init__(self, fmu: str | os.PathLike[str], mapping: FaultInjectionMap, *,
                 instance_name: str = "ftc-verify-supervisor", tolerance: float | None = None,
                 log: Callable[[str, str, str], None] | None = None,
                 workdir: str | os.PathLike[str] | None = None) -> None:
        self.path = Path(fmu)
        self.workdir, self.pending = None if workdir is None else str(workdir), None  # see the module docstring
        self.mapping = mapping
        self.fmi_version, self.calls = "2.0", CALL_NAMES["2.0"]  # set from the model description
        self.instance_name = str(instance_name)
        if tolerance is not None and not (isinstance(tolerance, (int, float)) and 0 < tolerance < 1):
            raise self.err(f"tolerance: expected a number in (0, 1), got {tolerance!r}")
        self.tolerance = None if tolerance is None else float(tolerance)
        self.log = log
        self.stats = {"library_loads": 0, "instantiations": 0, "resets": 0, "reinstantiations": 0,
                      "paths": 0, "steps": 0}
        self.messages: deque[tuple[str, str, str]] = deque(maxlen=200)  # (status, category, text)
        self.log_counts: dict[str, int] = {}  # messages logged by the FMU, per status
        self._tmp: tempfile.TemporaryDirectory[str] | None = None
        self.slave: Any = None
        self._component_live = False
        self._dirty = False  # the instance has been initialised since the last reset
        self.dead = False  # fmi2Fatal seen: no further calls into the FMU
        self.closed = False
        self._callbacks: Any = None
        self._logger_ref: Any = None
        self._fault_cache: dict[int, list[tuple[str, Any, Any]]] = {}
        self._read_groups: dict[bool, tuple[VarGroup, VarGroup]] = {}
        try:
            self._open()
        except BaseException:
            self.close()
            raise

    def __enter__(self) -> "FMUSession":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def extraction_dir(self) -> Path | None:
        """The temporary folder the FMU is extracted into (None once closed)."""
        return None if self._tmp is None else Path(self._tmp.name)

    # -------------------------------------------------------------------- opening
    def err(self, what: str) -> FMUError:
        """An :class:`FMUError` naming the FMU file."""
        return FMUError(f"{self.path}: {what}")

    def _read_archive(self) -> tuple[set[str], bytes]:
        p = self.path
        if not p.is_file():
            raise self.err("no such FMU file")
        if not zipfile.is_zipfile(p):
            raise self.err("not an FMU (not a zip archive)")
        try:
            with zipfile.ZipFile(p) as zf:
                infos = zf.infolist()
                for info in infos:
                    why = _unsafe_member(info.filename)
                    if why is not None:
                        raise self.err(
                            f"archive member {info.filename!r} {why}: it would be extracted outside the "
                            "extraction folder (zip-slip); refusing to extract the FMU"
                        )
                names = {info.filename for info in infos}
                if "modelDescription.xml" not in names:
                    raise self.err("modelDescription.xml is missing from the archive (not an FMU)")
                return names, zf.read("modelDescription.xml")
        except FMUError:
            raise
        except (zipfile.BadZipFile, OSError, RuntimeError) as exc:
            raise self.err(f"cannot read the archive: {exc}") from None

    def _read_model_description(self, xml: bytes) -> Any:
        from fmpy import read_model_description

        try:
            root = ET.fromstring(xml)
        except ET.ParseError as exc:
            raise self.err(f"modelDescription.xml is not well-formed XML: {exc}") from None
        if root.tag != "fmiModelDescription":
            raise self.err(f"modelDescription.xml: root element is <{root.tag}>, not <fmiModelDescription>")
        version = root.get("fmiVersion")
        if version != "2.0" and not str(version).startswith("3."):
            raise self.err(
                f"modelDescription.xml declares fmiVersion {version!r}; the supervisor needs an "
                "FMI 2.0 or 3.0 co-simulation FMU (fmiVersion \"2.0\" or \"3.0\")"
            )
        if version != "2.0" and (root.get("guid") is not None or root.find("ModelVariables/ScalarVariable") is not None):
            raise self.err(f"modelDescription.xml declares fmiVersion {version!r} but is laid out as FMI 2.0 (guid, "
                           "ScalarVariable): declare fmiVersion \"2.0\", or export the model as FMI 3.0")
        try:
            md = read_model_description(str(self.path), validate=True)
        except Exception as exc:  # fmpy raises plain Exceptions with the schema problems
            raise self.err(f"invalid modelDescription.xml: {exc}") from None
        if md.coSimulation is None:
            raise self.err("modelDescription.xml has no <CoSimulation> element (Model Exchange only?)")
        self.fmi_version = "3.0" if is_fmi3(md) else "2.0"
        self.calls = CALL_NAMES[self.fmi_version]
        if self.fmi_version == "3.0":  # fmpy reads FMI 3.0's plural attribute into nothing
            cs = root.find("CoSimulation")
            md.coSimulation.providesDirectionalDerivative = cs.get("providesDirectionalDerivatives") in ("true", "1")
        return md

    def _open(self) -> None:
        import fmpy

        names, xml = self._read_archive()
        md = self._read_model_description(xml)
        cs = md.coSimulation
        self.model_description = md
        self.model_identifier = cs.modelIdentifier
        self.can_vary_step = bool(cs.canHandleVariableCommunicationStepSize)
        platform = fmpy.platform_tuple if self.fmi_version == "3.0" else fmpy.platform
        lib = f"binaries/{platform}/{cs.modelIdentifier}{fmpy.sharedLibraryExtension}"
        if lib not in names:
            found = sorted({n.split("/")[1] for n in names if n.startswith("binaries/") and n.count("/") >= 2})
            hint = f"it has binaries for {found}" if found else "it has no binaries"
            if any(n.startswith("sources/") for n in names):
                hint += " (C sources are included: rebuild it for this platform)"
            raise self.err(f"no binary for this platform: {lib} is missing; {hint}")

        self._set_variables(resolve_variables(md, self.mapping, self.err))

        self._tmp = tempfile.TemporaryDirectory(prefix="ftc-verify-fmu-", dir=self.workdir)
        try:
            with zipfile.ZipFile(self.path) as zf:
                zf.extractall(self._tmp.name)
        except (zipfile.BadZipFile, OSError, RuntimeError) as exc:
            raise self.err(f"cannot extract the archive: {exc}") from None
        self._load(md, self._tmp.name)

    def _set_variables(self, rv: ResolvedVariables) -> None:
        self.variables = rv
        self.n, self.nu, self.nw = len(rv.states), len(rv.inputs), len(rv.disturbances)
        self.ny, self.nym = len(rv.outputs), len(rv.measured)
        self.feedthrough = rv.feedthrough
        self.uw = VarGroup(rv.inputs + rv.disturbances)
        self.delta = VarGroup(rv.delta)
        self.init = VarGroup(rv.initial)
        self._param_writes = self._typed_writes(rv.parameters, [v for _, v in self.mapping.parameters],
                                                "[parameters] sets it to", "parameter")

    def read_groups(self, measured: bool) -> tuple[VarGroup, VarGroup]:
        """``(before, after)``: the variables read at a grid point before ``u, w`` are
        written (``x``, then ``y_m`` when ``measured``, then ``y`` unless it has
        feedthrough) and after (``y`` with feedthrough, else nothing)."""
        groups = self._read_groups.get(measured)
        if groups is None:
            rv = self.variables
            before = rv.states + (rv.measured if measured else ())
            if self.feedthrough:
                groups = (VarGroup(before), VarGroup(rv.outputs))
            else:
                groups = (VarGroup(before + rv.outputs), VarGroup(()))
            self._read_groups[measured] = groups
        return groups

    def _logger(self) -> Callable[..., None]:
        def logger(*args: Any) -> None:  # FMI 2.0: (env, instance, status, category, message); 3.0: no instance
            try:
                self._log_message(args[-3], args[-2], args[-1], escaped=len(args) == 5)
            except Exception:  # never let an exception cross the C boundary
                pass
            except BaseException as exc:  # a signal's exception: re-raised after the FMI call
                if self.pending is None:
                    self.pending = exc

        return logger

    def _log_message(self, status: int, category: bytes | None, message: bytes | None, escaped: bool = True) -> None:
        """Keep (and forward to :attr:`log`) one message of the FMU's logger callback
        (``escaped``: an FMI 2.0 message, a printf format with ``%`` doubled)."""
        text = (message or b"").decode("utf-8", "replace")
        text = text.replace("%%", "%") if escaped else text
        label = _status_label(status)
        self.log_counts[label] = self.log_counts.get(label, 0) + 1
        cat = (category or b"").decode("utf-8", "replace")
        self.messages.append((label, cat, text))
        if self.log is not None:
            self.log(label, cat, text)

    def raise_pending(self) -> None:
        """Raise :attr:`pending` (module docstring); call it between FMI calls."""
        exc, self.pending = self.pending, None
        if exc is not None:
            raise exc

    def _load(self, md: Any, unzip: str) -> None:
        cwd = os.getcwd()
        try:  # FMI 3.0: an FMU3Adapter answering the FMI 2.0 calls (plants/fmi3.py)
            self._logger_ref = self._logger()
            self.slave, self._callbacks = load_slave(md, unzip, self.model_identifier, self.instance_name,
                                                     self._logger_ref)
        except Exception as exc:  # missing library, unloadable binary, missing fmi2/fmi3 functions
            lib = f"binaries/<platform>/{self.model_identifier}"
            raise self.err(f"cannot load the FMU binary ({lib}): {exc}") from None
        finally:
            if os.getcwd() != cwd:  # fmpy does not restore the directory when loading fails
                os.chdir(cwd)
        self.stats["library_loads"] += 1
        self._instantiate()

    def _instantiate(self) -> None:
        try:
            self.slave.instantiate(callbacks=self._callbacks, loggingOn=True)
        except Exception:
            raise self.err(f"{self.calls['instantiate']} failed{self.said()}") from None
        self._component_live = True
        self._dirty = False
        self.stats["instantiations"] += 1

    def _reinstantiate(self) -> None:
        """Free the instance after a failed ``fmi2Reset`` and create a fresh one."""
        s = self.slave
        self._component_live = False
        try:
            s.fmi2FreeInstance(s.component)
        except Exception:
            pass
        self._instantiate()
        self.stats["reinstantiations"] += 1

    # -------------------------------------------------------------------- closing
    def close(self) -> None:
        """Terminate and free the instance, unload the library, remove the extracted files."""
        if self.closed:
            return
        self.closed = True
        slave, self.slave = self.slave, None
        if slave is not None:
            try:
                if self._component_live and not self.dead:
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
        self._callbacks = self._logger_ref = None
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None

    # -------------------------------------------------------------------- errors
    def said(self, count: int = 4) -> str:
        """The FMU's last non-OK log messages, as a suffix for error messages."""
        bad = [f"[{s}] {t}" for s, _, t in self.messages if s != "OK"]
        return ("; the FMU reported: " + " | ".join(bad[-count:])) if bad else ""

    def call_error(self, exc: Any, when: str, names: Sequence[str]) -> FMUError:
        """The :class:`FMUError` for a failed FMI call (fmpy's ``FMICallException``)."""
        status = getattr(exc, "status", None)
        function = getattr(exc, "function", f"an {self.calls['prefix']} function")
        if status == 4:  # fmi2Fatal / fmi3Fatal: the instance must not be called any more
            self.dead = True
        label = _status_label(status) if status is not None else "an error"
        var = f" ({', '.join(names)})" if names else ""
        return self.err(f"{function}{var} returned {label} {when}{self.said()}")

    def check_open(self) -> None:
        """Raise unless the instance can be called."""
        if self.closed or self.slave is None:
            raise self.err("the supervisor is closed")
        if self.dead:
            raise self.err(f"the FMU returned {self.calls['fatal']} earlier; the instance cannot be used any more")

    # -------------------------------------------------------------------- writing
    def _typed_value(self, v: Any, val: Any, what: str, label: str) -> Any:
        """``val`` converted for the FMI type of ``v`` and checked against its range;
        ``what`` says where the value comes from (e.g. "mode 1 (0-based) maps to")."""
        kind = _FAULT_KIND[v.type]
        if kind == "int":
            if isinstance(val, float) and not val.is_integer():
                raise self.err(f"{label} {v.name!r} is {v.type}; {what} non-integer {val!r}")
            val = int(val)
            lo, hi = INT_RANGES.get(v.type, (None, None))
            lo, hi = (int(v.min) if v.min is not None else lo), (int(v.max) if v.max is not None else hi)
            if (lo is not None and val < lo) or (hi is not None and val > hi):
                raise self.err(f"{label} {v.name!r}: {what} {val}, outside its range [{lo}, {hi}] ({v.type})")
            return val
        if kind == "bool":
            if val not in (0, 1):
                raise self.err(f"{label} {v.name!r} is Boolean; {what} {val!r}")
            return int(bool(val))
        val = float(val)
        lo = float(v.min) if v.min is not None else -math.inf
        hi = float(v.max) if v.max is not None else math.inf
        if not lo <= val <= hi:
            raise self.err(f"{label} {v.name!r}: {what} {val}, outside its declared range [{v.min}, {v.max}]")
        return val

    def _typed_writes(self, variables: Sequence[Any], values: Sequence[Any], what: str,
                      label: str = "variable") -> list[tuple[str, Any, Any]]:
        """``[(kind, VarGroup, ctypes values)]`` writing ``values`` into ``variables``."""
        from fmpy.fmi2 import fmi2Boolean, fmi2Integer, fmi2Real

        out = []
        for kind, ctype in (("real", fmi2Real), ("int", fmi2Integer), ("bool", fmi2Boolean)):
            pairs = [(v, self._typed_value(v, val, what, label)) for v, val in zip(variables, values)
                     if _FAULT_KIND[v.type] == kind]
            if pairs:
                out.append((kind, VarGroup([v for v, _ in pairs], ctype), c_buffer(ctype, [x for _, x in pairs])))
        return out

    def _write(self, writes: list[tuple[str, Any, Any]], when: str) -> None:
        from fmpy.fmi1 import FMICallException

        s = self.slave
        for kind, grp, vals in writes:
            setter = {"real": s.fmi2SetReal, "int": s.fmi2SetInteger, "bool": s.fmi2SetBoolean}[kind]
            try:
                setter(s.component, grp.vr, grp.n, vals)
            except FMICallException as exc:
                shown = [f"{n} = {v}" for n, v in zip(grp.names, list(vals))]
                raise self.call_error(exc, when, shown) from None

    def fault_writes(self, mode: int) -> list[tuple[str, Any, Any]]:
        """The typed writes of the 0-based true mode's fault values (validated once per mode)."""
        cached = self._fault_cache.get(mode)
        if cached is None:
            what = f"fault mode {mode} (0-based) maps to"
            cached = self._typed_writes(self.variables.fault, self.mapping.values_for(mode), what, "fault variable")
            self._fault_cache[mode] = cached
        return cached

    def set_fault(self, mode: int, when: str) -> None:
        """Write the 0-based true mode ``mode`` into the fault variables."""
        self._write(self.fault_writes(mode), f"{when} (setting fault mode {mode}, 0-based)")

    def delta_values(self, seg: tuple[Any, Any]) -> Any:
        """The ctypes values of ``(Delta1, Delta2)`` for the map's Delta inputs (None: none)."""
        if self.delta.n == 0:
            return None
        from fmpy.fmi2 import fmi2Real

        parts = []
        if self.mapping.delta1:
            parts.append(np.asarray(seg[0], dtype=float).ravel())
        if self.mapping.delta2:
            parts.append(np.asarray(seg[1], dtype=float).ravel())
        return c_buffer(fmi2Real, np.concatenate(parts).tolist())

    def set_delta(self, values: Any, when: str) -> None:
        """Write :meth:`delta_values` into the FMU (nothing for None)."""
        if values is None or self.delta.n == 0:
            return
        from fmpy.fmi1 import FMICallException

        s = self.slave
        try:
            s.fmi2SetReal(s.component, self.delta.vr, self.delta.n, values)
        except FMICallException as exc:
            raise self.call_error(exc, f"{when} (setting Delta)", self.delta.names) from None

    def start_path(self, x0: Any, mode0: int, delta0: Any) -> None:
        """Reset (unless fresh), set up, and initialise the instance at ``t = 0`` with the
        initial state ``x0`` (ctypes), the 0-based true mode and the first Delta values."""
        from fmpy.fmi1 import FMICallException

        self.messages.clear()  # errors of this path quote this path's messages only
        if self._dirty:
            try:
                self.slave.reset()
                self.stats["resets"] += 1
            except FMICallException:  # an FMU that cannot reset gets a fresh instance
                self._reinstantiate()
        s, calls = self.slave, self.calls
        stage, names = calls["setup"], ()
        try:
            self._dirty = True
            s.setupExperiment(tolerance=self.tolerance, startTime=0.0)
            stage = calls["enter"]
            s.enterInitializationMode()
            self._write(self._param_writes, "in initialization mode (setting [parameters])")
            if self.init.n:
                stage, names = calls["set_real"], self.init.names
                s.fmi2SetReal(s.component, self.init.vr, self.init.n, x0)
            self.set_fault(mode0, "in initialization mode")
            self.set_delta(delta0, "in initialization mode")
            stage, names = calls["exit"], ()
            s.exitInitializationMode()
        except FMICallException as exc:
            raise self.call_error(exc, f"in {stage} while initialising a path at t = 0", names) from None
        finally:
            self.raise_pending()

    def last_successful_time(self) -> float | None:
        """``fmi2GetRealStatus(fmi2LastSuccessfulTime)``, or None where the FMU does not answer."""
        try:
            return float(self.slave.getRealStatus(2))  # fmi2LastSuccessfulTime = 2
        except Exception:  # fmpy raises on a non-OK status; not every FMU implements the call
            return None

    def check_advanced(self, t_end: float, where: str) -> None:
        """Raise when ``fmi2LastSuccessfulTime`` lags behind the end ``t_end`` of the last step."""
        last = self.last_successful_time()
        if last is not None and last < t_end - 1e-9 * max(1.0, abs(t_end)):
            raise self.err(f"{where}: after the last {self.calls['step']} to t = {t_end!r} the FMU reports "
                           f"{self.calls['last_time']} = {last!r}: it did not advance as asked (does it ignore "
                           "variable communication steps?)")

    def probe_outputs(self, x: np.ndarray, uw: np.ndarray, delta0: Any) -> tuple[np.ndarray, np.ndarray]:
        """``(y_m, y)`` read at ``t = 0`` after initialising at the state ``x`` (through the
        initial-state variables) in the first fault mode with inputs and disturbances ``uw``."""
        from fmpy.fmi1 import FMICallException
        from fmpy.fmi2 import fmi2Real

        if not self.init.n:
            raise self.err(
                "the map has an operating point but no initial_states, so paths cannot start at it; name the "
                "variables that set the initial state (or the states, if their start values can be set)"
            )
        self.start_path(c_buffer(fmi2Real, np.asarray(x, dtype=float).tolist()), 0, delta0)
        s = self.slave
        out = VarGroup(self.variables.measured + self.variables.outputs)
        try:
            s.fmi2SetReal(s.component, self.uw.vr, self.uw.n, c_buffer(fmi2Real, np.asarray(uw, dtype=float).tolist()))
            s.fmi2GetReal(s.component, out.vr, out.n, out.buf)
        except FMICallException as exc:
            raise self.call_error(exc, "at the operating point (t = 0, first fault mode)", out.names) from None
        vals = np.array(list(out.buf)[:out.n], dtype=float)
        return vals[:self.nym], vals[self.nym:]
