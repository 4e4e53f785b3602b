"""Plant map files: a user's FMI 2.0 FMU as the plant of the FTC loop (TOML).

A plant map names, for one FMU, the variables of every role of the loop, the operating
point the linear design is made around, start values of parameters, the region the design
is trusted in, one table of fault values per fault mode, and optionally the fault/FDI
chain. Full example (:doc:`/user-guide/plant`)::

    fmu = "Motor.fmu"                     # relative to this file
    name = "dc-motor"                     # optional (default: the file's stem)
    tolerance = 1e-8                      # optional: passed to fmi2SetupExperiment
    [variables]
    inputs = ["V"]                        # u, in the order of B's columns (Real inputs)
    disturbances = ["tau_load"]           # w (Real inputs)
    states = ["omega", "i"]               # x
    measured = ["omega_meas"]             # y_m (outputs)
    performance = ["omega"]               # y
    initial_states = ["omega", "i"]       # optional: set to x_op + x0 before initialisation
    delta1 = []; delta2 = []              # optional: Real inputs carrying Delta1, Delta2
    [operating_point]
    inputs = [12.0]
    states = [100.0, 7.0]                 # omitted: found by `linearize --trim`
    disturbances = [0.0]                  # optional (default 0)
    [parameters]
    J = 0.01
    [region]
    states_min = [50.0, -5.0]
    states_max = [150.0, 15.0]
    inputs_min = [0.0]            # optional: actuator limits, checked on u_op + u
    inputs_max = [24.0]
    [[fault]]
    name = "nominal"
    set = { k_eff = 1.0, R_extra = 0.0 }
    [[fault]]
    name = "demagnetised"
    set = { k_eff = 0.6 }                 # what is not named keeps the first table's value
    [chain]                               # optional, as in a system file
    alpha = [[-0.5, 0.5], [1.0, -1.0]]
    beta_min = [[0.0, 2.0], [2.5, 0.0]]
    beta_max = [[0.0, 3.0], [3.5, 0.0]]
    [risk]                                # optional: `verify` estimates P(leave [region] in [0, T])
    horizon = 5.0                         # T (seconds)
    target = 1e-3                         # optional: the probability the design must stay below
    backend = "fmu"                       # optional: "fmu" (this map's FMU, default) or "reference"
    method = "importance"                 # optional: or "crude"
    relative_error = 0.2                  # optional, with confidence, max_paths, pilot_paths, ftti

:func:`load_plant_map` checks the file on its own (keys, types, counts, fault tables);
the names are checked against ``modelDescription.xml`` when the FMU is opened
(:func:`ftc_verify.plants.fault_map.resolve_variables`), through the
:class:`~ftc_verify.plants.fault_map.FaultInjectionMap` that :meth:`PlantMap.injection_map`
returns. Every error names the map file and the key.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w

from ..errors import ProblemFileError, ValidationError
from ..model.files import PLANT_MAP, check_kind, parse_chain, read_toml, tables, unknown_keys, write_atomic
from ..model.system import FTCSystem, JointChain
from .fault_map import FaultInjectionMap, OperatingPoint

__all__ = ["FaultMode", "RiskTarget", "PlantMap", "load_plant_map", "dump_plant_map", "save_plant_map", "ROLE_KEYS",
           "map_path_for", "linear_jump_plant_map", "check_against_system", "check_controller"]

_TOP = {"fmu", "name", "tolerance", "variables", "operating_point", "parameters", "region", "fault", "chain", "risk"}
#: Keys of ``[variables]`` and what they carry.
ROLE_KEYS = {
    "inputs": "control inputs u",
    "disturbances": "disturbance inputs w",
    "states": "states x",
    "measured": "measured outputs y_m",
    "performance": "performance outputs y",
    "initial_states": "initial-state variables",
    "delta1": "Delta1 inputs",
    "delta2": "Delta2 inputs",
}
_OP = {"inputs", "states", "disturbances"}

Scalar = float | int | bool


@dataclass(frozen=True)
class FaultMode:
    """One fault mode: its name and the value of every fault variable (in map order)."""

    name: str
    values: tuple[Scalar, ...]


@dataclass(frozen=True)
class RiskTarget:
    """The ``[risk]`` table: the risk stage of ``verify`` on the map's ``[region]`` (the
    envelope). ``target``: the probability the loop must stay below (``None``: the stage
    reports only); the other fields are the settings of :func:`ftc_verify.risk.run.run_risk`
    (defaults as ``ftc-verify risk``'s options, ``max_paths`` 10,000)."""

    horizon: float
    target: float | None = None
    backend: str = "fmu"
    method: str = "importance"
    relative_error: float = 0.2
    confidence: float = 0.95
    max_paths: int = 10_000
    pilot_paths: int = 500
    ftti: float | None = None

    def to_dict(self) -> dict[str, Any]:
        """The TOML table (``None`` fields left out)."""
        return {k: v for k, v in vars(self).items() if v is not None}


@dataclass(frozen=True)
class PlantMap:
    """A checked plant map file (module docstring). Arrays are float64, names tuples.

    ``states_op`` is None when the file gives no ``[operating_point].states`` (then only
    ``linearize --trim`` can run until it is found). ``fault_variables`` is the ordered
    union of the names in the ``[[fault]]`` tables.
    """

    source: Path
    fmu: Path
    name: str
    inputs: tuple[str, ...]
    disturbances: tuple[str, ...]
    states: tuple[str, ...]
    measured: tuple[str, ...]
    performance: tuple[str, ...]
    initial_states: tuple[str, ...]
    delta1: tuple[str, ...]
    delta2: tuple[str, ...]
    inputs_op: np.ndarray
    states_op: np.ndarray | None
    disturbances_op: np.ndarray
    parameters: tuple[tuple[str, Scalar], ...]
    states_min: np.ndarray | None
    states_max: np.ndarray | None
    inputs_min: np.ndarray | None
    inputs_max: np.ndarray | None
    fault_variables: tuple[str, ...]
    faults: tuple[FaultMode, ...]
    chain: JointChain | None
    tolerance: float | None
    risk: RiskTarget | None = None

    @property
    def m(self) -> int:
        """Number of fault modes."""
        return len(self.faults)

    def where(self, key: str) -> str:
        return f"{self.source}: {key}"

    def require(self, role: str, command: str) -> None:
        """Raise unless ``[variables].role`` names at least one variable."""
        if not getattr(self, role):
            raise ProblemFileError(
                f"{self.source}: [variables].{role} ({ROLE_KEYS[role]}) is empty, but {command} needs it"
            )

    def require_states_op(self, command: str) -> np.ndarray:
        """``states_op``, or an error saying how to find it."""
        if self.states_op is None:
            raise ProblemFileError(
                f"{self.source}: [operating_point].states is missing, but {command} needs it; "
                "find it with `ftc-verify linearize --trim` and write it into the map"
            )
        return self.states_op

    def with_states_op(self, states_op: np.ndarray) -> PlantMap:
        """The same map with the operating-point states (e.g. found by trimming)."""
        return replace(self, states_op=_floats(states_op, len(self.states), self.where("[operating_point].states")))

    def operating_point(self) -> OperatingPoint:
        return OperatingPoint(inputs=self.inputs_op, states=self.require_states_op("co-simulation"),
                              disturbances=self.disturbances_op)

    def injection_map(self) -> FaultInjectionMap:
        """The :class:`FaultInjectionMap` the supervisor and the linearisation use."""
        try:
            return FaultInjectionMap(
                fault=self.fault_variables, inputs=self.inputs, states=self.states,
                disturbances=self.disturbances, outputs=self.performance, measured=self.measured,
                fault_values=tuple(f.values for f in self.faults), initial_states=self.initial_states,
                delta1=self.delta1, delta2=self.delta2, parameters=self.parameters,
                operating_point=None if self.states_op is None else self.operating_point(),
                fault_names=tuple(f.name for f in self.faults), source=str(self.source),
            )
        except ValidationError as exc:
            raise ProblemFileError(f"{self.source}: {exc}") from None


# ------------------------------------------------------------------------------------------
# Reading
# ------------------------------------------------------------------------------------------


def _scalar(value: Any, where: str) -> Scalar:
    if isinstance(value, bool):
        return value
    if isinstance(value, int):
        if abs(value) > 2**31 - 1:
            raise ProblemFileError(f"{where}: integer {value} is out of the FMI Integer range")
        return value
    if isinstance(value, float) and math.isfinite(value):
        return value
    raise ProblemFileError(f"{where}: expected a finite number or true/false, got {value!r}")


def _shown(value: Any) -> str:
    """``value`` for an error message: numpy scalars and arrays as plain numbers and lists
    (``200.0``, ``[1.0, 2.0]``, never ``np.float64(200.0)``), anything else as its repr."""
    if isinstance(value, (np.ndarray, np.generic)):
        return repr(value.tolist())
    if isinstance(value, (list, tuple)):
        return repr([v.tolist() if isinstance(v, (np.ndarray, np.generic)) else v for v in value])
    return repr(value)


def _floats(value: Any, count: int, where: str, *, finite: bool = True) -> np.ndarray:
    if isinstance(value, (str, bytes, dict)) or not isinstance(value, (list, tuple, np.ndarray)):
        raise ProblemFileError(f"{where}: expected a list of {count} numbers, got {_shown(value)}")
    if len(value) != count:
        raise ProblemFileError(f"{where}: expected {count} numbers (one per variable), got {len(value)}: "
                               f"{_shown(value)}")
    out = []
    for v in value:
        if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)):
            raise ProblemFileError(f"{where}: expected numbers, got {_shown(v)}")
        f = float(v)
        if math.isnan(f) or (finite and not math.isfinite(f)):
            raise ProblemFileError(f"{where}: expected finite numbers, got {_shown(v)}")
        out.append(f)
    return np.asarray(out, dtype=float)


