r"""Co-simulation FMUs (FMI 2.0 and 3.0, source code and a binary) of an FDI-switched controller.

The controller of :mod:`ftc_verify.export.ccode` -- per FDI mode :math:`l`,
:math:`u_k = C_{c,l} x_{c,k} + D_{c,l} v_k`, :math:`x_{c,k+1} = \Phi_{c,l} x_{c,k} +
\Gamma_{c,l} v_k` with the sampled matrices of period :math:`h` -- behind the FMI
glue ``fmus/controller/ctrl_glue.c`` (FMI 2.0 Co-Simulation; with the FMI 2.0 glue every
FMU shares, ``fmus/common/fmi2_common.h``) or ``ctrl_glue3.c`` (FMI 3.0: the ODE FMUs' FMI
3.0 glue ``fmus/ode/ode_glue3.c`` around the FMI 2.0 glue). Every file compiled in travels in
the archive's ``sources/`` and enters the GUID. Built with
the package's toolchain (:mod:`ftc_verify.plants.build`: gcc, the FMI headers of fmpy,
the flags, the atomic reproducible archive) and the model-description elements of the ODE
FMUs (:func:`~ftc_verify.plants.model_description.add_description_elements`).

Variables, value references (one sequence over every type) and causalities:

====================  =======================  =============================================
``v[1]..v[nv]``       1 .. nv                  input, Real / Float64: ``x`` or ``y_m``
``u[1]..u[nu]``       nv+1 .. nv+nu            output, direct feedthrough of ``v``, ``fdi_mode``
``xc[1]..xc[nc]``     nv+nu+1 .. nv+nu+nc      local: the controller state
``samplePeriod``      nv+nu+nc+1               constant (unit ``s``): the period ``h``
``fdi_mode``          nv+nu+nc+2               input, Integer / Int32, ``1..m``
====================  =======================  =============================================

(FMI 3.0 adds the independent variable ``time``, value reference 0.) The default
experiment's step is ``h``; ``canHandleVariableCommunicationStepSize`` is false and a
``doStep`` of another length fails with a log message. The certificate (``gamma``, the
period, the system's name and SHA-256) is written into the model description's vendor
annotations (FMI 2.0 ``<VendorAnnotations><Tool name="ftc-verify">``, FMI 3.0
``<Annotations><Annotation type="org.ftc-verify.certificate">``) and the controller and system
files into ``resources/``.
"""

from __future__ import annotations

import hashlib
import re
import tempfile
import uuid
from pathlib import Path
from xml.etree import ElementTree as ET

from .. import __version__
from ..errors import FMUError, ValidationError
from ..plants.build import (CFLAGS, COMMON_FILES, binary_platform, common_source_dir, find_gcc, fmi2_include_dir,
                            fmi3_platform_tuple, link_flags, run_compiler, source_members, write_zip)
from ..plants.model_description import add_description_elements
from ..plants.ode_fmu import ode_source_dir
from .ccode import ControllerTables

__all__ = ["FMI_VERSIONS", "CONTROLLER_SOURCE", "controller_source_dir", "model_identifier", "controller_guid",
           "controller_model_description", "spec_header", "build_controller_fmu"]

#: The FMI versions an exported controller can have.
FMI_VERSIONS = ("2.0", "3.0")
#: The name of the generated controller file inside the FMU's ``sources/``.
CONTROLLER_SOURCE = "ftc_controller.c"
_GLUE = {"2.0": ("ctrl_glue.c",), "3.0": ("ctrl_glue.c", "ctrl_glue3.c")}
_LAYOUT_VERSION = "1"
_NOT_IDENT = re.compile(r"[^A-Za-z0-9_]")


def controller_source_dir() -> Path:
    """The folder of the controller glue (``fmus/controller`` of the source tree).

    Raises
    ------
    FMUError
        When the glue files are missing.
    """
    path = ode_source_dir().parent / "controller"
    if not all((path / name).is_file() for name in _GLUE["3.0"]):
        raise FMUError(f"{path}: C sources of the controller FMU glue ({', '.join(_GLUE['3.0'])}) not found")
    return path


