r"""FMI 2.0 FMUs (Model Exchange *and* Co-Simulation in one archive) of a nonlinear ODE in C.

The model

.. math::

    \dot x = f(t, x, u, p), \qquad y = g(t, x, u, p)

with states :math:`x`, Real inputs :math:`u`, Real parameters :math:`p` and Real outputs
:math:`y` is one C file (contract and value-reference layout: ``fmus/ode/ode_model.h``)
compiled together with the generic glue ``fmus/ode/ode_glue.c`` (which includes the FMI 2.0
glue every FMU of the package shares, ``fmus/common/fmi2_common.h``) and a header
``ode_spec.h`` generated from an :class:`OdeFmuSpec` (names, start values, GUID,
``ODE_SPEC_HAS_JACOBIAN``). Value references are consecutive from 1: states, their
derivatives ``der(x)``, inputs, parameters, outputs.

Co-Simulation (``fmi2DoStep``) integrates with the embedded Dormand--Prince 5(4) pair
(FSAL, 5th-order solution propagated), inputs held over the step. A step of size
:math:`h` from :math:`x` to :math:`x_{new}` is accepted when

.. math::

    \sqrt{\tfrac{1}{n_x} \sum_i \Big(\frac{e_i}{a + r \max(|x_i|, |x_{new,i}|)}\Big)^2} \le 1,

:math:`e` the embedded error estimate, :math:`r` the ``tolerance`` of
``fmi2SetupExperiment`` (default ``1e-8``, at least ``1e-13``) and :math:`a = 10^{-2} r`;
the next step is :math:`h \min(5, \max(0.2, 0.9\,\mathrm{err}^{-1/5}))`, and the last
internal step is cut so that a communication step ends exactly at :math:`t + h`.
Model Exchange leaves integration to the importer. With ``has_jacobian`` the model's exact
Jacobians serve ``fmi2GetDirectionalDerivative``.

The binary is cached in :func:`~ftc_verify.plants.build.cache_dir` under a name
carrying the SHA-256 of the glue (the shared file included), the model source, the generated header, the FMI headers,
the compiler flags and the compiler's identity, and is checked once after compiling by
instantiating it (the model's ``ODE_NX``.. and ``ODE_HAS_JACOBIAN`` must match the spec).
"""

from __future__ import annotations

import ctypes
import hashlib
import itertools
import math
import os
import re
import tempfile
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from xml.etree import ElementTree as ET

from .. import __version__
from ..errors import FMUError, ValidationError
from .model_description import add_description_elements
from .build import (CFLAGS, COMMON_FILES, FMI2_HEADERS, binary_platform, build_lock, cache_dir, common_source_dir,
                    compiler_identity, file_hash, find_gcc, fmi2_include_dir, fmu_destination, fmus_folder, hash_files,
                    is_cached, link_flags, record_hash, run_compiler, source_members, write_zip)

__all__ = ["DEFAULT_RTOL", "GLUE_FILES", "VARIABLE_GROUPS", "OdeVariable", "OdeFmuSpec", "ode_source_dir",
           "ode_spec_header", "ode_model_description", "value_reference_groups", "add_description_basics", "build_ode_binary", "compile_ode_binary", "build_ode_fmu",
           "package_ode_fmu", "probe_binary", "spec_guid",
           "motor_spec"]

#: Relative tolerance of ``fmi2DoStep`` when ``fmi2SetupExperiment`` defines none.
DEFAULT_RTOL = 1e-8
#: Files of ``fmus/ode`` every ODE FMU is built from.
GLUE_FILES = ("ode_model.h", "ode_glue.c")
_LAYOUT_VERSION = "1"  # bumped when the generated layout changes (enters the GUID)
_IDENT = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")
#: The variable groups of an :class:`OdeFmuSpec`, in value-reference order (``der(x)`` follows the states).
VARIABLE_GROUPS = ("states", "inputs", "parameters", "outputs")