def _names(p: Path, doc: dict[str, Any], key: str) -> tuple[str, ...]:
    val = doc.get(key, [])
    where = f"{p}: [variables].{key}"
    if not isinstance(val, list) or not all(isinstance(n, str) and n for n in val):
        raise ProblemFileError(f"{where}: expected a list of variable names, got {val!r}")
    dup = sorted({n for n in val if val.count(n) > 1})
    if dup:
        raise ProblemFileError(f"{where}: names {dup} are given more than once")
    return tuple(val)


def _faults(p: Path, doc: dict[str, Any]) -> tuple[tuple[str, ...], tuple[FaultMode, ...]]:
    raw = tables(p, doc, "fault")
    names: list[str] = []
    first: dict[str, Scalar] = {}
    modes = []
    for k, t in enumerate(raw, start=1):
        unknown_keys(p, f"fault[{k}]", list(t), {"name", "set"})
        name = t.get("name", f"mode {k}")
        if not isinstance(name, str) or not name:
            raise ProblemFileError(f"{p}: fault[{k}].name: expected a non-empty string, got {name!r}")
        sets = t.get("set")
        if not isinstance(sets, dict) or not sets:
            raise ProblemFileError(f"{p}: fault[{k}].set: expected a table of variable = value, got {sets!r}")
        vals = {v: _scalar(x, f"{p}: fault[{k}].set.{v}") for v, x in sets.items()}
        if k == 1:
            first, names = vals, list(vals)
        else:
            extra = sorted(set(vals) - set(first))
            if extra:
                raise ProblemFileError(
                    f"{p}: fault[{k}].set names {extra}, which fault[1] does not set; the first table "
                    "must give every fault variable its value in the nominal mode"
                )
        modes.append(FaultMode(name, tuple(vals.get(v, first[v]) for v in names)))
    seen = [m.name for m in modes]
    dup = sorted({n for n in seen if seen.count(n) > 1})
    if dup:
        raise ProblemFileError(f"{p}: [[fault]] names {dup} are used more than once")
    return tuple(names), tuple(modes)


