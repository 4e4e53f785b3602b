"""System files: FTC systems in TOML (controller files: :mod:`ftc_verify.controllers.files`).

System file (all keys shown; ``A1, A2, B1, B2`` optional, in pairs)::

    name = "paper-section-vi"
    [chain]
    alpha    = [[-0.5, 0.5], [1.0, -1.0]]
    beta_min = [[0.0, 2.0], [2.5, 0.0]]   # beta[fdi][true]
    beta_max = [[0.0, 3.0], [3.5, 0.0]]
    fault_during_delay = true             # optional: the named variant (not the paper's model)
    delay_phases = 4                      # optional: Erlang-4 detection delays (default 1, exponential)
    false_alarm_min = [[0.0, 0.05], [0.05, 0.0]]   # optional, with false_alarm_max:
    false_alarm_max = [[0.0, 0.2], [0.2, 0.0]]     # false-alarm rates [true][reported]
    [[mode]]            # one table per fault mode, in order 1..m
    A = [[...]]; B = [[...]]; C = [[...]]; D = [[...]]
    Cy = [[...]]        # optional: measured outputs y_m = Cy x (default C)
    A1 = [[...]]; A2 = [[...]]; B1 = [[...]]; B2 = [[...]]

Reading uses the standard library's :mod:`tomllib`; writing uses ``tomli_w`` (the
companion writer of the same TOML family), and floats are written with ``repr`` so that
load -> save -> load is exact. Files are written atomically (temporary file in the
same folder, then :func:`os.replace`). Every error names the file, the table index
(1-based, as in the file) and the key.
"""

from __future__ import annotations

import difflib
import errno
import os
import tempfile
import math
import tomllib
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w

from ..errors import OutputError, ProblemFileError, ValidationError
from .output_paths import output_target
from .system import FTCSystem, JointChain, Matrix, Mode

__all__ = [
    "load_system",
    "dump_system",
    "save_system",
    "write_atomic",
    "parse_chain",
    "read_toml",
    "read_named",
    "unknown_keys",
    "check_kind",
    "SYSTEM_FILE",
    "CONTROLLER_FILE",
    "PLANT_MAP",
]

_TOP_KEYS = {"name", "chain", "mode"}
_CHAIN_KEYS = {"alpha", "beta_min", "beta_max"}
_CHAIN_OPTIONAL = {"fault_during_delay", "delay_phases", "false_alarm_min", "false_alarm_max"}
_MODE_KEYS = ("A", "B", "C", "D", "Cy", "A1", "A2", "B1", "B2")


def read_toml(path: Path, literals: dict[float, tuple[str, ...]] | None = None) -> dict[str, Any]:
    """The parsed TOML document of ``path`` (errors name the file). With ``literals``
    (a dict to fill), every number is also recorded as written: the float read maps to
    the decimal texts that were read as it (:func:`ftc_verify.analysis.exact.written`
    proves on those exact numbers)."""
    def parse_float(text: str) -> float:
        value = float(text)
        if literals is not None and math.isfinite(value):
            literals[value] = tuple(sorted({*literals.get(value, ()), text.replace("_", "")}))
        return value

    try:
        with open(path, "rb") as fh:
            doc = tomllib.load(fh, parse_float=parse_float)
        if literals is not None:
            _record_integers(doc, literals)
        return doc
    except FileNotFoundError:
        raise ProblemFileError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise ProblemFileError(f"{path}: is a directory, not a TOML file") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ProblemFileError(f"{path}: not valid TOML: {exc}") from None
    except RecursionError:  # Python's parser recursing into arrays nested hundreds deep
        raise ProblemFileError(f"{path}: nested too deeply to be read (arrays or tables inside one another "
                               "hundreds of levels deep; the files of this tool nest a few levels)") from None
    except OSError as exc:
        raise ProblemFileError(f"{path}: cannot be read: {exc.strerror}") from None


def _record_integers(value: Any, literals: dict[float, tuple[str, ...]]) -> None:
    """Add the integers of a parsed TOML value to ``literals`` (as their exact text)."""
    if isinstance(value, dict):
        for v in value.values():
            _record_integers(v, literals)
    elif isinstance(value, list):
        for v in value:
            _record_integers(v, literals)
    elif isinstance(value, int) and not isinstance(value, bool) and abs(value) < 2 ** 1000:
        f = float(value)
        literals[f] = tuple(sorted({*literals.get(f, ()), str(value)}))


