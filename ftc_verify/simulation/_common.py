r"""Shared private helpers of the numpy simulators (validation and per-mode matrices).

Used by :mod:`~ftc_verify.simulation.reference`, :mod:`~ftc_verify.simulation.vectorised`
and :mod:`~ftc_verify.simulation.continuous`. The plant of the true mode :math:`i` with
the norm-bounded uncertainty of the chain segment (paper eq. (13)) is

.. math::

    A = A_i + A1_i \Delta_1 A2_i, \qquad B = B_i + B1_i \Delta_2 B2_i,

and the controller entry used in joint mode :math:`(i, j)` is
:math:`e = ` ``controller.index(i, j, m)`` (:math:`j`, or :math:`i m + j` for
full-information gains), reading :math:`v = M_i x` with
:math:`M_i = ` ``controller.measurement(mode_i)`` (:math:`I` or :math:`C_{y,i}`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from ..controllers.controller import Controller
from ..errors import ValidationError
from ..model.system import FTCSystem, Matrix
from .delta import DeltaSchedule
from .paths import ChainPath

__all__ = [
    "PathArrays",
    "check_controller",
    "initial_state",
    "path_list",
    "path_arrays",
    "perturbed",
    "delta_key",
    "full_intervals",
    "measurements",
    "run_options",
]


# ------------------------------------------------------------------------------ arguments
def check_controller(system: FTCSystem, controller: Any) -> Controller:
    """``controller`` after :meth:`Controller.check` against ``system`` (a bare gain list
    or any other type is rejected, naming ``controller``)."""
    if not isinstance(controller, Controller):
        raise ValidationError(
            f"controller: expected a ftc_verify.controllers.Controller (e.g. Controller.state_feedback(gains)), "
            f"got {type(controller).__name__}"
        )
    return controller.check(system)


def initial_state(system: FTCSystem, x0: ArrayLike | None) -> np.ndarray:
    """The plant initial state: ``n`` finite numbers (default zeros)."""
    n = system.dims[0]
    if x0 is None:
        return np.zeros(n)
    try:
        arr = np.asarray(x0, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ValidationError(f"x0: expected {n} finite numbers, got {x0!r}") from None
    if arr.size != n or not np.all(np.isfinite(arr)):
        raise ValidationError(f"x0: expected {n} finite numbers, got {x0!r}")
    return arr


def path_list(paths: ChainPath | Sequence[ChainPath]) -> list[ChainPath]:
    """A non-empty list of :class:`ChainPath` (a single path is wrapped)."""
    if isinstance(paths, ChainPath):
        return [paths]
    try:
        out = list(paths)
    except TypeError:
        raise ValidationError(f"paths: expected a sequence of ChainPath, got {type(paths).__name__}") from None
    if not out:
        raise ValidationError("paths: expected a non-empty sequence of ChainPath, got none")
    for k, p in enumerate(out):
        if not isinstance(p, ChainPath):
            raise ValidationError(f"paths[{k}]: expected a ChainPath, got {type(p).__name__}")
    return out


# ------------------------------------------------------------------------------ path arrays
@dataclass(frozen=True)
class PathArrays:
    """All paths' segments concatenated (segment ``g`` of path ``p`` is ``off[p] + g``)."""

    times: np.ndarray  # (S,) segment start times
    true: np.ndarray  # (S,)
    fdi: np.ndarray  # (S,)
    count: np.ndarray  # (P,) segments per path
    off: np.ndarray  # (P,) offset of the first segment
    horizon: np.ndarray  # (P,)

    def select(self, sel: np.ndarray) -> PathArrays:
        """The arrays of the paths ``sel`` only (in that order)."""
        segsel = self.segments(sel)
        cnt = self.count[sel]
        return PathArrays(self.times[segsel], self.true[segsel], self.fdi[segsel], cnt,
                          np.concatenate(([0], np.cumsum(cnt)[:-1])), self.horizon[sel])

    def segments(self, sel: np.ndarray) -> np.ndarray:
        """Concatenated segment indices of the paths ``sel``."""
        return np.concatenate([np.arange(self.off[p], self.off[p] + self.count[p]) for p in sel])


def _mode_arrays(paths: list[ChainPath], count: np.ndarray) -> tuple[list[np.ndarray], ...]:
    times = [np.asarray(p.times, dtype=float).reshape(-1) for p in paths]
    true = [np.asarray(p.true).reshape(-1) for p in paths]
    fdi = [np.asarray(p.fdi).reshape(-1) for p in paths]
    for name, arrs in (("true", true), ("fdi", fdi)):
        sizes = np.fromiter((a.size for a in arrs), dtype=np.int64, count=len(paths))
        if np.any(sizes != count):
            k = int(np.argmax(sizes != count))
            raise ValidationError(f"paths[{k}].{name}: {sizes[k]} entries for {count[k]} segment times")
    return times, true, fdi


def _check_modes(m: int, off: np.ndarray, name: str, arr: np.ndarray, per_path: list[np.ndarray]) -> None:
    if arr.dtype.kind in "iu":
        bad = (arr < 0) | (arr >= m)
        k = int(np.searchsorted(off, int(np.argmax(bad)), side="right") - 1) if np.any(bad) else -1
    else:
        k = next(j for j, a in enumerate(per_path) if a.dtype.kind not in "iu")
    if k >= 0:
        raise ValidationError(
            f"paths[{k}].{name}: modes must be integers in 0..{m - 1} (0-based), got {per_path[k].tolist()}"
        )


