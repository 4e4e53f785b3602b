"""The ``modelDescription.xml`` of the ``LinearJumpPlant`` FMU.

This module also holds :func:`add_description_elements`, the ``<UnitDefinitions>``,
``<LogCategories>`` and ``<DefaultExperiment>`` the ODE FMUs and the exported controller
FMUs write. For the ``LinearJumpPlant`` it implements the FMU's variable list (:func:`variable_names`, value references
1, 2, ... in the order of ``ljp_layout`` in ``fmus/LinearJumpPlant/model.c``) and the
model description generated per system (:func:`model_description`): the variables with
their causality, the ``<ModelStructure>`` (outputs ``x``, ``y``, ``ym``; ``y[i]`` and
``ym[i]`` depend on ``mode`` when row ``i`` of ``C``, resp. ``Cy``, differs between
modes) and the co-simulation capabilities.
"""

from __future__ import annotations

from collections.abc import Iterable
from xml.etree import ElementTree as ET

import numpy as np

from .. import __version__
from ..model.system import FTCSystem
from .system_text import MODEL_IDENTIFIER, FMUDims, fmu_dims

__all__ = ["SOURCE_FILES", "variable_names", "model_description", "add_description_elements"]

#: C sources of the FMU (in :func:`ftc_verify.plants.linear_jump.source_dir`).
SOURCE_FILES = ("model.h", "model.c", "fmi2_glue.c")

_CAPABILITIES = {
    "modelIdentifier": MODEL_IDENTIFIER,
    "needsExecutionTool": "false",
    "canHandleVariableCommunicationStepSize": "true",
    "canInterpolateInputs": "false",
    "maxOutputDerivativeOrder": "0",
    "canRunAsynchronuously": "false",
    "canBeInstantiatedOnlyOncePerProcess": "false",
    "canNotUseMemoryManagementFunctions": "false",
    "canGetAndSetFMUstate": "true",
    "canSerializeFMUstate": "true",
    "providesDirectionalDerivative": "false",
}

_LOG_CATEGORIES = (
    ("logEvents", "information: instantiation, systemFile, new discretisations"),
    ("logStatusWarning", "warnings"),
    ("logStatusError", "errors (always reported)"),
    ("logAll", "all of the above"),
)


def variable_names(dims: FMUDims) -> list[str]:
    """Names of the FMU's variables in value-reference order (references 1, 2, ...);
    the layout must match ``ljp_layout`` in ``model.c``."""
    names = [f"x0[{k}]" for k in range(1, dims.n + 1)]
    names += [f"u[{k}]" for k in range(1, dims.nu + 1)]
    names += [f"w[{k}]" for k in range(1, dims.nw + 1)]
    names += [f"Delta1[{i},{j}]" for i in range(1, dims.q1 + 1) for j in range(1, dims.p1 + 1)]
    names += [f"Delta2[{i},{j}]" for i in range(1, dims.q2 + 1) for j in range(1, dims.p2 + 1)]
    names += [f"x[{k}]" for k in range(1, dims.n + 1)]
    names += [f"y[{k}]" for k in range(1, dims.ny + 1)]
    names += [f"ym[{k}]" for k in range(1, int(dims.nym) + 1)]  # type: ignore[arg-type]
    names += ["mode", "systemFile"]
    return names


def _variable(name: str, d: FMUDims) -> tuple[dict[str, str], str, dict[str, str]]:
    """``(attributes, type element, type attributes)`` of the variable ``name``."""
    param = {"causality": "parameter", "variability": "fixed", "initial": "exact"}
    cont_in = {"causality": "input", "variability": "continuous"}
    out = {"causality": "output", "variability": "continuous", "initial": "calculated"}
    base = name.split("[", 1)[0]
    if base == "x0":
        return {**param, "description": f"initial state {name.replace('x0', 'x')}"}, "Real", {"start": "0.0"}
    if base == "u":
        return {**cont_in, "description": "control input (held over a step)"}, "Real", {"start": "0.0"}
    if base == "w":
        return {**cont_in, "description": "disturbance input (held over a step)"}, "Real", {"start": "0.0"}
    if base in ("Delta1", "Delta2"):
        what = "A + A1 Delta1 A2" if base == "Delta1" else "B + B1 Delta2 B2"
        return ({**cont_in, "description": f"uncertainty in {what} (||Delta|| <= 1 is not enforced)"},
                "Real", {"start": "0.0"})
    if base == "x":
        return {**out, "description": "state"}, "Real", {}
    if base == "y":
        return {**out, "description": "output y = C x of the current mode"}, "Real", {}
    if base == "ym":
        return ({**out, "description": "measured output ym = Cy x of the current mode (Cy = C when not given)"},
                "Real", {})
    if name == "mode":
        return ({"causality": "input", "variability": "discrete",
                 "description": f"true fault mode r (1..{d.m}), held over a step"},
                "Integer", {"start": "1", "min": "1", "max": str(d.m)})
    if name == "systemFile":
        return ({**param, "description": "system file (path or file URI) read at "
                 "fmi2ExitInitializationMode instead of resources/system.txt; same dimensions"},
                "String", {"start": ""})
    raise AssertionError(f"unknown variable {name!r}")  # pragma: no cover - variable_names is closed


