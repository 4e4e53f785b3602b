"""The pieces of one supervisor run that are plain data: the prepared control law, the
operating-point offsets, one path's plan on its grid, and the record built from the rows
read (:class:`~ftc_verify.simulation.supervisor.Supervisor` runs the FMI calls)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..controllers.controller import Controller
from .paths import ChainPath
from .records import PathRecord

__all__ = ["LoopLaw", "Offsets", "PathPlan", "full_intervals", "record_from_rows"]


def full_intervals(t: np.ndarray, step: float) -> np.ndarray:
    """Which grid intervals are full ``[k step, (k+1) step]`` (both ends the floats
    ``k * step`` exactly, as :func:`communication_grid` makes them)."""
    k = np.rint(t / step)
    is_mult = (k * step == t) & (k >= 0)
    return is_mult[:-1] & is_mult[1:] & (k[1:] == k[:-1] + 1)


@dataclass(frozen=True)
class LoopLaw:
    """The controller prepared for one run: contiguous matrices and the full-step updates."""

    controller: Controller
    full_info: bool
    m: int | None
    measured: bool  # v = y_m read from the FMU (else v = x)
    Cc: tuple[np.ndarray, ...]
    Dc: tuple[np.ndarray, ...]
    full_steps: tuple[tuple[np.ndarray, np.ndarray], ...]  # (Phi_c, Gamma_c) per entry, h = step

    def entry(self, true: int, fdi: int) -> int:
        return true * self.m + fdi if self.full_info else fdi  # type: ignore[operator]

    def update(self, e: int, full: bool, h: float) -> tuple[np.ndarray, np.ndarray]:
        return self.full_steps[e] if full else self.controller.discretise(e, h)


@dataclass(frozen=True)
class Offsets:
    """The operating point as offsets: of the values read before ``u`` (``x``, ``y_m``,
    maybe ``y``), of ``y`` read after ``u``, and of the written ``u``, ``w``; and ``x_op``."""

    read: np.ndarray
    y: np.ndarray
    u: np.ndarray
    w: np.ndarray
    x: np.ndarray


@dataclass(frozen=True)
class PathPlan:
    """One path on its grid: modes, segments and events, the disturbance and Delta values."""

    path: ChainPath
    t: np.ndarray
    true: np.ndarray
    fdi: np.ndarray
    W: np.ndarray
    events: list[int]
    seg: list[int]
    full: list[bool]
    delta_c: list[Any] | None


def record_from_rows(plan: PathPlan, law: LoopLaw, n: int, XR: np.ndarray, U: np.ndarray, Y: np.ndarray | None,
            XC: np.ndarray) -> PathRecord:
    """The :class:`PathRecord` from the rows read before ``u`` (``x``, ``y_m``, ``y``)."""
    nv = law.controller.n_v if law.measured else 0
    X = XR[:, :n]
    YM = XR[:, n:n + nv] if law.measured else X
    if Y is None:  # y was read with x
        Y = XR[:, n + nv:]
    return PathRecord(path=plan.path, t=plan.t, true=plan.true, fdi=plan.fdi, x=np.ascontiguousarray(X), u=U,
                      w=plan.W, y=np.ascontiguousarray(Y), xc=XC, ym=np.ascontiguousarray(YM))
