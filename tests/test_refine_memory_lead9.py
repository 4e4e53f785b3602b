"""``verify --h-max-work``: the refinement's program runs in the sampled-loop child while
the Monte Carlo keeps its records, so their memory is checked together (review of the
refinement, issue 31)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from ftc_verify.analysis.moments import sampled_refine
from ftc_verify.analysis.moments.sampled import SampledLoop, SampledResult
from ftc_verify.analysis.moments.sampled_cover import cubic_memory
from ftc_verify.cli.common import EXIT_BAD_INPUT
from ftc_verify.controllers.files import load_controller
from ftc_verify.model.files import load_system
from ftc_verify.simulation.spec import SimulationSpec
from ftc_verify.verification.sampled_stage import sampled_stage

from cli_inprocess import run_cli

ROOT = Path(__file__).resolve().parents[1]
PAPER, GAINS = ROOT / "examples" / "paper.toml", ROOT / "examples" / "paper_gains.toml"
STEP, HORIZON, PATHS = 0.05, 400.0, 2000


def _needs() -> tuple[float, float]:
    """The refinement's program and the records of the command below, as estimated."""
    system, controller = load_system(PAPER), load_controller(GAINS)
    spec = SimulationSpec(step=STEP, horizon=HORIZON, n_paths=PATHS, seed=1)
    records, _ = spec.records_memory(system, controller, PATHS)
    return cubic_memory(SampledLoop.build(system, controller)), records


def test_verify_refuses_refinement_and_records_that_fit_only_alone(tmp_path: Path) -> None:
    program, records = _needs()
    assert records > 0.1 * program  # the sum, not either part, must decide
    limit = int(max(program, records) + 0.5 * min(program, records))  # each fits alone, not both
    args = ["verify", str(PAPER), "--gains", str(GAINS), "--step", str(STEP), "--horizon", str(HORIZON),
            "--paths", str(PATHS), "--h-max-work", "1000", "--out", str(tmp_path / "rep")]
    out = run_cli(args, env={"FTC_VERIFY_MEMORY_LIMIT": str(limit)})
    assert out.returncode == EXIT_BAD_INPUT, out.stderr
    assert "recorded paths" in out.stderr and "h_max refinement" in out.stderr and "--h-max-work" in out.stderr
    assert "Traceback" not in out.stderr and not (tmp_path / "rep").exists()
    # each alone fits under that limit: the refusal was the sum's
    system, controller = load_system(PAPER), load_controller(GAINS)
    spec = SimulationSpec(step=STEP, horizon=HORIZON, n_paths=PATHS, seed=1)
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("FTC_VERIFY_MEMORY_LIMIT", str(limit))
        spec.check_memory(system, controller, PATHS)
        sampled_refine.check_refine(system, controller, STEP, 1000.0)


def test_stage_does_not_refine_beside_records_over_the_limit(monkeypatch: pytest.MonkeyPatch) -> None:
    """A synthesized controller is checked in the stage: with the records' bytes reserved
    the refinement is not run, and the check line says why; with nothing reserved it is."""
    program, _ = _needs()
    monkeypatch.setenv("FTC_VERIFY_MEMORY_LIMIT", str(int(1.5 * program)))
    calls: list[float] = []

    def refine(system: Any, controller: Any, result: SampledResult, work: float, *, loop: Any = None) -> SampledResult:
        calls.append(work)
        return result

    monkeypatch.setattr(sampled_refine, "refine_result", refine)
    system, controller = load_system(PAPER), load_controller(GAINS)
    res, check = sampled_stage(system, controller, STEP, here=True, h_max_work=1000.0, reserved=program)
    assert res is not None and calls == []
    assert "refinement not run" in check.detail and "beside the Monte Carlo's records" in check.detail and check.ok
    res, check = sampled_stage(system, controller, STEP, here=True, h_max_work=1000.0, reserved=0.0)
    assert calls == [1000.0] and "refinement not run" not in check.detail
