"""Writing the main job's report: ``report.json``, ``report.md`` and PNG plots.

The output folder holds exactly one run. Everything is first written into a staging
folder *beside* it (``.NAME.staging-*`` in the same parent, never inside it), then the
staging folder replaces the output folder whole: the old folder is renamed aside, the
staging folder renamed into place, the old one removed. An interrupted run (SIGINT, or
SIGTERM through the CLI) removes its staging folder and leaves the previous report
untouched. :func:`check_out_dir` refuses, before any work, a folder that holds anything
but a previous report, so that no user file is ever replaced.
"""

from __future__ import annotations

import math
import os
import shutil
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from ..claimtext import lower_text, upper_text
from ..errors import ProblemFileError
from ..jsonable import dumps
from ..model.output_paths import check_name, kind_of, probe_folder
from .verify import VerifyReport

__all__ = ["REPORT_FILES", "check_out_dir", "write_report", "render_markdown", "table_row", "draw_figures",
           "EarlyFigures", "cpu_seconds"]

#: Every file a report may hold; a folder with anything else is not replaced.
REPORT_FILES = frozenset({"report.json", "report.md", "fig1_path.png", "ratio_distribution.png", "gamma_bracket.png"})


def _num(value: float | None, spec: str = ".6g") -> str:
    """A number for the report, or "-" where JSON has null (infinite, diverged, not computed)."""
    return "-" if value is None else format(value, spec)


def _bound(value: float | None, side: str) -> str:
    """A proved bound for the report, rounded outward (``side`` "up" or "down"), or "-"."""
    if value is None:
        return "-"
    return upper_text(value) if side == "up" else lower_text(value)


def _nums(values: Any, spec: str = ".4g") -> str:
    """A (nested) list of numbers as written in the report, ``-`` for none or null.

    >>> _nums([[0.1234567891, 2.0], [None, 1e-9]])
    '[[0.1235, 2], [-, 1e-09]]'
    """
    if values is None:
        return "-"
    if isinstance(values, (list, tuple)):
        return "[" + ", ".join(_nums(v, spec) for v in values) + "]"
    return format(values, spec)


def table_row(*cells: object) -> str:
    r"""One row of a markdown table, every ``|`` inside a cell escaped.

    A ``|`` in a cell (``E||y||^2``) would otherwise end the cell when the table renders
    (GitHub-flavoured markdown, markdown-it), and the number after it would vanish; ``\|``
    renders as ``|``, in code spans too. A line break inside a cell would end the row, so
    it becomes a space.

    >>> print(table_row("max E||y||^2", 0.5))
    | max E\|\|y\|\|^2 | 0.5 |
    """
    return "| " + " | ".join(" ".join(str(c).splitlines()).replace("|", "\\|") for c in cells) + " |"



def _risk_lines(risk: dict[str, Any] | None) -> list[str]:
    """The ``## Risk`` section of the markdown report (the plant map's ``[risk]`` stage)."""
    if not risk:
        return []
    if "probability" not in risk:
        return ["", "## Risk", "", risk["detail"]]
    bound = risk.get("upper_bound") or {}
    timing = risk.get("timing") or {}
    rows = [("envelope", risk["envelope"]), ("horizon T (s)", _num(risk["horizon"])),
            ("target", _num(risk.get("target"))),
            (f"probability of leaving within [0, T] ({risk['method']}, {risk['backend']})", _num(risk["probability"])),
            (f"{100 * risk['confidence']:g} % interval ({risk['interval']})", _nums(risk["ci"])),
            ("paths (left the envelope)", f"{risk['paths']} ({risk['hits']})"),
            ("proved upper bound (continuous-time loop)", _num(bound.get("value"))),
            ("FDI timing: worst P(detection delay > ftti)", _num(timing.get("worst")))]
    return ["", "## Risk", "", "| quantity | value |", "|---|---|",
            *(table_row(k, v) for k, v in rows), "", risk["detail"]]

