"""Result types shared by the simulation backends (FMU supervisor and numpy reference).

A :class:`PathRecord` holds one simulated path on its communication grid
(:func:`ftc_verify.simulation.paths.communication_grid`): ``t`` (N+1 points), the joint mode on each
interval, and ``x, u, w, y`` at the grid points (``u`` is the value held on the
interval that starts there, computed at the last control sample,
:func:`ftc_verify.simulation.paths.sample_points`; ``w`` is the disturbance's value at
the point, the plant receiving the value of the last sample), plus the controller state
``xc`` (``(N+1, n_c)``, zero columns for a static controller) and the measured output
``ym`` at the point (``(N+1, n_v)``: ``x`` itself for state feedback; the controller
reads it at the samples). Norms over the horizon use the trapezoidal
rule on the grid (error O(h^2) for smooth signals; the same rule on both backends, so
they compare exactly).

A path whose loop state leaves the ball :data:`DIVERGENCE_BOUND` (Euclidean norm of
``(x, x_c)``, or a non-finite value) is stopped there on both backends: its record keeps
the grid points before the crossing, ``diverged_at`` is the time of the crossing, and its
norms are infinite (``null`` with a reason in JSON).

A path on which the plant FMU failed (an ``fmi2Error`` or ``fmi2Discard`` status inside
the loop: a plant that escapes in finite time, a ``sqrt`` of a negative number...) is
stopped the same way: ``diverged_at`` is the time of the failing call, ``failure`` the
FMU's message, and its norms are infinite. Neither is bad input: both are results.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .paths import ChainPath

__all__ = ["DIVERGENCE_BOUND", "PathRecord", "SimulationResult", "l2_norm", "diverged", "divergence_note",
           "divergence_line"]

#: Norm of the loop state ``(x, x_c)`` beyond which a path counts as diverged and is stopped.
DIVERGENCE_BOUND = 1e10


def diverged(*states: np.ndarray) -> bool:
    """True when the stacked states are not finite or their norm exceeds :data:`DIVERGENCE_BOUND`."""
    sq = sum(float(np.dot(s, s)) for s in states)
    return not sq <= DIVERGENCE_BOUND ** 2  # NaN compares False: diverged


def divergence_note(records: Sequence[PathRecord]) -> str | None:
    """One line naming the diverged and failed paths (1-based) and when, or None."""
    bad = [(k, r.diverged_at) for k, r in enumerate(records, start=1) if r.diverged_at is not None]
    failures = {k: r.failure for k, r in enumerate(records, start=1) if r.failure is not None}
    return divergence_line(bad, len(records), failures)


def divergence_line(bad: Sequence[tuple[int, float]], total: int,
                    failures: dict[int, str] | None = None) -> str | None:
    """The line of :func:`divergence_note` from ``(1-based path, time)`` pairs, or None;
    ``failures`` maps the paths on which the plant FMU failed to its message."""
    if not bad:
        return None
    failures = failures or {}
    shown = ", ".join(f"path {k} at t = {t:.6g}" + (" (the plant FMU failed)" if k in failures else "")
                      for k, t in bad[:5])
    more = f" and {len(bad) - 5} more" if len(bad) > 5 else ""
    failed = len(failures)
    what = (f"diverged (|(x, x_c)| > {DIVERGENCE_BOUND:g})" if not failed else
            "failed in the plant FMU" if failed == len(bad) else
            f"diverged (|(x, x_c)| > {DIVERGENCE_BOUND:g}) or failed in the plant FMU")
    line = f"{len(bad)} of {total} paths {what}: {shown}{more}"
    if failed:
        first = min(failures)
        line += f"; path {first}: {failures[first]}"
    return line


def l2_norm(t: np.ndarray, signal: np.ndarray) -> float:
    """``sqrt(integral |signal|^2 dt)`` by the trapezoidal rule; ``signal`` is ``(N+1, k)``."""
    sq = np.sum(np.asarray(signal, dtype=float) ** 2, axis=1)
    return float(np.sqrt(np.sum(0.5 * (sq[1:] + sq[:-1]) * np.diff(t))))


@dataclass(frozen=True, eq=False)
class PathRecord:
    """One simulated path: grid, modes per interval (0-based) and sampled signals."""

    path: ChainPath
    t: np.ndarray
    true: np.ndarray
    fdi: np.ndarray
    x: np.ndarray
    u: np.ndarray
    w: np.ndarray
    y: np.ndarray
    xc: np.ndarray
    ym: np.ndarray
    diverged_at: float | None = None
    failure: str | None = None

    def truncated(self, k: int) -> PathRecord:
        """The record of a path that diverged at grid point ``k``: points ``0 .. k-1`` kept."""
        return PathRecord(self.path, self.t[:k], self.true[:k - 1], self.fdi[:k - 1], self.x[:k], self.u[:k],
                          self.w[:k], self.y[:k], self.xc[:k], self.ym[:k], diverged_at=float(self.t[k]))

    def failed(self, keep: int, time: float, message: str) -> PathRecord:
        """The record of a path on which the plant FMU failed at ``time`` with ``message``:
        the grid points ``0 .. keep-1`` (those completely recorded) kept."""
        j = max(keep - 1, 0)
        return PathRecord(self.path, self.t[:keep], self.true[:j], self.fdi[:j], self.x[:keep], self.u[:keep],
                          self.w[:keep], self.y[:keep], self.xc[:keep], self.ym[:keep], diverged_at=float(time),
                          failure=message)

    @property
    def y_norm(self) -> float:
        """``||y||_2`` over the horizon (infinite for a diverged path)."""
        return math.inf if self.diverged_at is not None else l2_norm(self.t, self.y)

    @property
    def w_norm(self) -> float:
        """``||w||_2`` over the horizon (up to the divergence for a diverged path)."""
        return l2_norm(self.t, self.w)

    @property
    def switches(self) -> dict[str, int]:
        """Numbers of fault and FDI switches on the path."""
        return {"fault": self.path.fault_switches, "fdi": self.path.fdi_switches}


@dataclass(frozen=True, eq=False)
class SimulationResult:
    """All paths of one simulation run, with what is needed to reproduce it."""

    backend: str
    seed: int | None
    step: float
    horizon: float
    disturbance: str
    records: tuple[PathRecord, ...]
    options: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (per-path norms and switch counts, not the trajectories)."""
        return {
            "backend": self.backend,
            "seed": self.seed,
            "paths": len(self.records),
            "step": self.step,
            "horizon": self.horizon,
            "disturbance": self.disturbance,
            "y_norm": [r.y_norm for r in self.records],
            "w_norm": [r.w_norm for r in self.records],
            "switches": [r.switches for r in self.records],
            "diverged": [{"path": k, "t": r.diverged_at} | ({"fmu_failure": r.failure} if r.failure else {})
                         for k, r in enumerate(self.records, start=1) if r.diverged_at is not None],
            "divergence": divergence_note(self.records),
            "beta": [r.path.beta.tolist() for r in self.records],
            "options": self.options,
            **({"fmu": self.options.get("fmu"), "model_identifier": self.options.get("model_identifier")}
               if self.backend == "fmu" else {}),
        }