def _bounds(p: Path, reg: dict[str, Any], role: str, count: int) -> tuple[np.ndarray | None, np.ndarray | None]:
    """``[region].{role}_min`` and ``_max`` (a missing side is infinite; both missing: None)."""
    if f"{role}_min" not in reg and f"{role}_max" not in reg:
        return None, None
    lo, hi = (_floats(reg[key], count, f"{p}: [region].{key}", finite=False) if key in reg
              else np.full(count, sign * np.inf) for key, sign in ((f"{role}_min", -1.0), (f"{role}_max", 1.0)))
    bad = np.flatnonzero(~(lo < hi))
    if bad.size:
        k = int(bad[0])
        raise ProblemFileError(f"{p}: [region]: {role}_min[{k}] = {_shown(lo[k])} is not below "
                               f"{role}_max[{k}] = {_shown(hi[k])}")
    return lo, hi


def _region(p: Path, doc: dict[str, Any], n: int, nu: int) -> tuple[np.ndarray | None, ...]:
    """State bounds (the region the linear design is trusted in) and actuator limits."""
    reg = doc.get("region")
    if reg is None:
        return None, None, None, None
    if not isinstance(reg, dict):
        raise ProblemFileError(f"{p}: [region]: expected a table, got {reg!r}")
    unknown_keys(p, "[region]", list(reg), {"states_min", "states_max", "inputs_min", "inputs_max"})
    return _bounds(p, reg, "states", n) + _bounds(p, reg, "inputs", nu)