# ------------------------------------------------------------------------------------------
# Specification
# ------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class OdeVariable:
    """One Real variable of an ODE FMU.

    Parameters
    ----------
    name : str
        A C identifier, unique in its spec (state ``x`` also names ``der(x)``).
    start : float
        Finite start value (ignored for outputs, which are calculated).
    description, unit : str
        Free text; a non-empty ``unit`` is declared in ``<UnitDefinitions>``.
    tunable : bool
        Parameters only: ``variability="tunable"`` (settable at any time) when true,
        ``"fixed"`` (settable before and in Initialization Mode) otherwise.
    """

    name: str
    start: float = 0.0
    description: str = ""
    unit: str = ""
    tunable: bool = True

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not _IDENT.match(self.name):
            raise ValidationError(
                f"OdeVariable.name: {self.name!r} is not a C identifier ([A-Za-z_][A-Za-z0-9_]*)"
            )
        try:
            start = float(self.start)
        except (TypeError, ValueError):
            raise ValidationError(f"OdeVariable {self.name!r}: start {self.start!r} is not a number") from None
        if not math.isfinite(start):
            raise ValidationError(f"OdeVariable {self.name!r}: start = {start} is not finite")
        object.__setattr__(self, "start", start)
        for attr in ("description", "unit"):
            if not isinstance(getattr(self, attr), str):
                raise ValidationError(f"OdeVariable {self.name!r}: {attr} must be a str, got {getattr(self, attr)!r}")
        if not isinstance(self.tunable, bool):
            raise ValidationError(f"OdeVariable {self.name!r}: tunable must be a bool, got {self.tunable!r}")


@dataclass(frozen=True, kw_only=True)
class OdeFmuSpec:
    """What :func:`build_ode_fmu` needs: variables, C source and metadata (keyword-only).

    Parameters
    ----------
    model_name : str
        Model name and ``modelIdentifier`` (a C identifier).
    states, inputs, parameters, outputs : tuple of OdeVariable
        In the order of the C arrays ``x``, ``u``, ``p``, ``y``; at least one state.
    c_source : str
        The model C file (contract: ``fmus/ode/ode_model.h``).
    description : str
        The model description's ``description``.
    has_jacobian : bool
        Must equal the model's ``ODE_HAS_JACOBIAN``; sets ``providesDirectionalDerivative``.
    stop_time, step_size, tolerance : float
        ``<DefaultExperiment>`` (start time 0).
    """

    model_name: str
    states: tuple[OdeVariable, ...]
    c_source: str
    inputs: tuple[OdeVariable, ...] = ()
    parameters: tuple[OdeVariable, ...] = ()
    outputs: tuple[OdeVariable, ...] = ()
    description: str = ""
    has_jacobian: bool = False
    stop_time: float = 10.0
    step_size: float = 0.01
    tolerance: float = DEFAULT_RTOL

    def __post_init__(self) -> None:
        if not isinstance(self.model_name, str) or not _IDENT.match(self.model_name):
            raise ValidationError(f"OdeFmuSpec.model_name: {self.model_name!r} is not a C identifier")
        if self.model_name == "ode_glue":  # <model_name>.c would clash with the glue's file
            raise ValidationError("OdeFmuSpec.model_name: 'ode_glue' is reserved")
        where = f"OdeFmuSpec {self.model_name!r}"
        seen: dict[str, str] = {}
        for group in VARIABLE_GROUPS:
            items = getattr(self, group)
            if isinstance(items, (str, bytes)) or not hasattr(items, "__iter__"):
                raise ValidationError(f"{where}: {group} must be a sequence of OdeVariable, got {items!r}")
            items = tuple(items)
            object.__setattr__(self, group, items)
            for v in items:
                if not isinstance(v, OdeVariable):
                    raise ValidationError(f"{where}: {group} holds {v!r}, not an OdeVariable")
                if v.name in seen:
                    raise ValidationError(f"{where}: variable name {v.name!r} is used twice ({seen[v.name]} and {group})")
                seen[v.name] = group
        if not self.states:
            raise ValidationError(f"{where}: states is empty (an ODE needs at least one state)")
        if not isinstance(self.c_source, str) or not self.c_source.strip():
            raise ValidationError(f"{where}: c_source is empty")
        if not isinstance(self.has_jacobian, bool) or not isinstance(self.description, str):
            raise ValidationError(f"{where}: has_jacobian must be a bool and description a str")
        for attr in ("stop_time", "step_size", "tolerance"):
            value = getattr(self, attr)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not (0 < value < math.inf):
                raise ValidationError(f"{where}: {attr} = {value!r} must be a finite number > 0")
            object.__setattr__(self, attr, float(value))

    def variable_names(self) -> list[str]:
        """All variable names in value-reference order (1, 2, ...)."""
        return ([v.name for v in self.states] + [f"der({v.name})" for v in self.states]
                + [v.name for group in VARIABLE_GROUPS[1:] for v in getattr(self, group)])


