"""Build and validate an FMI 2.0 Co-Simulation FMU of an :class:`~ftc_verify.model.FTCSystem`.

The FMU ``LinearJumpPlant`` simulates the plant of the reference paper in its *true* fault
mode ``r`` (an Integer input), with the uncertainties as inputs::

    x' = (A_r + A1_r Delta1 A2_r) x + (B_r + B1_r Delta2 B2_r) u + D_r w,   y = C_r x.

``fmi2DoStep`` integrates the dynamics exactly for inputs held constant over the step
(zero-order hold) via the matrix exponential of an augmented matrix; see
``fmus/README.md`` for the variables, the resource format and the error bound.

One compiled binary serves every system: the C sources in ``fmus/LinearJumpPlant`` are
compiled once with gcc into a cache folder (``$FTC_VERIFY_CACHE/fmus``, default
``~/.cache/ftc-verify/fmus``; the file name carries a hash of the sources, the FMI headers,
the compiler flags and the compiler version, so a stale binary is never reused), and
:func:`build_fmu` zips it together with a ``modelDescription.xml`` and a
``resources/system.txt`` generated for the given system.

Functions
---------
:func:`build_binary`  compile (or reuse) the shared library.
:func:`build_fmu`     assemble the ``.fmu`` for a system.
:func:`validate`      :func:`fmpy.validation.validate_fmu` plus consistency checks.
:func:`system_text`, :func:`parse_system_text`  the resource file format.
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
import re
import shutil
import subprocess
import sys
import tempfile
import uuid
import zipfile
from dataclasses import dataclass
from pathlib import Path
from xml.etree import ElementTree as ET

import numpy as np

from . import __version__
from .errors import FTCError, ValidationError
from .model import FTCSystem

__all__ = [
    "FMUError",
    "MODEL_IDENTIFIER",
    "FMUDims",
    "source_dir",
    "fmi2_include_dir",
    "cache_dir",
    "build_binary",
    "build_fmu",
    "validate",
    "fmu_dims",
    "system_text",
    "parse_system_text",
    "model_description",
    "variable_names",
]

#: Model identifier: name of the shared library and of the FMU's C sources folder.
MODEL_IDENTIFIER = "LinearJumpPlant"
#: C sources of the FMU (in :func:`source_dir`); their content enters the binary's hash.
SOURCE_FILES = ("model.h", "model.c", "fmi2_glue.c")
#: FMI 2.0 headers (from fmpy) the sources include; their content enters the hash.
FMI2_HEADERS = ("fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h")
#: Compiler flags (the hash covers them).
CFLAGS = ("-std=c99", "-O2", "-fPIC", "-shared", "-fvisibility=hidden", "-Wall", "-Wextra")
#: Version of the ``resources/system.txt`` format (must equal LJP_FORMAT_VERSION in model.h).
FORMAT_VERSION = 1
#: Bumped when the generated FMU layout changes (enters the GUID).
_LAYOUT_VERSION = "1"
_ZIP_DATE = (1980, 1, 1, 0, 0, 0)  # fixed timestamps: the same system gives the same .fmu


class FMUError(FTCError, RuntimeError):
    """Building, locating or validating the FMU failed (names the file and the problem)."""


# ------------------------------------------------------------------------------------------
# Locations
# ------------------------------------------------------------------------------------------


def source_dir() -> Path:
    """Folder with the C sources of the FMU.

    ``<repository>/fmus/LinearJumpPlant`` in a source checkout (or an editable install);
    otherwise the package data ``ftc_verify._fmus/LinearJumpPlant`` if the installed
    package ships ``fmus/`` under that name (see ``fmus/README.md``).
    """
    candidates = [Path(__file__).resolve().parents[1] / "fmus" / MODEL_IDENTIFIER]
    try:
        spec = importlib.util.find_spec(f"{__package__}._fmus")
    except (ImportError, ValueError):
        spec = None
    if spec is not None and spec.submodule_search_locations:
        candidates += [Path(p) / MODEL_IDENTIFIER for p in spec.submodule_search_locations]
    for path in candidates:
        if all((path / name).is_file() for name in SOURCE_FILES):
            return path
    raise FMUError(
        f"{candidates[0]}: C sources of the {MODEL_IDENTIFIER} FMU ({', '.join(SOURCE_FILES)}) "
        "not found; they ship with the source checkout of ftc-verify, in fmus/"
    )


def fmi2_include_dir() -> Path:
    """Folder with the FMI 2.0 C headers shipped inside the fmpy package."""
    try:
        import fmpy
    except ImportError as exc:  # pragma: no cover - fmpy is a dependency
        raise FMUError(f"fmpy is needed for the FMI 2.0 headers and validation: {exc}") from None
    path = Path(fmpy.__file__).resolve().parent / "c-code"
    missing = [h for h in FMI2_HEADERS if not (path / h).is_file()]
    if missing:
        raise FMUError(f"{path}: FMI 2.0 header(s) {missing} not found in the fmpy package")
    return path


def cache_dir() -> Path:
    """Cache folder for binaries and FMUs: ``$FTC_VERIFY_CACHE/fmus`` if that variable is
    set, else ``$XDG_CACHE_HOME/ftc-verify/fmus`` (default ``~/.cache/ftc-verify/fmus``)."""
    root = os.environ.get("FTC_VERIFY_CACHE")
    if root:
        base = Path(root).expanduser()
    else:
        xdg = os.environ.get("XDG_CACHE_HOME")
        base = (Path(xdg).expanduser() if xdg else Path.home() / ".cache") / "ftc-verify"
    path = base / "fmus"
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise FMUError(f"{path}: cannot create the FMU cache folder: {exc.strerror}") from None
    return path


def _platform() -> tuple[str, str]:
    """``(binaries folder, shared library suffix)`` of this machine, as fmpy names them."""
    import fmpy

    if sys.platform.startswith("win"):
        raise FMUError("building the LinearJumpPlant FMU with gcc is not supported on Windows")
    return fmpy.platform, fmpy.sharedLibraryExtension


# ------------------------------------------------------------------------------------------
# Compiling the shared library
# ------------------------------------------------------------------------------------------


def _find_gcc(src: Path) -> str:
    gcc = shutil.which("gcc")
    if gcc is None:
        raise FMUError(
            f"gcc not found on PATH: it is needed to compile the FMU binary from {src} "
            "(install it, e.g. `apt-get install gcc`)"
        )
    return gcc


def _compiler_identity(gcc: str) -> str:
    try:
        out = subprocess.run(
            [gcc, "-dumpfullversion", "-dumpmachine"],
            capture_output=True, text=True, timeout=60, check=False,
        )
    except OSError as exc:
        raise FMUError(f"{gcc}: cannot run the compiler: {exc.strerror}") from None
    if out.returncode != 0:
        raise FMUError(f"{gcc}: `gcc -dumpfullversion -dumpmachine` failed: {out.stderr.strip()}")
    return " ".join(out.stdout.split())


def _link_flags() -> tuple[str, ...]:
    flags: tuple[str, ...] = ("-lm",)
    if sys.platform.startswith("linux"):
        flags += ("-Wl,-z,defs",)  # every symbol resolved at link time
    return flags


def build_binary(force: bool = False, *, sources: Path | None = None) -> Path:
    """Compile the FMU's shared library into :func:`cache_dir` and return its path.

    The file is named ``LinearJumpPlant-<hash>.so`` where the hash covers the C sources,
    the FMI headers, the compiler flags and the compiler's version; an existing file with
    that name is reused unless ``force``. Compilation writes a temporary file and renames
    it, so concurrent builds are safe. ``sources`` overrides the sources folder (default
    :func:`source_dir`). Raises :class:`FMUError` when gcc is missing or fails (the
    message carries gcc's command line and stderr).
    """
    src = Path(sources) if sources is not None else source_dir()
    for name in SOURCE_FILES:
        if not (src / name).is_file():
            raise FMUError(f"{src / name}: C source of the {MODEL_IDENTIFIER} FMU not found")
    include = fmi2_include_dir()
    gcc = _find_gcc(src)
    _, suffix = _platform()
    flags = CFLAGS + _link_flags()

    h = hashlib.sha256()
    h.update(f"ftc-verify {MODEL_IDENTIFIER} binary\0".encode())
    for name in SOURCE_FILES:
        h.update(name.encode() + b"\0" + (src / name).read_bytes() + b"\0")
    for name in FMI2_HEADERS:
        h.update(name.encode() + b"\0" + (include / name).read_bytes() + b"\0")
    h.update(" ".join(flags).encode() + b"\0")
    h.update(_compiler_identity(gcc).encode())
    target = cache_dir() / f"{MODEL_IDENTIFIER}-{h.hexdigest()[:20]}{suffix}"
    if target.is_file() and not force:
        return target

    fd, tmp_name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    cmd = [
        gcc, *CFLAGS, "-I", str(include), "-I", str(src),
        *(str(src / name) for name in SOURCE_FILES if name.endswith(".c")),
        "-o", str(tmp), *_link_flags(),
    ]
    try:
        try:
            proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600, check=False)
        except OSError as exc:
            raise FMUError(f"{gcc}: cannot run the compiler: {exc.strerror}") from None
        except subprocess.TimeoutExpired:
            raise FMUError(f"{src}: gcc did not finish within 600 s") from None
        if proc.returncode != 0:
            raise FMUError(
                f"{src}: compiling the {MODEL_IDENTIFIER} FMU failed (gcc exit status "
                f"{proc.returncode})\ncommand: {' '.join(cmd)}\n{proc.stderr.strip()}"
            )
        os.chmod(tmp, 0o755)
        os.replace(tmp, target)
    finally:
        tmp.unlink(missing_ok=True)
    return target


# ------------------------------------------------------------------------------------------
# The system, its dimensions and the resource file
# ------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class FMUDims:
    """Dimensions that fix the FMU's variables: ``Delta1`` is ``q1 x p1`` and ``Delta2``
    is ``q2 x p2`` (0 when the channel is absent in every mode)."""

    n: int
    nu: int
    ny: int
    nw: int
    m: int
    q1: int = 0
    p1: int = 0
    q2: int = 0
    p2: int = 0

    def as_tuple(self) -> tuple[int, ...]:
        return (self.n, self.nu, self.ny, self.nw, self.m, self.q1, self.p1, self.q2, self.p2)


_DIM_NAMES = ("n", "nu", "ny", "nw", "m", "q1", "p1", "q2", "p2")


def _channel_shape(system: FTCSystem, left: str, right: str) -> tuple[int, int]:
    shapes = {}
    for k, md in enumerate(system.modes, start=1):
        lv, rv = getattr(md, left), getattr(md, right)
        if lv is not None:
            shapes[k] = (int(lv.shape[1]), int(rv.shape[0]))
    if not shapes:
        return 0, 0
    first_mode, first = next(iter(shapes.items()))
    for k, shp in shapes.items():
        if shp != first:
            delta = "Delta1" if left == "A1" else "Delta2"
            raise ValidationError(
                f"{system.name}: mode {k}: {left} ({shp[0]} columns) / {right} ({shp[1]} rows) "
                f"imply a {shp[0]} x {shp[1]} {delta}, but mode {first_mode} implies "
                f"{first[0]} x {first[1]}; the FMU has one {delta} input shared by all modes"
            )
    return first


def fmu_dims(system: FTCSystem) -> FMUDims:
    """The FMU dimensions of ``system``; raises :class:`~ftc_verify.errors.ValidationError`
    when the modes' uncertainty weights imply different ``Delta`` shapes."""
    n, nu, ny, nw = system.dims
    q1, p1 = _channel_shape(system, "A1", "A2")
    q2, p2 = _channel_shape(system, "B1", "B2")
    return FMUDims(n, nu, ny, nw, system.m, q1, p1, q2, p2)


def _fmt(v: float) -> str:
    return repr(float(v))  # shortest round-trip representation; C's strtod reads it exactly


def system_text(system: FTCSystem, guid: str | None = None) -> str:
    """The ``resources/system.txt`` of ``system`` (format in ``fmus/README.md``).

    Modes without an uncertainty channel that other modes have get zero weights.
    """
    d = fmu_dims(system)
    name = " ".join(str(system.name).split())
    lines = [
        f"# {MODEL_IDENTIFIER} system file (format {FORMAT_VERSION}), written by "
        f"ftc-verify {__version__}",
        f"# system: {name}",
        f"{MODEL_IDENTIFIER} {FORMAT_VERSION}",
    ]
    if guid is not None:
        if not guid or any(ch.isspace() for ch in guid):
            raise ValueError(f"guid must be a non-empty word, got {guid!r}")
        lines.append(f"guid {guid}")
    lines += [f"{key} {val}" for key, val in zip(_DIM_NAMES, d.as_tuple())]

    def matrix(key: str, value: np.ndarray | None, rows: int, cols: int) -> None:
        arr = np.zeros((rows, cols)) if value is None else np.asarray(value, dtype=float)
        assert arr.shape == (rows, cols), (key, arr.shape, rows, cols)
        lines.append(f"{key} {rows} {cols}")
        lines.extend("  " + " ".join(_fmt(v) for v in row) for row in arr)

    for k, md in enumerate(system.modes, start=1):
        lines.append(f"mode {k}")
        matrix("A", md.A, d.n, d.n)
        matrix("B", md.B, d.n, d.nu)
        matrix("C", md.C, d.ny, d.n)
        matrix("D", md.D, d.n, d.nw)
        if d.q1:
            matrix("A1", md.A1, d.n, d.q1)
            matrix("A2", md.A2, d.p1, d.n)
        if d.q2:
            matrix("B1", md.B1, d.n, d.q2)
            matrix("B2", md.B2, d.p2, d.nu)
    lines.append("end")
    return "\n".join(lines) + "\n"


def parse_system_text(text: str, source: str = "system.txt") -> dict:
    """Read a system file written by :func:`system_text` (the C reader's rules, in Python).

    Returns ``{"guid": str | None, "dims": FMUDims, "modes": [ {key: ndarray} ]}``; raises
    :class:`FMUError` naming ``source`` and the line on malformed input.
    """
    tokens: list[tuple[str, int]] = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        tokens.extend((tok, lineno) for tok in line.split("#", 1)[0].split())
    pos = 0

    def nxt(what: str) -> tuple[str, int]:
        nonlocal pos
        if pos >= len(tokens):
            raise FMUError(f"{source}: unexpected end of file, expected {what}")
        pos += 1
        return tokens[pos - 1]

    def word(expected: str) -> None:
        tok, line = nxt(f"'{expected}'")
        if tok != expected:
            raise FMUError(f"{source}:{line}: expected '{expected}', got '{tok}'")

    def integer(what: str) -> int:
        tok, line = nxt(what)
        try:
            return int(tok)
        except ValueError:
            raise FMUError(f"{source}:{line}: {what}: expected an integer, got '{tok}'") from None

    word(MODEL_IDENTIFIER)
    version = integer("format version")
    if version != FORMAT_VERSION:
        raise FMUError(f"{source}: format version {version} is not supported")
    guid = None
    if pos < len(tokens) and tokens[pos][0] == "guid":
        pos += 1
        guid = nxt("the guid")[0]
    values = []
    for key in _DIM_NAMES:
        word(key)
        values.append(integer(key))
    dims = FMUDims(*values)
    modes = []
    for k in range(1, dims.m + 1):
        word("mode")
        if integer("mode number") != k:
            raise FMUError(f"{source}: modes must be listed in order 1..{dims.m}")
        shapes = {"A": (dims.n, dims.n), "B": (dims.n, dims.nu), "C": (dims.ny, dims.n),
                  "D": (dims.n, dims.nw)}
        if dims.q1:
            shapes.update(A1=(dims.n, dims.q1), A2=(dims.p1, dims.n))
        if dims.q2:
            shapes.update(B1=(dims.n, dims.q2), B2=(dims.p2, dims.nu))
        mode = {}
        for key, (rows, cols) in shapes.items():
            word(key)
            r, c = integer(f"{key} rows"), integer(f"{key} columns")
            if (r, c) != (rows, cols):
                raise FMUError(f"{source}: mode {k}: {key} is {r} x {c}, expected {rows} x {cols}")
            nums = []
            for _ in range(rows * cols):
                tok, line = nxt(f"an entry of {key}")
                try:
                    nums.append(float(tok))
                except ValueError:
                    raise FMUError(f"{source}:{line}: mode {k}: {key}: not a number: '{tok}'") from None
            mode[key] = np.array(nums, dtype=float).reshape(rows, cols)
        modes.append(mode)
    word("end")
    if pos != len(tokens):
        raise FMUError(f"{source}:{tokens[pos][1]}: unexpected text after 'end': '{tokens[pos][0]}'")
    return {"guid": guid, "dims": dims, "modes": modes}


# ------------------------------------------------------------------------------------------
# modelDescription.xml
# ------------------------------------------------------------------------------------------


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
    names += ["mode", "systemFile"]
    return names


def model_description(system: FTCSystem, guid: str) -> str:
    """The ``modelDescription.xml`` text of the FMU for ``system``."""
    d = fmu_dims(system)
    root = ET.Element("fmiModelDescription", {
        "fmiVersion": "2.0",
        "modelName": MODEL_IDENTIFIER,
        "guid": guid,
        "description": (
            f"Linear Markov-jump plant '{system.name}' (n={d.n}, nu={d.nu}, ny={d.ny}, "
            f"nw={d.nw}, m={d.m} modes): x' = (A + A1 Delta1 A2) x + (B + B1 Delta2 B2) u + D w, "
            "y = C x in the true fault mode; exact zero-order-hold steps"
        ),
        "generationTool": f"ftc-verify {__version__}",
        "variableNamingConvention": "structured",
        "numberOfEventIndicators": "0",
    })
    cs = ET.SubElement(root, "CoSimulation", {
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
    })
    files = ET.SubElement(cs, "SourceFiles")
    for name in SOURCE_FILES:
        if name.endswith(".c"):
            ET.SubElement(files, "File", {"name": name})
    cats = ET.SubElement(root, "LogCategories")
    for name, text in (
        ("logEvents", "information: instantiation, systemFile, new discretisations"),
        ("logStatusWarning", "warnings"),
        ("logStatusError", "errors (always reported)"),
        ("logAll", "all of the above"),
    ):
        ET.SubElement(cats, "Category", {"name": name, "description": text})
    ET.SubElement(root, "DefaultExperiment",
                  {"startTime": "0.0", "stopTime": "10.0", "stepSize": "0.01"})

    variables = ET.SubElement(root, "ModelVariables")
    index: dict[str, int] = {}

    def var(name: str, vr: int, attrs: dict[str, str], typ: str, type_attrs: dict[str, str]) -> None:
        sv = ET.SubElement(variables, "ScalarVariable", {"name": name, "valueReference": str(vr), **attrs})
        ET.SubElement(sv, typ, type_attrs)
        index[name] = len(index) + 1

    names = variable_names(d)
    vr_of = {name: k for k, name in enumerate(names, start=1)}
    param = {"causality": "parameter", "variability": "fixed", "initial": "exact"}
    cont_in = {"causality": "input", "variability": "continuous"}
    out = {"causality": "output", "variability": "continuous", "initial": "calculated"}
    for name in names:
        base = name.split("[", 1)[0]
        if base == "x0":
            var(name, vr_of[name], {**param, "description": f"initial state {name.replace('x0', 'x')}"},
                "Real", {"start": "0.0"})
        elif base == "u":
            var(name, vr_of[name], {**cont_in, "description": "control input (held over a step)"},
                "Real", {"start": "0.0"})
        elif base == "w":
            var(name, vr_of[name], {**cont_in, "description": "disturbance input (held over a step)"},
                "Real", {"start": "0.0"})
        elif base in ("Delta1", "Delta2"):
            what = "A + A1 Delta1 A2" if base == "Delta1" else "B + B1 Delta2 B2"
            var(name, vr_of[name],
                {**cont_in, "description": f"uncertainty in {what} (||Delta|| <= 1 is not enforced)"},
                "Real", {"start": "0.0"})
        elif base == "x":
            var(name, vr_of[name], {**out, "description": "state"}, "Real", {})
        elif base == "y":
            var(name, vr_of[name], {**out, "description": "output y = C x of the current mode"}, "Real", {})
        elif name == "mode":
            var(name, vr_of[name],
                {"causality": "input", "variability": "discrete",
                 "description": f"true fault mode r (1..{d.m}), held over a step"},
                "Integer", {"start": "1", "min": "1", "max": str(d.m)})
        elif name == "systemFile":
            var(name, vr_of[name],
                {**param, "description": "system file (path or file URI) read at "
                 "fmi2ExitInitializationMode instead of resources/system.txt; same dimensions"},
                "String", {"start": ""})

    structure = ET.SubElement(root, "ModelStructure")
    outputs = ET.SubElement(structure, "Outputs")
    c_stack = np.stack([np.asarray(md.C, dtype=float) for md in system.modes])
    for k in range(1, d.n + 1):
        ET.SubElement(outputs, "Unknown", {"index": str(index[f"x[{k}]"]), "dependencies": ""})
    for i in range(1, d.ny + 1):
        rows = c_stack[:, i - 1, :]
        if np.all(rows == rows[0]):  # y[i] = C[i, :] x does not depend on the mode
            ET.SubElement(outputs, "Unknown", {"index": str(index[f"y[{i}]"]), "dependencies": ""})
        else:
            ET.SubElement(outputs, "Unknown", {
                "index": str(index[f"y[{i}]"]),
                "dependencies": str(index["mode"]),
                "dependenciesKind": "dependent",
            })
    initial = ET.SubElement(structure, "InitialUnknowns")
    for name in names:
        if name.startswith(("x[", "y[")):
            ET.SubElement(initial, "Unknown", {"index": str(index[name])})

    ET.indent(root, space="  ")
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


# ------------------------------------------------------------------------------------------
# Assembling the FMU
# ------------------------------------------------------------------------------------------


def _slug(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name).strip("._-") or "system"


def _write_zip(path: Path, members: list[tuple[str, bytes, int]]) -> None:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp_name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    except OSError as exc:
        raise FMUError(f"{path}: cannot write the FMU: {exc.strerror}") from None
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_DEFLATED) as zf:
            for name, data, mode in members:
                info = zipfile.ZipInfo(name, date_time=_ZIP_DATE)
                info.compress_type = zipfile.ZIP_DEFLATED
                info.external_attr = (0o100000 | mode) << 16
                zf.writestr(info, data)
        os.replace(tmp, path)
    except OSError as exc:
        raise FMUError(f"{path}: cannot write the FMU: {exc.strerror}") from None
    finally:
        tmp.unlink(missing_ok=True)