def _chain(p: Path, doc: dict[str, Any], m: int) -> JointChain | None:
    ch = doc.get("chain")
    if ch is None:
        return None
    if not isinstance(ch, dict):
        raise ProblemFileError(f"{p}: [chain]: expected a table, got {ch!r}")
    chain = parse_chain(p, ch)
    if chain.m != m:
        raise ProblemFileError(f"{p}: [chain] has {chain.m} modes but there are {m} [[fault]] tables")
    return chain


def _risk(p: Path, doc: dict[str, Any], has_region: bool) -> RiskTarget | None:
    """The ``[risk]`` table (:class:`RiskTarget`), checked; it needs ``[region]`` states."""
    tab = doc.get("risk")
    if tab is None:
        return None
    if not isinstance(tab, dict):
        raise ProblemFileError(f"{p}: [risk]: expected a table, got {tab!r}")
    unknown_keys(p, "[risk]", list(tab), {f.name for f in fields(RiskTarget)})
    if not has_region:
        raise ProblemFileError(f"{p}: [risk]: the envelope is [region].states_min / states_max, which the map lacks")
    if "horizon" not in tab:
        raise ProblemFileError(f"{p}: [risk].horizon: missing (the envelope is watched on [0, horizon])")
    out: dict[str, Any] = {}
    for key, value in tab.items():
        where = f"{p}: [risk].{key}"
        if key in ("backend", "method"):
            allowed = ("fmu", "reference") if key == "backend" else ("importance", "crude")
            if value not in allowed:
                raise ProblemFileError(f"{where}: {value!r} is not one of {', '.join(allowed)}")
        elif key in ("max_paths", "pilot_paths"):
            if isinstance(value, bool) or not isinstance(value, int) or value < 2:
                raise ProblemFileError(f"{where}: expected an integer of at least 2, got {_shown(value)}")
        else:
            ok = not isinstance(value, bool) and isinstance(value, (int, float)) and 0 < value < math.inf
            if not ok or (key in ("target", "confidence") and value >= 1):
                bound = "in (0, 1)" if key in ("target", "confidence") else "positive and finite"
                raise ProblemFileError(f"{where}: expected a number {bound}, got {_shown(value)}")
            value = float(value)
        out[key] = value
    return RiskTarget(**out)


def _build_hint(p: Path, fmu_path: Path) -> str:
    """How to make the missing FMU: ``build-fmu`` of the Modelica model of the same name
    beside it, else the build command the map's comments give, else where to read."""
    model = fmu_path.with_suffix(".mo")
    if model.is_file():
        return f"build it first: ftc-verify build-fmu {model} -o {fmu_path}"
    try:
        comments = [line.lstrip("# ").strip() for line in p.read_text(encoding="utf-8").splitlines()
                    if line.startswith("#")]
    except (OSError, UnicodeDecodeError):
        comments = []
    commands = [line for line in comments if line.startswith(("python ", "ftc-verify build-fmu"))]
    if commands:
        return f"build it first (the map's comment): {commands[0]}"
    return "build it first (ftc-verify build-fmu for a Modelica model) or correct the fmu key"