# ------------------------------------------------------------------------------------------
# Sources, generated header, model description
# ------------------------------------------------------------------------------------------


def ode_source_dir() -> Path:
    """Folder with :data:`GLUE_FILES` (and ``motor.c``).

    ``<repository>/fmus/ode`` in a source checkout or editable install, else ``ode/`` in the
    package data ``ftc_verify._fmus`` (the way
    :func:`~ftc_verify.plants.linear_jump.source_dir` finds its sources).
    """
    found, first = fmus_folder("ode", GLUE_FILES)
    if found is None:
        raise FMUError(f"{first}: C sources of the ODE FMU glue ({', '.join(GLUE_FILES)}) not found")
    return found


def spec_guid(tag: str, spec: OdeFmuSpec, src: Path, glue_files: tuple[str, ...]) -> str:
    """The GUID of an ODE FMU of either FMI version: a UUID from the SHA-256 of ``tag``, the
    spec, the ``glue_files`` of ``src`` and the shared glue (:data:`~ftc_verify.plants.build.COMMON_FILES`)."""
    h = hashlib.sha256(f"ftc-verify {tag}\0{spec!r}\0".encode())
    for name in glue_files:
        h.update((src / name).read_bytes())
    for name in COMMON_FILES:
        h.update((common_source_dir(src) / name).read_bytes())
    return "{" + str(uuid.UUID(hex=h.hexdigest()[:32], version=5)) + "}"



def ode_spec_header(spec: OdeFmuSpec, guid: str) -> str:
    """The generated ``ode_spec.h`` (see ``fmus/ode/ode_model.h``) for ``spec``."""

    def array(ctype: str, name: str, items: list[str], dummy: str) -> str:
        return f"static const {ctype} {name}[] = {{{', '.join(items) or dummy}}};"

    lines = [
        f"/* generated by ftc-verify {__version__} for {spec.model_name}: do not edit */",
        "#ifndef ODE_SPEC_H", "#define ODE_SPEC_H",
        f'#define ODE_SPEC_MODEL_NAME "{spec.model_name}"', f'#define ODE_SPEC_GUID "{guid}"',
        f"#define ODE_SPEC_HAS_JACOBIAN {int(spec.has_jacobian)}",
    ]
    for key, group in zip("XUPY", VARIABLE_GROUPS):
        lines.append(f"#define ODE_SPEC_N{key} {len(getattr(spec, group))}")
    for key, group in zip("XUP", VARIABLE_GROUPS):
        lines.append(array("double", f"ODE_SPEC_{key}_START", [repr(v.start) for v in getattr(spec, group)], "0.0"))
    lines.append(array("int", "ODE_SPEC_P_TUNABLE", [str(int(v.tunable)) for v in spec.parameters], "0"))
    for key, group in zip("XUPY", VARIABLE_GROUPS):
        lines.append(array("char *const", f"ODE_SPEC_{key}_NAMES", [f'"{v.name}"' for v in getattr(spec, group)], '""'))
    return "\n".join(lines + ["#endif", ""])


_CAPABILITIES = {"needsExecutionTool": "false", "canBeInstantiatedOnlyOncePerProcess": "false",
                 "canNotUseMemoryManagementFunctions": "false", "canGetAndSetFMUstate": "true",
                 "canSerializeFMUstate": "true"}
_CS_CAPABILITIES = {"canHandleVariableCommunicationStepSize": "true", "canInterpolateInputs": "false",
                    "maxOutputDerivativeOrder": "0", "canRunAsynchronuously": "false"}


