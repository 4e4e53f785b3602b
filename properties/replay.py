"""Write a failing property example as files that ``ftc-verify analyze`` reproduces.

:func:`replay_on_failure` wraps a property body: when an assertion fails it saves the
drawn system and gains as TOML (:mod:`ftc_verify.problem_files`) under
``$FTC_FAILURES_DIR`` (default ``.hypothesis/failures``), named by a hash of the content,
and adds the replay command to the assertion message. Shrinking overwrites nothing: each
distinct example gets its own pair of files.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np

from ftc_verify.model import FTCSystem
from ftc_verify.problem_files import dump_gains, dump_system, write_atomic

__all__ = ["replay_on_failure", "failures_dir"]


def failures_dir() -> Path:
    """Where failing examples are written."""
    return Path(os.environ.get("FTC_FAILURES_DIR", ".hypothesis/failures"))


def save_example(system: FTCSystem, gains: Sequence[np.ndarray]) -> tuple[Path, Path]:
    """Write ``system`` and ``gains``; return their paths."""
    text_sys, text_gains = dump_system(system), dump_gains(gains)
    tag = hashlib.sha256((text_sys + text_gains).encode()).hexdigest()[:12]
    folder = failures_dir()
    folder.mkdir(parents=True, exist_ok=True)
    sys_path, gains_path = folder / f"system-{tag}.toml", folder / f"gains-{tag}.toml"
    write_atomic(sys_path, text_sys)
    write_atomic(gains_path, text_gains)
    return sys_path, gains_path


@contextlib.contextmanager
def replay_on_failure(system: FTCSystem, gains: Sequence[np.ndarray]) -> Iterator[None]:
    """Save the example and name the replay command if the body raises AssertionError."""
    try:
        yield
    except AssertionError as exc:
        sys_path, gains_path = save_example(system, gains)
        raise AssertionError(f"{exc}\nreplay: ftc-verify analyze {sys_path} --gains {gains_path}") from exc