def build_fmu(system: FTCSystem, dest: Path | None = None) -> Path:
    """Build the FMU of ``system`` and return its path.

    ``dest``: the ``.fmu`` file to write, or an existing folder (the file is then
    ``<folder>/<system name>.fmu``); default: ``<cache_dir()>/<name>-<hash>.fmu``. The
    binary comes from :func:`build_binary` (compiled only when missing or out of date);
    the archive holds ``modelDescription.xml``, ``binaries/<platform>/LinearJumpPlant.so``,
    ``resources/system.txt`` and the C sources in ``sources/``. The same system and
    binary always give byte-identical FMUs.
    """
    if not isinstance(system, FTCSystem):
        raise ValidationError(f"build_fmu: expected an FTCSystem, got {type(system).__name__}")
    fmu_dims(system)  # channel consistency, before compiling anything
    binary = build_binary()
    platform, suffix = _platform()
    src = source_dir()
    unguided = system_text(system)
    digest = hashlib.sha256(
        f"{_LAYOUT_VERSION}\0{binary.name}\0{unguided}".encode()
    ).hexdigest()
    guid = "{" + str(uuid.UUID(hex=digest[:32], version=5)) + "}"
    members = [
        ("modelDescription.xml", model_description(system, guid).encode(), 0o644),
        (f"binaries/{platform}/{MODEL_IDENTIFIER}{suffix}", binary.read_bytes(), 0o755),
        ("resources/system.txt", system_text(system, guid).encode(), 0o644),
    ]
    members += [(f"sources/{name}", (src / name).read_bytes(), 0o644) for name in SOURCE_FILES]

    if dest is None:
        path = cache_dir() / f"{_slug(system.name)}-{digest[:12]}.fmu"
    else:
        path = Path(dest)
        if path.is_dir():
            path = path / f"{_slug(system.name)}.fmu"
    _write_zip(path, members)
    return path