def render_markdown(rep: VerifyReport) -> str:
    """The readable summary, with the verdict line first."""
    d = rep.to_dict()
    lines = [
        f"# ftc-verify report: {rep.system.name}",
        "",
        f"**Verdict: {d['verdict'].upper()}** -- certified robust gamma "
        f"{'-' if d['gamma_certified'] is None else upper_text(d['gamma_certified'])}",
        "",
        f"{d['options']['fdi_model']}.",
        "",
        "| check | result | detail |",
        "|---|---|---|",
    ]
    lines += [table_row(c["name"], "pass" if c["ok"] else "FAIL", c["detail"]) for c in d["checks"]]
    if d["options"].get("delta"):
        lines += ["", f"Delta in the Monte Carlo: {d['options']['delta']}."]
    lines += ["", "## Numbers", ""]
    mc = d["mc"] or {}
    up, down = "up", "down"  # proved bounds rounded outward (ftc_verify.claimtext)
    rows: list[tuple[str, Any] | tuple[str, Any, str]] = [
        ("certified robust gamma (Lemma 4.1)", d["gamma_certified"], up),
        ("certified nominal gamma (Theorem 3.2)", d["gamma_nominal_certified"], up),
        ("spectral abscissa (float estimate, worst rate vertex or witness)", d["spectral_abscissa"]),
        ("exact E||y||^2/||w||^2, worst case over beta vertices and Delta", d["exact_energy_ratio"]),
        ("proved lower bound of the robust gain", (d["gamma_lower_bound"] or {}).get("value"), down),
        ("Monte Carlo mean ratio (FMU)", mc.get("mean_ratio")),
        ("Monte Carlo one-sided upper bound (alpha 1e-6)", mc.get("upper_bound")),
        ("Monte Carlo paths", mc.get("paths")),
    ]
    lines += ["| quantity | value |", "|---|---|"]
    lines += [table_row(row[0], _bound(row[1], row[2]) if len(row) == 3 else _num(row[1])) for row in rows]
    failure = d.get("plant_failure")
    if failure:
        lines += ["", "## The plant FMU failed", "",
                  f"{failure['fmu']} crashed or returned fmi2Fatal"
                  + (f" on path {failure['path'] + 1}" if failure["path"] is not None else "")
                  + (f" at t = {failure['time']:.6g}" if failure["time"] is not None else "")
                  + f": {failure['detail']}. The Monte Carlo stopped there."]
    plant = d.get("plant")
    if plant:
        lines += ["", f"## Plant: {plant['fmu']} (model identifier {plant['model_identifier']})", "",
                  "| quantity | value |", "|---|---|",
                  table_row("measure", plant["measure"]),
                  table_row("attenuation on the plant: mean E||y - y_op||^2/||w||^2"
                            + (" of y(w) - y(w = 0)" if plant["measure"] == "incremental" else ""),
                            _num(plant["mean_ratio"])),
                  table_row("its one-sided upper bound (alpha 1e-6)", _num(plant["upper_bound"])),
                  table_row("largest excursion from the operating point, per state", _nums(plant["max_excursion"])),
                  table_row("linearisation error (FMU vs linear reference, relative)",
                            _num(plant["linearisation_error"], ".3g")),
                  table_row("inputs: smallest and largest value, per input (absolute)", _nums(plant["input_range"])),
                  table_row("paths that left [region] (states or input limits)",
                            f"{plant['left_region']} of {plant['paths']}"),
                  table_row("paths that failed in the plant FMU (not counted above)",
                            f"{plant.get('failed_in_plant', 0)} of {plant['paths']}")]
        if plant["fault_response_energy"] is not None:
            lines.append(table_row("fault response: mean ||y(w = 0) - y_op||^2 (not bounded by gamma)",
                                   _num(plant["fault_response_energy"])))
    lines += _risk_lines(d.get("risk"))
    ctrl = d["controller"] or {}
    matrices = ctrl.get("gains", ctrl.get("entries"))
    lines += ["", f"Controller: {ctrl.get('kind', 'none found')}: {matrices}", "",
              f"Seed {d['seed']}; options {d['options']}; stage times (s) "
              + ", ".join(f"{k} {v:.2f}" for k, v in d["seconds"].items()), "",
              "Plots: `fig1_path.png` (one path: true modes, FDI modes, states, output and disturbance), "
              "`ratio_distribution.png` (||y||_2/||w||_2 over paths against gamma), "
              "`gamma_bracket.png` (each certified gamma and its proved lower bound, with the exact and "
              "Monte Carlo attenuation)."]
    return "\n".join(lines) + "\n"


