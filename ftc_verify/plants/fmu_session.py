"""One opened FMI 2.0 or 3.0 co-simulation FMU: checks, variables, FMI calls, logging and cleanup.

This module implements :class:`FMUSession`, the FMU side of the co-simulation supervisor
(:mod:`ftc_verify.simulation.supervisor`):

* the archive is checked before anything is extracted (no member may leave the
  extraction folder; :mod:`ftc_verify.plants.fmu_archive`), the model description must be
  FMI 2.0 or 3.0 with a co-simulation interface and a binary for this platform;
* every variable of the :class:`~ftc_verify.plants.fault_map.FaultInjectionMap` must
  exist with a usable type and causality
  (:func:`~ftc_verify.plants.fault_map.resolve_variables`);
* the FMU is extracted into a :class:`tempfile.TemporaryDirectory` owned by the session
  (removed on :meth:`FMUSession.close`), loaded once and instantiated once; paths reuse
  the instance through ``fmi2Reset`` (:meth:`FMUSession.start_path`);
* the variables are read, written and the FMU stepped with :meth:`FMUSession.read`,
  :meth:`FMUSession.write` and :meth:`FMUSession.step`, each the call of the FMU's version
  (``fmi2GetReal`` or ``fmi3GetFloat64``...: :class:`~ftc_verify.plants.fmi_calls.SlaveCalls`);
  a status other than OK or Warning raises :class:`FMICallError`, which
  :meth:`FMUSession.call_error` turns into the :class:`~ftc_verify.errors.FMUError` naming
  the FMU file, the call, the variables and the time, with the FMU's own log messages.

Call names in errors are those of the FMU's version (``fmi3DoStep``...). A signal handler's exception (Ctrl-C, the CLI's SIGTERM) raised inside the logger
callback, where ctypes would drop it, is kept as :attr:`FMUSession.pending` and raised
after the FMI call returns (:meth:`FMUSession.raise_pending`).

The logger callback is a plain ctypes callback kept alive by the session until the
instance is freed (fmpy's ``addLoggerProxy`` is deliberately not used: it keeps the last
callbacks in a process-wide global). Without the proxy the message arrives unformatted;
the LinearJumpPlant formats its messages itself (``%`` doubled), which is undone here.
"""

from __future__ import annotations

import ctypes
import os
import tempfile
import zipfile
from collections import deque
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import FMUError
from .fault_map import FaultInjectionMap, ResolvedVariables, resolve_variables
from .fmi_calls import CALL_NAMES, FAULT_KINDS, SlaveCalls, load_slave, typed_value
from .fmu_archive import read_archive, read_model_description, require_binary

__all__ = ["FMUError", "FMICallError", "FMUSession", "VarGroup", "c_buffer"]

_STATUS = ("OK", "Warning", "Discard", "Error", "Fatal", "Pending")


def _status_label(status: int) -> str:
    return _STATUS[status] if 0 <= status < len(_STATUS) else f"illegal status {status}"


def c_buffer(ctype: Any, values: Sequence[Any]) -> Any:
    """A ctypes array of ``ctype`` holding ``values``."""
    return (ctype * len(values))(*values)


class VarGroup:
    """Value references of a list of variables of one kind (``"real"``, ``"int"`` or
    ``"bool"``, :data:`~ftc_verify.plants.fmi_calls.FAULT_KINDS`), with a ctypes buffer."""

    __slots__ = ("buf", "ctype", "kind", "n", "names", "vr")

    def __init__(self, variables: Sequence[Any], kind: str = "real") -> None:
        self.names = tuple(v.name for v in variables)
        self.n = len(variables)
        self.kind = kind
        self.ctype = ctypes.c_double if kind == "real" else ctypes.c_int  # fmi2Real; fmi2Integer, fmi2Boolean
        self.vr = c_buffer(ctypes.c_uint, [v.valueReference for v in variables])  # fmi2ValueReference
        self.buf = (self.ctype * max(self.n, 1))()


