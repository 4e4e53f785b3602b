"""Build and validate an FMI 2.0 Co-Simulation FMU of an :class:`~ftc_verify.model.FTCSystem`.

The FMU ``LinearJumpPlant`` simulates the plant of the reference paper in its *true* fault
mode ``r`` (an Integer input), with the uncertainties as inputs::

    x' = (A_r + A1_r Delta1 A2_r) x + (B_r + B1_r Delta2 B2_r) u + D_r w,   y = C_r x,   ym = Cy_r x.

``fmi2DoStep`` integrates the dynamics exactly for inputs held constant over the step
(zero-order hold) via the matrix exponential of an augmented matrix; see
``fmus/README.md`` for the variables, the resource format and the error bound.

One compiled binary serves every system: the C sources in ``fmus/LinearJumpPlant`` (and
the FMI 2.0 glue every FMU shares, ``fmus/common/fmi2_common.h``) are compiled once with gcc into a cache folder (``$FTC_VERIFY_CACHE/fmus``, default
``~/.cache/ftc-verify/fmus``; the file name carries a hash of the sources, the FMI headers,
the compiler flags and the compiler version, so a stale binary is never reused; the
toolchain is :mod:`ftc_verify.plants.build`), and
:func:`build_fmu` zips it together with a ``modelDescription.xml`` and a
``resources/system.txt`` generated for the given system.

Functions
---------
* :func:`build_binary` -- compile (or reuse) the shared library.
* :func:`build_fmu` -- assemble the ``.fmu`` for a system.
* :func:`validate` -- :func:`fmpy.validation.validate_fmu` plus consistency checks.
* :func:`system_text`, :func:`parse_system_text` -- the resource file format
  (:mod:`ftc_verify.plants.system_text`, re-exported here).
* :func:`model_description`, :func:`variable_names` -- the model description
  (:mod:`ftc_verify.plants.model_description`, re-exported here).
"""

from __future__ import annotations

import hashlib
import os
import re
import tempfile
import uuid
import zipfile
from pathlib import Path

from ..errors import FMUError, ValidationError
from ..model.system import FTCSystem
from .build import (CFLAGS, COMMON_FILES, FMI2_HEADERS, binary_platform, build_lock, cache_dir, common_source_dir,
                    compiler_identity, file_hash, find_gcc, fmi2_include_dir, fmu_destination, fmus_folder, hash_files,
                    is_cached, link_flags, record_hash, run_compiler, source_members, write_zip)
from .plant_map import linear_jump_plant_map, map_path_for, save_plant_map
from .model_description import SOURCE_FILES, model_description, variable_names
from .system_text import FORMAT_VERSION, MODEL_IDENTIFIER, FMUDims, fmu_dims, parse_system_text, system_text

__all__ = [
    "FMUError",
    "MODEL_IDENTIFIER",
    "FORMAT_VERSION",
    "SOURCE_FILES",
    "FMUDims",
    "source_dir",
    "build_binary",
    "build_fmu",
    "validate",
    "fmu_dims",
    "system_text",
    "parse_system_text",
    "model_description",
    "variable_names",
]

#: Bumped when the generated FMU layout changes (enters the GUID).
_LAYOUT_VERSION = "2"


# ------------------------------------------------------------------------------------------
# Locations
# ------------------------------------------------------------------------------------------


def source_dir() -> Path:
    """Folder with the C sources of the FMU.

    ``<repository>/fmus/LinearJumpPlant`` in a source checkout (or an editable install);
    otherwise the package data ``ftc_verify._fmus/LinearJumpPlant`` if the installed
    package ships ``fmus/`` under that name (see ``fmus/README.md``).
    """
    found, first = fmus_folder(MODEL_IDENTIFIER, SOURCE_FILES)
    if found is not None:
        return found
    raise FMUError(
        f"{first}: C sources of the {MODEL_IDENTIFIER} FMU ({', '.join(SOURCE_FILES)}) "
        "not found; they ship with the source checkout of ftc-verify, in fmus/"
    )


# ------------------------------------------------------------------------------------------
# Compiling the shared library
# ------------------------------------------------------------------------------------------


