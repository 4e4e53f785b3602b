"""FMI 3.0 Co-Simulation FMUs of the ODE models of :mod:`ftc_verify.plants.ode_fmu`.

The same :class:`~ftc_verify.plants.ode_fmu.OdeFmuSpec` and model C file, compiled with
``fmus/ode/ode_glue3.c``: the FMI 3.0 glue that includes the FMI 2.0 glue ``ode_glue.c``
and forwards to it, so integration (Dormand--Prince 5(4), the tolerance of
``fmi3EnterInitializationMode``), directional derivatives and the FMU state are those of
the FMI 2.0 FMU. Variables are ``Float64`` scalars with the value references of
``fmus/ode/ode_model.h`` plus the independent variable ``time`` (value reference 0); the
binary lies in ``binaries/<platform tuple>/`` (``x86_64-linux``) as FMI 3.0 requires.
Only Co-Simulation is served.
"""

from __future__ import annotations

import ctypes
from pathlib import Path
from xml.etree import ElementTree as ET

from .. import __version__
from ..errors import FMUError, ValidationError
from .build import FMI2_HEADERS, fmi2_include_dir
from .ode_fmu import (GLUE_FILES, OdeFmuSpec, add_description_basics, compile_ode_binary, ode_source_dir,
                      package_ode_fmu, probe_binary, spec_guid,
                      value_reference_groups)

__all__ = ["GLUE3_FILES", "FMI3_HEADERS", "ode_model_description3", "build_ode_binary3", "build_ode_fmu3"]

#: Files of ``fmus/ode`` every FMI 3.0 ODE FMU is built from.
GLUE3_FILES = GLUE_FILES + ("ode_glue3.c",)
#: FMI 3.0 headers (from fmpy) the glue includes; their content enters the hash.
FMI3_HEADERS = ("fmi3Functions.h", "fmi3FunctionTypes.h", "fmi3PlatformTypes.h")
_LAYOUT_VERSION = "1"


def _guid3(spec: OdeFmuSpec, src: Path) -> str:
    return spec_guid(f"ode fmu3 {_LAYOUT_VERSION}", spec, src, GLUE3_FILES)


def _variables(spec: OdeFmuSpec) -> list[dict[str, str]]:
    """The ``<Float64>`` attributes in value-reference order (``time`` first, reference 0)."""
    def extra(v: object, start: bool = True) -> dict[str, str]:
        out = {"description": v.description} if v.description else {}  # type: ignore[attr-defined]
        if v.unit:  # type: ignore[attr-defined]
            out["unit"] = v.unit  # type: ignore[attr-defined]
        if start:
            out["start"] = repr(v.start)  # type: ignore[attr-defined]
        return out

    out = [{"name": "time", "causality": "independent", "variability": "continuous",
            "description": "simulation time"}]
    out += [{"name": v.name, "causality": "local", "variability": "continuous", "initial": "exact", **extra(v)}
            for v in spec.states]
    out += [{"name": f"der({v.name})", "causality": "local", "variability": "continuous", "initial": "calculated",
             "description": f"time derivative of {v.name}", "derivative": str(k)}
            for k, v in enumerate(spec.states, start=1)]
    out += [{"name": v.name, "causality": "input", "variability": "continuous", **extra(v)} for v in spec.inputs]
    out += [{"name": v.name, "causality": "parameter", "variability": "tunable" if v.tunable else "fixed",
             "initial": "exact", **extra(v)} for v in spec.parameters]
    out += [{"name": v.name, "causality": "output", "variability": "continuous", "initial": "calculated",
             **extra(v, start=False)} for v in spec.outputs]
    return out