class FMICallError(FMUError):
    """An FMI call of an :class:`FMUSession` returned a status other than OK or Warning.

    Attributes
    ----------
    function : str
        The FMI function, named as in the FMU's version (``fmi2DoStep``, ``fmi3GetFloat64``...).
    status : int
        Its status (2 Discard, 3 Error, 4 Fatal).
    """

    def __init__(self, message: str, function: str, status: int) -> None:
        super().__init__(message)
        self.function, self.status = function, status

    def __reduce__(self) -> tuple[Any, ...]:  # picklable across processes
        return (FMICallError, (str(self), self.function, self.status))


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

    Notes
    -----
    ``stats`` counts library loads, instantiations (and re-instantiations after a
    failed ``fmi2Reset``), resets, paths and steps;
    ``messages`` keeps the FMU's last 200 log messages of the current path, ``log_counts`` counts them
    per status. On any error while opening, everything opened so far is released.
    """

    def __init__(self, fmu: str | os.PathLike[str], mapping: FaultInjectionMap, *,
                 instance_name: str = "ftc-verify-supervisor", tolerance: float | None = None,
                 log: Callable[[str, str, str], None] | None = None,
                 workdir: str | os.PathLike[str] | None = None) -> None:
        self.path = Path(fmu)
        self.workdir = None if workdir is None else str(workdir)
        self.pending: BaseException | None = None  # see the module docstring
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
        from fmpy.fmi1 import FMICallException

        self._call_exception = FMICallException  # what the calls raise above Warning
        self._calls: SlaveCalls | None = None
        self._setters: dict[str, Callable[..., Any]] = {}  # per VarGroup kind
        self._component: Any = None  # the instance the calls of read, write and step go to
        self._logger_ref: Any = None
        self._fault_cache: dict[int, list[tuple[VarGroup, Any]]] = {}
        self._read_groups: dict[bool, tuple[VarGroup, VarGroup]] = {}
        try:
            self._open()
        except BaseException:
            self.close()
            raise

    def __enter__(self) -> FMUSession:
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

    def _open(self) -> None:
        names, xml = read_archive(self.path, self.err)
        md, self.fmi_version = read_model_description(self.path, xml, self.err)
        self.calls = CALL_NAMES[self.fmi_version]
        cs = md.coSimulation
        self.model_description = md
        self.model_identifier = cs.modelIdentifier
        self.can_vary_step = bool(cs.canHandleVariableCommunicationStepSize)
        require_binary(names, cs.modelIdentifier, self.fmi_version, self.err)
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
        """Raise ``pending`` (module docstring); call it between FMI calls."""
        exc, self.pending = self.pending, None
        if exc is not None:
            raise exc

    def _load(self, md: Any, unzip: str) -> None:
        cwd = os.getcwd()
        try:
            self._logger_ref = self._logger()
            self.slave, calls = load_slave(md, unzip, self.model_identifier, self.instance_name, self._logger_ref)
        except Exception as exc:  # missing library, unloadable binary, missing fmi2/fmi3 functions
            lib = f"binaries/<platform>/{self.model_identifier}"
            raise self.err(f"cannot load the FMU binary ({lib}): {exc}") from None
        finally:
            if os.getcwd() != cwd:  # fmpy does not restore the directory when loading fails
                os.chdir(cwd)
        self._calls = calls
        self._setters = {"real": calls.set_real, "int": calls.set_integer, "bool": calls.set_boolean}
        self.stats["library_loads"] += 1
        self._instantiate()

    def _instantiate(self) -> None:
        try:
            self._calls.instantiate()  # type: ignore[union-attr]
        except Exception:
            raise self.err(f"{self.calls['instantiate']} failed{self.said()}") from None
        self._component = self.slave.component
        self._component_live = True
        self._dirty = False
        self.stats["instantiations"] += 1

    def _reinstantiate(self) -> None:
        """Free the instance after a failed ``fmi2Reset`` and create a fresh one."""
        self._component_live = False
        try:
            self._calls.free_instance()  # type: ignore[union-attr]
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
                    self._calls.free_instance()  # type: ignore[union-attr]
                self._component_live = False
            finally:
                try:
                    slave.freeLibrary()
                except Exception:
                    pass
        self._calls = self._component = self._logger_ref = None
        self._setters = {}
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None

    # -------------------------------------------------------------------- errors
    def said(self, count: int = 4) -> str:
        """The FMU's last non-OK log messages, as a suffix for error messages."""
        bad = [f"[{s}] {t}" for s, _, t in self.messages if s != "OK"]
        return ("; the FMU reported: " + " | ".join(bad[-count:])) if bad else ""

    def call_error(self, exc: Any, when: str, names: Sequence[str]) -> FMUError:
        """The :class:`FMUError` for a failed FMI call (an :class:`FMICallError`, or
        fmpy's ``FMICallException``) made ``when`` on the variables ``names``."""
        status = getattr(exc, "status", None)
        function = getattr(exc, "function", f"an {self.calls['prefix']} function")
        if status == 4:  # fmi2Fatal / fmi3Fatal: the instance must not be called any more
            self.dead = True
        label = _status_label(status) if status is not None else "an error"
        var = f" ({', '.join(names)})" if names else ""
        return self.err(f"{function}{var} returned {label}{' ' + when if when else ''}{self.said()}")

    def _failed_call(self, exc: Any, names: Sequence[str]) -> FMICallError:
        """The :class:`FMICallError` of fmpy's ``FMICallException`` ``exc`` on the variables ``names``."""
        error = self.call_error(exc, "", names)
        return FMICallError(str(error), exc.function, exc.status)

    def failed(self, function: str, status: int, names: Sequence[str]) -> FMICallError:
        """The :class:`FMICallError` :meth:`read`/:meth:`write`/:meth:`step` raise when ``function`` returns ``status``."""
        return self._failed_call(self._call_exception(function=function, status=status), names)

    def raw_calls(self) -> tuple[Any, Any, Any, Any] | None:
        """``(fmi2GetReal, fmi2SetReal, fmi2DoStep, component)``, the unchecked ctypes calls of an
        FMI 2.0 FMU and its instance (new after a failed reset: ask after :meth:`start_path`;
        FMI 3.0: ``None``); the caller raises :meth:`failed` above Warning, as :meth:`step` does."""
        raw = None if self._calls is None else self._calls.raw
        return None if raw is None else (*raw, self._component)

    def check_open(self) -> None:
        """Raise unless the instance can be called."""
        if self.closed or self.slave is None:
            raise self.err("the supervisor is closed")
        if self.dead:
            raise self.err(f"the FMU returned {self.calls['fatal']} earlier; the instance cannot be used any more")

    # -------------------------------------------------------------------- writing
    def _typed_writes(self, variables: Sequence[Any], values: Sequence[Any], what: str,
                      label: str = "variable") -> list[tuple[VarGroup, Any]]:
        """``[(VarGroup, ctypes values)]`` writing ``values`` into ``variables``, one group per kind."""
        out = []
        for kind in ("real", "int", "bool"):
            pairs = [(v, typed_value(v, val, what, label, self.err)) for v, val in zip(variables, values)
                     if FAULT_KINDS[v.type] == kind]
            if pairs:
                grp = VarGroup([v for v, _ in pairs], kind)
                out.append((grp, c_buffer(grp.ctype, [x for _, x in pairs])))
        return out

    def _write(self, writes: list[tuple[VarGroup, Any]], when: str) -> None:
        for grp, vals in writes:
            try:
                self.write(grp, vals)
            except FMICallError as exc:
                shown = [f"{n} = {v}" for n, v in zip(grp.names, list(vals))]
                raise self.call_error(exc, when, shown) from None

    def fault_writes(self, mode: int) -> list[tuple[VarGroup, Any]]:
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

    def delta_values(self, seg: Sequence[Any]) -> Any:
        """The ctypes values of ``(Delta1, Delta2)`` for the map's Delta inputs (None: none)."""
        if self.delta.n == 0:
            return None
        parts = []
        if self.mapping.delta1:
            parts.append(np.asarray(seg[0], dtype=float).ravel())
        if self.mapping.delta2:
            parts.append(np.asarray(seg[1], dtype=float).ravel())
        return c_buffer(self.delta.ctype, np.concatenate(parts).tolist())

    def set_delta(self, values: Any, when: str) -> None:
        """Write :meth:`delta_values` into the FMU (nothing for None)."""
        if values is None or self.delta.n == 0:
            return
        try:
            self.write(self.delta, values)
        except FMICallError as exc:
            raise self.call_error(exc, f"{when} (setting Delta)", self.delta.names) from None

    # -------------------------------------------------------------------- FMI calls
    def read(self, group: VarGroup) -> Any:
        """Read the Real (FMI 3.0: ``Float64``) variables of ``group`` into its buffer.

        Parameters
        ----------
        group : VarGroup
            The variables (``fmi2GetReal`` / ``fmi3GetFloat64``).

        Returns
        -------
        ctypes array
            ``group.buf``, whose first ``group.n`` entries now hold the values.

        Raises
        ------
        FMICallError
            When the call returns a status other than OK or Warning.
        """
        try:
            self._calls.get_real(self._component, group.vr, group.n, group.buf)  # type: ignore[union-attr]
        except self._call_exception as exc:
            raise self._failed_call(exc, group.names) from None
        return group.buf

    def write(self, group: VarGroup, values: Any) -> None:
        """Set the variables of ``group`` to ``values``, through the setter of its kind.

        Parameters
        ----------
        group : VarGroup
            The variables: Real (``fmi2SetReal`` / ``fmi3SetFloat64``), Integer
            (``fmi2SetInteger`` / ``fmi3SetInt32``... by type) or Boolean.
        values
            A ctypes array of ``group.ctype`` (e.g. ``group.buf``), or numbers.

        Raises
        ------
        FMICallError
            When the call returns a status other than OK or Warning.
        """
        if not isinstance(values, ctypes.Array):
            values = c_buffer(group.ctype, np.asarray(values, dtype=float).tolist() if group.kind == "real"
                              else [int(v) for v in values])
        try:
            self._setters[group.kind](self._component, group.vr, group.n, values)
        except self._call_exception as exc:
            raise self._failed_call(exc, group.names) from None

    def step(self, t: float, h: float) -> None:
        """One communication step from ``t`` to ``t + h`` (``fmi2DoStep`` / ``fmi3DoStep``),
        then :meth:`raise_pending`.

        Raises
        ------
        FMICallError
            When the call returns a status other than OK or Warning (FMI 3.0: also when the
            FMU sets ``terminateSimulation``).
        """
        try:
            self._calls.do_step(self._component, t, h)  # type: ignore[union-attr]
        except self._call_exception as exc:
            raise self._failed_call(exc, ()) from None
        if self.pending is not None:
            self.raise_pending()

    def directional_derivative(self, unknowns: Sequence[int], knowns: Sequence[int],
                               seed: Sequence[float]) -> list[float]:
        """The derivatives of the variables ``unknowns`` along ``seed`` in the variables
        ``knowns`` (value references; ``fmi2GetDirectionalDerivative`` /
        ``fmi3GetDirectionalDerivative``). Raises :class:`FMICallError` as :meth:`read`."""
        try:
            return list(self.slave.getDirectionalDerivative(list(unknowns), list(knowns), list(seed)))
        except self._call_exception as exc:
            raise self._failed_call(exc, ()) from None

    # -------------------------------------------------------------------- paths
    def start_path(self, x0: Any, mode0: int, delta0: Any) -> None:
        """Reset (unless fresh), set up, and initialise the instance at ``t = 0`` with the
        initial state ``x0`` (ctypes or numbers), the 0-based true mode and the first Delta values."""
        self.messages.clear()  # errors of this path quote this path's messages only
        if self._dirty:
            try:
                self.slave.reset()
                self.stats["resets"] += 1
            except self._call_exception:  # an FMU that cannot reset gets a fresh instance
                self._reinstantiate()
        calls, names = self._calls, ()
        stage = self.calls["setup"]
        try:
            self._dirty = True
            calls.setup_experiment(self.tolerance, 0.0)  # type: ignore[union-attr]
            stage = self.calls["enter"]
            calls.enter_initialization()  # type: ignore[union-attr]
            self._write(self._param_writes, "in initialization mode (setting [parameters])")
            if self.init.n:
                stage, names = self.calls["set_real"], self.init.names
                self.write(self.init, x0)
            self.set_fault(mode0, "in initialization mode")
            self.set_delta(delta0, "in initialization mode")
            stage, names = self.calls["exit"], ()
            self.slave.exitInitializationMode()
        except (self._call_exception, FMICallError) as exc:
            raise self.call_error(exc, f"in {stage} while initialising a path at t = 0", names) from None
        finally:
            self.raise_pending()

    def last_successful_time(self) -> float | None:
        """``fmi2GetRealStatus(fmi2LastSuccessfulTime)`` (FMI 3.0: ``lastSuccessfulTime`` of
        the last ``fmi3DoStep``), or None where the FMU does not answer."""
        try:
            return float(self._calls.last_successful_time())  # type: ignore[union-attr]
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
        if not self.init.n:
            raise self.err(
                "the map has an operating point but no initial_states, so paths cannot start at it; name the "
                "variables that set the initial state (or the states, if their start values can be set)"
            )
        self.start_path(np.asarray(x, dtype=float), 0, delta0)
        out = VarGroup(self.variables.measured + self.variables.outputs)
        try:
            self.write(self.uw, np.asarray(uw, dtype=float))
            self.read(out)
        except FMICallError as exc:
            raise self.call_error(exc, "at the operating point (t = 0, first fault mode)", out.names) from None
        vals = np.array(list(out.buf)[:out.n], dtype=float)
        return vals[:self.nym], vals[self.nym:]
