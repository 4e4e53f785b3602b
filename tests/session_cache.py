"""Results computed once per test session and shared by every pytest-xdist worker.

A module-scoped fixture runs once per test process, and under ``pytest -n 2`` the tests
of a module are spread over both workers, so an expensive fixture (a synthesis, a CLI
run, an FMU build) ran twice. :func:`computed_once` runs ``compute`` in the first process
that asks, under a file lock in the session's shared folder (the ``shared_tmp`` fixture of
``tests/conftest.py``: the parent of the workers' temporary folders), keeps its result
(pickled) and the files it wrote in a folder of its own there, and hands the other
processes the kept result. A ``compute`` that raises keeps nothing: the next process
tries again and sees the same error.

:func:`shared_plant` and :func:`copied_plants` are the test plant FMUs of
``tests/fmu_plants.py`` built this way: once per session (a ``gcc`` run each; a module
fixture building them ran again in every test process and whenever pytest-xdist's
order left the module and came back to it, 1.3-1.8 s each time).
"""

from __future__ import annotations

import fcntl
import pickle
import re
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, TypeVar

if TYPE_CHECKING:
    from ftc_verify.plants.ode_fmu import OdeFmuSpec

__all__ = ["computed_once", "one_state_spec", "shared_plant", "copied_plants"]

T = TypeVar("T")


def computed_once(shared: Path, key: str, compute: Callable[[Path], T]) -> T:
    """``compute(folder)`` run once per session for ``key`` (module docstring); ``folder``
    (``shared / key``, created) is where it may write files that the result names."""
    if not re.fullmatch(r"[\w.-]+", key):
        raise ValueError(f"key: letters, digits, '.', '-' and '_' only, got {key!r}")
    folder = shared / key
    kept = shared / f"{key}.pickle"
    with open(shared / f"{key}.lock", "a") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            if not kept.is_file():
                folder.mkdir(exist_ok=True)
                result = compute(folder)
                kept.write_bytes(pickle.dumps(result, protocol=pickle.HIGHEST_PROTOCOL))
                return result
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)
    value: T = pickle.loads(kept.read_bytes())
    return value


def one_state_spec(kind: str) -> OdeFmuSpec:
    """The spec :func:`fmu_plants.build_plant` builds for a one-state ``kind``."""
    from fmu_plants import _RHS, _SOURCE

    from ftc_verify.plants.ode_fmu import OdeFmuSpec, OdeVariable

    return OdeFmuSpec(
        model_name=f"Plant_{kind}", states=(OdeVariable("x"),), inputs=(OdeVariable("u"), OdeVariable("w")),
        parameters=(OdeVariable("k", 1.0),), outputs=(OdeVariable("y_meas"), OdeVariable("y_out")),
        c_source=_SOURCE.format(nx=1, rhs=_RHS[kind]), description=f"test plant ({kind})")


def shared_plant(shared: Path, kind: str, fmi_version: str = "2.0") -> Path:
    """The folder of the test plant ``kind`` (:func:`fmu_plants.build_plant`: ``plant.fmu``,
    ``plant.toml``, ``system.toml``, ``K.toml``; with ``fmi_version="3.0"`` its FMU is the
    FMI 3.0 build of the same model), built once per session in ``shared`` with the
    compiled binary cached there too (``FTC_VERIFY_CACHE``). Read it or copy it
    (:func:`copied_plants`); never write into it: every test process sees it."""
    from cli_inprocess import environment
    from fmu_plants import build_plant

    from ftc_verify.plants.ode_fmu import build_ode_fmu

    def build(folder: Path) -> Path:
        with environment({"FTC_VERIFY_CACHE": str(shared / "plant-binaries")}):
            build_plant(folder, kind)
            if fmi_version != "2.0":
                build_ode_fmu(one_state_spec(kind), folder / "plant.fmu", fmi_version=fmi_version)
        return folder

    return computed_once(shared, f"plant-{kind}-fmi{fmi_version}", build)


def copied_plants(shared: Path, into: Path, kinds: dict[str, tuple[str, str]]) -> dict[str, Path]:
    """``{name: copy of shared_plant(shared, kind, fmi_version)}`` for ``kinds = {name:
    (kind, fmi_version)}``, each copied to ``into / name`` (a folder of this test process's
    own, so that the commands run in it may write there)."""
    return {name: Path(shutil.copytree(shared_plant(shared, kind, version), into / name))
            for name, (kind, version) in kinds.items()}
