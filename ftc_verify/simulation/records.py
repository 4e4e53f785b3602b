"""Result types shared by the simulation backends (FMU supervisor and numpy reference).

A :class:`PathRecord` holds one simulated path on its communication grid
(:func:`ftc_verify.paths.communication_grid`): ``t`` (N+1 points), the joint mode on each
interval, and ``x, u, w, y`` sampled at the grid points (``u`` and ``w`` are the values
held on the interval that starts there), plus the controller state ``xc`` (``(N+1, n_c)``,
zero columns for a static controller) and the measured output ``ym`` that the controller
read (``(N+1, n_v)``: ``x`` itself for state feedback). Norms over the horizon use the trapezoidal
rule on the grid (error O(h^2) for smooth signals; the same rule on both backends, so
they compare exactly).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .paths import ChainPath

__all__ = ["PathRecord", "SimulationResult", "l2_norm"]


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

    @property
    def y_norm(self) -> float:
        """``||y||_2`` over the horizon."""
        return l2_norm(self.t, self.y)

    @property
    def w_norm(self) -> float:
        """``||w||_2`` over the horizon."""
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
            "beta": [r.path.beta.tolist() for r in self.records],
            "options": self.options,
        }
