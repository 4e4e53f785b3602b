"""The checks of an FMU archive made before anything is extracted from it.

:class:`~ftc_verify.plants.fmu_session.FMUSession` reads the archive with
:func:`read_archive` (no member may leave the extraction folder: absolute names, ``..``,
drive letters and backslashes are refused, see :func:`unsafe_member`) and its model
description with :func:`read_model_description` (FMI 2.0 or 3.0, schema-valid, with a
co-simulation interface), and checks that it has a binary for this platform
(:func:`require_binary`).
"""

from __future__ import annotations

import os
import zipfile
from collections.abc import Callable
from pathlib import Path, PurePosixPath
from typing import Any
from xml.etree import ElementTree as ET

from ..errors import FMUError
from .fmi_calls import is_fmi3

__all__ = ["unsafe_member", "read_archive", "read_model_description", "require_binary"]


def unsafe_member(name: str) -> str | None:
    """Why the archive member ``name`` could land outside the extraction folder (None: it cannot)."""
    if "\\" in name:
        return "contains a backslash"
    if name.startswith("/"):
        return "is an absolute path"
    if ":" in name:
        return "contains a drive or device letter (':')"
    if "\0" in name:
        return "contains a NUL character"
    if ".." in PurePosixPath(name).parts:
        return "contains a '..' component"
    root = os.path.join(os.sep, "extract-root")
    if os.path.commonpath([root, os.path.normpath(os.path.join(root, name))]) != root:
        return "resolves outside the extraction folder"
    return None


def read_archive(path: Path, err: Callable[[str], FMUError]) -> tuple[set[str], bytes]:
    """The member names of the FMU archive ``path`` and its ``modelDescription.xml``.

    Parameters
    ----------
    path : Path
        The ``.fmu`` file.
    err : callable
        Makes the :class:`~ftc_verify.errors.FMUError` raised for a problem (naming the file).

    Returns
    -------
    tuple
        ``(names, xml)``: the set of member names and the bytes of ``modelDescription.xml``.

    Raises
    ------
    FMUError
        When the file is missing, not a zip archive, unreadable, has an unsafe member
        (:func:`unsafe_member`) or no ``modelDescription.xml``.
    """
    if not path.is_file():
        raise err("no such FMU file")
    if not zipfile.is_zipfile(path):
        raise err("not an FMU (not a zip archive)")
    try:
        with zipfile.ZipFile(path) as zf:
            infos = zf.infolist()
            for info in infos:
                why = unsafe_member(info.filename)
                if why is not None:
                    raise err(
                        f"archive member {info.filename!r} {why}: it would be extracted outside the "
                        "extraction folder (zip-slip); refusing to extract the FMU"
                    )
            names = {info.filename for info in infos}
            if "modelDescription.xml" not in names:
                raise err("modelDescription.xml is missing from the archive (not an FMU)")
            return names, zf.read("modelDescription.xml")
    except FMUError:
        raise
    except (zipfile.BadZipFile, OSError, RuntimeError) as exc:
        raise err(f"cannot read the archive: {exc}") from None