def unknown_keys(path: Path, where: str, keys: Sequence[str], allowed: set[str] | Sequence[str]) -> None:
    """Refuse keys outside ``allowed``, with the closest allowed key for each (a typo)."""
    extra = sorted(set(keys) - set(allowed))
    if extra:
        pairs = [(key, close) for key in extra for close in _closest(key, allowed)]
        guesses = [f"{close!r}" + (f" for {key!r}" if len(extra) > 1 else "") for key, close in pairs]
        hint = f" (did you mean {', '.join(guesses)}?)" if guesses else ""
        raise ProblemFileError(
            f"{path}: {where}: unknown key(s) {extra}{hint}; allowed: {sorted(allowed)}"
        )


def _closest(key: str, allowed: set[str] | Sequence[str]) -> list[str]:
    """The allowed key ``key`` most likely misspells: the same but for case, else the closest
    by :func:`difflib.get_close_matches` (ratio >= 0.6), else none."""
    same_case = [a for a in allowed if a.lower() == key.lower()]
    return same_case[:1] or difflib.get_close_matches(key, list(allowed), n=1, cutoff=0.6)


#: A system file, told by its ``[chain]`` and ``[[mode]]`` tables (:func:`check_kind`).
SYSTEM_FILE = "a system file ([chain] and [[mode]] tables)"
#: A controller file, told by its ``[[gain]]`` or ``[[controller]]`` tables.
CONTROLLER_FILE = "a controller file ([[gain]] or [[controller]] tables)"
#: A plant map, told by its ``fmu`` key and ``[variables]`` table.
PLANT_MAP = "a plant map (fmu and [variables])"
_KINDS = ((SYSTEM_FILE, ("chain", "mode")), (CONTROLLER_FILE, ("gain",)), (CONTROLLER_FILE, ("controller",)),
          (PLANT_MAP, ("fmu", "variables")))


def check_kind(path: Path, doc: dict[str, Any], expected: str) -> None:
    """Refuse a file of another kind than ``expected`` (:data:`SYSTEM_FILE`,
    :data:`CONTROLLER_FILE`, :data:`PLANT_MAP`) with one line saying what it is, e.g. a
    system file given as ``--controller``; a file of no known kind is left to the
    loader's own checks."""
    found = next((kind for kind, keys in _KINDS if all(key in doc for key in keys)), None)
    if found is not None and found != expected:
        raise ProblemFileError(f"{path}: this is {found}, not {expected}")


def _table(path: Path, doc: dict[str, Any], key: str) -> dict[str, Any]:
    val = doc.get(key)
    if not isinstance(val, dict):
        raise ProblemFileError(f"{path}: [{key}]: missing table (got {val!r})")
    return val


def tables(path: Path, doc: dict[str, Any], key: str) -> list[dict[str, Any]]:
    val = doc.get(key)
    if not isinstance(val, list) or not val or not all(isinstance(t, dict) for t in val):
        raise ProblemFileError(f"{path}: [[{key}]]: expected one or more [[{key}]] tables, got {val!r}")
    return val


def parse_chain(p: Path, chain_doc: dict[str, Any]) -> JointChain:
    """The :class:`JointChain` of a ``[chain]`` table of the file ``p`` (a system file or a
    plant map): every error names the file, ``[chain]`` and the key."""
    unknown_keys(p, "[chain]", list(chain_doc), _CHAIN_KEYS | _CHAIN_OPTIONAL)
    for key in sorted(_CHAIN_KEYS):
        if key not in chain_doc:
            raise ProblemFileError(f"{p}: [chain]: missing key '{key}'")
    variant = chain_doc.get("fault_during_delay", False)
    if not isinstance(variant, bool):
        raise ProblemFileError(f"{p}: [chain].fault_during_delay: expected true or false, got {variant!r}")
    phases = chain_doc.get("delay_phases", 1)
    if isinstance(phases, bool) or not isinstance(phases, int):
        raise ProblemFileError(f"{p}: [chain].delay_phases: expected a whole number of phases (1 = exponential "
                               f"delays), got {phases!r}")
    try:
        return JointChain(chain_doc["alpha"], chain_doc["beta_min"], chain_doc["beta_max"], variant, phases,
                          chain_doc.get("false_alarm_min"), chain_doc.get("false_alarm_max"))
    except ValidationError as exc:
        raise ProblemFileError(f"{p}: {exc}") from None


