"""The plant commands of the CLI: ``ftc-verify plant`` and ``ftc-verify linearize`` (a
user's FMU through a plant map, :mod:`ftc_verify.plants.plant_map`) and ``ftc-verify
build-fmu`` (a Modelica model to an FMU, :mod:`ftc_verify.plants.modelica`).

Both follow the exit-code contract of :mod:`ftc_verify.cli.main`: 0 with a verdict line,
1 when ``plant --check`` finds a fault that changes nothing, ``linearize --trim`` finds no
stationary point, or the plant FMU fails in one of these commands' FMI calls (an ``fmi2DoStep``
returning ``fmi2Error``...: a failed check, a linearisation that could not be computed; the
verdict line names the FMU, the call, the fault mode and time and the FMU's own log message,
and ``--json`` prints it in one JSON object) or crashes (a segfault: the FMU and the signal),
2 for a bad map or FMU (one line naming the file, the key and the value), and never writes
an output that is one of its inputs. ``plant`` and ``linearize`` make their FMU calls in a
watched child (:func:`~ftc_verify.simulation.isolated.call_isolated`), so a crash never
ends this process and SIGTERM / Ctrl-C stop an FMU that hangs at once (143 / 130).
``linearize -o`` writes a linearisation whose error estimate exceeds
:data:`~ftc_verify.plants.linearize.ACCURACY_FRACTION` of its entries only with
``--accept-inaccurate`` (exit 1 otherwise, nothing written).
"""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import numpy as np

from ..jsonable import dumps
from .common import EXIT_NEGATIVE, EXIT_OK, check_output_file, positive

__all__ = ["add_plant_commands", "describe_plant", "LINEARIZE_ROUTES", "LINEARIZE_ACCURACY"]

#: :data:`ftc_verify.plants.linearize.ROUTES` and ``ACCURACY_FRACTION``, written here so that
#: building the parser (``--help``) imports neither numpy nor scipy (a test checks they agree).
LINEARIZE_ROUTES = ("directional", "finite-differences", "identification")
LINEARIZE_ACCURACY = 1e-3


def _variable(v: Any) -> dict[str, Any]:
    unit = getattr(v, "unit", None) or (getattr(v.declaredType, "unit", None) if v.declaredType else None)
    return {"name": v.name, "type": v.type, "causality": v.causality, "variability": v.variability,
            "start": v.start, "unit": unit, "description": v.description}


def describe_plant(pm: Any, session: Any) -> dict[str, Any]:
    """The FMU's interface and every role of the map resolved to its variable."""
    import numpy as np

    md, rv = session.model_description, session.variables
    cs, me = md.coSimulation, md.modelExchange
    by_name = {v.name: v for v in md.modelVariables}
    warnings = []
    if pm.states_op is None:
        warnings.append("[operating_point].states missing: find it with `ftc-verify linearize --trim`")
    if not rv.initial:
        warnings.append("no initial_states: paths start at the FMU's own start values, not at the operating point")
    if not cs.canHandleVariableCommunicationStepSize:
        warnings.append("the FMU cannot vary its communication step: jump times will be moved to the step grid")
    if not pm.measured:
        warnings.append("no measured outputs: only state-feedback controllers can run on this plant")
    if not pm.disturbances:
        warnings.append("no disturbances: attenuation cannot be measured on this plant (simulate/verify need w)")
    if pm.states_min is None:
        warnings.append("no [region]: paths are not checked against the region the linear design is trusted in")
    return {
        "map": str(pm.source), "fmu": str(pm.fmu), "fmi_version": md.fmiVersion,
        "model_identifier": cs.modelIdentifier, "model_name": md.modelName,
        "interfaces": ["CoSimulation"] + (["ModelExchange"] if me is not None else []),
        "can_handle_variable_communication_step_size": bool(cs.canHandleVariableCommunicationStepSize),
        "provides_directional_derivative": bool(cs.providesDirectionalDerivative),
        "can_get_and_set_fmu_state": bool(cs.canGetAndSetFMUstate),
        "roles": {role: [_variable(by_name[n]) for n in getattr(pm, role)]
                  for role in ("inputs", "disturbances", "states", "measured", "performance", "initial_states")},
        "faults": [{"name": f.name, "set": dict(zip(pm.fault_variables, f.values))} for f in pm.faults],
        "fault_variables": [_variable(by_name[n]) for n in pm.fault_variables],
        "parameters": dict(pm.parameters),
        "operating_point": {"inputs": pm.inputs_op.tolist(), "disturbances": pm.disturbances_op.tolist(),
                            "states": None if pm.states_op is None else pm.states_op.tolist()},
        "region": {f"{role}_{side}": [float(v) if np.isfinite(v) else None for v in getattr(pm, f"{role}_{side}")]
                   for role in ("states", "inputs") for side in ("min", "max")
                   if getattr(pm, f"{role}_{side}") is not None},
        "warnings": warnings,
        "fdi_model": None if pm.chain is None else pm.chain.describe(),
    }


