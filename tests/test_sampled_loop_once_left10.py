"""One sampled loop per command: ``analyze --period`` and ``verify``'s sampled stages build
:class:`~ftc_verify.analysis.moments.sampled.SampledLoop` once and pass it to the
analysis, the ``h_max`` refinement and the gains (before, the gains built it again, and
``verify --h-max-work`` with a given controller built it in the CLI and in the stage).

Every build, in this process or in the forked children the stages run in, appends its
process id to a file: the count is over the whole command."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import pytest

from ftc_verify.analysis.moments.sampled import SampledLoop
from ftc_verify.cli.common import EXIT_OK
from ftc_verify.cli.main import main
from ftc_verify.controllers.files import load_controller
from ftc_verify.model.files import load_system
from ftc_verify.verification.sampled_stage import sampled_stages

ROOT = Path(__file__).resolve().parents[1]
PAPER, GAINS = ROOT / "examples" / "paper.toml", ROOT / "examples" / "paper_gains.toml"


def _count_builds(monkeypatch: pytest.MonkeyPatch, log: Path) -> None:
    build = SampledLoop.build.__func__  # type: ignore[attr-defined]

    def counted(cls: type[SampledLoop], system: Any, controller: Any) -> SampledLoop:
        with open(log, "a", encoding="utf-8") as fh:
            fh.write(f"{os.getpid()}\n")
        return build(cls, system, controller)  # type: ignore[no-any-return]

    monkeypatch.setattr(SampledLoop, "build", classmethod(counted))


def _builds(log: Path) -> int:
    return len(log.read_text(encoding="utf-8").split()) if log.exists() else 0


def test_analyze_period_builds_the_loop_once(monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    log = tmp_path / "builds"
    _count_builds(monkeypatch, log)
    assert main(["analyze", str(PAPER), "--gains", str(GAINS), "--period", "0.05"]) == EXIT_OK
    out = capsys.readouterr().out
    assert "mean-square stable over the rate box (proved)" in out and "gamma <= " in out  # the gains ran
    assert _builds(log) == 1


def test_sampled_stages_build_the_loop_once(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """The analysis here, the gains in their forked child: one build in all, and the
    gains were computed (their child got the loop)."""
    log = tmp_path / "builds"
    _count_builds(monkeypatch, log)
    checks: list[Any] = []
    found = sampled_stages(load_system(PAPER), load_controller(GAINS), 0.05, 0.25, checks, {}, here=True)
    assert _builds(log) == 1
    assert found["sampled"].verdict == "stable" and all(check.ok for check in checks)
    assert found["sampled"].performance is not None and found["sampled"].performance.nominal.gamma is not None


def test_a_loop_built_for_another_controller_is_refused() -> None:
    """A stage given the loop of another controller would prove that loop and report it
    for this controller (review, round 10): :meth:`SampledLoop.of` refuses it, naming both."""
    import dataclasses

    import numpy as np

    from ftc_verify.analysis.moments.sampled import sampled_analysis
    from ftc_verify.errors import ValidationError

    system, gains = load_system(PAPER), load_controller(GAINS)
    zero = dataclasses.replace(gains, Dc=tuple(np.zeros_like(D) for D in gains.Dc), name="zero gains")
    loop = SampledLoop.build(system, gains)
    assert SampledLoop.of(system, gains, loop) is loop
    with pytest.raises(ValidationError, match="'zero gains'"):
        sampled_analysis(system, zero, 0.05, loop=loop)
