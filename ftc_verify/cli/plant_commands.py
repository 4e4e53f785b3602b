"""The plant commands of the CLI: ``ftc-verify plant`` and ``ftc-verify linearize`` (a
user's FMU through a plant map, :mod:`ftc_verify.plants.plant_map`) and ``ftc-verify
build-fmu`` (a Modelica model to an FMU, :mod:`ftc_verify.plants.modelica`).

Both follow the exit-code contract of :mod:`ftc_verify.cli.main`: 0 with a verdict line,
1 when ``plant --check`` finds a fault that changes nothing or ``linearize --trim`` finds no
stationary point, 2 for a bad map or FMU (one line naming the file, the key and the value).
"""

from __future__ import annotations

import argparse
import json
from typing import Any

import numpy as np

from .main import EXIT_NEGATIVE, EXIT_OK, _check_output_file, _positive

__all__ = ["add_plant_commands", "describe_plant"]


def _variable(v: Any) -> dict[str, Any]:
    unit = getattr(v, "unit", None) or (getattr(v.declaredType, "unit", None) if v.declaredType else None)
    return {"name": v.name, "type": v.type, "causality": v.causality, "variability": v.variability,
            "start": v.start, "unit": unit, "description": v.description}


def describe_plant(pm: Any, session: Any) -> dict[str, Any]:
    """The FMU's interface and every role of the map resolved to its variable."""
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
    }


def _check_faults(pm: Any, session: Any, step: float) -> list[dict[str, Any]]:
    """One step of ``step`` from the operating point in every fault mode; a mode whose
    states and outputs equal the first mode's after the step changes nothing."""
    from fmpy.fmi2 import fmi2Real

    from ..plants.fmu_session import VarGroup, c_buffer

    x0 = pm.states_op if pm.states_op is not None else np.zeros(len(pm.states))
    uw = np.concatenate([pm.inputs_op, pm.disturbances_op])
    rv = session.variables
    grp = VarGroup(rv.states + rv.outputs + rv.measured)
    rows, first = [], None
    for i, f in enumerate(pm.faults):
        session.start_path(c_buffer(fmi2Real, x0.tolist()), i, None)
        s = session.slave
        s.fmi2SetReal(s.component, session.uw.vr, session.uw.n, c_buffer(fmi2Real, uw.tolist()))
        s.doStep(0.0, step)
        s.fmi2GetReal(s.component, grp.vr, grp.n, grp.buf)
        vals = np.array(list(grp.buf)[:grp.n])
        first = vals if first is None else first
        inert = i > 0 and bool(np.array_equal(vals, first))
        rows.append({"mode": i + 1, "name": f.name, "after_step": vals.tolist(), "changes_nothing": inert})
    return rows


def _cmd_plant(args: argparse.Namespace) -> int:
    from ..plants.fmu_session import FMUSession
    from ..plants.plant_map import load_plant_map

    pm = load_plant_map(args.plant)
    with FMUSession(pm.fmu, pm.injection_map(), tolerance=pm.tolerance) as session:
        d = describe_plant(pm, session)
        if args.check:
            d["check"] = _check_faults(pm, session, args.step)
    inert = [r["name"] for r in d.get("check", []) if r["changes_nothing"]]
    verdict = "fail" if inert else ("checked" if args.check else "done")
    if args.json:
        print(json.dumps(d | {"verdict": verdict}, indent=2, allow_nan=False))
    else:
        print(f"ftc-verify plant: {d['map']}")
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
            print(f"  check mode {r['mode']} ({r['name']}): {'CHANGES NOTHING' if r['changes_nothing'] else 'ok'}")
        for w in d["warnings"]:
            print(f"  warning: {w}")
        print(f"  verdict: {verdict}" + (f" (fault modes {inert} change nothing)" if inert else ""))
    return EXIT_NEGATIVE if inert else EXIT_OK