def _scalar_variables(spec: OdeFmuSpec) -> list[tuple[dict[str, str], dict[str, str]]]:
    """``(ScalarVariable attributes, Real attributes)`` in value-reference order."""
    def unit(v: OdeVariable) -> dict[str, str]:
        return {"unit": v.unit} if v.unit else {}

    def desc(text: str) -> dict[str, str]:
        return {"description": text} if text else {}

    out = []
    for v in spec.states:
        out.append(({"name": v.name, **desc(v.description), "causality": "local", "variability": "continuous",
                      "initial": "exact"}, {"start": repr(v.start), **unit(v)}))
    for k, v in enumerate(spec.states, start=1):
        out.append(({"name": f"der({v.name})", "description": f"time derivative of {v.name}", "causality": "local",
                     "variability": "continuous", "initial": "calculated"}, {"derivative": str(k)}))
    for v in spec.inputs:
        out.append(({"name": v.name, **desc(v.description), "causality": "input", "variability": "continuous"},
                    {"start": repr(v.start), **unit(v)}))
    for v in spec.parameters:
        out.append(({"name": v.name, **desc(v.description), "causality": "parameter",
                     "variability": "tunable" if v.tunable else "fixed", "initial": "exact"},
                    {"start": repr(v.start), **unit(v)}))
    for v in spec.outputs:
        out.append(({"name": v.name, **desc(v.description), "causality": "output", "variability": "continuous",
                     "initial": "calculated"}, unit(v)))
    return out


def value_reference_groups(spec: OdeFmuSpec) -> list[list[int]]:
    """The value references of the states, ``der(states)``, inputs, parameters and outputs
    of ``spec``'s FMU (both FMI versions): consecutive from 1, in that order."""
    sizes = [len(spec.states), *(len(getattr(spec, g)) for g in VARIABLE_GROUPS)]  # x, der(x), u, p, y
    bounds = list(itertools.accumulate([1, *sizes]))
    return [list(range(a, b)) for a, b in itertools.pairwise(bounds)]


def add_description_basics(root: ET.Element, spec: OdeFmuSpec, step_call: str) -> None:
    """The ``UnitDefinitions``, ``LogCategories`` and ``DefaultExperiment`` elements of
    ``spec``'s model description, the same for both FMI versions but for the name of the
    step function (``step_call``) in the ``logEvents`` description."""
    units = {v.unit for g in VARIABLE_GROUPS for v in getattr(spec, g) if v.unit}
    add_description_elements(root, units, f"information: instantiation, internal steps per {step_call}",
                             stop_time=spec.stop_time, tolerance=spec.tolerance, step_size=spec.step_size)


def _model_structure(parent: ET.Element, spec: OdeFmuSpec) -> None:
    """Outputs and derivatives depend on all states and inputs; initial unknowns also on
    the parameters (declared conservatively, ``dependenciesKind="dependent"``)."""
    states, derivs, inputs, params, outputs = value_reference_groups(spec)
    for tag, indices, deps in (("Outputs", outputs, states + inputs), ("Derivatives", derivs, states + inputs),
                               ("InitialUnknowns", derivs + outputs, states + inputs + params)):
        if not indices:
            continue  # the schema forbids an empty list
        el = ET.SubElement(parent, tag)
        for index in indices:
            ET.SubElement(el, "Unknown", {"index": str(index), "dependencies": " ".join(map(str, deps)),
                                          "dependenciesKind": " ".join(["dependent"] * len(deps))})


def ode_model_description(spec: OdeFmuSpec, guid: str) -> str:
    """The ``modelDescription.xml`` text (FMI 2.0, ``<ModelExchange>`` and ``<CoSimulation>``)."""
    root = ET.Element("fmiModelDescription", {
        "fmiVersion": "2.0", "modelName": spec.model_name, "guid": guid,
        "description": spec.description or f"ODE model {spec.model_name}",
        "generationTool": f"ftc-verify {__version__} (ode_fmu)",
        "variableNamingConvention": "structured", "numberOfEventIndicators": "0",
    })
    jac = {"providesDirectionalDerivative": "true" if spec.has_jacobian else "false"}
    for tag, extra in (("ModelExchange", {"completedIntegratorStepNotNeeded": "true"}),
                       ("CoSimulation", _CS_CAPABILITIES)):
        el = ET.SubElement(root, tag, {"modelIdentifier": spec.model_name, **_CAPABILITIES, **extra, **jac})
        files = ET.SubElement(el, "SourceFiles")
        for name in ("ode_glue.c", f"{spec.model_name}.c"):
            ET.SubElement(files, "File", {"name": name})
    add_description_basics(root, spec, "fmi2DoStep")
    variables = ET.SubElement(root, "ModelVariables")
    for vr, (attrs, real) in enumerate(_scalar_variables(spec), start=1):
        sv = ET.SubElement(variables, "ScalarVariable", {"name": attrs.pop("name"), "valueReference": str(vr), **attrs})
        ET.SubElement(sv, "Real", real)
    _model_structure(ET.SubElement(root, "ModelStructure"), spec)
    ET.indent(root, space="  ")
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


