"""The envelope probability against the horizon: estimates at several horizons and their
figure (matplotlib, Agg canvas, no pyplot state, written atomically as
:func:`ftc_verify.verification.plots.plot_path` does).

:math:`P(\\text{leave within } [0, T])` is non-decreasing in :math:`T`; each point is an
independent run of :func:`~ftc_verify.risk.run.run_risk` (its own pilot and tilt, the same
seed), drawn with its confidence interval as an error bar on a logarithmic axis.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from ..controllers.controller import Controller
from ..errors import ValidationError
from ..model.system import FTCSystem
from ..verification.plots import save_figure
from .envelope import Envelope
from .estimate import Estimate, Settings
from .run import run_risk

__all__ = ["risk_by_horizon", "plot_risk_by_horizon"]


def risk_by_horizon(system: FTCSystem, controller: Controller, envelope: Envelope, horizons: Sequence[float], *,
                    step: float, settings: Settings, x0: Sequence[float] | None = None,
                    disturbance: str = "paper", backend: str = "reference", plant: Any = None) -> list[Estimate]:
    """One estimate per horizon (module docstring), the rate array at the box's centre."""
    return [run_risk(system, controller, envelope, horizon=float(h), step=step, settings=settings, x0=x0,
                     disturbance=disturbance, backend=backend, plant=plant).estimate for h in horizons]


def plot_risk_by_horizon(horizons: Sequence[float], estimates: Sequence[Estimate], path: str | os.PathLike[str], *,
                         title: str = "") -> None:
    """Draw the estimates against the horizon with their intervals (log axis; a zero
    estimate is a grey triangle at the bottom of the axis, not on the line) and write the figure to ``path``
    (``.png``, ``.pdf`` or ``.svg``) atomically."""
    out = Path(path)
    fmt = out.suffix.lower().lstrip(".")
    if fmt not in ("png", "pdf", "svg"):
        raise ValidationError(f"--plot {out}: unsupported file type {out.suffix!r}; use .png, .pdf or .svg")
    p = np.array([e.probability for e in estimates])
    lo = np.array([e.ci[0] for e in estimates])
    hi = np.array([e.ci[1] for e in estimates])
    positive = p[p > 0]
    floor = float(positive.min()) / 10 if positive.size else 1e-12
    fig = Figure(figsize=(6.0, 4.0))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    h = np.asarray(horizons, dtype=float)
    hit = p > 0
    ax.errorbar(h[hit], p[hit], yerr=[p[hit] - np.maximum(lo[hit], floor), hi[hit] - p[hit]], fmt="o-", capsize=3,
                label=f"estimate, {int(100 * estimates[0].confidence)} % interval")
    if not hit.all():
        ax.plot(h[~hit], np.full(int((~hit).sum()), floor), "v", color="gray", label="estimate 0 (no path left)")
    ax.set_yscale("log")
    ax.set_xlabel("horizon T")
    ax.set_ylabel("P(leave the envelope within [0, T])")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    if title:
        ax.set_title(title)
    save_figure(fig, out, fmt, f"--plot {out}: cannot write")