def _step_mode(pm: Any, session: Any, mode: int, step: float, grp: Any) -> np.ndarray:
    """The states and outputs after one step of ``step`` from the operating point in the
    0-based fault mode ``mode``; every FMI call through the session's error path
    (:func:`~ftc_verify.plants.linearize.fmi_calls`: a failing call raises ``PlantRunError``)."""
    import numpy as np

    from ..plants.linearize import fmi_calls

    x0 = pm.states_op if pm.states_op is not None else np.zeros(len(pm.states))
    uw = np.concatenate([pm.inputs_op, pm.disturbances_op])
    where = f"in fault mode {mode + 1} ({pm.faults[mode].name}) during plant --check"
    with fmi_calls(session, f"at t = 0 {where}", session.uw.names):
        session.start_path(x0, mode, None)
        session.write(session.uw, uw)
    with fmi_calls(session, f"in the step from t = 0 to t = {step:g} {where}"):
        session.step(0.0, step)
    with fmi_calls(session, f"at t = {step:g} {where}", grp.names):
        values = session.read(grp)
    return np.array(list(values)[:grp.n], dtype=float)


def _check_faults(pm: Any, session: Any, step: float) -> list[dict[str, Any]]:
    """One step of ``step`` from the operating point in every fault mode; a mode whose
    states and outputs equal the first mode's after the step changes nothing. A mode in
    which the FMU fails gets ``error`` (the FMU, call, time and log message) instead of
    values; after ``fmi2Fatal`` the remaining modes are not run."""
    import numpy as np

    from ..errors import PlantRunError
    from ..plants.fmu_session import VarGroup

    rv = session.variables
    grp = VarGroup(rv.states + rv.outputs + rv.measured)
    for i in range(pm.m):  # bad fault values are bad input (exit 2), found before any step
        session.fault_writes(i)
    rows: list[dict[str, Any]] = []
    first = None
    for i, f in enumerate(pm.faults):
        row: dict[str, Any] = {"mode": i + 1, "name": f.name, "after_step": None, "changes_nothing": False,
                               "error": None}
        rows.append(row)
        if session.dead:
            row["error"] = "not run: the FMU returned fmi2Fatal in an earlier mode"
            continue
        try:
            vals = _step_mode(pm, session, i, step, grp)
        except PlantRunError as exc:
            row["error"] = str(exc)
            continue
        first = vals if i == 0 else first
        row["after_step"] = vals.tolist()
        row["changes_nothing"] = i > 0 and first is not None and bool(np.array_equal(vals, first))
    return rows


def _describe_and_check(pm: Any, check: bool, step: float) -> dict[str, Any]:
    """:func:`describe_plant` and, with ``check``, :func:`_check_faults`: what ``plant``
    computes in its watched child (:func:`~ftc_verify.simulation.isolated.call_isolated`)."""
    from ..plants.fmu_session import FMUSession

    with FMUSession(pm.fmu, pm.injection_map(), tolerance=pm.tolerance) as session:
        d = describe_plant(pm, session)
        if check:
            d["check"] = _check_faults(pm, session, step)
    return d