# ------------------------------------------------------------------------------------------
# Compiling, checking, caching
# ------------------------------------------------------------------------------------------


def _compile(gcc: str, spec: OdeFmuSpec, sources: list[Path], includes: list[Path], out: Path) -> None:
    cmd = [gcc, *CFLAGS, *(a for d in includes for a in ("-I", str(d))), *map(str, sources), "-o", str(out),
           *link_flags()]
    proc = run_compiler(cmd, f"{spec.model_name}.c")  # own process group and TMPDIR, killed on any exception
    if proc.returncode != 0:
        raise FMUError(
            f"{spec.model_name}.c: compiling the ODE FMU {spec.model_name!r} failed (gcc exit status "
            f"{proc.returncode})\ncommand: {' '.join(cmd)}\n{proc.stderr.strip()}"
        )


def probe_binary(lib: Path, spec: OdeFmuSpec, *, what: str, call: str, argtypes: list[Any], args: tuple[Any, ...],
                 free: str, messages: list[str]) -> None:
    """Load the fresh binary ``lib`` (``what``: how messages name it), create one instance by
    ``dll.<call>(*args)`` and free it by ``dll.<free>``. The glue then compares ``ODE_NX``,
    ``ODE_NU``, ``ODE_NP``, ``ODE_NY`` and ``ODE_HAS_JACOBIAN`` of the model file with the
    spec; when no instance is created, :class:`FMUError` carries the glue's ``messages``
    (collected by the caller's logger)."""
    from fmpy import freeLibrary

    try:
        dll = ctypes.CDLL(str(lib))
    except OSError as exc:
        raise FMUError(f"{lib}: cannot load the compiled {what} binary: {exc}") from None
    try:
        create, release = getattr(dll, call), getattr(dll, free)
        create.restype, create.argtypes, release.argtypes = ctypes.c_void_p, argtypes, [ctypes.c_void_p]
        comp = create(*args)
        if not comp:
            raise FMUError(f"{spec.model_name}.c: the model file does not match its OdeFmuSpec: "
                           + ("; ".join(messages) or f"{call} failed"))
        release(comp)
    finally:
        freeLibrary(dll._handle)


def _probe(lib: Path, spec: OdeFmuSpec, guid: str) -> None:
    """Instantiate the fresh binary once (:func:`probe_binary`, FMI 2.0 Co-Simulation)."""
    from fmpy import calloc, free
    from fmpy.fmi2 import (fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE, fmi2CallbackFunctions,
                           fmi2CallbackLoggerTYPE)

    messages: list[str] = []

    def logger(env: object, name: object, status: int, category: object, message: bytes | None) -> None:
        messages.append((message or b"").decode("utf-8", "replace").replace("%%", "%"))

    cb = fmi2CallbackFunctions()
    cb.logger = fmi2CallbackLoggerTYPE(logger)
    cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
    cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
    probe_binary(lib, spec, what="ODE FMU", call="fmi2Instantiate",
                 argtypes=[ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_char_p,
                           ctypes.POINTER(fmi2CallbackFunctions), ctypes.c_int, ctypes.c_int],
                 args=(b"probe", 0, guid.encode(), b"", ctypes.byref(cb), 0, 0), free="fmi2FreeInstance",
                 messages=messages)


def build_ode_binary(spec: OdeFmuSpec, force: bool = False) -> Path:
    """Compile (or reuse) the shared library of ``spec`` in :func:`~ftc_verify.plants.build.cache_dir`; its path.

    The file ``<model_name>-<hash>.so`` is reused while the SHA-256 recorded beside it at
    compile time still matches (unless ``force``). Compiling happens in a temporary folder
    (gcc ``-std=c99 -O2 -fPIC -shared -fvisibility=hidden``, ``-lm``), then the binary is
    instantiated once (``_probe``) and renamed into place, all under
    :func:`~ftc_verify.plants.build.build_lock`, so concurrent builds compile once.
    Raises :class:`FMUError` with gcc's command line and stderr when compiling fails,
    or with the glue's message when the model file does not match the spec.
    """
    if not isinstance(spec, OdeFmuSpec):
        raise ValidationError(f"build_ode_binary: expected an OdeFmuSpec, got {type(spec).__name__}")
    src = ode_source_dir()
    guid = spec_guid(f"ode fmu {_LAYOUT_VERSION}", spec, src, GLUE_FILES)
    return compile_ode_binary(spec, guid, force=force, hash_tag="ode binary", stem=spec.model_name,
                              glue_files=GLUE_FILES, glue_source="ode_glue.c", headers=FMI2_HEADERS,
                              probe=_probe)


