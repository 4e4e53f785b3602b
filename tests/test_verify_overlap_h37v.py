"""Stages of ``verify`` run beside each other (issue 37): the sampled-loop stages in a child
during the Monte Carlo (:class:`~ftc_verify.verification.sampled_stage.SampledRun`), each
stage's start and end on one time line (``timings["timeline"]`` of ``report.json``), and
the one helper that starts python-control's cross-check for ``analyze`` and ``verify``
(:func:`~ftc_verify.cli.common.with_cross_check`)."""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from ftc_verify.cli.common import Stopwatch, load, with_cross_check
from ftc_verify.prestart import Prestarted
from ftc_verify.verification import sampled_stage
from ftc_verify.verification.report import write_report
from ftc_verify.verification.sampled_stage import SampledRun
from ftc_verify.verification.verify import Check, VerifyReport

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "examples" / "paper.toml"
GAINS = ROOT / "examples" / "paper_gains.toml"
fork_only = pytest.mark.skipif(not hasattr(os, "fork"), reason="POSIX fork")


def _fake_stages(system: Any, controller: Any, step: float, g2: float, checks: list[Check],
                 seconds: dict[str, float], mc: Any = None, spans: Any = None, here: bool = False,
                 h_max_work: float | None = None, reserved: float = 0.0, loop: Any = None) -> dict[str, Any]:
    """Stands in for the real stages: says where it ran and appends two checks."""
    t0 = time.perf_counter()
    checks += [Check("first", True, f"pid {os.getpid()}"), Check("second", here, f"step {step}")]
    seconds["sampled"] = time.perf_counter() - t0
    spans["sampled"] = (t0, t0 + seconds["sampled"])
    return {"sampled": os.getpid(), "sampled_exact": (g2,)}