def read_model_description(path: Path, xml: bytes, err: Callable[[str], FMUError]) -> tuple[Any, str]:
    """fmpy's model description of the FMU ``path``, checked, and its FMI version.

    Parameters
    ----------
    path : Path
        The ``.fmu`` file (fmpy reads and validates its model description).
    xml : bytes
        Its ``modelDescription.xml`` (:func:`read_archive`), checked first.
    err : callable
        Makes the :class:`~ftc_verify.errors.FMUError` raised for a problem.

    Returns
    -------
    tuple
        ``(md, version)``: the model description and ``"2.0"`` or ``"3.0"``. For FMI 3.0,
        ``md.coSimulation.providesDirectionalDerivative`` is read from the plural attribute
        ``providesDirectionalDerivatives`` (fmpy leaves it unset).

    Raises
    ------
    FMUError
        When the XML is not well-formed, not FMI 2.0 or 3.0 (or laid out as the other
        version), invalid against the schema, or has no ``<CoSimulation>`` element.
    """
    from fmpy import read_model_description as fmpy_read

    try:
        root = ET.fromstring(xml)
    except ET.ParseError as exc:
        raise err(f"modelDescription.xml is not well-formed XML: {exc}") from None
    if root.tag != "fmiModelDescription":
        raise err(f"modelDescription.xml: root element is <{root.tag}>, not <fmiModelDescription>")
    version = root.get("fmiVersion")
    if version not in ("2.0", "3.0"):
        raise err(
            f"modelDescription.xml declares fmiVersion {version!r}; the supervisor needs an "
            "FMI 2.0 or 3.0 co-simulation FMU (fmiVersion \"2.0\" or \"3.0\")"
        )
    if version != "2.0" and (root.get("guid") is not None or root.find("ModelVariables/ScalarVariable") is not None):
        raise err(f"modelDescription.xml declares fmiVersion {version!r} but is laid out as FMI 2.0 (guid, "
                  "ScalarVariable): declare fmiVersion \"2.0\", or export the model as FMI 3.0")
    if version == "3.0":
        _unique_value_references(root, err)
    try:
        md = fmpy_read(str(path), validate=True)
    except Exception as exc:  # fmpy raises plain Exceptions with the schema problems
        what = str(exc) if type(exc) is Exception else f"{type(exc).__name__}: {exc}"
        raise err(f"invalid modelDescription.xml: {what}") from None
    if md.coSimulation is None:
        raise err("modelDescription.xml has no <CoSimulation> element (Model Exchange only?)")
    fmi_version = "3.0" if is_fmi3(md) else "2.0"
    if fmi_version == "3.0":  # fmpy reads FMI 3.0's plural attribute into nothing
        cs = root.find("CoSimulation")
        if cs is None:
            raise err("modelDescription.xml has no <CoSimulation> element (Model Exchange only?)")
        md.coSimulation.providesDirectionalDerivative = cs.get("providesDirectionalDerivatives") in ("true", "1")
    return md, fmi_version


def _unique_value_references(root: ET.Element, err: Callable[[str], FMUError]) -> None:
    """FMI 3.0: every variable has a valueReference of its own (aliases are ``<Alias>``
    elements, not shared references as in FMI 2.0); a reference used twice is named with
    both variables."""
    variables = root.find("ModelVariables")
    seen: dict[str, str] = {}
    for var in () if variables is None else variables:
        ref, name = var.get("valueReference"), str(var.get("name"))
        if ref is None:
            continue
        if ref in seen:
            raise err(f"modelDescription.xml: valueReference {ref} is used by both {seen[ref]!r} and {name!r} "
                      "(FMI 3.0 references are unique)")
        seen[ref] = name


def require_binary(names: set[str], model_identifier: str, fmi_version: str, err: Callable[[str], FMUError]) -> None:
    """Raise unless the archive members ``names`` hold the binary of ``model_identifier``
    for this platform (FMI 3.0: under the platform tuple, e.g. ``x86_64-linux``).

    Raises
    ------
    FMUError
        Naming the missing library, the platforms the archive has binaries for, and
        whether it ships C sources to rebuild from (``err`` makes it).
    """
    import fmpy

    platform = fmpy.platform_tuple if fmi_version == "3.0" else fmpy.platform
    lib = f"binaries/{platform}/{model_identifier}{fmpy.sharedLibraryExtension}"
    if lib not in names:
        found = sorted({n.split("/")[1] for n in names if n.startswith("binaries/") and n.count("/") >= 2})
        hint = f"it has binaries for {found}" if found else "it has no binaries"
        if any(n.startswith("sources/") for n in names):
            hint += " (C sources are included: rebuild it for this platform)"
        raise err(f"no binary for this platform: {lib} is missing; {hint}")