def build_binary(force: bool = False, *, sources: Path | None = None) -> Path:
    """Compile the FMU's shared library into :func:`~ftc_verify.plants.build.cache_dir` and return its path.

    The file is named ``LinearJumpPlant-<hash>.so`` where the hash covers the C sources,
    the FMI headers, the compiler flags and the compiler's version; an existing file with
    that name is reused unless ``force``, and only while its SHA-256 matches the one
    recorded beside it at compile time (``<binary>.sha256``): a corrupted or truncated
    cached binary is compiled again instead of being loaded. Concurrent builds are safe:
    the check and the compilation run under :func:`~ftc_verify.plants.build.build_lock`, and the binary is written to
    a temporary file and renamed into place. ``sources`` overrides the sources folder (default
    :func:`source_dir`). Raises :class:`FMUError` when gcc is missing or fails (the
    message carries gcc's command line and stderr).
    """
    src = Path(sources) if sources is not None else source_dir()
    for name in SOURCE_FILES:
        if not (src / name).is_file():
            raise FMUError(f"{src / name}: C source of the {MODEL_IDENTIFIER} FMU not found")
    include = fmi2_include_dir()
    common = common_source_dir(src)
    gcc = find_gcc(src)
    _, suffix = binary_platform()
    flags = CFLAGS + link_flags()

    h = hashlib.sha256()
    h.update(f"ftc-verify {MODEL_IDENTIFIER} binary\0".encode())
    hash_files(h, src, SOURCE_FILES)
    hash_files(h, common, COMMON_FILES)
    hash_files(h, include, FMI2_HEADERS)
    h.update(" ".join(flags).encode() + b"\0")
    h.update(compiler_identity(gcc).encode())
    target = cache_dir() / f"{MODEL_IDENTIFIER}-{h.hexdigest()[:20]}{suffix}"
    with build_lock(target):
        if not force and is_cached(target):
            return target  # else missing, forced, or corrupted (hash changed): compiled again
        _compile_binary(gcc, src, [include, src, common], target)
    return target


def _compile_binary(gcc: str, src: Path, includes: list[Path], target: Path) -> None:
    """gcc into a temporary file beside ``target``, its hash recorded, renamed into place."""
    fd, tmp_name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    cmd = [
        gcc, *CFLAGS, *(a for d in includes for a in ("-I", str(d))),
        *(str(src / name) for name in SOURCE_FILES if name.endswith(".c")),
        "-o", str(tmp), *link_flags(),
    ]
    try:
        proc = run_compiler(cmd, str(src))
        if proc.returncode != 0:
            raise FMUError(
                f"{src}: compiling the {MODEL_IDENTIFIER} FMU failed (gcc exit status "
                f"{proc.returncode})\ncommand: {' '.join(cmd)}\n{proc.stderr.strip()}"
            )
        os.chmod(tmp, 0o755)
        record_hash(target, file_hash(tmp))
        os.replace(tmp, target)
    finally:
        tmp.unlink(missing_ok=True)


# ------------------------------------------------------------------------------------------
# Assembling the FMU
# ------------------------------------------------------------------------------------------


def _slug(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name).strip("._-") or "system"


def build_fmu(system: FTCSystem, dest: Path | None = None) -> Path:
    """Build the FMU of ``system`` and return its path.

    ``dest``: the ``.fmu`` file to write, or an existing folder (the file is then
    ``<folder>/<system name>.fmu``); default: ``<cache_dir()>/<name>-<hash>.fmu``. The
    binary comes from :func:`build_binary` (compiled only when missing or out of date);
    the archive holds ``modelDescription.xml``, ``binaries/<platform>/LinearJumpPlant.so``,
    ``resources/system.txt`` and the C sources in ``sources/``. The same system and
    binary always give byte-identical FMUs. Its plant map (:func:`ftc_verify.plants.plant_map.linear_jump_plant_map`)
    is written beside it as ``<name>.plant.toml`` (:func:`~ftc_verify.plants.plant_map.map_path_for`).
    """
    if not isinstance(system, FTCSystem):
        raise ValidationError(f"build_fmu: expected an FTCSystem, got {type(system).__name__}")
    fmu_dims(system)  # channel consistency, before compiling anything
    binary = build_binary()
    platform, suffix = binary_platform()
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
    members += source_members(src, SOURCE_FILES) + source_members(common_source_dir(src), COMMON_FILES)
    path = fmu_destination(dest, cache_dir() / f"{_slug(system.name)}-{digest[:12]}.fmu", _slug(system.name))
    write_zip(path, members)
    save_plant_map(linear_jump_plant_map(system, path), map_path_for(path))
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
    platform, suffix = binary_platform()
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