@fork_only
def test_the_stages_run_in_a_child_and_their_checks_go_where_they_were(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(sampled_stage, "sampled_stages", _fake_stages)
    run = SampledRun(None, None, 0.01, 0.25, None, at=1)  # type: ignore[arg-type]
    checks = [Check("certified", True, ""), Check("gamma bracket", True, ""), Check("Monte Carlo (FMU)", True, "")]
    seconds: dict[str, float] = {}
    spans: dict[str, tuple[float, float]] = {}
    found = run.join(checks, seconds, spans)
    assert found["sampled"] != os.getpid() and found["sampled_exact"] == (0.25,)  # computed in the child
    assert [c.name for c in checks] == ["certified", "first", "second", "gamma bracket", "Monte Carlo (FMU)"]
    assert checks[2].ok  # the child ran the stages "here" (no child of its own)
    assert set(seconds) == set(spans) == {"sampled", "sampled_wait"}
    assert all(a <= b for a, b in spans.values())


def _sleeps(*args: Any, **kwargs: Any) -> dict[str, Any]:
    time.sleep(60)
    return {}


@fork_only
def test_cancel_ends_a_running_child(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(sampled_stage, "sampled_stages", _sleeps)
    run = SampledRun(None, None, 0.01, 0.25, None, at=0)  # type: ignore[arg-type]
    pid = run._child.pid  # type: ignore[union-attr]
    t0 = time.perf_counter()
    run.cancel()
    assert time.perf_counter() - t0 < 5.0
    with pytest.raises(ProcessLookupError):
        os.kill(pid, 0)  # reaped and gone


def test_the_stopwatch_puts_marks_and_other_spans_on_one_time_line() -> None:
    watch = Stopwatch()
    time.sleep(0.01)
    watch.mark("load")
    t0 = time.perf_counter()
    time.sleep(0.01)
    watch.mark("stages")
    line = watch.timeline({"beside": (t0, time.perf_counter())})
    assert list(line)[:2] == ["startup", "load"]
    assert line["startup"][0] == 0.0 and line["startup"][1] == pytest.approx(watch.timings["startup"], abs=1e-3)
    for name in ("load", "stages"):
        start, end = line[name]
        assert end - start == pytest.approx(watch.timings[name], abs=1e-3)
    assert line["load"][1] == line["stages"][0]  # marks follow each other
    assert line["stages"][0] <= line["beside"][0] <= line["beside"][1] <= line["stages"][1] + 1e-3
    starts = [v[0] for v in line.values()]
    assert starts == sorted(starts)


def _double(x: float) -> float:
    return 2 * x


@fork_only
def test_the_prestarted_child_reports_when_it_imported_and_ran() -> None:
    child = Prestarted(("math",))
    try:
        t0 = time.perf_counter()
        child.submit(_double, 4.0)
        assert child.result() == 8.0
        t1 = time.perf_counter()
    finally:
        child.cancel()
    spans = child.spans
    assert set(spans) == {"import", "run", "wait"}
    assert spans["import"][0] <= spans["import"][1] <= spans["run"][0] <= spans["run"][1] <= spans["wait"][1] <= t1
    assert spans["run"][0] >= t0 - 1e-6  # the job ran after it was submitted (one clock for both processes)


@fork_only
def test_with_cross_check_starts_the_child_after_the_shared_imports_and_ends_it() -> None:
    seen: dict[str, Any] = {}

    def command(args: argparse.Namespace, watch: Stopwatch, check: Any) -> int:
        seen.update(args=args, watch=watch, check=check, pid=check.pid)
        return 7

    args = argparse.Namespace()
    sys.modules.pop("ftc_verify.jsonable", None)  # the shared module: imported again before the fork
    assert with_cross_check(args, command, "ftc_verify.jsonable") == 7
    assert "ftc_verify.jsonable" in sys.modules
    assert seen["args"] is args and isinstance(seen["watch"], Stopwatch) and seen["pid"] > 0
    assert seen["check"].pid == 0  # cancelled and reaped at the end
    with pytest.raises(ProcessLookupError):
        os.kill(seen["pid"], 0)


def test_report_json_has_every_stage_on_the_time_line(tmp_path: Path) -> None:
    system, _ = load(str(PAPER), str(GAINS))
    t = time.perf_counter()
    spans = {"synthesis": (t, t + 2.0), "monte_carlo": (t + 2.1, t + 5.0), "sampled": (t + 2.05, t + 6.0)}
    rep = VerifyReport(system, None, None, None, None, (), (), None, (), (Check("synthesis", False, "none"),),
                       seed=1, options={"fdi_model": "FDI: test"}, seconds={k: b - a for k, (a, b) in spans.items()}, spans=spans)
    watch = Stopwatch()
    write_report(rep, tmp_path / "out", watch)
    timings = json.loads((tmp_path / "out" / "report.json").read_text())["timings"]
    line = timings["timeline"]
    assert {"startup", "synthesis", "monte_carlo", "sampled", "report_plots"} <= set(line)
    for name, (a, b) in spans.items():  # each stage's own start and end, seconds since the process started
        assert line[name][1] - line[name][0] == pytest.approx(b - a, abs=1e-3)
        assert line[name][0] == pytest.approx(a - watch.origin, abs=1e-3)
    assert line["sampled"][0] < line["monte_carlo"][0] < line["monte_carlo"][1] < line["sampled"][1]  # overlapping
    assert np.isclose(timings["monte_carlo"], 2.9) and timings["total"] >= line["report_plots"][1] - 1e-3


def test_figures_drawn_early_are_moved_into_the_report(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from ftc_verify.verification import report as report_module

    def fake_draw(rep: VerifyReport, folder: Path) -> None:
        (folder / "gamma_bracket.png").write_bytes(b"\x89PNG\r\n\x1a\n early")

    monkeypatch.setattr(report_module, "draw_figures", fake_draw)
    system, _ = load(str(PAPER), str(GAINS))
    rep = VerifyReport(system, None, None, None, None, (), (), None, (), (Check("synthesis", False, "none"),),
                       seed=1, options={"fdi_model": "FDI: test"})
    out = tmp_path / "out"
    figures = report_module.EarlyFigures(out)
    try:
        figures(rep)
        assert figures.folder is not None and figures.folder.parent == tmp_path
        assert figures.folder.name.startswith(".out.figures-")
        written = write_report(rep, out, None, figures)
    finally:
        figures.close()
    assert (out / "gamma_bracket.png").read_bytes().endswith(b"early") and out / "gamma_bracket.png" in written
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # no figures or staging folder left
    timings = json.loads((out / "report.json").read_text())["timings"]
    assert figures.span is not None
    assert timings["report_plots"] == pytest.approx(figures.span[1] - figures.span[0])


def _running(pid: int) -> bool:
    """Whether ``pid`` is a live process (a zombie awaiting its reaper is not)."""
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] != "Z"
    except FileNotFoundError:
        return False


@fork_only
@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="reads /proc")
def test_cancel_ends_the_gains_grandchild_too(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """``verify``'s sampled stages fork the gains beside the energies
    (``sampled_stage._gains_child``); cancelling the stages' child ends that grandchild as
    well (it stays in the child's process group), whatever the platform's parent-death
    signal does."""
    from ftc_verify.analysis.moments import sampled_gamma

    monkeypatch.setattr(sampled_gamma, "sampled_performance", _sleeps)
    marker = tmp_path / "grandchild.pid"

    def stages(*args: Any, **kwargs: Any) -> dict[str, Any]:
        gains = sampled_stage._gains_child(None, None, 0.01, None)  # type: ignore[arg-type]
        marker.write_text(str(gains.pid))
        time.sleep(60)
        return {}

    monkeypatch.setattr(sampled_stage, "sampled_stages", stages)
    run = SampledRun(None, None, 0.01, 0.25, None, at=0)  # type: ignore[arg-type]
    deadline = time.monotonic() + 30
    while not marker.exists() or not marker.read_text():
        assert time.monotonic() < deadline, "the grandchild was not started"
        time.sleep(0.02)
    grandchild = int(marker.read_text())
    assert _running(grandchild) and os.getpgid(grandchild) == run._child.pid  # type: ignore[union-attr]
    run.cancel()
    deadline = time.monotonic() + 5
    while _running(grandchild):
        assert time.monotonic() < deadline, "the gains grandchild outlived the cancelled stages"
        time.sleep(0.02)