def _cmd_linearize(args: argparse.Namespace) -> int:
    from ..errors import FMUError
    from ..model.files import save_system
    from ..plants.linearize import linearize_plant, trim_plant
    from ..plants.plant_map import load_plant_map

    if args.output:
        _check_output_file(args.output, "-o")
    pm = load_plant_map(args.plant)
    if pm.chain is None and args.output:
        raise FMUError(f"{pm.source}: [chain] is missing; a system file needs the chain (add it to the map)")
    if args.trim:
        try:
            pm = pm.with_states_op(trim_plant(pm))
        except FMUError as exc:
            print(f"ftc-verify linearize: {exc}")
            print("  verdict: fail (no stationary point)")
            return EXIT_NEGATIVE
    lin = linearize_plant(pm, route=args.route)
    if args.output:
        save_system(lin.system(pm.name, pm.chain), args.output)
    d = lin.to_dict() | {"map": str(pm.source), "fmu": str(pm.fmu), "output": args.output, "verdict": "done"}
    if args.json:
        print(json.dumps(d, indent=2, allow_nan=False))
        return EXIT_OK
    print(f"ftc-verify linearize: {pm.source} ({pm.fmu.name}), route {lin.route}")
    print(f"  operating point x = {lin.states_op.tolist()}, u = {pm.inputs_op.tolist()}")
    for k, m in enumerate(lin.modes, start=1):
        print(f"  mode {k} ({m.name}): A = {np.round(m.A, 6).tolist()}, B = {np.round(m.B, 6).tolist()}; "
              f"drift |f| = {np.linalg.norm(m.drift):.3g}; error estimates {m.errors}")
    for note in lin.notes:
        print(f"  note: {note}")
    if args.output:
        print(f"  system written to {args.output}")
    print("  verdict: done")
    return EXIT_OK


def _cmd_build_fmu(args: argparse.Namespace) -> int:
    from ..plants.modelica import build_modelica_fmu

    if args.output:
        _check_output_file(args.output, "-o", (".fmu",))
    fmu = build_modelica_fmu(args.model_file, model=args.model, dest=args.output)
    print(f"ftc-verify build-fmu: {args.model_file}{f' ({args.model})' if args.model else ''}")
    print(f"  FMU {fmu}: model exchange + co-simulation, checked against CasADi's evaluation of the model")
    print("  verdict: built")
    return EXIT_OK


def add_plant_commands(sub: Any) -> None:
    """Register ``plant``, ``linearize`` and ``build-fmu`` on the CLI's subparsers."""
    from ..plants.linearize import ROUTES

    b = sub.add_parser("build-fmu", help="compile a flat Modelica model into an FMI 2.0 FMU (pymoca + CasADi + gcc)")
    b.add_argument("model_file", help="Modelica .mo file")
    b.add_argument("--model", default=None, help="model name (default: the file's stem)")
    b.add_argument("-o", "--output", default=None, help="FMU file to write (default: the cache folder)")
    b.set_defaults(func=_cmd_build_fmu)

    p = sub.add_parser("plant", help="show a plant map's FMU interface and resolved roles (--check: every fault acts)")
    p.add_argument("plant", help="plant map TOML file")
    p.add_argument("--check", action="store_true", help="one short step in every fault mode; flag faults that change nothing")
    p.add_argument("--step", type=_positive, default=0.1, help="step length of --check (default 0.1)")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=_cmd_plant)

    lz = sub.add_parser("linearize", help="linearise a plant map's FMU per fault mode into a system file")
    lz.add_argument("plant", help="plant map TOML file")
    lz.add_argument("--trim", action="store_true", help="first find the states that make mode 1 stationary")
    lz.add_argument("--route", default=None, choices=ROUTES, help="default: the best the FMU allows")
    lz.add_argument("-o", "--output", default=None, help="system TOML file to write")
    lz.add_argument("--json", action="store_true")
    lz.set_defaults(func=_cmd_linearize)