def load_plant_map(path: str | os.PathLike[str]) -> PlantMap:
    """Read and check a plant map file (format in the module docstring)."""
    p = Path(path)
    doc = read_toml(p)
    check_kind(p, doc, PLANT_MAP)
    unknown_keys(p, "top level", list(doc), _TOP)
    fmu = doc.get("fmu")
    if not isinstance(fmu, str) or not fmu:
        raise ProblemFileError(f"{p}: fmu: expected the FMU's file name (relative to the map), got {fmu!r}")
    fmu_path = (p.parent / fmu).resolve()
    if not fmu_path.is_file():
        raise ProblemFileError(f"{p}: fmu: no such file {str(fmu_path)!r}; {_build_hint(p, fmu_path)}")
    name = doc.get("name", p.stem)
    if not isinstance(name, str) or not name:
        raise ProblemFileError(f"{p}: name: expected a non-empty string, got {name!r}")
    tol = doc.get("tolerance")
    if tol is not None and (isinstance(tol, bool) or not isinstance(tol, (int, float)) or not 0 < tol < 1):
        raise ProblemFileError(f"{p}: tolerance: expected a number in (0, 1), got {tol!r}")
    var = doc.get("variables")
    if not isinstance(var, dict):
        raise ProblemFileError(f"{p}: [variables]: missing table (got {var!r})")
    unknown_keys(p, "[variables]", list(var), set(ROLE_KEYS))
    roles = {key: _names(p, var, key) for key in ROLE_KEYS}
    op = doc.get("operating_point", {})
    if not isinstance(op, dict):
        raise ProblemFileError(f"{p}: [operating_point]: expected a table, got {op!r}")
    unknown_keys(p, "[operating_point]", list(op), _OP)
    nu, nw, n = len(roles["inputs"]), len(roles["disturbances"]), len(roles["states"])
    u_op = _floats(op["inputs"], nu, f"{p}: [operating_point].inputs") if "inputs" in op else np.zeros(nu)
    w_op = _floats(op["disturbances"], nw, f"{p}: [operating_point].disturbances") if "disturbances" in op else np.zeros(nw)
    x_op = _floats(op["states"], n, f"{p}: [operating_point].states") if "states" in op else None
    params = doc.get("parameters", {})
    if not isinstance(params, dict):
        raise ProblemFileError(f"{p}: [parameters]: expected a table of name = value, got {params!r}")
    parameters = tuple((k, _scalar(v, f"{p}: [parameters].{k}")) for k, v in params.items())
    if roles["initial_states"] and len(roles["initial_states"]) != n:
        raise ProblemFileError(f"{p}: [variables].initial_states: {len(roles['initial_states'])} names for "
                               f"{n} states")
    fault_vars, faults = _faults(p, doc)
    clash = sorted(set(fault_vars) & {k for k, _ in parameters})
    if clash:
        raise ProblemFileError(f"{p}: {clash} are set both in [parameters] and in [[fault]]; name each in one place")
    lo, hi, u_lo, u_hi = _region(p, doc, n, nu)
    return PlantMap(source=p, fmu=fmu_path, name=name, **roles, inputs_op=u_op, states_op=x_op,
                    disturbances_op=w_op, parameters=parameters, states_min=lo, states_max=hi,
                    inputs_min=u_lo, inputs_max=u_hi,
                    fault_variables=fault_vars, faults=faults, chain=_chain(p, doc, len(faults)),
                    tolerance=None if tol is None else float(tol),
                    risk=_risk(p, doc, lo is not None and hi is not None))


# ------------------------------------------------------------------------------------------
# Writing (build-fmus writes the LinearJumpPlant's map)
# ------------------------------------------------------------------------------------------


def dump_plant_map(pm: PlantMap, *, relative_to: Path | None = None) -> str:
    """The TOML text of ``pm`` (inverse of :func:`load_plant_map`); the FMU path is written
    relative to ``relative_to`` (the folder of the map file) when it lies below it."""
    fmu = pm.fmu
    if relative_to is not None:
        try:
            fmu = fmu.relative_to(relative_to.resolve())
        except ValueError:
            pass
    doc: dict[str, Any] = {"fmu": str(fmu), "name": pm.name}
    if pm.tolerance is not None:
        doc["tolerance"] = pm.tolerance
    doc["variables"] = {k: list(getattr(pm, k)) for k in ROLE_KEYS if getattr(pm, k)}
    op: dict[str, Any] = {"inputs": pm.inputs_op.tolist(), "disturbances": pm.disturbances_op.tolist()}
    if pm.states_op is not None:
        op["states"] = pm.states_op.tolist()
    doc["operating_point"] = op
    if pm.parameters:
        doc["parameters"] = dict(pm.parameters)
    region = {f"{role}_{side}": getattr(pm, f"{role}_{side}").tolist()
              for role in ("states", "inputs") for side in ("min", "max") if getattr(pm, f"{role}_{side}") is not None}
    if region:
        doc["region"] = region
    doc["fault"] = [{"name": f.name, "set": dict(zip(pm.fault_variables, f.values))} for f in pm.faults]
    if pm.chain is not None:
        c = pm.chain
        doc["chain"] = {"alpha": c.alpha.tolist(), "beta_min": c.beta_min.tolist(), "beta_max": c.beta_max.tolist(),
                        **({"fault_during_delay": True} if c.fault_during_delay else {})}
    if pm.risk is not None:
        doc["risk"] = pm.risk.to_dict()
    return tomli_w.dumps(doc)