def _ratio_plot(rep: VerifyReport, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ratios = [r.y_norm / r.w_norm for r in rep.records if r.w_norm > 0 and r.diverged_at is None]
    diverged = sum(r.diverged_at is not None for r in rep.records)
    fig, ax = plt.subplots(figsize=(6, 3.5))
    ax.hist(ratios, bins=30, color="tab:blue", alpha=0.8)
    if diverged:
        ax.set_title(f"{diverged} of {len(rep.records)} paths diverged (not shown)")
    if rep.gamma_certified is not None:
        ax.axvline(rep.gamma_certified, color="tab:red", label=f"certified gamma {upper_text(rep.gamma_certified, 4)}")
    if rep.mc is not None and math.isfinite(rep.mc.mean_ratio):
        ax.axvline(np.sqrt(rep.mc.mean_ratio), color="k", ls="--", label="sqrt(mean ratio)")
    ax.set_xlabel("||y||_2 / ||w||_2 per path")
    ax.set_ylabel("paths")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _bracket_plot(rep: VerifyReport, path: Path) -> bool:
    """Each certified gamma and its proved lower bound as an interval, beside the square
    roots of the exact energy ratio and of the Monte Carlo bound; ``False`` (nothing
    drawn) without a proved bracket."""
    an = rep.analysis
    if an is None:
        return False
    bars = [(label, low.value, res.gamma) for label, res, low in (("nominal", an.nominal, an.nominal_lower),
                                                                    ("robust", an.robust, an.robust_lower))
            if res.certified and res.gamma is not None and low is not None and low.value is not None]
    if not bars:
        return False
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 2.8))
    for k, (_, low, high) in enumerate(bars):
        ax.plot([low, high], [k, k], lw=6, color="tab:blue", solid_capstyle="butt")
        ax.plot([low], [k], "|", ms=18, color="k")
        ax.plot([high], [k], "|", ms=18, color="tab:red")
    if rep.exact_energy_ratio is not None:
        ax.axvline(math.sqrt(rep.exact_energy_ratio), color="tab:green", ls=":", label="sqrt(exact energy ratio)")
    if rep.mc is not None and rep.mc.upper_bound is not None and math.isfinite(rep.mc.upper_bound):
        ax.axvline(math.sqrt(rep.mc.upper_bound), color="k", ls="--", label="sqrt(Monte Carlo upper bound)")
    ax.set_yticks(range(len(bars)), [f"{name} gain" for name, _, _ in bars])
    ax.set_ylim(-0.8, len(bars) - 0.2)
    ax.set_xlabel("gain: proved lower bound (black) .. certified gamma (red)")
    ax.legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return True


def check_out_dir(out_dir: str | os.PathLike[str]) -> Path:
    """Check before any work that ``out_dir`` can receive a report (module docstring): not
    a file, no foreign files in it, and a new file can be created in the folder that will
    hold it (:func:`~ftc_verify.model.output_paths.probe_folder`, an actual write). A symbolic
    link to a folder is written through: the folder it points to is replaced (as files
    are, :mod:`ftc_verify.model.output_paths`)."""
    if not str(out_dir).strip():
        raise ProblemFileError(f"--out {str(out_dir)!r}: empty folder name; give a folder name")
    check_name(out_dir, f"--out {out_dir}")  # a link loop, a name too long
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise ProblemFileError(f"--out {out}: exists and is {kind_of(out.stat().st_mode)}, not a folder")
    if out.is_dir():
        foreign = sorted(p.name for p in out.iterdir() if p.name not in REPORT_FILES)
        if foreign:
            raise ProblemFileError(
                f"--out {out}: holds files that are not an ftc-verify report ({', '.join(foreign[:5])}); "
                "choose a new or empty folder, or one that holds only a previous report"
            )
    probe_folder(out.resolve().parent, f"--out {out}")  # an actual write where the staging folder goes
    return out


def _swap_in(stage: Path, out: Path) -> None:
    """Replace ``out`` (if any) by ``stage`` whole."""
    old = None
    if out.exists():
        old = Path(tempfile.mkdtemp(prefix=f".{out.name}.old-", dir=out.parent))
        os.replace(out, old / "previous")
    try:
        os.replace(stage, out)
    except BaseException:
        if old is not None:
            os.replace(old / "previous", out)
        raise
    finally:
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)


def draw_figures(rep: VerifyReport, folder: Path) -> None:
    """The report's PNGs in ``folder``: the paper's Fig. 1 for the first path (drawn in a
    forked child beside the other two), the distribution of the paths' gains and the
    gamma bracket (each only when its data exists)."""
    from .plots import plot_path

    forked = None
    if rep.records:
        plant = rep.plant or {}

        def fig1() -> None:
            plot_path(rep.records[0], folder / "fig1_path.png", title=f"{rep.system.name}: one sample path"
                      + (f" on {Path(plant['fmu']).name}" if plant else ""),
                      state_offset=plant.get("states_op"), state_names=plant.get("states"))

        if hasattr(os, "fork"):  # the largest figure drawn in a child beside the other two
            from ..analysis.solvers import ForkedCall

            forked = ForkedCall(fig1, "the path figure")
        else:
            fig1()
    try:
        if rep.records:
            _ratio_plot(rep, folder / "ratio_distribution.png")
        if rep.gamma_certified is not None:
            _bracket_plot(rep, folder / "gamma_bracket.png")
        if forked is not None:
            forked.result()
    finally:
        if forked is not None:
            forked.cancel()