def _check_times(T: np.ndarray, off: np.ndarray, count: np.ndarray, horizon: np.ndarray,
                 times: list[np.ndarray]) -> None:
    if not np.all(np.isfinite(T)):
        raise ValidationError("paths: non-finite jump time")
    first = T[off]
    if np.any(first != 0.0):
        k = int(np.argmax(first != 0.0))
        raise ValidationError(f"paths[{k}].times: must start at 0, got {first[k]!r}")
    step_ok = np.diff(T) > 0
    step_ok[off[1:] - 1] = True  # across path boundaries
    if not np.all(step_ok):
        k = int(np.searchsorted(off, int(np.argmax(~step_ok)), side="right") - 1)
        raise ValidationError(f"paths[{k}].times: must increase strictly, got {times[k].tolist()}")
    last = T[off + count - 1]
    if np.any(last >= horizon):
        k = int(np.argmax(last >= horizon))
        raise ValidationError(f"paths[{k}].times: jump time {last[k]!r} not below the horizon {horizon[k]!r}")


def path_arrays(system: FTCSystem, paths: list[ChainPath]) -> PathArrays:
    """Concatenate and validate (vectorised over paths): times start at 0, increase
    strictly and stay below the horizon; modes are in ``0..m-1``."""
    count = np.fromiter((np.asarray(p.times).size for p in paths), dtype=np.int64, count=len(paths))
    times, true, fdi = _mode_arrays(paths, count)
    if np.any(count == 0):
        k = int(np.argmax(count == 0))
        raise ValidationError(f"paths[{k}].times: empty")
    horizon = np.fromiter((float(p.horizon) for p in paths), dtype=float, count=len(paths))
    bad = ~np.isfinite(horizon) | (horizon <= 0)
    if np.any(bad):
        k = int(np.argmax(bad))
        raise ValidationError(f"paths[{k}].horizon: must be a positive finite number, got {horizon[k]!r}")
    T = np.concatenate(times)
    tr = np.concatenate(true)
    fd = np.concatenate(fdi)
    off = np.concatenate(([0], np.cumsum(count)[:-1]))
    _check_modes(system.m, off, "true", tr, true)
    _check_modes(system.m, off, "fdi", fd, fdi)
    _check_times(T, off, count, horizon, times)
    return PathArrays(T, tr.astype(np.int64), fd.astype(np.int64), count, off, horizon)


# ------------------------------------------------------------------------------ per-mode matrices
def perturbed(system: FTCSystem, i: int, d1: Matrix | None, d2: Matrix | None) -> tuple[Matrix, Matrix]:
    """``(A_i + A1_i Delta1 A2_i, B_i + B1_i Delta2 B2_i)`` (paper eq. (13))."""
    md = system.modes[i]
    A, B = md.A, md.B
    if md.A1 is not None and md.A2 is not None and d1 is not None:
        A = A + md.A1 @ d1 @ md.A2
    if md.B1 is not None and md.B2 is not None and d2 is not None:
        B = B + md.B1 @ d2 @ md.B2
    return A, B


def delta_key(d1: Matrix | None, d2: Matrix | None) -> tuple[bytes, bytes]:
    """A hashable key of one ``(Delta1, Delta2)`` value."""
    return (b"" if d1 is None else np.ascontiguousarray(d1).tobytes(),
            b"" if d2 is None else np.ascontiguousarray(d2).tobytes())


def full_intervals(t: np.ndarray, step: float) -> np.ndarray:
    """Which grid intervals are full-length ``[k step, (k+1) step]``: both ends are the
    floats ``k * step`` and ``(k+1) * step`` exactly (as :func:`communication_grid` makes
    them with ``arange(...) * step``)."""
    k = np.rint(t / step)
    is_mult = (k * step == t) & (k >= 0)
    return is_mult[:-1] & is_mult[1:] & (k[1:] == k[:-1] + 1)


def measurements(system: FTCSystem, controller: Controller) -> tuple[Matrix, ...]:
    """``M_i`` per true mode: the map ``x -> v`` the controller reads (``I`` or ``Cy_i``)."""
    return tuple(controller.measurement(md) for md in system.modes)


def run_options(system: FTCSystem, schedule: DeltaSchedule, x0: np.ndarray, controller: Controller,
                **extra: Any) -> dict[str, Any]:
    """The ``options`` of a :class:`~ftc_verify.simulation.SimulationResult`."""
    m = system.m
    opts: dict[str, Any] = {
        "delta": schedule.kind,
        "x0": x0.tolist(),
        "gains": "full-information" if controller.full_information(m) else "fdi",
        "controller": controller.describe(m),
        "n_c": controller.n_c,
        "fault_during_delay": bool(system.chain.fault_during_delay),
    }
    for name in ("Delta1", "Delta2"):
        val = getattr(schedule, name)
        if val is not None:
            opts[name] = np.asarray(val).tolist()
    opts.update(extra)
    return opts
