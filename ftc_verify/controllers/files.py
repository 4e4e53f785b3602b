"""Controller files (TOML): static gains and dynamic controllers in one format.

Static state feedback, one ``[[gain]]`` table per FDI mode (``u = K x``, ``nu x n``)::

    name = "paper K1, K2"          # optional
    [[gain]]
    K = [[2.4563, 29.4954], [-21.0010, -7.5161]]
    [[gain]]
    K = [[1.9998, 24.5445], [-12.4093, -3.2219]]

Full-information gains (baseline ``full-info``) are ``m * m`` ``[[gain]]`` tables in the
order ``s = (true - 1) * m + fdi``.

Dynamic output feedback on ``y_m = Cy x``, one ``[[controller]]`` table per FDI mode::

    name = "observer-based"
    [[controller]]
    Ac = [[...]]    # n_c x n_c
    Bc = [[...]]    # n_c x ny_m
    Cc = [[...]]    # nu x n_c
    Dc = [[...]]    # nu x ny_m

A ``[[controller]]`` table with ``Dc`` alone is static output feedback ``u = Dc y_m``.
An optional top-level ``period = 0.05`` (seconds, ``> 0``) is the sampling period of a
digital implementation (:attr:`Controller.period`; written by ``synthesize --period``).
A file holds either ``[[gain]]`` or ``[[controller]]`` tables, never both; every table has
the same keys and shapes. Errors name the file, the table (1-based) and the key, with the
shape found against the one expected. Floats are written with ``repr`` so that load ->
save -> load is exact; writes are atomic (:func:`ftc_verify.model.files.write_atomic`).
"""

from __future__ import annotations

import dataclasses

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w

from ..errors import ProblemFileError, ValidationError
from ..model.files import CONTROLLER_FILE, read_named, tables, tolist, unknown_keys, write_atomic
from ..model.system import FTCSystem, Matrix, as_matrix
from .controller import Controller, check_period

__all__ = [
    "load_controller",
    "dump_controller",
    "save_controller",
    "load_gains",
    "dump_gains",
    "save_gains",
    "check_gains",
]

_TOP_KEYS = {"name", "period", "gain", "controller"}
_DYNAMIC_KEYS = ("Ac", "Bc", "Cc", "Dc")


def _matrix(p: Path, value: Any, where: str) -> Matrix:
    try:
        return as_matrix(value, where)
    except ValidationError as exc:
        raise ProblemFileError(f"{p}: {exc}") from None


def _load_gain_tables(p: Path, tbls: list[dict[str, Any]], name: str) -> Controller:
    gains: list[Matrix] = []
    for k, tbl in enumerate(tbls, start=1):
        unknown_keys(p, f"gain[{k}]", list(tbl), {"K"})
        if "K" not in tbl:
            raise ProblemFileError(f"{p}: gain[{k}]: missing key 'K'")
        K = _matrix(p, tbl["K"], f"gain[{k}].K")
        if gains and K.shape != gains[0].shape:
            raise ProblemFileError(
                f"{p}: gain[{k}].K: shape {K.shape[0]} x {K.shape[1]} differs from gain[1].K "
                f"({gains[0].shape[0]} x {gains[0].shape[1]})"
            )
        gains.append(K)
    return Controller.state_feedback(gains, name=name)


def _load_controller_tables(p: Path, tbls: list[dict[str, Any]], name: str) -> Controller:
    first_keys = None
    parts: dict[str, list[Matrix]] = {key: [] for key in _DYNAMIC_KEYS}
    for k, tbl in enumerate(tbls, start=1):
        unknown_keys(p, f"controller[{k}]", list(tbl), set(_DYNAMIC_KEYS))
        keys = set(tbl)
        if keys != set(_DYNAMIC_KEYS) and keys != {"Dc"}:
            missing = sorted(set(_DYNAMIC_KEYS) - keys)
            raise ProblemFileError(
                f"{p}: controller[{k}]: missing key(s) {missing} (a dynamic controller needs "
                "Ac, Bc, Cc, Dc; static output feedback has Dc alone)"
            )
        if first_keys is not None and keys != first_keys:
            raise ProblemFileError(
                f"{p}: controller[{k}]: keys {sorted(keys)} differ from controller[1] ({sorted(first_keys)})"
            )
        first_keys = keys
        for key in _DYNAMIC_KEYS:
            if key in tbl:
                parts[key].append(_matrix(p, tbl[key], f"controller[{k}].{key}"))
    if first_keys == {"Dc"}:
        nu, nv = parts["Dc"][0].shape
        parts["Ac"] = [np.zeros((0, 0))] * len(tbls)
        parts["Bc"] = [np.zeros((0, nv))] * len(tbls)
        parts["Cc"] = [np.zeros((nu, 0))] * len(tbls)
    try:
        return Controller(tuple(parts["Ac"]), tuple(parts["Bc"]), tuple(parts["Cc"]), tuple(parts["Dc"]),
                          measures="output", name=name)
    except ValidationError as exc:
        raise ProblemFileError(f"{p}: {exc}") from None