def model_identifier(stem: str) -> str:
    """A C identifier from a file stem (``K.fmu`` -> ``K``): other characters become ``_``,
    and a leading digit (or an empty name) gets ``ftc_`` in front."""
    ident = _NOT_IDENT.sub("_", stem)
    return ident if ident and not ident[0].isdigit() and ident not in ("ctrl_glue", "ctrl_glue3") else f"ftc_{ident}"


def controller_guid(c_source: str, identifier: str, fmi_version: str) -> str:
    """The GUID (instantiation token) of a controller FMU: a UUID from the SHA-256 of the
    generated C file, the identifier, the FMI version and the glue sources."""
    h = hashlib.sha256(f"ftc-verify controller fmu {_LAYOUT_VERSION}\0{identifier}\0{fmi_version}\0".encode())
    h.update(c_source.encode())
    src = controller_source_dir()
    for name in _GLUE[fmi_version]:
        h.update((src / name).read_bytes())
    if fmi_version == "3.0":
        h.update((ode_source_dir() / "ode_glue3.c").read_bytes())
    for name in COMMON_FILES:
        h.update((common_source_dir(src) / name).read_bytes())
    return "{" + str(uuid.UUID(hex=h.hexdigest()[:32], version=5)) + "}"


def _variables(t: ControllerTables) -> list[tuple[str, dict[str, str], str, dict[str, str]]]:
    """``(name, attributes, FMI 2.0 type, type attributes)`` in value-reference order (from 1)."""
    v_what = "plant state x" if t.measures == "state" else "measured output y_m = Cy x (of the true mode)"
    out = [(f"v[{i}]", {"causality": "input", "variability": "continuous",
                        "description": f"controller input: {v_what}, component {i}, held over a step"},
            "Real", {"start": "0.0"}) for i in range(1, t.nv + 1)]
    out += [(f"u[{i}]", {"causality": "output", "variability": "continuous", "initial": "calculated",
                         "description": f"control input u = Cc[l] xc + Dc[l] v, component {i} (l = fdi_mode)"},
             "Real", {}) for i in range(1, t.nu + 1)]
    out += [(f"xc[{i}]", {"causality": "local", "variability": "discrete", "initial": "exact",
                          "description": f"controller state, component {i} (0 at the start)"},
             "Real", {"start": "0.0"}) for i in range(1, t.nc + 1)]
    out.append(("samplePeriod", {"causality": "local", "variability": "constant", "initial": "exact",
                                 "description": "the sampling period h the update is exact for (the only step accepted)"},
                "Real", {"unit": "s", "start": repr(t.step)}))
    out.append(("fdi_mode", {"causality": "input", "variability": "discrete",
                             "description": f"the FDI mode l (1..{t.modes}) the controller entry is chosen by"},
                "Integer", {"start": "1", "min": "1", "max": str(t.modes)}))
    return out


def _certificate_element(parent: ET.Element, tag: str, certificate: dict[str, str]) -> None:
    ET.SubElement(parent, tag, dict(sorted(certificate.items())))


