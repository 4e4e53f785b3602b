"""Results computed once per test session and shared by every pytest-xdist worker.

A module-scoped fixture runs once per test process, and under ``pytest -n 2`` the tests
of a module are spread over both workers, so an expensive fixture (a synthesis, a CLI
run, an FMU build) ran twice. :func:`computed_once` runs ``compute`` in the first process
that asks, under a file lock in the session's shared folder (the ``shared_tmp`` fixture of
``tests/conftest.py``: the parent of the workers' temporary folders), keeps its result
(pickled) and the files it wrote in a folder of its own there, and hands the other
processes the kept result. A ``compute`` that raises keeps nothing: the next process
tries again and sees the same error.
"""

from __future__ import annotations

import fcntl
import pickle
import re
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

__all__ = ["computed_once"]

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