def read_named(path: Path, kind: str, top_keys: set[str]) -> tuple[dict[str, Any], str, dict[float, tuple[str, ...]]]:
    """``(document, name, literals)`` of a system or controller file: read with the
    decimal texts of its numbers (:func:`read_toml`), refused when it is a file of another
    kind (:func:`check_kind`) or has top-level keys outside ``top_keys``
    (:func:`unknown_keys`); ``name`` is its ``name`` string, by default the file's stem."""
    literals: dict[float, tuple[str, ...]] = {}
    doc = read_toml(path, literals)
    check_kind(path, doc, kind)
    unknown_keys(path, "top level", list(doc), top_keys)
    name = doc.get("name", path.stem)
    if not isinstance(name, str):
        raise ProblemFileError(f"{path}: name: expected a string, got {name!r}")
    return doc, name, literals


def load_system(path: str | os.PathLike[str]) -> FTCSystem:
    """Read and validate an FTC system file (format in the module docstring)."""
    p = Path(path)
    doc, name, literals = read_named(p, SYSTEM_FILE, _TOP_KEYS)
    chain = parse_chain(p, _table(p, doc, "chain"))
    modes = []
    for k, md in enumerate(tables(p, doc, "mode"), start=1):
        unknown_keys(p, f"mode[{k}]", list(md), _MODE_KEYS)
        for key in ("A", "B", "C", "D"):
            if key not in md:
                raise ProblemFileError(f"{p}: mode[{k}]: missing key '{key}'")
        try:
            modes.append(Mode(**{key: md[key] for key in md}, label=f"mode[{k}]"))
        except ValidationError as exc:
            raise ProblemFileError(f"{p}: {exc}") from None
    try:
        return FTCSystem(name, tuple(modes), chain, literals=literals)
    except ValidationError as exc:
        raise ProblemFileError(f"{p}: {exc}") from None


def tolist(a: Matrix) -> list[list[float]]:
    return [[float(v) for v in row] for row in np.asarray(a)]


def dump_system(system: FTCSystem) -> str:
    """The TOML text of ``system`` (inverse of :func:`load_system`)."""
    ch = system.chain
    doc: dict[str, Any] = {
        "name": system.name,
        "chain": {
            "alpha": tolist(ch.alpha),
            "beta_min": tolist(ch.beta_min),
            "beta_max": tolist(ch.beta_max),
            **({"fault_during_delay": True} if ch.fault_during_delay else {}),
            **({"delay_phases": ch.delay_phases} if ch.delay_phases != 1 else {}),
            **({"false_alarm_min": tolist(ch.false_alarm_min), "false_alarm_max": tolist(ch.false_alarm_max)}
               if ch.false_alarm_min is not None and ch.false_alarm_max is not None else {}),
        },
        "mode": [
            {key: tolist(getattr(md, key)) for key in _MODE_KEYS if getattr(md, key) is not None}
            for md in system.modes
        ],
    }
    return tomli_w.dumps(doc)


def write_atomic(path: str | os.PathLike[str], text: str) -> None:
    """Write ``text`` to ``path`` via a temporary file in the same folder and a rename,
    so that a failure never leaves a half-written file. A symbolic link is written through
    (the file it points to is replaced) and an existing target that is not a regular file
    (a FIFO, a device) is refused, never replaced (:mod:`ftc_verify.model.output_paths`).

    Raises
    ------
    ValidationError
        ``path`` is an existing FIFO, device, socket or folder (names it and what it is).
    ProblemFileError
        The folder refuses the temporary file (names the path and the OS error).
    OutputError
        Writing or renaming failed (a full disk, a quota, a permission lost): names
        the path and the OS error; the temporary file is removed.
    """
    p = Path(path)
    target = output_target(p, str(p))
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=target.parent)
    except OSError as exc:
        raise ProblemFileError(f"{p}: cannot write: {exc.strerror}") from None
    try:
        umask = os.umask(0)
        os.umask(umask)
        os.fchmod(fd, 0o666 & ~umask)  # mkstemp creates 0600; give the usual permissions
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
        os.replace(tmp, target)
    except OSError as exc:  # a full disk, a quota, a permission lost since the checks
        Path(tmp).unlink(missing_ok=True)
        raise OutputError(f"{p}: cannot write: {exc.strerror or exc} ({errno.errorcode.get(exc.errno or 0, 'OSError')})"
                          ) from None
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def save_system(system: FTCSystem, path: str | os.PathLike[str]) -> None:
    """Write ``system`` to ``path`` atomically."""
    write_atomic(path, dump_system(system))
