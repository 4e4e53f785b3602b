"""Write a failing property example as files that ``ftc-verify analyze`` reproduces.

:func:`replay_on_failure` wraps a property body: when an assertion fails it saves the
drawn system and controller as TOML (:mod:`ftc_verify.model.files`,
:mod:`ftc_verify.controllers.files`) under ``$FTC_FAILURES_DIR`` (default
``.hypothesis/failures``), named by a hash of the content, and adds the replay command to
the assertion message. Shrinking overwrites nothing: each distinct example gets its own
pair of files.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
from collections.abc import Iterator
from pathlib import Path

from ftc_verify.controllers import Controller, dump_controller
from ftc_verify.model.files import dump_system, write_atomic
from ftc_verify.model.system import FTCSystem

__all__ = ["replay_on_failure", "save_example", "failures_dir"]


def failures_dir() -> Path:
    """Where failing examples are written."""
    return Path(os.environ.get("FTC_FAILURES_DIR", ".hypothesis/failures"))


def save_example(system: FTCSystem, controller: Controller) -> tuple[Path, Path]:
    """Write ``system`` and ``controller``; return their paths."""
    text_sys, text_ctrl = dump_system(system), dump_controller(controller)
    tag = hashlib.sha256((text_sys + text_ctrl).encode()).hexdigest()[:12]
    folder = failures_dir()
    folder.mkdir(parents=True, exist_ok=True)
    sys_path, ctrl_path = folder / f"system-{tag}.toml", folder / f"controller-{tag}.toml"
    write_atomic(sys_path, text_sys)
    write_atomic(ctrl_path, text_ctrl)
    return sys_path, ctrl_path


@contextlib.contextmanager
def replay_on_failure(system: FTCSystem, controller: Controller) -> Iterator[None]:
    """Save the example and name the replay command if the body raises AssertionError."""
    try:
        yield
    except AssertionError as exc:
        sys_path, ctrl_path = save_example(system, controller)
        raise AssertionError(f"{exc}\nreplay: ftc-verify analyze {sys_path} --controller {ctrl_path}") from exc
