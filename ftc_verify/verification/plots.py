"""Figures of simulated paths (matplotlib, Agg canvas, no pyplot state).

:func:`plot_path` draws the reference paper's Fig. 1 for one
:class:`~ftc_verify.simulation.PathRecord`: (a) the system (true fault) modes, (b) the
FDI modes, (c) the states and (d) the output with the disturbance, in four stacked
panels sharing the time axis. Modes are shown 1-based, as in the paper.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from ..errors import ValidationError
from ..model.output_paths import output_target
from ..simulation.records import PathRecord

__all__ = ["plot_path", "save_figure"]


def save_figure(fig: Figure, out: Path, fmt: str, failure: str) -> None:
    """Write ``fig`` to ``out`` atomically: a temporary file in the same folder (mode
    ``0o666`` less the umask, as ``open`` would give), renamed over ``out`` only once
    complete, removed on any failure; a folder that cannot be written raises
    :class:`~ftc_verify.errors.ValidationError` with ``failure`` and the OS's reason. A
    symbolic link is written through; an existing ``out`` that is not a regular file (a
    FIFO, a device) is refused, never replaced (:mod:`ftc_verify.model.output_paths`)."""
    target = output_target(out, str(out))
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{out.name}.", suffix=f".{fmt}", dir=target.parent)
    except OSError as exc:
        raise ValidationError(f"{failure}: {exc.strerror}") from None
    try:
        umask = os.umask(0)
        os.umask(umask)
        os.fchmod(fd, 0o666 & ~umask)
        with os.fdopen(fd, "wb") as fh:
            fig.savefig(fh, format=fmt)
        os.replace(tmp, target)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _mode_steps(t: np.ndarray, modes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Grid and 1-based modes for a post-step plot (the last interval's mode held to the end)."""
    return t, np.append(modes, modes[-1]) + 1


def _switch_times(t: np.ndarray, modes: np.ndarray) -> np.ndarray:
    """Grid times at which the mode held on the next interval differs from the previous one."""
    modes = np.asarray(modes)
    return t[1:len(modes)][np.flatnonzero(np.diff(modes))]


def plot_path(record: PathRecord, path: str | os.PathLike[str], *, title: str = "",
              state_offset: np.ndarray | None = None, state_names: list[str] | None = None) -> None:
    """Draw Fig. 1 of the paper for ``record`` and write it to ``path`` atomically.

    Parameters
    ----------
    record : PathRecord
        One simulated path (any backend).
    path : str or path-like
        Output file; the format follows the suffix (``.png`` if none). The figure is
        saved to a temporary file in the same folder, then renamed over ``path``.
    title : str
        Figure title (optional).
    state_offset : array, optional
        Added to the recorded states before drawing them (a plant's operating point, so
        that panel (c) shows absolute values such as tank levels, not deviations).
    state_names : list of str, optional
        Legend labels of the states (a plant map's state variables).

    Notes
    -----
    Fault switches (true mode changes) are marked in panels (c) and (d) by dotted blue
    lines, FDI switches by dashed orange lines.
    """
    if not isinstance(record, PathRecord):
        raise ValidationError(f"record: expected a PathRecord, got {type(record).__name__}")
    out = Path(path)
    fmt = out.suffix[1:].lower() or "png"
    fig = Figure(figsize=(8.0, 9.0), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(4, 1, sharex=True)
    t = np.asarray(record.t, dtype=float)
    m = int(max(np.max(record.true), np.max(record.fdi))) + 1
    for ax, modes, label, tag in ((axes[0], record.true, "system mode $r_t$", "(a)"),
                                  (axes[1], record.fdi, "FDI mode $l_t$", "(b)")):
        tt, mm = _mode_steps(t, np.asarray(modes))
        ax.step(tt, mm, where="post", color="tab:blue" if tag == "(a)" else "tab:orange")
        ax.set_ylabel(label)
        ax.set_yticks(range(1, max(m, 2) + 1))
        ax.set_ylim(0.5, max(m, 2) + 0.5)
        ax.set_title(f"{tag} {'system modes' if tag == '(a)' else 'FDI modes'}", loc="left", fontsize=10)
    x = np.asarray(record.x) + (0.0 if state_offset is None else np.asarray(state_offset, dtype=float))
    names = state_names or [f"$x_{{{k + 1}}}$" for k in range(x.shape[1])]
    for k in range(x.shape[1]):
        axes[2].plot(t, x[:, k], label=names[k])
    for ax in axes[2:]:  # one collection per kind: a path over 1e5 s had 1e5 switches (1 Line2D each: GBs)
        ax.vlines(_switch_times(t, record.true), 0, 1, transform=ax.get_xaxis_transform(), color="tab:blue",
                  linestyle=":", linewidth=1.0)
        ax.vlines(_switch_times(t, record.fdi), 0, 1, transform=ax.get_xaxis_transform(), color="tab:orange",
                  linestyle="--", linewidth=1.0)
    axes[2].set_ylabel("state" if state_offset is None else "state (absolute)")
    axes[2].set_title("(c) system state response", loc="left", fontsize=10)
    axes[2].legend(loc="upper right", fontsize=8)
    y = np.asarray(record.y)
    w = np.asarray(record.w)
    for k in range(y.shape[1]):
        axes[3].plot(t, y[:, k], label=f"$y_{{{k + 1}}}$" if y.shape[1] > 1 else "$y$")
    for k in range(w.shape[1]):
        axes[3].plot(t, w[:, k], "--", label=f"$w_{{{k + 1}}}$" if w.shape[1] > 1 else "$w$")
    axes[3].set_ylabel("output / disturbance")
    axes[3].set_title(f"(d) output and disturbance ($\\|y\\|_2$ = {record.y_norm:.4g}, "
                      f"$\\|w\\|_2$ = {record.w_norm:.4g})", loc="left", fontsize=10)
    axes[3].legend(loc="upper right", fontsize=8)
    axes[3].set_xlabel("t")
    axes[3].set_xlim(t[0], t[-1])
    for ax in axes:
        ax.grid(True, alpha=0.3)
    if title:
        fig.suptitle(title)
    save_figure(fig, out, fmt, f"{out}: cannot write the figure")