# ------------------------------------------------------------------------------------------
# Validation
# ------------------------------------------------------------------------------------------


def validate(path: str | os.PathLike[str]) -> list[str]:
    """Problems found in the FMU at ``path`` (empty list: none).

    :func:`fmpy.validation.validate_fmu` (schema, variable names, model structure, start
    values) plus checks of this FMU's own contract: the binary for this platform and
    ``resources/system.txt`` are present and readable, the guid of ``system.txt`` equals
    the model description's, and the variables are those its dimensions imply.
    Raises :class:`FMUError` when the file does not exist or is not a zip archive.
    """
    from fmpy import read_model_description
    from fmpy.validation import validate_fmu

    p = Path(path)
    if not p.is_file():
        raise FMUError(f"{p}: no such FMU file")
    if not zipfile.is_zipfile(p):
        raise FMUError(f"{p}: not an FMU (not a zip archive)")
    problems = list(validate_fmu(str(p)))
    if problems:
        return problems
    platform, suffix = _platform()
    lib = f"binaries/{platform}/{MODEL_IDENTIFIER}{suffix}"
    with zipfile.ZipFile(p) as zf:
        names = set(zf.namelist())
        if lib not in names:
            problems.append(f"{p}: {lib} is missing")
        if "resources/system.txt" not in names:
            problems.append(f"{p}: resources/system.txt is missing")
            return problems
        text = zf.read("resources/system.txt").decode("utf-8", errors="replace")
    md = read_model_description(str(p))
    try:
        parsed = parse_system_text(text, f"{p}!resources/system.txt")
    except FMUError as exc:
        problems.append(str(exc))
        return problems
    if parsed["guid"] != md.guid:
        problems.append(
            f"{p}: resources/system.txt has guid {parsed['guid']}, modelDescription.xml {md.guid}"
        )
    if md.coSimulation is None or md.coSimulation.modelIdentifier != MODEL_IDENTIFIER:
        problems.append(f"{p}: no CoSimulation element with modelIdentifier {MODEL_IDENTIFIER}")
    expected = variable_names(parsed["dims"])
    actual = [(v.name, v.valueReference) for v in md.modelVariables]
    if actual != [(name, k) for k, name in enumerate(expected, start=1)]:
        problems.append(
            f"{p}: the variables of modelDescription.xml do not match the dimensions of "
            f"resources/system.txt ({parsed['dims']})"
        )
    return problems
