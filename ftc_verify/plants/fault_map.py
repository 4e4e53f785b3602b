"""The fault-injection map: which FMU variables carry which role of the FTC loop.

This module implements :class:`FaultInjectionMap`, a declarative, frozen description of an
FMI 2.0 or 3.0 co-simulation FMU as seen by the supervisor (:mod:`ftc_verify.simulation.supervisor`):
the variable(s) the true fault mode is written into, the control inputs ``u``, the
disturbance inputs ``w``, the ``Delta`` inputs, the state ``x`` and the outputs ``y`` that
are recorded, the measured outputs ``y_m`` an output-feedback controller reads, and the
initial-state parameters. :meth:`FaultInjectionMap.for_linear_jump_plant` gives the map of
the project's ``LinearJumpPlant`` FMU; any other FMU works by naming its variables. The
names are checked against ``modelDescription.xml`` by :func:`resolve_variables` when the FMU
is opened (:class:`ftc_verify.plants.fmu_session.FMUSession`). Types are named as in FMI 2.0;
in an FMI 3.0 FMU a Real is a scalar ``Float64`` and an Integer any of ``Int8`` .. ``UInt64``
(:data:`FAULT_TYPES_FMI3`); array variables are refused.
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import FMUError, ValidationError
from ..model.system import FTCSystem

__all__ = ["FAULT_TYPES", "FAULT_TYPES_FMI3", "FaultInjectionMap", "OperatingPoint", "ROLES", "ResolvedVariables", "resolve_variables"]

#: FMI types a fault variable may have.
FAULT_TYPES = ("Real", "Integer", "Boolean", "Enumeration")
#: The same for an FMI 3.0 FMU.
FAULT_TYPES_FMI3 = ("Float64", "Int8", "UInt8", "Int16", "UInt16", "Int32", "UInt32", "Int64", "UInt64", "Boolean",
                    "Enumeration")

#: The name-list fields of the map and what they carry (used in error messages).
ROLES = {
    "fault": "fault mode",
    "inputs": "control input u",
    "states": "state x",
    "disturbances": "disturbance input w",
    "outputs": "output y",
    "measured": "measured output y_m",
    "initial_states": "initial state x0",
    "delta1": "Delta input",
    "delta2": "Delta input",
}


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


def _fault_values(vals: Any, fault: tuple[str, ...]) -> tuple[tuple[float | int | bool, ...], ...]:
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
        if len(row) != len(fault):
            raise ValidationError(
                f"{where}: expected {len(fault)} value(s), one per fault variable "
                f"{list(fault)}, got {v!r}"
            )
        out.append(tuple(_scalar(x, where) for x in row))
    return tuple(out)


@dataclass(frozen=True)
class OperatingPoint:
    """The operating point the loop runs around (absolute FMU values).

    The supervisor works in deviation variables: the controller sees ``x - states`` and
    ``y_m - y_m,op``, its output is added to ``inputs``, the disturbance shape is added to
    ``disturbances``; records hold deviations (``y - y_op`` for the performance output).
    ``y_op``, ``y_m,op`` are read from the FMU at this point in the first fault mode when a
    path set starts (:meth:`ftc_verify.plants.fmu_session.FMUSession.probe_outputs`).
    """

    inputs: np.ndarray
    states: np.ndarray
    disturbances: np.ndarray

    def __post_init__(self) -> None:
        for name in ("inputs", "states", "disturbances"):
            arr = np.asarray(getattr(self, name), dtype=float).reshape(-1)
            if not np.all(np.isfinite(arr)):
                raise ValidationError(f"OperatingPoint.{name}: expected finite numbers, got {arr.tolist()}")
            object.__setattr__(self, name, arr)

    def is_zero(self) -> bool:
        return not (self.inputs.any() or self.states.any() or self.disturbances.any())


@dataclass(frozen=True)
class FaultInjectionMap:
    """Which FMU variables carry what (declarative; names as in ``modelDescription.xml``).

    Parameters
    ----------
    fault
        Variable(s) carrying the fault mode: inputs or tunable parameters of type
        Integer, Enumeration, Boolean or Real.
    inputs
        The control inputs ``u`` (Real), in the order of the controller's output rows.
    states
        The state ``x`` (Real: states or a state estimate), recorded at every grid point
        and read by state-feedback controllers, in the order of their columns.
    disturbances
        The disturbance inputs ``w`` (Real); every channel gets the same shape
        (:func:`ftc_verify.simulation.paths.disturbance`).
    outputs
        The outputs ``y`` (Real) recorded at every grid point.
    measured
        The measured outputs ``y_m`` (Real) an output-feedback controller
        (``Controller.measures == "output"``) reads, in the order of its input columns;
        empty: the FMU exposes none (only state feedback can run).
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
        (:mod:`ftc_verify.simulation.delta`); empty: the FMU has no such channel.
    parameters
        ``(name, value)`` start values written in initialisation mode on every path.
    operating_point
        The :class:`OperatingPoint` (None: the origin, absolute values = deviations).
    fault_names
        A name per fault mode (for messages and reports; default ``mode 1``, ...).
    source
        The plant map file this map comes from, named in errors about its roles (None:
        built in code; not compared).
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
    measured: tuple[str, ...] = ()
    parameters: tuple[tuple[str, float | int | bool], ...] = ()
    operating_point: OperatingPoint | None = None
    fault_names: tuple[str, ...] = ()
    source: str | None = field(default=None, compare=False)

    def __post_init__(self) -> None:
        for name in ROLES:
            object.__setattr__(self, name, _names(getattr(self, name), name))
        params = tuple((str(k), _scalar(v, f"FaultInjectionMap.parameters[{k!r}]")) for k, v in self.parameters)
        object.__setattr__(self, "parameters", params)
        object.__setattr__(self, "fault_names", _names(self.fault_names, "fault_names"))
        op = self.operating_point
        if op is not None:
            if not isinstance(op, OperatingPoint):
                raise ValidationError(f"FaultInjectionMap.operating_point: expected an OperatingPoint, got {op!r}")
            for field_name, names in (("inputs", self.inputs), ("states", self.states),
                                      ("disturbances", self.disturbances)):
                if getattr(op, field_name).size != len(names):
                    raise ValidationError(
                        f"FaultInjectionMap.operating_point.{field_name}: {getattr(op, field_name).size} values "
                        f"for {len(names)} variables {list(names)}")
        for name in ("fault", "inputs", "states"):
            if not getattr(self, name):
                raise ValidationError(f"FaultInjectionMap.{name}: at least one variable is needed")
        written = self.fault + self.inputs + self.disturbances + self.delta1 + self.delta2
        clash = sorted({n for n in written if written.count(n) > 1})
        if clash:
            raise ValidationError(f"FaultInjectionMap: variables {clash} are given more than one role to write")
        if self.fault_values is not None:
            object.__setattr__(self, "fault_values", _fault_values(self.fault_values, self.fault))

    def values_for(self, mode: int) -> tuple[float | int | bool, ...]:
        """Values written into ``fault`` in the 0-based true mode ``mode``."""
        if self.fault_values is None:
            return (mode + 1,) * len(self.fault)
        if not 0 <= mode < len(self.fault_values):
            raise ValidationError(
                f"FaultInjectionMap.fault_values: no value for mode {mode} (0-based); "
                f"{len(self.fault_values)} mode(s) are mapped"
            )
        return self.fault_values[mode]

    def check_delta(self, shapes: tuple[tuple[int, int] | None, tuple[int, int] | None], kind: str) -> None:
        """Check ``delta1``, ``delta2`` against the system's ``Delta`` shapes
        (:func:`ftc_verify.simulation.delta.delta_shapes`) for a schedule of ``kind``."""
        for shape, names, label in ((shapes[0], self.delta1, "delta1"), (shapes[1], self.delta2, "delta2")):
            size = 0 if shape is None else shape[0] * shape[1]
            which = "Delta1" if label == "delta1" else "Delta2"
            if names and len(names) != size:
                raise ValidationError(
                    f"FaultInjectionMap.{label}: {len(names)} names, but the system's {which} has {size} entries ({shape})"
                )
            if size and not names and kind != "zero":
                raise ValidationError(f"delta: kind {kind!r} needs FaultInjectionMap.{label} (the FMU's {which} inputs)")

    @classmethod
    def for_linear_jump_plant(cls, system: FTCSystem) -> FaultInjectionMap:
        """The map of the ``LinearJumpPlant`` FMU of ``system`` (:func:`ftc_verify.plants.build_fmu`):
        Integer ``mode`` (1-based), ``u[k]``, ``w[k]``, ``x[k]``, ``y[k]``, the measured
        outputs ``ym[k]``, ``x0[k]`` and the ``Delta1[i,j]``, ``Delta2[i,j]`` inputs its
        uncertainty channels imply."""
        from .system_text import fmu_dims

        d = fmu_dims(system)
        return cls(
            fault=("mode",),
            inputs=tuple(f"u[{k}]" for k in range(1, d.nu + 1)),
            states=tuple(f"x[{k}]" for k in range(1, d.n + 1)),
            disturbances=tuple(f"w[{k}]" for k in range(1, d.nw + 1)),
            outputs=tuple(f"y[{k}]" for k in range(1, d.ny + 1)),
            measured=tuple(f"ym[{k}]" for k in range(1, int(d.nym) + 1)),  # type: ignore[arg-type]
            initial_states=tuple(f"x0[{k}]" for k in range(1, d.n + 1)),
            delta1=tuple(f"Delta1[{i},{j}]" for i in range(1, d.q1 + 1) for j in range(1, d.p1 + 1)),
            delta2=tuple(f"Delta2[{i},{j}]" for i in range(1, d.q2 + 1) for j in range(1, d.p2 + 1)),
        )