def load_controller(path: str | os.PathLike[str]) -> Controller:
    """Read a controller file (module docstring); check it against a system with
    :meth:`Controller.check`."""
    p = Path(path)
    doc, name, literals = read_named(p, CONTROLLER_FILE, _TOP_KEYS)
    return dataclasses.replace(_controller_tables(p, doc, name), literals=literals)


def _controller_tables(p: Path, doc: dict[str, Any], name: str) -> Controller:
    if "gain" in doc and "controller" in doc:
        raise ProblemFileError(
            f"{p}: both [[gain]] and [[controller]] tables: a file holds one controller, "
            "either static gains or a dynamic controller"
        )
    period = None
    if "period" in doc:
        try:
            period = check_period(doc["period"], "period")
        except ValidationError as exc:
            raise ProblemFileError(f"{p}: {exc}") from None
    if "controller" in doc:
        return _load_controller_tables(p, tables(p, doc, "controller"), name).with_period(period)
    if "gain" not in doc:
        raise ProblemFileError(f"{p}: no [[gain]] or [[controller]] tables (one per FDI mode is needed)")
    return _load_gain_tables(p, tables(p, doc, "gain"), name).with_period(period)


def dump_controller(controller: Controller) -> str:
    """The TOML text of a controller file (inverse of :func:`load_controller`)."""
    doc: dict[str, Any] = {}
    if controller.name:
        doc["name"] = controller.name
    if controller.period is not None:
        doc["period"] = controller.period
    if controller.is_state_feedback:
        doc["gain"] = [{"K": tolist(K)} for K in controller.Dc]
    elif controller.static:
        doc["controller"] = [{"Dc": tolist(D)} for D in controller.Dc]
    else:
        doc["controller"] = [
            {key: tolist(getattr(controller, key)[k]) for key in _DYNAMIC_KEYS}
            for k in range(controller.entries)
        ]
    return tomli_w.dumps(doc)


def save_controller(controller: Controller, path: str | os.PathLike[str]) -> None:
    """Write a controller file atomically."""
    write_atomic(path, dump_controller(controller))


def load_gains(path: str | os.PathLike[str]) -> tuple[Matrix, ...]:
    """The gains of a static state-feedback controller file (``[[gain]]`` tables)."""
    controller = load_controller(path)
    if not controller.is_state_feedback:
        raise ProblemFileError(f"{path}: holds a {controller.describe()}, not [[gain]] tables")
    return controller.gains


def dump_gains(gains: Sequence[Matrix], name: str | None = None) -> str:
    """The TOML text of a gains file (:func:`dump_controller` of state feedback)."""
    return dump_controller(Controller.state_feedback(gains, name=name or ""))


def save_gains(gains: Sequence[Matrix], path: str | os.PathLike[str], name: str | None = None) -> None:
    """Write a gains file atomically."""
    write_atomic(path, dump_gains(gains, name))


def check_gains(system: FTCSystem, gains: Sequence[Matrix], source: str = "gains") -> tuple[Matrix, ...]:
    """Validate state-feedback gains against ``system`` (``m`` or ``m * m`` of them)."""
    try:
        controller = Controller.state_feedback(gains)
    except ValidationError as exc:
        raise ValidationError(f"{source}: {exc}") from None
    return controller.check(system, source=source).gains
