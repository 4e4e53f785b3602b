"""Build and validate an FMI 2.0 Co-Simulation FMU of an :class:`~ftc_verify.model.FTCSystem`.

The FMU ``LinearJumpPlant`` simulates the plant of the reference paper in its *true* fault
mode ``r`` (an Integer input), with the uncertainties as inputs::

    x' = (A_r + A1_r Delta1 A2_r) x + (B_r + B1_r Delta2 B2_r) u + D_r w,   y = C_r x,   ym = Cy_r x.

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
:func:`system_text`, :func:`parse_system_text`  the resource file format
                      (:mod:`ftc_verify.plants.system_text`, re-exported here).
:func:`model_description`, :func:`variable_names`  the model description
                      (:mod:`ftc_verify.plants.model_description`, re-exported here).
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import uuid
import zipfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from ..errors import FMUError, ValidationError
from ..model.system import FTCSystem
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
    "build_lock",
    "run_compiler",
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

#: FMI 2.0 headers (from fmpy) the sources include; their content enters the hash.
FMI2_HEADERS = ("fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h")
#: Compiler flags (the hash covers them).
CFLAGS = ("-std=c99", "-O2", "-fPIC", "-shared", "-fvisibility=hidden", "-Wall", "-Wextra")
#: Bumped when the generated FMU layout changes (enters the GUID).
_LAYOUT_VERSION = "2"
_ZIP_DATE = (1980, 1, 1, 0, 0, 0)  # fixed timestamps: the same system gives the same .fmu


# ------------------------------------------------------------------------------------------
# Locations
# ------------------------------------------------------------------------------------------


def source_dir() -> Path:
    """Folder with the C sources of the FMU.

    ``<repository>/fmus/LinearJumpPlant`` in a source checkout (or an editable install);
    otherwise the package data ``ftc_verify._fmus/LinearJumpPlant`` if the installed
    package ships ``fmus/`` under that name (see ``fmus/README.md``).
    """
    candidates = [Path(__file__).resolve().parents[2] / "fmus" / MODEL_IDENTIFIER]
    try:
        spec = importlib.util.find_spec("ftc_verify._fmus")
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


def run_compiler(cmd: list[str], what: str, timeout: float = 600.0) -> subprocess.CompletedProcess[str]:
    """Run the compiler command ``cmd`` and return its completed process (text output).

    gcc starts in its own process group (``start_new_session``) with ``TMPDIR`` set to a
    fresh folder this call owns, so its helpers (``cc1``, ``as``, ``collect2``) and their
    ``cc*.s`` / ``cc*.o`` files are reachable: on *any* exception while it runs (Ctrl-C, the
    command line's SIGTERM exception, the time limit) the whole group is killed with SIGKILL
    and waited for before the exception goes on, and the folder is removed in every case.

    Parameters
    ----------
    cmd : list of str
        The command line, compiler first.
    what : str
        What is compiled (a file name), for the error messages.
    timeout : float
        Seconds before the group is killed and :class:`FMUError` raised.

    Raises
    ------
    FMUError
        When the compiler cannot be started or does not finish within ``timeout``.
    """
    scratch = tempfile.mkdtemp(prefix="ftc-verify-gcc-")
    proc: subprocess.Popen[str] | None = None
    try:
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                env=os.environ | {"TMPDIR": scratch}, start_new_session=True)
        out, err = proc.communicate(timeout=timeout)
    except BaseException as exc:
        if proc is not None:
            _kill_group(proc)
        if isinstance(exc, OSError):
            raise FMUError(f"{cmd[0]}: cannot run the compiler: {exc.strerror}") from None
        if isinstance(exc, subprocess.TimeoutExpired):
            raise FMUError(f"{what}: gcc did not finish within {timeout:g} s") from None
        raise
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    return subprocess.CompletedProcess(cmd, proc.returncode, out, err)


def _kill_group(proc: subprocess.Popen[str]) -> None:
    """SIGKILL the process group of ``proc`` (its own session), wait for it and (up to 5 s)
    for the rest of the group (``cc1``, ``as``: reaped by init once gcc is gone), close its pipes."""
    import time

    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass
    proc.wait()
    deadline = time.monotonic() + 5.0
    while time.monotonic() < deadline:
        try:
            os.killpg(proc.pid, 0)
        except (ProcessLookupError, PermissionError):
            break
        time.sleep(0.01)
    for pipe in (proc.stdout, proc.stderr):
        if pipe is not None:
            pipe.close()


def _compiler_identity(gcc: str) -> str:
    out = run_compiler([gcc, "-dumpfullversion", "-dumpmachine"], gcc, timeout=60)
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
    that name is reused unless ``force``, and only while its SHA-256 matches the one
    recorded beside it at compile time (``<binary>.sha256``): a corrupted or truncated
    cached binary is compiled again instead of being loaded. Concurrent builds are safe:
    the check and the compilation run under :func:`build_lock`, and the binary is written to
    a temporary file and renamed into place. ``sources`` overrides the sources folder (default
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
    with build_lock(target):
        if not force and _cached(target):
            return target  # else missing, forced, or corrupted (hash changed): compiled again
        _compile_binary(gcc, src, include, target)
    return target


def _cached(target: Path) -> bool:
    """Whether ``target`` exists and still has the SHA-256 recorded at compile time."""
    return target.is_file() and _recorded_hash(target) == _file_hash(target)


@contextmanager
def build_lock(target: Path, timeout: float = 900.0) -> Iterator[None]:
    """Hold the file lock ``<target>.lock`` (``filelock``, an OS-level lock released when
    the process dies) while ``target`` is checked and built, so that processes building
    the same cache entry at once -- test workers, Dask workers -- compile it once and
    never load a half-written file (the file itself is also renamed into place)."""
    from filelock import FileLock, Timeout

    lock = FileLock(f"{target}.lock", timeout=timeout)
    try:
        lock.acquire()
    except Timeout:
        raise FMUError(f"{target}.lock: another build has held this lock for more than {timeout:g} s") from None
    try:
        yield
    finally:
        lock.release()


def _compile_binary(gcc: str, src: Path, include: Path, target: Path) -> None:
    """gcc into a temporary file beside ``target``, its hash recorded, renamed into place."""
    fd, tmp_name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    cmd = [
        gcc, *CFLAGS, "-I", str(include), "-I", str(src),
        *(str(src / name) for name in SOURCE_FILES if name.endswith(".c")),
        "-o", str(tmp), *_link_flags(),
    ]
    try:
        proc = run_compiler(cmd, str(src))
        if proc.returncode != 0:
            raise FMUError(
                f"{src}: compiling the {MODEL_IDENTIFIER} FMU failed (gcc exit status "
                f"{proc.returncode})\ncommand: {' '.join(cmd)}\n{proc.stderr.strip()}"
            )
        os.chmod(tmp, 0o755)
        _record_hash(target, _file_hash(tmp))
        os.replace(tmp, target)
    finally:
        tmp.unlink(missing_ok=True)


def _file_hash(path: Path) -> str:
    """SHA-256 of a file's bytes (hex)."""
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _hash_file(binary: Path) -> Path:
    """Where the SHA-256 of a cached binary is recorded: ``<binary>.sha256`` beside it."""
    return binary.with_name(binary.name + ".sha256")


def _recorded_hash(binary: Path) -> str | None:
    try:
        return _hash_file(binary).read_text(encoding="ascii").strip()
    except (OSError, UnicodeDecodeError):
        return None


def _record_hash(binary: Path, digest: str) -> None:
    """Write ``<binary>.sha256`` atomically (temporary file, then rename)."""
    record = _hash_file(binary)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{record.name}.", suffix=".tmp", dir=record.parent)
    with os.fdopen(fd, "w", encoding="ascii") as fh:
        fh.write(digest + "\n")
    os.replace(tmp_name, record)


# ------------------------------------------------------------------------------------------
# Assembling the FMU
# ------------------------------------------------------------------------------------------


def _slug(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name).strip("._-") or "system"


def _umask() -> int:
    """The process's umask, read without changing it where Linux tells it
    (``/proc/self/status``), else by setting and restoring it."""
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _write_zip(path: Path, members: list[tuple[str, bytes, int]]) -> None:
    """Write the FMU archive atomically; the file gets ``0o666 & ~umask`` like any other
    output (the temporary file it is renamed from was created ``0o600``)."""
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
        os.chmod(tmp, 0o666 & ~_umask())
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
    binary always give byte-identical FMUs. Its plant map (:func:`ftc_verify.plants.plant_map.linear_jump_plant_map`)
    is written beside it as ``<name>.plant.toml`` (:func:`~ftc_verify.plants.plant_map.map_path_for`).
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