def save_plant_map(pm: PlantMap, path: str | os.PathLike[str]) -> None:
    """Write ``pm`` to ``path`` atomically (the FMU path relative to the map's folder)."""
    write_atomic(path, dump_plant_map(pm, relative_to=Path(path).parent))


def map_path_for(fmu: str | os.PathLike[str]) -> Path:
    """Where ``build-fmus`` writes the map of an FMU: ``X.fmu`` -> ``X.plant.toml``."""
    return Path(fmu).with_suffix(".plant.toml")


def linear_jump_plant_map(system: FTCSystem, fmu: str | os.PathLike[str]) -> PlantMap:
    """The plant map of the ``LinearJumpPlant`` FMU ``fmu`` built for ``system``: the
    Integer ``mode`` carries the 1-based fault mode, the operating point is the origin,
    the chain is the system's (so ``linearize`` gives the system back)."""
    fim = FaultInjectionMap.for_linear_jump_plant(system)
    n, nu, nw = len(fim.states), len(fim.inputs), len(fim.disturbances)
    return PlantMap(
        source=map_path_for(fmu), fmu=Path(fmu).resolve(), name=system.name, inputs=fim.inputs,
        disturbances=fim.disturbances, states=fim.states, measured=fim.measured, performance=fim.outputs,
        initial_states=fim.initial_states, delta1=fim.delta1, delta2=fim.delta2, inputs_op=np.zeros(nu),
        states_op=np.zeros(n), disturbances_op=np.zeros(nw), parameters=(), states_min=None, states_max=None,
        inputs_min=None, inputs_max=None,
        fault_variables=("mode",), faults=tuple(FaultMode(f"mode {k}", (k,)) for k in range(1, system.m + 1)),
        chain=system.chain, tolerance=None,
    )


def check_against_system(pm: PlantMap, system: FTCSystem) -> None:
    """Raise unless the map's roles and fault tables fit ``system`` (one fault table per
    mode; as many inputs, states, disturbances, performance and measured outputs as the
    system's ``B`` columns, ``A`` rows, ``D`` columns, ``C`` rows and ``Cy`` rows)."""
    n, nu, ny, nw = system.dims
    if pm.m != system.m:
        raise ProblemFileError(f"{pm.source}: {pm.m} [[fault]] tables, but the system {system.name!r} has "
                               f"{system.m} modes (one table per mode, in mode order)")
    counts = (("inputs", nu, "columns of B"), ("states", n, "rows of A"), ("disturbances", nw, "columns of D"),
              ("performance", ny, "rows of C"))
    for role, want, what in counts:
        got = len(getattr(pm, role))
        if got != want:
            raise ProblemFileError(f"{pm.source}: [variables].{role} names {got} variable(s), but the system "
                                   f"{system.name!r} has {want} ({what})")
    if pm.measured and len(pm.measured) != system.ny_measured:
        raise ProblemFileError(f"{pm.source}: [variables].measured names {len(pm.measured)} variable(s), but the "
                               f"system {system.name!r} has {system.ny_measured} measured outputs (rows of Cy)")


def check_controller(plant: PlantMap, controller: Any, source: str | os.PathLike[str]) -> None:
    """Raise unless ``controller`` can read the plant map's signals, before any analysis.

    An output-feedback controller (``controller.measures == "output"``) reads
    ``controller.n_v`` measured outputs: ``[variables].measured`` must name exactly that many
    (an empty list is refused: there is nothing to read); a state-feedback controller reads
    ``controller.n_v`` states: ``[variables].states`` must name that many.

    Parameters
    ----------
    plant : PlantMap
        The loaded plant map.
    controller : Controller
        The loaded controller (:class:`ftc_verify.controllers.controller.Controller`).
    source : str or path
        The controller's file, named in the error.

    Raises
    ------
    ProblemFileError
        Naming the map file, the key, the count, the controller file and its input count.
    """
    output = controller.measures == "output"
    role = "measured" if output else "states"
    kind, signals = ("output-feedback", "measured outputs") if output else ("state-feedback", "states")
    got, want = len(getattr(plant, role)), int(controller.n_v)
    if got == want:
        return
    named = "is empty" if got == 0 else f"names {got} variable(s)"
    raise ProblemFileError(f"{plant.source}: [variables].{role} ({ROLE_KEYS[role]}) {named}, but the {kind} "
                           f"controller {source} reads {want} {signals} (its input count n_v = {want})")