def controller_model_description(t: ControllerTables, *, identifier: str, guid: str, fmi_version: str,
                                 description: str, certificate: dict[str, str]) -> str:
    """The ``modelDescription.xml`` text of a controller FMU (module docstring).

    Parameters
    ----------
    t : ControllerTables
        The sampled controller.
    identifier, guid : str
        The model identifier and GUID (:func:`model_identifier`, :func:`controller_guid`).
    fmi_version : {"2.0", "3.0"}
    description : str
        The model description's ``description``.
    certificate : dict of str
        Attributes of the ``Certificate`` element of the vendor annotations.
    """
    fmi3 = fmi_version == "3.0"
    head = {"fmiVersion": fmi_version, "modelName": identifier,
            ("instantiationToken" if fmi3 else "guid"): guid, "description": description,
            "generationTool": f"ftc-verify {__version__} (export-controller)", "variableNamingConvention": "structured"}
    if not fmi3:
        head["numberOfEventIndicators"] = "0"
    root = ET.Element("fmiModelDescription", head)
    cs = {"modelIdentifier": identifier, "needsExecutionTool": "false", "canBeInstantiatedOnlyOncePerProcess": "false",
          "canHandleVariableCommunicationStepSize": "false", "maxOutputDerivativeOrder": "0"}
    if fmi3:
        cs |= {"canGetAndSetFMUState": "true", "canSerializeFMUState": "true", "providesDirectionalDerivatives": "false",
               "hasEventMode": "false", "providesIntermediateUpdate": "false", "mightReturnEarlyFromDoStep": "false",
               "fixedInternalStepSize": repr(t.step)}
        ET.SubElement(root, "CoSimulation", cs)
    else:
        cs |= {"canNotUseMemoryManagementFunctions": "false", "canGetAndSetFMUstate": "true",
               "canSerializeFMUstate": "true", "providesDirectionalDerivative": "false",
               "canInterpolateInputs": "false", "canRunAsynchronuously": "false"}
        files = ET.SubElement(ET.SubElement(root, "CoSimulation", cs), "SourceFiles")
        ET.SubElement(files, "File", {"name": "ctrl_glue.c"})
    add_description_elements(root, ["s"], "information: instantiation, every step (FDI mode, time)",
                             stop_time=max(10.0, 10 * t.step), tolerance=None, step_size=t.step)
    variables = _variables(t)
    if not fmi3:
        _certificate_element(ET.SubElement(ET.SubElement(root, "VendorAnnotations"), "Tool", {"name": "ftc-verify"}),
                             "Certificate", certificate)
        mv = ET.SubElement(root, "ModelVariables")
        for vr, (name, attrs, typ, type_attrs) in enumerate(variables, start=1):
            ET.SubElement(ET.SubElement(mv, "ScalarVariable", {"name": name, "valueReference": str(vr), **attrs}),
                          typ, type_attrs)
    else:
        mv = ET.SubElement(root, "ModelVariables")
        ET.SubElement(mv, "Float64", {"name": "time", "valueReference": "0", "causality": "independent",
                                      "variability": "continuous", "description": "simulation time"})
        for vr, (name, attrs, typ, type_attrs) in enumerate(variables, start=1):
            tag = "Float64" if typ == "Real" else "Int32"
            ET.SubElement(mv, tag, {"name": name, "valueReference": str(vr), **attrs, **type_attrs})
    _structure(root, t, fmi3)
    if fmi3:
        note = ET.SubElement(ET.SubElement(root, "Annotations"), "Annotation", {"type": "org.ftc-verify.certificate"})
        _certificate_element(note, "Certificate", certificate)
    ET.indent(root, space="  ")
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def _structure(root: ET.Element, t: ControllerTables, fmi3: bool) -> None:
    """``u[i]`` depends on every ``v`` and ``fdi_mode`` (direct feedthrough) and on the
    controller state (which FMI does not list: ``xc`` is discrete)."""
    inputs = list(range(1, t.nv + 1)) + [t.nv + t.nu + t.nc + 2]
    deps = {"dependencies": " ".join(map(str, inputs)), "dependenciesKind": " ".join(["dependent"] * len(inputs))}
    outputs = range(t.nv + 1, t.nv + t.nu + 1)
    structure = ET.SubElement(root, "ModelStructure")
    if fmi3:
        for vr in outputs:
            ET.SubElement(structure, "Output", {"valueReference": str(vr), **deps})
        for vr in outputs:
            ET.SubElement(structure, "InitialUnknown", {"valueReference": str(vr), **deps})
        return
    for tag in ("Outputs", "InitialUnknowns"):
        el = ET.SubElement(structure, tag)
        for index in outputs:
            ET.SubElement(el, "Unknown", {"index": str(index), **deps})