def compile_ode_binary(spec: OdeFmuSpec, guid: str, *, force: bool, hash_tag: str, stem: str,
                       glue_files: tuple[str, ...], glue_source: str, headers: tuple[str, ...],
                       probe: Any) -> Path:
    """The cached shared library of ``spec`` for either FMI version (:func:`build_ode_binary`):
    ``<stem>-<hash>.so`` in :func:`~ftc_verify.plants.build.cache_dir`, the hash over ``hash_tag``, the
    ``glue_files``, the generated header, the model, the FMI ``headers``, the flags and the
    compiler; compiled from the model and ``glue_source`` and checked by
    ``probe(lib, spec, guid)`` under the build lock."""
    src = ode_source_dir()
    common = common_source_dir(src)
    header = ode_spec_header(spec, guid)
    include = fmi2_include_dir()
    gcc = find_gcc(src)
    _, suffix = binary_platform()
    h = hashlib.sha256(f"ftc-verify {hash_tag} {_LAYOUT_VERSION}\0".encode())
    hash_files(h, src, glue_files)
    hash_files(h, common, COMMON_FILES)
    h.update(header.encode() + b"\0" + spec.c_source.encode() + b"\0")
    hash_files(h, include, headers)
    h.update(" ".join(CFLAGS + link_flags()).encode() + b"\0" + compiler_identity(gcc).encode())
    target = cache_dir() / f"{stem}-{h.hexdigest()[:20]}{suffix}"
    with build_lock(target):
        if not force and is_cached(target):
            return target
        with tempfile.TemporaryDirectory(prefix=f".{spec.model_name}.", dir=target.parent) as tmp_name:
            tmp = Path(tmp_name)
            (tmp / "ode_spec.h").write_text(header, encoding="utf-8")
            model = tmp / f"{spec.model_name}.c"
            model.write_text(spec.c_source, encoding="utf-8")
            lib = tmp / f"{spec.model_name}{suffix}"
            _compile(gcc, spec, [model, src / glue_source], [tmp, src, common, include], lib)
            probe(lib, spec, guid)
            os.chmod(lib, 0o755)
            record_hash(target, file_hash(lib))
            os.replace(lib, target)
    return target

def build_ode_fmu(spec: OdeFmuSpec, dest: Path | None = None, *, fmi_version: str = "2.0") -> Path:
    """Build the ``.fmu`` of ``spec`` and return its path.

    Parameters
    ----------
    spec : OdeFmuSpec
        The model.
    dest : Path, optional
        The ``.fmu`` file, or an existing folder (then ``<folder>/<model_name>.fmu``);
        default ``<cache_dir()>/<model_name>-<hash>.fmu``.
    fmi_version : str
        ``"2.0"`` (Model Exchange and Co-Simulation), or ``"3.0"`` for an FMI 3.0
        Co-Simulation FMU (:func:`ftc_verify.plants.ode_fmu3.build_ode_fmu3`).

    Returns
    -------
    Path
        The FMU: ``modelDescription.xml``, ``binaries/<platform>/<model_name>.so`` (from
        :func:`build_ode_binary`) and ``sources/`` (glue, header, generated ``ode_spec.h``,
        ``<model_name>.c``), written atomically; the same spec gives a byte-identical file.
    """
    if fmi_version == "3.0":
        from .ode_fmu3 import build_ode_fmu3

        return build_ode_fmu3(spec, dest)
    if fmi_version != "2.0":
        raise ValidationError(f"build_ode_fmu: fmi_version must be \"2.0\" or \"3.0\", got {fmi_version!r}")
    binary = build_ode_binary(spec)
    src = ode_source_dir()
    guid = spec_guid(f"ode fmu {_LAYOUT_VERSION}", spec, src, GLUE_FILES)
    return package_ode_fmu(spec, guid=guid, binary=binary, platform=binary_platform()[0],
                           model_description=ode_model_description(spec, guid), glue_files=GLUE_FILES,
                           dest=dest, cache_stem=f"{spec.model_name}-{guid[1:13]}")