class EarlyFigures:
    """The figures of a report drawn before its last stages end: ``verify`` calls this
    with the report so far (:func:`~ftc_verify.verification.verify.run_verify`'s
    ``meanwhile``) while its sampled-loop stages still run in their child; the figures
    need none of those stages. They go into a folder beside ``out_dir``
    (``.NAME.figures-*``, like the staging folder), which :func:`write_report` empties
    into the report; :meth:`close` (in a ``finally``) removes what is left."""

    def __init__(self, out_dir: str | os.PathLike[str]) -> None:
        self.out = Path(out_dir)
        self.folder: Path | None = None
        self.span: tuple[float, float] | None = None  # when they were drawn (time.perf_counter)

    def __call__(self, rep: VerifyReport) -> None:
        t0 = time.perf_counter()
        try:
            folder = Path(tempfile.mkdtemp(prefix=f".{self.out.name}.figures-", dir=self.out.resolve().parent))
        except OSError as exc:
            raise ProblemFileError(f"{self.out}: cannot create a folder beside it: {exc.strerror}") from None
        self.folder = folder
        draw_figures(rep, folder)
        self.span = (t0, time.perf_counter())

    def close(self) -> None:
        """Remove the folder of the figures (after :func:`write_report` or an error)."""
        if self.folder is not None:
            shutil.rmtree(self.folder, ignore_errors=True)
            self.folder = None


def write_report(rep: VerifyReport, out_dir: str | os.PathLike[str], watch: Any = None,
                 figures: EarlyFigures | None = None) -> list[Path]:
    """Write ``report.json``, ``report.md`` and the plots as the whole content of
    ``out_dir``; return the paths.

    ``report.json`` gets ``timings``, the wall-time breakdown: the stages of
    :func:`~ftc_verify.verification.verify.run_verify` (``rep.seconds``) and the plots'
    ``report_plots``; with ``watch`` (the CLI's :class:`~ftc_verify.cli.common.Stopwatch`)
    also its marks (``startup``, ``imports_and_load``, ...) and ``total``, the seconds
    from the process's start to this file. Stages run beside each other (the sampled
    loop's in a child during the Monte Carlo, python-control's cross-check in another),
    so the durations overlap: ``timings["timeline"]`` gives every stage's
    ``[start, end]``, seconds since the process started (with ``watch``; else since the
    first stage started), ordered by start; ``timings["cpu"]``, the CPU seconds so far
    (:func:`cpu_seconds`). ``figures``: the figures already drawn
    (:class:`EarlyFigures`, when it was called), moved in instead of drawn here."""
    t0 = time.perf_counter()

    out = check_out_dir(out_dir)
    real = out.resolve()  # a link to a folder: the folder it points to is replaced, not the link
    try:
        stage = Path(tempfile.mkdtemp(prefix=f".{out.name}.staging-", dir=real.parent))
    except OSError as exc:
        raise ProblemFileError(f"{out}: cannot create a staging folder beside it: {exc.strerror}") from None
    try:
        if figures is not None and figures.folder is not None and figures.span is not None:
            for png in sorted(figures.folder.iterdir()):
                os.replace(png, stage / png.name)
            drawn = figures.span
        else:
            draw_figures(rep, stage)
            drawn = (t0, time.perf_counter())
        spans = dict(rep.spans) | {"report_plots": drawn}
        timings: dict[str, Any] = dict(rep.seconds) | {"report_plots": drawn[1] - drawn[0]}
        timings["cpu"] = cpu_seconds()
        if watch is not None:
            timings = dict(watch.timings) | timings | {"total": watch.total(), "timeline": watch.timeline(spans)}
        else:
            origin = min(a for a, _ in spans.values())
            timings["timeline"] = {k: [round(a - origin, 4), round(b - origin, 4)]
                                   for k, (a, b) in sorted(spans.items(), key=lambda item: item[1][0])}
        (stage / "report.json").write_text(dumps(rep.to_dict() | {"timings": timings}) + "\n")
        (stage / "report.md").write_text(render_markdown(rep))
        names = sorted(item.name for item in stage.iterdir())
        stage.chmod(0o777 & ~_umask())
        _swap_in(stage, real)
        return [out / name for name in names]
    finally:
        shutil.rmtree(stage, ignore_errors=True)


def cpu_seconds() -> dict[str, float]:
    """CPU seconds (user + system) of this process (``process``) and of its child
    processes that ended and were waited for (``children``: the plant processes of the
    Monte Carlo, the forked synthesis, analysis and sampled-loop stages, python-control's
    cross-check once it ended), and their sum ``total``: beside the wall times, what the
    run cost the machine's cores (empty where the ``resource`` module is missing)."""
    try:
        import resource
    except ImportError:  # pragma: no cover - not POSIX
        return {}
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    mine, theirs = own.ru_utime + own.ru_stime, kids.ru_utime + kids.ru_stime
    return {"process": round(mine, 3), "children": round(theirs, 3), "total": round(mine + theirs, 3)}


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask
