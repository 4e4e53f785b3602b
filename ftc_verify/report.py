"""Writing the main job's report: ``report.json``, ``report.md`` and PNG plots.

Everything is first written into a temporary folder next to the output folder and moved
into place file by file with :func:`os.replace`, so an interrupted run leaves either the
previous files or the new ones, never half-written ones.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from .errors import ProblemFileError
from .verify import VerifyReport

__all__ = ["write_report", "render_markdown"]


def render_markdown(rep: VerifyReport) -> str:
    """The readable summary, with the verdict line first."""
    d = rep.to_dict()
    lines = [
        f"# ftc-verify report: {rep.system.name}",
        "",
        f"**Verdict: {d['verdict'].upper()}** -- certified robust gamma "
        f"{'-' if d['gamma_certified'] is None else format(d['gamma_certified'], '.6g')}",
        "",
        "| check | result | detail |",
        "|---|---|---|",
    ]
    lines += [f"| {c['name']} | {'pass' if c['ok'] else 'FAIL'} | {c['detail']} |" for c in d["checks"]]
    lines += ["", "## Numbers", ""]
    mc = d["mc"] or {}
    rows = [
        ("certified robust gamma (Lemma 4.1)", d["gamma_certified"]),
        ("certified nominal gamma (Theorem 3.2)", d["gamma_nominal_certified"]),
        ("spectral abscissa (worst beta vertex)", d["spectral_abscissa"]),
        ("exact E||y||^2/||w||^2, worst case over beta vertices and Delta", d["exact_energy_ratio"]),
        ("worst-case disturbance gain (lower bound)", d["worst_case_gain"]),
        ("Monte Carlo mean ratio (FMU)", mc.get("mean_ratio")),
        ("Monte Carlo one-sided upper bound (alpha 1e-6)", mc.get("upper_bound")),
        ("Monte Carlo paths", mc.get("paths")),
    ]
    lines += ["| quantity | value |", "|---|---|"]
    lines += [f"| {k} | {'-' if v is None else format(v, '.6g')} |" for k, v in rows]
    lines += ["", f"Gains (u = K[fdi] x): {d['gains']}", "",
              f"Seed {d['seed']}; options {d['options']}; stage times (s) "
              + ", ".join(f"{k} {v:.2f}" for k, v in d["seconds"].items()), "",
              "Plots: `fig1_path.png` (one path: true modes, FDI modes, states, output and disturbance), "
              "`ratio_distribution.png` (||y||_2/||w||_2 over paths against gamma), "
              "`worst_case.png` (the worst-case disturbance)."]
    return "\n".join(lines) + "\n"


def _ratio_plot(rep: VerifyReport, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ratios = [r.y_norm / r.w_norm for r in rep.records if r.w_norm > 0]
    fig, ax = plt.subplots(figsize=(6, 3.5))
    ax.hist(ratios, bins=30, color="tab:blue", alpha=0.8)
    if rep.gamma_certified is not None:
        ax.axvline(rep.gamma_certified, color="tab:red", label=f"certified gamma {rep.gamma_certified:.4g}")
    if rep.mc is not None:
        ax.axvline(np.sqrt(rep.mc.mean_ratio), color="k", ls="--", label="sqrt(mean ratio)")
    ax.set_xlabel("||y||_2 / ||w||_2 per path")
    ax.set_ylabel("paths")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _worst_plot(rep: VerifyReport, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    assert rep.worst is not None
    wc = rep.worst
    fig, ax = plt.subplots(figsize=(6, 3.5))
    for c in range(wc.w.shape[1]):
        ax.step(wc.t, np.append(wc.w[:, c], wc.w[-1, c]), where="post", label=f"w[{c + 1}]")
    ax.set_title(f"worst-case disturbance: gain {wc.gain:.4g} (certified {rep.gamma_certified:.4g})")
    ax.set_xlabel("t")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_report(rep: VerifyReport, out_dir: str | os.PathLike[str]) -> list[Path]:
    """Write ``report.json``, ``report.md`` and the plots into ``out_dir``; return the paths."""
    from .plots import plot_path

    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
        stage = Path(tempfile.mkdtemp(prefix=".ftc-verify-", dir=out))
    except OSError as exc:
        raise ProblemFileError(f"{out}: cannot create the output folder: {exc.strerror}") from None
    try:
        (stage / "report.json").write_text(json.dumps(rep.to_dict(), indent=2) + "\n")
        (stage / "report.md").write_text(render_markdown(rep))
        if rep.records:
            plot_path(rep.records[0], stage / "fig1_path.png", title=f"{rep.system.name}: one sample path")
            _ratio_plot(rep, stage / "ratio_distribution.png")
        if rep.worst is not None:
            _worst_plot(rep, stage / "worst_case.png")
        written = []
        for item in sorted(stage.iterdir()):
            os.replace(item, out / item.name)
            written.append(out / item.name)
        return written
    finally:
        shutil.rmtree(stage, ignore_errors=True)