# ------------------------------------------------------------------------------------------
# The map against the model description (checked when an FMU is opened)
# ------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ResolvedVariables:
    """The model variables (fmpy objects) of each role of the map, in the map's order."""

    fault: tuple[Any, ...]
    inputs: tuple[Any, ...]
    disturbances: tuple[Any, ...]
    delta: tuple[Any, ...]
    states: tuple[Any, ...]
    outputs: tuple[Any, ...]
    measured: tuple[Any, ...]
    initial: tuple[Any, ...]
    feedthrough: bool
    parameters: tuple[Any, ...] = ()


def _settable(v: Any, role: str, types: Sequence[str], err: Callable[[str], FMUError]) -> Any:
    if v.type not in types:
        raise err(f"variable {v.name!r} ({role}) has type {v.type}; expected {' or '.join(types)}")
    if v.causality == "input" or (v.causality == "parameter" and v.variability == "tunable"):
        return v
    if v.causality == "parameter" and v.variability == "fixed":
        raise err(
            f"variable {v.name!r} ({role}) is a parameter with variability 'fixed': it can only be set before initialisation, "
            "but this role is written during a path, so it must be an input or a tunable parameter; declare it "
            "tunable in the model (Modelica: annotation Evaluate=false, not final; FMI: variability=\"tunable\")"
        )
    raise err(
        f"variable {v.name!r} ({role}) has causality {v.causality!r}"
        + (f" and variability {v.variability!r}" if v.causality == "parameter" else "")
        + "; it must be an input or a tunable parameter to be set during the simulation"
    )


