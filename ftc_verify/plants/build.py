"""The build toolchain of the package's FMUs: gcc, the binary cache, its lock, the archive.

:mod:`ftc_verify.plants.linear_jump` (the ``LinearJumpPlant``), :mod:`ftc_verify.plants.ode_fmu`
and :mod:`ftc_verify.plants.ode_fmu3` (ODE FMUs of FMI 2.0 and 3.0) build their binaries
and archives with the functions of this module:

* :func:`find_gcc`, :func:`compiler_identity`, :func:`run_compiler`, :data:`CFLAGS` and
  :func:`link_flags`: the compiler, its identity (a part of every cache key), one
  compiler run in its own process group, and the flags;
* :func:`fmi2_include_dir`: the FMI headers shipped with fmpy (:data:`FMI2_HEADERS`);
* :func:`fmus_folder`, :func:`common_source_dir` (:data:`COMMON_FILES`, the C glue every FMU
  shares), :func:`hash_files`, :func:`source_members` and :func:`fmu_destination`: the C
  sources of the FMUs, their part of the cache keys, of the archives and where they go;
* :func:`cache_dir`, :func:`build_lock`, :func:`file_hash`, :func:`record_hash`,
  :func:`recorded_hash` and :func:`is_cached`: the cache of compiled binaries, each
  reused while the SHA-256 recorded beside it at compile time still matches;
* :func:`binary_platform` and :func:`write_zip`: the ``binaries/`` folder name and library
  suffix of this machine, and the atomic, reproducible writing of an ``.fmu`` archive.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import zipfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from ..errors import FMUError

__all__ = ["FMI2_HEADERS", "COMMON_FILES", "CFLAGS", "ZIP_DATE", "fmi2_include_dir", "fmus_folder", "common_source_dir",
           "hash_files", "source_members", "fmu_destination", "cache_dir", "binary_platform", "fmi3_platform_tuple", "find_gcc",
           "run_compiler", "compiler_identity", "link_flags", "build_lock", "file_hash", "hash_record_path",
           "recorded_hash", "record_hash", "is_cached", "write_zip"]

#: FMI 2.0 headers (from fmpy) the sources include; their content enters the cache keys.
FMI2_HEADERS = ("fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h")
#: The C glue every FMU shares (``fmus/common``): compiled in through the include path, packed
#: into each FMU's ``sources/`` and hashed into every cache key.
COMMON_FILES = ("fmi2_common.h",)
#: Compiler flags (the cache keys cover them).
CFLAGS = ("-std=c99", "-O2", "-fPIC", "-shared", "-fvisibility=hidden", "-Wall", "-Wextra")
#: The timestamp of every archive member: the same inputs give the same ``.fmu`` bytes.
ZIP_DATE = (1980, 1, 1, 0, 0, 0)


# ------------------------------------------------------------------------------------------
# Locations
# ------------------------------------------------------------------------------------------


def fmi2_include_dir() -> Path:
    """The folder of the FMI C headers shipped inside the fmpy package.

    Returns
    -------
    Path
        fmpy's ``c-code`` folder (it also holds the FMI 3.0 headers).

    Raises
    ------
    FMUError
        When fmpy is missing or one of :data:`FMI2_HEADERS` is not in that folder.
    """
    try:
        import fmpy
    except ImportError as exc:  # pragma: no cover - fmpy is a dependency
        raise FMUError(f"fmpy is needed for the FMI 2.0 headers and validation: {exc}") from None
    path = Path(fmpy.__file__).resolve().parent / "c-code"
    missing = [h for h in FMI2_HEADERS if not (path / h).is_file()]
    if missing:
        raise FMUError(f"{path}: FMI 2.0 header(s) {missing} not found in the fmpy package")
    return path


def fmus_folder(sub: str, files: tuple[str, ...]) -> tuple[Path | None, Path]:
    """The folder ``sub`` of the FMUs' C sources that holds every one of ``files``.

    ``<repository>/fmus/<sub>`` in a source checkout (or an editable install), else
    ``<sub>`` of the package data ``ftc_verify._fmus`` (``pyproject.toml`` maps it onto
    ``fmus/``). Returns ``(found or None, the first candidate)`` (the latter for messages).
    """
    import importlib.util

    candidates = [Path(__file__).resolve().parents[2] / "fmus" / sub]
    try:
        spec = importlib.util.find_spec("ftc_verify._fmus")
    except (ImportError, ValueError):
        spec = None
    if spec is not None and spec.submodule_search_locations:
        candidates += [Path(p) / sub for p in spec.submodule_search_locations]
    found = next((path for path in candidates if all((path / name).is_file() for name in files)), None)
    return found, candidates[0]


def common_source_dir(beside: Path | None = None) -> Path:
    """The folder of :data:`COMMON_FILES` a glue in ``beside`` compiles with.

    ``beside`` itself when it holds them (a quoted ``#include`` finds the copy beside the
    glue first: an unpacked ``sources/``), else ``fmus/common`` (:func:`fmus_folder`).

    Raises
    ------
    FMUError
        When the files are nowhere.
    """
    if beside is not None and all((Path(beside) / name).is_file() for name in COMMON_FILES):
        return Path(beside)
    found, first = fmus_folder("common", COMMON_FILES)
    if found is None:
        raise FMUError(f"{first}: the C glue every FMU shares ({', '.join(COMMON_FILES)}) not found")
    return found


def hash_files(h: hashlib._Hash, folder: Path, names: tuple[str, ...]) -> None:
    """Feed ``name NUL content NUL`` of each file into the hash ``h`` (a part of a cache key)."""
    for name in names:
        h.update(name.encode() + b"\0" + (folder / name).read_bytes() + b"\0")


def source_members(folder: Path, names: tuple[str, ...]) -> list[tuple[str, bytes, int]]:
    """The archive members ``sources/<name>`` of the files ``names`` in ``folder`` (for :func:`write_zip`)."""
    return [(f"sources/{name}", (folder / name).read_bytes(), 0o644) for name in names]


def fmu_destination(dest: Path | None, default: Path, name: str) -> Path:
    """Where a builder writes its ``.fmu``: ``default`` when ``dest`` is None, ``<dest>/<name>.fmu``
    when ``dest`` is an existing folder, else ``dest``."""
    if dest is None:
        return default
    path = Path(dest)
    return path / f"{name}.fmu" if path.is_dir() else path


def cache_dir() -> Path:
    """The cache folder of binaries and FMUs (created when missing).

    Returns
    -------
    Path
        ``$FTC_VERIFY_CACHE/fmus`` if that variable is set, else
        ``$XDG_CACHE_HOME/ftc-verify/fmus`` (default ``~/.cache/ftc-verify/fmus``).

    Raises
    ------
    FMUError
        When the folder cannot be created.
    """
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


def binary_platform() -> tuple[str, str]:
    """The FMI 2.0 ``binaries`` folder and shared library suffix of this machine.

    Returns
    -------
    tuple of str
        ``(folder, suffix)`` as fmpy names them, e.g. ``("linux64", ".so")``.

    Raises
    ------
    FMUError
        On Windows, where the FMUs are not built with gcc.
    """
    import fmpy

    if sys.platform.startswith("win"):
        raise FMUError("building the LinearJumpPlant FMU with gcc is not supported on Windows")
    return fmpy.platform, fmpy.sharedLibraryExtension


def fmi3_platform_tuple() -> str:
    """The FMI 3.0 ``binaries`` folder of this machine as fmpy names it (e.g. ``x86_64-linux``)."""
    import fmpy

    return str(fmpy.platform_tuple)


# ------------------------------------------------------------------------------------------
# The compiler
# ------------------------------------------------------------------------------------------


def find_gcc(src: Path) -> str:
    """The path of ``gcc`` on ``PATH``.

    Parameters
    ----------
    src : Path
        What is to be compiled, named in the error message.

    Raises
    ------
    FMUError
        When there is no ``gcc`` on ``PATH``.
    """
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
        Seconds before the group is killed and :class:`~ftc_verify.errors.FMUError` raised.

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


def compiler_identity(gcc: str) -> str:
    """The compiler's version and target machine, as one line.

    Parameters
    ----------
    gcc : str
        The compiler (:func:`find_gcc`).

    Returns
    -------
    str
        The output of ``gcc -dumpfullversion -dumpmachine``, whitespace collapsed (it
        enters the cache keys: another compiler gives another binary).

    Raises
    ------
    FMUError
        When the command fails.
    """
    out = run_compiler([gcc, "-dumpfullversion", "-dumpmachine"], gcc, timeout=60)
    if out.returncode != 0:
        raise FMUError(f"{gcc}: `gcc -dumpfullversion -dumpmachine` failed: {out.stderr.strip()}")
    return " ".join(out.stdout.split())


def link_flags() -> tuple[str, ...]:
    """The link flags: ``-lm``, and on Linux ``-Wl,-z,defs`` (every symbol resolved at link time).

    Returns
    -------
    tuple of str
        The flags, placed after the sources on the command line (the cache keys cover them).
    """
    flags: tuple[str, ...] = ("-lm",)
    if sys.platform.startswith("linux"):
        flags += ("-Wl,-z,defs",)  # every symbol resolved at link time
    return flags


# ------------------------------------------------------------------------------------------
# The binary cache
# ------------------------------------------------------------------------------------------


@contextmanager
def build_lock(target: Path, timeout: float = 900.0) -> Iterator[None]:
    """Hold the file lock ``<target>.lock`` while ``target`` is checked and built.

    The lock (``filelock``) is an OS-level lock released when the process dies, so that
    processes building the same cache entry at once -- test workers, Dask workers --
    compile it once and never load a half-written file (the file itself is also renamed
    into place).

    Parameters
    ----------
    target : Path
        The cache entry.
    timeout : float
        Seconds to wait for the lock.

    Raises
    ------
    FMUError
        When another process holds the lock for longer than ``timeout``.
    """
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


def file_hash(path: Path) -> str:
    """The SHA-256 of the bytes of the file ``path``, in hex."""
    return hashlib.sha256(path.read_bytes()).hexdigest()


def hash_record_path(binary: Path) -> Path:
    """Where the SHA-256 of a cached binary is recorded: ``<binary>.sha256`` beside it."""
    return binary.with_name(binary.name + ".sha256")


def recorded_hash(binary: Path) -> str | None:
    """The SHA-256 recorded for ``binary`` at compile time (None: no readable record)."""
    try:
        return hash_record_path(binary).read_text(encoding="ascii").strip()
    except (OSError, UnicodeDecodeError):
        return None


def record_hash(binary: Path, digest: str) -> None:
    """Write ``digest`` to :func:`hash_record_path` of ``binary`` atomically (temporary file, then rename).

    Parameters
    ----------
    binary : Path
        The cache entry the digest belongs to.
    digest : str
        Its :func:`file_hash`.
    """
    record = hash_record_path(binary)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{record.name}.", suffix=".tmp", dir=record.parent)
    with os.fdopen(fd, "w", encoding="ascii") as fh:
        fh.write(digest + "\n")
    os.replace(tmp_name, record)


def is_cached(target: Path) -> bool:
    """Whether ``target`` exists and still has the SHA-256 recorded at compile time
    (a corrupted or truncated cached binary is not reused)."""
    return target.is_file() and recorded_hash(target) == file_hash(target)


# ------------------------------------------------------------------------------------------
# The archive
# ------------------------------------------------------------------------------------------


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


def write_zip(path: Path, members: list[tuple[str, bytes, int]]) -> None:
    """Write an FMU archive atomically and reproducibly.

    Parameters
    ----------
    path : Path
        The ``.fmu`` file (its folder is created when missing). It gets ``0o666 & ~umask``
        like any other output (the temporary file it is renamed from was created ``0o600``).
    members : list of (str, bytes, int)
        ``(name, data, mode)`` of each member, deflated, dated :data:`ZIP_DATE`.

    Raises
    ------
    FMUError
        When the file cannot be written.
    ValidationError
        ``path`` is an existing FIFO, device or socket (a link is written through,
        :func:`~ftc_verify.model.output_paths.output_target`).
    """
    from ..model.output_paths import output_target

    path = output_target(path, str(path))
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
                info = zipfile.ZipInfo(name, date_time=ZIP_DATE)
                info.compress_type = zipfile.ZIP_DEFLATED
                info.external_attr = (0o100000 | mode) << 16
                zf.writestr(info, data)
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except OSError as exc:
        raise FMUError(f"{path}: cannot write the FMU: {exc.strerror}") from None
    finally:
        tmp.unlink(missing_ok=True)