def _compile(c_source: str, spec_header: str, fmi_version: str, identifier: str, out: Path) -> None:
    """Compile the controller's shared library ``out`` (the package's flags, ``-Werror``)."""
    src, include = controller_source_dir(), fmi2_include_dir()
    gcc = find_gcc(src / _GLUE[fmi_version][-1])
    tmp = out.parent
    (tmp / CONTROLLER_SOURCE).write_text(c_source, encoding="utf-8")
    (tmp / "ctrl_spec.h").write_text(spec_header, encoding="utf-8")
    includes = (tmp, src, ode_source_dir(), common_source_dir(src), include)
    cmd = [gcc, *CFLAGS, "-Werror", *(a for d in includes for a in ("-I", str(d))),
           str(src / _GLUE[fmi_version][-1]), "-o", str(out), *link_flags()]
    proc = run_compiler(cmd, CONTROLLER_SOURCE)
    if proc.returncode != 0:
        lines = [ln for ln in proc.stderr.splitlines() if "error" in ln] or proc.stderr.strip().splitlines() or ["?"]
        raise FMUError(f"{CONTROLLER_SOURCE}: compiling the controller FMU {identifier!r} failed (gcc exit status "
                       f"{proc.returncode}): {lines[0].strip()}")


def spec_header(identifier: str, guid: str) -> str:
    """The generated ``ctrl_spec.h``: the model name and GUID the glue checks."""
    return (f"/* generated by ftc-verify {__version__}: do not edit */\n#ifndef CTRL_SPEC_H\n#define CTRL_SPEC_H\n"
            f'#define CTRL_MODEL_NAME "{identifier}"\n#define CTRL_GUID "{guid}"\n#endif\n')


def build_controller_fmu(tables: ControllerTables, c_source: str, dest: Path, *, fmi_version: str, description: str,
                         certificate: dict[str, str], resources: dict[str, str]) -> Path:
    """Compile and write the controller FMU ``dest`` (atomically); returns ``dest``.

    Parameters
    ----------
    tables : ControllerTables
        The sampled controller (:func:`~ftc_verify.export.ccode.controller_tables`).
    c_source : str
        Its C file (:func:`~ftc_verify.export.ccode.controller_c_source`).
    dest : Path
        The ``.fmu`` file; its stem gives the model identifier (:func:`model_identifier`).
    fmi_version : {"2.0", "3.0"}
    description : str
        The model description's ``description``.
    certificate : dict of str
        The certificate's attributes (vendor annotations).
    resources : dict of str
        Files written under ``resources/`` (name -> text).

    Raises
    ------
    FMUError
        When gcc is missing or fails (its first error line).
    """
    if fmi_version not in FMI_VERSIONS:
        raise ValidationError(f"--fmi {fmi_version!r}: expected one of {', '.join(FMI_VERSIONS)}")
    identifier = model_identifier(Path(dest).stem)
    guid = controller_guid(c_source, identifier, fmi_version)
    header = spec_header(identifier, guid)
    folder, suffix = binary_platform()
    if fmi_version == "3.0":
        folder = fmi3_platform_tuple()
    with tempfile.TemporaryDirectory(prefix="ftc-verify-controller-") as tmp_name:
        lib = Path(tmp_name) / f"{identifier}{suffix}"
        _compile(c_source, header, fmi_version, identifier, lib)
        binary = lib.read_bytes()
    src = controller_source_dir()
    md = controller_model_description(tables, identifier=identifier, guid=guid, fmi_version=fmi_version,
                                      description=description, certificate=certificate)
    members = [("modelDescription.xml", md.encode(), 0o644), (f"binaries/{folder}/{identifier}{suffix}", binary, 0o755),
               (f"sources/{CONTROLLER_SOURCE}", c_source.encode(), 0o644), ("sources/ctrl_spec.h", header.encode(), 0o644)]
    members += source_members(src, _GLUE[fmi_version]) + source_members(common_source_dir(src), COMMON_FILES)
    if fmi_version == "3.0":
        members += source_members(ode_source_dir(), ("ode_glue3.c",))
    members += [(f"resources/{name}", text.encode(), 0o644) for name, text in sorted(resources.items())]
    write_zip(Path(dest), members)
    return Path(dest)