def _output_unknowns(parent: ET.Element, system: FTCSystem, d: FMUDims, index: dict[str, int]) -> None:
    """``<Outputs>``: ``x`` depends on nothing; ``y[i]``/``ym[i]`` on ``mode`` when their row varies."""
    for k in range(1, d.n + 1):
        ET.SubElement(parent, "Unknown", {"index": str(index[f"x[{k}]"]), "dependencies": ""})
    for prefix, stack in (
        ("y", np.stack([np.asarray(md.C, dtype=float) for md in system.modes])),
        ("ym", np.stack([np.asarray(md.measured, dtype=float) for md in system.modes])),
    ):
        for i in range(1, stack.shape[1] + 1):
            rows = stack[:, i - 1, :]
            if np.all(rows == rows[0]):  # the row does not depend on the mode
                ET.SubElement(parent, "Unknown", {"index": str(index[f"{prefix}[{i}]"]), "dependencies": ""})
            else:
                ET.SubElement(parent, "Unknown", {
                    "index": str(index[f"{prefix}[{i}]"]),
                    "dependencies": str(index["mode"]),
                    "dependenciesKind": "dependent",
                })


def model_description(system: FTCSystem, guid: str) -> str:
    """The ``modelDescription.xml`` text of the FMU for ``system``."""
    d = fmu_dims(system)
    root = ET.Element("fmiModelDescription", {
        "fmiVersion": "2.0",
        "modelName": MODEL_IDENTIFIER,
        "guid": guid,
        "description": (
            f"Linear Markov-jump plant '{system.name}' (n={d.n}, nu={d.nu}, ny={d.ny}, "
            f"nw={d.nw}, nym={d.nym}, m={d.m} modes): x' = (A + A1 Delta1 A2) x + (B + B1 Delta2 B2) u "
            "+ D w, y = C x, ym = Cy x in the true fault mode; exact zero-order-hold steps"
        ),
        "generationTool": f"ftc-verify {__version__}",
        "variableNamingConvention": "structured",
        "numberOfEventIndicators": "0",
    })
    cs = ET.SubElement(root, "CoSimulation", dict(_CAPABILITIES))
    files = ET.SubElement(cs, "SourceFiles")
    for name in SOURCE_FILES:
        if name.endswith(".c"):
            ET.SubElement(files, "File", {"name": name})
    cats = ET.SubElement(root, "LogCategories")
    for name, text in _LOG_CATEGORIES:
        ET.SubElement(cats, "Category", {"name": name, "description": text})
    ET.SubElement(root, "DefaultExperiment", {"startTime": "0.0", "stopTime": "10.0", "stepSize": "0.01"})

    variables = ET.SubElement(root, "ModelVariables")
    names = variable_names(d)
    index = {name: k for k, name in enumerate(names, start=1)}  # value reference == index
    for name in names:
        attrs, typ, type_attrs = _variable(name, d)
        sv = ET.SubElement(variables, "ScalarVariable", {"name": name, "valueReference": str(index[name]), **attrs})
        ET.SubElement(sv, typ, type_attrs)

    structure = ET.SubElement(root, "ModelStructure")
    _output_unknowns(ET.SubElement(structure, "Outputs"), system, d, index)
    initial = ET.SubElement(structure, "InitialUnknowns")
    for name in names:
        if name.startswith(("x[", "y[", "ym[")):
            ET.SubElement(initial, "Unknown", {"index": str(index[name])})

    ET.indent(root, space="  ")
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def add_description_elements(root: ET.Element, units: Iterable[str], events: str, *, stop_time: float,
                             tolerance: float | None, step_size: float) -> None:
    """``<UnitDefinitions>`` (the ``units``, sorted; none when empty), ``<LogCategories>``
    (``logEvents`` described by ``events``, warnings, errors, all) and
    ``<DefaultExperiment>`` (start 0, ``stop_time``, ``tolerance`` when given, ``step_size``):
    the elements every FMU of the package writes, for FMI 2.0 and 3.0 alike."""
    names = sorted(set(units))
    if names:
        defs = ET.SubElement(root, "UnitDefinitions")
        for name in names:
            ET.SubElement(defs, "Unit", {"name": name})
    cats = ET.SubElement(root, "LogCategories")
    for name, text in (("logEvents", events),
                       ("logStatusWarning", "warnings"), ("logStatusError", "errors (always reported)"),
                       ("logAll", "all of the above")):
        ET.SubElement(cats, "Category", {"name": name, "description": text})
    experiment = {"startTime": "0.0", "stopTime": repr(stop_time)}
    if tolerance is not None:
        experiment["tolerance"] = repr(tolerance)
    ET.SubElement(root, "DefaultExperiment", experiment | {"stepSize": repr(step_size)})