def _readable(v: Any, role: str, err: Callable[[str], FMUError], real: str = "Real") -> Any:
    if v.type != real:
        raise err(f"variable {v.name!r} ({role}) has type {v.type}; expected {real}")
    return v


def _state(v: Any, continuous_states: set[str], source: str | None, err: Callable[[str], FMUError],
           real: str = "Real") -> Any:
    """``v`` if it can be a state ``x``: Real (``Float64``), and a continuous-time state of the
    FMU (the variable of a derivative in ``ModelStructure/Derivatives``) or at least a local or
    output variable with variability continuous; a parameter or an input is refused."""
    _readable(v, "state x", err, real)
    if v.name in continuous_states or (v.causality in ("local", "output") and v.variability == "continuous"):
        return v
    where = f"{source}: [variables].states" if source else "FaultInjectionMap.states"
    raise err(f"{where}: variable {v.name!r} has causality {v.causality!r} and variability {v.variability!r}; a "
              "state must be a continuous-time state of the FMU (listed in ModelStructure/Derivatives) or at least a "
              "local or output variable with variability 'continuous' (parameters and inputs are written by the "
              "loop, not states)")


def resolve_variables(md: Any, mapping: FaultInjectionMap, err: Callable[[str], FMUError]) -> ResolvedVariables:
    """Check every name of ``mapping`` against the model description ``md`` (fmpy's);
    ``err(what)`` builds the error naming the FMU. Each role's variables must fit it: see
    ``_settable`` (written roles), ``_state`` (the states) and the checks below."""
    by_name = {v.name: v for v in md.modelVariables}
    fmi3 = str(getattr(md, "fmiVersion", "") or "").startswith("3.")
    real, fault_types = ("Float64", FAULT_TYPES_FMI3) if fmi3 else ("Real", FAULT_TYPES)

    def lookup(names: Sequence[str], role: str) -> list[Any]:
        out = []
        for name in names:
            v = by_name.get(name)
            if v is None:
                close = difflib.get_close_matches(name, list(by_name), n=3)
                hint = f"; did you mean {close}?" if close else ""
                raise err(f"variable {name!r} ({role} in the map) is not declared in "
                          f"modelDescription.xml{hint}")
            if getattr(v, "dimensions", None):
                raise err(f"variable {name!r} ({role} in the map) is an array {v.type} of shape {v.shape}; the "
                          "map's roles take scalar variables only")
            out.append(v)
        return out

    m = mapping
    fault = [_settable(v, "fault mode", fault_types, err) for v in lookup(m.fault, "fault mode")]
    inputs = [_settable(v, "control input u", (real,), err) for v in lookup(m.inputs, "control input u")]
    dist = [_settable(v, "disturbance input w", (real,), err)
            for v in lookup(m.disturbances, "disturbance input w")]
    delta = [_settable(v, "Delta input", (real,), err) for v in lookup(m.delta1 + m.delta2, "Delta input")]
    continuous_states = {d.variable.derivative.name for d in md.derivatives
                         if d.variable is not None and d.variable.derivative is not None}
    states = [_state(v, continuous_states, m.source, err, real) for v in lookup(m.states, "state x")]
    outputs = [_readable(v, "output y", err, real) for v in lookup(m.outputs, "output y")]
    measured = [_readable(v, "measured output y_m", err, real) for v in lookup(m.measured, "measured output y_m")]
    params = lookup([k for k, _ in m.parameters], "parameter")
    for v in params:
        if v.type not in fault_types:
            raise err(f"variable {v.name!r} ([parameters]) has type {v.type}; [parameters] can set "
                      f"{', '.join(fault_types)}")
        if v.causality == "structuralParameter":
            raise err(f"variable {v.name!r} ([parameters]) is a structural parameter: it can only be set in "
                      "Configuration Mode, which the supervisor does not use")
        if v.causality not in ("parameter", "calculatedParameter", "input") and v.initial not in ("exact", "approx"):
            raise err(f"variable {v.name!r} ([parameters]) has causality {v.causality!r}; only parameters, inputs "
                      "and variables with an exact or approximate start value can be set before initialisation")
        if v.causality == "calculatedParameter" or v.variability == "constant":
            raise err(f"variable {v.name!r} ([parameters]) is a {v.variability} {v.causality}: it cannot be set")
    init = []
    for v in lookup(m.initial_states, "initial state x0"):
        _readable(v, "initial state x0", err, real)
        if not (v.causality in ("parameter", "input") or v.initial in ("exact", "approx")):
            raise err(f"variable {v.name!r} (initial state x0) has causality {v.causality!r} and initial "
                      f"{v.initial!r}; it cannot be set before initialisation")
        init.append(v)
    # Outputs y that depend directly on u or w (declared, or undeclared = all inputs)
    # are read after u, w are written; otherwise x and y are read in one call.
    uw_vrs = {v.valueReference for v in inputs + dist}
    deps = {u.variable.name: u.dependencies for u in md.outputs if u.variable is not None}
    feedthrough = any(
        (deps.get(v.name) is None and v.causality == "output")
        or any(d.valueReference in uw_vrs for d in (deps.get(v.name) or ()))
        for v in outputs
    )
    return ResolvedVariables(tuple(fault), tuple(inputs), tuple(dist), tuple(delta), tuple(states),
                             tuple(outputs), tuple(measured), tuple(init), feedthrough, tuple(params))