def package_ode_fmu(spec: OdeFmuSpec, *, guid: str, binary: Path, platform: str, model_description: str,
                    glue_files: tuple[str, ...], dest: Path | None, cache_stem: str) -> Path:
    """The ``.fmu`` archive of an ODE FMU, for either FMI version: ``modelDescription.xml``,
    the ``binary`` under ``binaries/<platform>/``, and the sources (the generated
    ``ode_spec.h``, the model, ``glue_files``); written atomically to ``dest`` (a folder:
    ``<model_name>.fmu`` in it; None: ``<cache_dir()>/<cache_stem>.fmu``)."""
    src = ode_source_dir()
    suffix = binary_platform()[1]
    members = [
        ("modelDescription.xml", model_description.encode(), 0o644),
        (f"binaries/{platform}/{spec.model_name}{suffix}", binary.read_bytes(), 0o755),
        ("sources/ode_spec.h", ode_spec_header(spec, guid).encode(), 0o644),
        (f"sources/{spec.model_name}.c", spec.c_source.encode(), 0o644),
    ]
    members += source_members(src, glue_files) + source_members(common_source_dir(src), COMMON_FILES)
    path = fmu_destination(dest, cache_dir() / f"{cache_stem}.fmu", spec.model_name)
    write_zip(path, members)
    return path


# ------------------------------------------------------------------------------------------
# The nonlinear DC motor test plant
# ------------------------------------------------------------------------------------------


def motor_spec() -> OdeFmuSpec:
    r"""Nonlinear DC motor ``DCMotor`` (C source ``fmus/ode/motor.c``, exact Jacobians).

    .. math::

        J \dot\omega = k_{eff} K i - b \omega - c\,\omega |\omega| - \tau_{load}, \qquad
        L \dot i = V - (R + R_{extra}) i - k_{eff} K \omega

    with outputs ``omega_meas`` = ``omega_out`` = :math:`\omega`, ``i_meas`` = :math:`i`.
    Nominal values :math:`J = 0.01, b = 5\cdot 10^{-4}, c = 3\cdot 10^{-5}, R = 1, L = 0.05,
    K = 0.05` (fixed) and the tunable fault parameters :math:`k_{eff} = 1`,
    :math:`R_{extra} = 0`. At :math:`V = 12`, :math:`\tau_{load} = 0` the stationary point
    is :math:`\omega = 100` rad/s, :math:`i = 7` A, where the quadratic drag's slope
    :math:`2 c \omega = 6\cdot 10^{-3}` dominates :math:`b`. Start: at rest, ``V`` = 12.
    """
    path = ode_source_dir() / "motor.c"
    try:
        source = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise FMUError(f"{path}: cannot read the DC motor model source: {exc.strerror}") from None
    V = OdeVariable
    return OdeFmuSpec(
        model_name="DCMotor",
        description="Nonlinear DC motor: J w' = k_eff K i - b w - c w|w| - tau_load, "
                    "L i' = V - (R + R_extra) i - k_eff K w",
        states=(V("omega", 0.0, "angular velocity", "rad/s"), V("i", 0.0, "armature current", "A")),
        inputs=(V("V", 12.0, "armature voltage", "V"), V("tau_load", 0.0, "load torque", "N.m")),
        parameters=(
            V("J", 0.01, "rotor inertia", "kg.m2", tunable=False),
            V("b", 5e-4, "viscous friction", "N.m.s/rad", tunable=False),
            V("c", 3e-5, "quadratic drag (torque c w|w|)", "N.m.s2/rad2", tunable=False),
            V("R", 1.0, "armature resistance", "Ohm", tunable=False),
            V("L", 0.05, "armature inductance", "H", tunable=False),
            V("K", 0.05, "torque / back-emf constant", "N.m/A", tunable=False),
            V("k_eff", 1.0, "fault: effectiveness of K (1 = healthy)"),
            V("R_extra", 0.0, "fault: extra armature resistance", "Ohm"),
        ),
        outputs=(V("omega_meas", 0.0, "measured angular velocity", "rad/s"),
                 V("omega_out", 0.0, "angular velocity (performance output)", "rad/s"),
                 V("i_meas", 0.0, "measured current", "A")),
        c_source=source,
        has_jacobian=True,
        stop_time=5.0,
        step_size=0.01,
    )