def _cmd_plant(args: argparse.Namespace) -> int:
    from ..errors import PlantRunError
    from ..plants.plant_map import load_plant_map
    from ..simulation.isolated import call_isolated

    pm = load_plant_map(args.plant)
    try:
        d = call_isolated(str(pm.fmu), "during plant --check" if args.check else "during plant",
                          _describe_and_check, pm, args.check, args.step)
    except PlantRunError as exc:
        return _failed(args, pm, "plant", "the plant FMU crashed", str(exc))
    inert = [r["name"] for r in d.get("check", []) if r["changes_nothing"]]
    failed = [r for r in d.get("check", []) if r["error"]]
    verdict = "fail" if inert or failed else ("checked" if args.check else "done")
    reasons = ([f"fault modes {inert} change nothing"] if inert else []) + \
        ([f"the plant FMU failed in fault modes {[r['name'] for r in failed]}"] if failed else [])
    if args.json:
        print(dumps(d | {"verdict": verdict, "reason": "; ".join(reasons) or None}))
    else:
        print(f"ftc-verify plant: {d['map']}")
        if d["fdi_model"]:
            print(f"  [chain] {d['fdi_model']}")
        print(f"  FMU {d['fmu']}: FMI {d['fmi_version']}, model identifier {d['model_identifier']}, "
              f"{' + '.join(d['interfaces'])}")
        print(f"  variable communication steps: {'yes' if d['can_handle_variable_communication_step_size'] else 'no'}; "
              f"directional derivatives: {'yes' if d['provides_directional_derivative'] else 'no'}")
        for role, vs in d["roles"].items():
            for v in vs:
                print(f"  {role:15s} {v['name']}: {v['type']} {v['causality']}/{v['variability']}, "
                      f"start {v['start']}, unit {v['unit'] or '-'}")
        for k, f in enumerate(d["faults"], start=1):
            print(f"  fault mode {k} ({f['name']}): {f['set']}")
        op = d["operating_point"]
        print(f"  operating point: u = {op['inputs']}, x = {op['states']}, w = {op['disturbances']}")
        for key, bound in d["region"].items():
            print(f"  region {key}: {bound}")
        for r in d.get("check", []):
            state = "FMU FAILED" if r["error"] else ("CHANGES NOTHING" if r["changes_nothing"] else "ok")
            print(f"  check mode {r['mode']} ({r['name']}): {state}" + (f": {r['error']}" if r["error"] else ""))
        for w in d["warnings"]:
            print(f"  warning: {w}")
        print(f"  verdict: {verdict}" + (f" ({'; '.join(reasons)})" if reasons else ""))
    return EXIT_NEGATIVE if inert or failed else EXIT_OK


def _failed(args: argparse.Namespace, pm: Any, command: str, reason: str, detail: str) -> int:
    """The answer of a ``plant`` or ``linearize`` that could not finish its FMU calls (the
    FMU failed or crashed; ``linearize --trim`` found no stationary point): the verdict line
    (or one JSON object with ``verdict: fail``), exit 1, nothing written."""
    if args.json:
        print(dumps({"map": str(pm.source), "fmu": str(pm.fmu), "output": None, "verdict": "fail",
                     "reason": reason, "detail": detail}))
    else:
        print(f"ftc-verify {command}: {pm.source} ({pm.fmu.name})")
        print(f"  {detail}")
        print(f"  verdict: fail ({reason})")
    return EXIT_NEGATIVE


def _trim_and_linearize(pm: Any, trim: bool, route: str | None) -> tuple[Any, Any]:
    """The map (its states at the trimmed point with ``trim``) and its linearisation: what
    ``linearize`` computes in its watched child (:func:`~ftc_verify.simulation.isolated.call_isolated`)."""
    from ..plants.linearize import linearize_plant, trim_plant

    if trim:
        pm = pm.with_states_op(trim_plant(pm))
    return pm, linearize_plant(pm, route=route)


def _cmd_linearize(args: argparse.Namespace) -> int:
    import numpy as np

    from ..errors import FMUError, PlantRunError
    from ..model.files import save_system
    from ..plants.linearize import ACCURACY_FRACTION, TrimFailed
    from ..plants.plant_map import load_plant_map
    from ..simulation.isolated import call_isolated

    if args.output:
        check_output_file(args.output, "-o", inputs=(args.plant,))
    pm = load_plant_map(args.plant)
    if pm.chain is None and args.output:
        raise FMUError(f"{pm.source}: [chain] is missing; a system file needs the chain (add it to the map)")
    try:
        pm, lin = call_isolated(str(pm.fmu), "during linearize", _trim_and_linearize, pm, args.trim, args.route)
    except TrimFailed as exc:
        return _failed(args, pm, "linearize", "no stationary point", str(exc))
    except PlantRunError as exc:
        return _failed(args, pm, "linearize", "the linearisation could not be computed: the plant FMU failed",
                       str(exc))
    refused = bool(lin.inaccurate) and bool(args.output) and not args.accept_inaccurate
    if args.output and not refused:
        assert pm.chain is not None
        save_system(lin.system(pm.name, pm.chain), args.output)
    verdict = "fail" if refused else "done"
    d = lin.to_dict() | {"map": str(pm.source), "fmu": str(pm.fmu), "output": None if refused else args.output,
                         "verdict": verdict}
    if refused:
        d["reason"] = (f"the error estimates exceed {ACCURACY_FRACTION:g} of the entries; the system file was not "
                       "written (--accept-inaccurate writes it anyway)")
    if args.json:
        print(dumps(d))
        return EXIT_NEGATIVE if refused else EXIT_OK
    print(f"ftc-verify linearize: {pm.source} ({pm.fmu.name}), route {lin.route}")
    print(f"  operating point x = {lin.states_op.tolist()}, u = {pm.inputs_op.tolist()}")
    for k, m in enumerate(lin.modes, start=1):
        print(f"  mode {k} ({m.name}): A = {np.round(m.A, 6).tolist()}, B = {np.round(m.B, 6).tolist()}; "
              f"drift |f| = {np.linalg.norm(m.drift):.3g}; error estimates "
              + ", ".join(f"{key} {val:.3g}" for key, val in m.errors.items()))
    for note in lin.notes:
        print(f"  note: {note}")
    for warning in lin.inaccurate:
        print(f"  warning: inaccurate linearisation: {warning}")
    if args.output and not refused:
        print(f"  system written to {args.output}")
    print(f"  verdict: {verdict}" + (f" ({d['reason']})" if refused else ""))
    return EXIT_NEGATIVE if refused else EXIT_OK


def _cmd_build_fmu(args: argparse.Namespace) -> int:
    from ..plants.modelica import build_modelica_fmu

    if args.output:
        check_output_file(args.output, "-o", (".fmu",), inputs=(args.model_file,))
    fmu = build_modelica_fmu(args.model_file, model=args.model, dest=args.output)
    print(f"ftc-verify build-fmu: {args.model_file}{f' ({args.model})' if args.model else ''}")
    print(f"  FMU {fmu}: model exchange + co-simulation, checked against CasADi's evaluation of the model")
    print("  verdict: built")
    return EXIT_OK


def add_plant_commands(sub: Any) -> None:
    """Register ``plant``, ``linearize`` and ``build-fmu`` on the CLI's subparsers."""
    b = sub.add_parser("build-fmu", help="compile a flat Modelica model into an FMI 2.0 FMU (pymoca + CasADi + gcc)")
    b.add_argument("model_file", help="Modelica .mo file")
    b.add_argument("--model", default=None, help="model name (default: the file's stem)")
    b.add_argument("-o", "--output", default=None, help="FMU file to write (default: the cache folder)")
    b.set_defaults(func=_cmd_build_fmu)

    p = sub.add_parser("plant", help="show a plant map's FMU interface and resolved roles (--check: every fault acts)")
    p.add_argument("plant", help="plant map TOML file")
    p.add_argument("--check", action="store_true", help="one short step in every fault mode; a fault that changes nothing, or an FMU "
                        "call that fails (e.g. fmi2DoStep returning fmi2Error), fails the check (exit 1)")
    p.add_argument("--step", type=positive, default=0.1, help="step length of --check (default 0.1)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    p.set_defaults(func=_cmd_plant)

    lz = sub.add_parser("linearize", help="linearise a plant map's FMU per fault mode into a system file")
    lz.add_argument("plant", help="plant map TOML file")
    lz.add_argument("--trim", action="store_true", help="first find the states that make mode 1 stationary")
    lz.add_argument("--route", default=None, choices=LINEARIZE_ROUTES, help="default: the best the FMU allows")
    lz.add_argument("-o", "--output", default=None, help="system TOML file to write (not the map itself)")
    lz.add_argument("--accept-inaccurate", action="store_true",
                    help=f"write -o even when a matrix's error estimate exceeds {LINEARIZE_ACCURACY:g} of its largest "
                         "entry (without it such a linearisation is reported, exit 1, and not written)")
    lz.add_argument("--json", action="store_true", help="print one JSON object instead of a summary")
    lz.set_defaults(func=_cmd_linearize)