def ode_model_description3(spec: OdeFmuSpec, guid: str) -> str:
    """The FMI 3.0 ``modelDescription.xml`` text (``<CoSimulation>`` only)."""
    root = ET.Element("fmiModelDescription", {
        "fmiVersion": "3.0", "modelName": spec.model_name, "instantiationToken": guid,
        "description": spec.description or f"ODE model {spec.model_name}",
        "generationTool": f"ftc-verify {__version__} (ode_fmu3)", "variableNamingConvention": "structured",
    })
    ET.SubElement(root, "CoSimulation", {
        "modelIdentifier": spec.model_name, "needsExecutionTool": "false",
        "canBeInstantiatedOnlyOncePerProcess": "false", "canGetAndSetFMUState": "true",
        "canSerializeFMUState": "true", "providesDirectionalDerivatives": "true" if spec.has_jacobian else "false",
        "canHandleVariableCommunicationStepSize": "true", "maxOutputDerivativeOrder": "0",
        "hasEventMode": "false", "providesIntermediateUpdate": "false", "mightReturnEarlyFromDoStep": "false",
    })
    add_description_basics(root, spec, "fmi3DoStep")
    variables = ET.SubElement(root, "ModelVariables")
    for vr, attrs in enumerate(_variables(spec)):
        name = attrs.pop("name")
        ET.SubElement(variables, "Float64", {"name": name, "valueReference": str(vr), **attrs})
    states, derivs, inputs, params, outputs = value_reference_groups(spec)
    structure = ET.SubElement(root, "ModelStructure")
    for tag, refs, deps in (("Output", outputs, states + inputs), ("ContinuousStateDerivative", derivs, states + inputs),
                            ("InitialUnknown", derivs + outputs, states + inputs + params)):
        for vr in refs:
            ET.SubElement(structure, tag, {"valueReference": str(vr), "dependencies": " ".join(map(str, deps)),
                                           "dependenciesKind": " ".join(["dependent"] * len(deps))})
    ET.indent(root, space="  ")
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def _probe3(lib: Path, spec: OdeFmuSpec, guid: str) -> None:
    """Instantiate the fresh binary once (:func:`~ftc_verify.plants.ode_fmu.probe_binary`:
    the glue checks the model file against the spec)."""
    messages: list[str] = []
    log_type = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_char_p)
    logger = log_type(lambda env, status, cat, msg: messages.append((msg or b"").decode("utf-8", "replace")))
    probe_binary(lib, spec, what="FMI 3.0 ODE FMU", call="fmi3InstantiateCoSimulation",
                 argtypes=[ctypes.c_char_p, ctypes.c_char_p, ctypes.c_char_p, ctypes.c_bool, ctypes.c_bool,
                           ctypes.c_bool, ctypes.c_bool, ctypes.c_void_p, ctypes.c_size_t, ctypes.c_void_p,
                           log_type, ctypes.c_void_p],
                 args=(b"probe", guid.encode(), b"", False, False, False, False, None, 0, None, logger, None),
                 free="fmi3FreeInstance", messages=messages)


def build_ode_binary3(spec: OdeFmuSpec, force: bool = False) -> Path:
    """Compile (or reuse) the FMI 3.0 shared library of ``spec`` in :func:`~ftc_verify.plants.build.cache_dir`
    (as :func:`~ftc_verify.plants.ode_fmu.build_ode_binary`, with ``ode_glue3.c``)."""
    if not isinstance(spec, OdeFmuSpec):
        raise ValidationError(f"build_ode_binary3: expected an OdeFmuSpec, got {type(spec).__name__}")
    src = ode_source_dir()
    if not (src / "ode_glue3.c").is_file():
        raise FMUError(f"{src / 'ode_glue3.c'}: the FMI 3.0 glue of the ODE FMU is missing")
    include = fmi2_include_dir()
    missing = [h for h in FMI3_HEADERS if not (include / h).is_file()]
    if missing:
        raise FMUError(f"{include}: FMI 3.0 header(s) {missing} not found in the fmpy package")
    return compile_ode_binary(spec, _guid3(spec, src), force=force, hash_tag="ode binary3",
                              stem=f"{spec.model_name}-fmi3", glue_files=GLUE3_FILES, glue_source="ode_glue3.c",
                              headers=FMI3_HEADERS + FMI2_HEADERS,
                              probe=_probe3)


def build_ode_fmu3(spec: OdeFmuSpec, dest: Path | None = None) -> Path:
    """Build the FMI 3.0 Co-Simulation ``.fmu`` of ``spec`` and return its path (``dest``
    as for :func:`~ftc_verify.plants.ode_fmu.build_ode_fmu`; default
    ``<cache_dir()>/<model_name>-fmi3-<hash>.fmu``)."""
    import fmpy

    binary = build_ode_binary3(spec)
    guid = _guid3(spec, ode_source_dir())
    return package_ode_fmu(spec, guid=guid, binary=binary, platform=fmpy.platform_tuple,
                           model_description=ode_model_description3(spec, guid), glue_files=GLUE3_FILES,
                           dest=dest, cache_stem=f"{spec.model_name}-fmi3-{guid[1:13]}")
