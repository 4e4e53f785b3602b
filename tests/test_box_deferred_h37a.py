"""The whole box's Theorem 3.1 LMI solved once in ``analyze`` (issue 37, item 3): the box
proof leaves it to the Theorem 3.1 stage (``root_lmi=False``), whose certificate proves the
verdict over the whole box; without a certificate there the box proof runs in full."""

from __future__ import annotations

import dataclasses
import importlib
import importlib.util
from pathlib import Path
from typing import Any

import pytest

from ftc_verify.analysis import box
from ftc_verify.analysis.box import ROOT_LMI_DEFERRED, box_stability
from ftc_verify.analysis.closedloop import ClosedLoop, state_feedback_loop
from ftc_verify.analysis.conditioning import conditioning_transform
from ftc_verify.analysis.moments.stability import mean_square_stability

ROOT = Path(__file__).resolve().parents[1]
analyze_module = importlib.import_module("ftc_verify.analysis.analyze")


def _loop() -> ClosedLoop:
    """benchmarks/analysis.py's random n = 3, m = 2 loop of seed 2: the whole box's centre
    candidate is positive definite but misses a vertex (the box's LMI is needed)."""
    spec = importlib.util.spec_from_file_location("bench_analysis", ROOT / "benchmarks" / "analysis.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    system, gains, _ = module.make_case(3, 2, 2, False)
    return state_feedback_loop(system, gains)


def test_the_box_proof_defers_the_whole_box_lmi_only_when_asked() -> None:
    loop = _loop()
    sim = conditioning_transform(loop.nominal())
    deferred = box_stability(loop, sim, root_lmi=False)
    assert deferred.verdict == "undecided" and deferred.reason == ROOT_LMI_DEFERRED and deferred.boxes == 1
    full = box_stability(loop, sim)
    assert full.verdict == "stable" and full.time_varying
    assert "Theorem 3.1 LMI on the sub-box" in full.regions[0].method


def test_analyze_proves_the_box_with_the_theorem_3_1_stage_and_solves_no_box_lmi(
        monkeypatch: pytest.MonkeyPatch) -> None:
    loop = _loop()

    def refuse(*args: Any, **kwargs: Any) -> bool:
        raise AssertionError("the whole box's LMI was solved in the box proof")

    monkeypatch.setattr(box, "_lmi_on", refuse)
    rep = analyze_module.analyze(loop, cross_validation=False)
    assert rep.mss.verdict == "stable" and rep.mss.time_varying and rep.certified_stable
    assert rep.mes_lmi.certified and "no solve" in rep.mes_lmi.message  # Theorem 3.2's P, checked in balls
    assert rep.mss.vertex_verdicts[0].method.startswith("the certified Theorem 3.1 LMI over the whole box")
    assert ROOT_LMI_DEFERRED in rep.mss.reason


def test_without_a_theorem_3_1_certificate_the_box_proof_runs_in_full(monkeypatch: pytest.MonkeyPatch) -> None:
    loop = _loop()
    real = analyze_module.mes_lmi

    def uncertified(*args: Any, **kwargs: Any) -> Any:
        return dataclasses.replace(real(*args, **kwargs), outcome="candidate")

    monkeypatch.setattr(analyze_module, "mes_lmi", uncertified)
    rep = analyze_module.analyze(loop, cross_validation=False, lower_bounds=False)
    assert not rep.mes_lmi.certified
    assert rep.mss.verdict == "stable" and ROOT_LMI_DEFERRED not in rep.mss.reason
    assert rep.mss.verdict == mean_square_stability(loop).verdict
    assert "Theorem 3.1 LMI on the sub-box" in rep.mss.vertex_verdicts[0].method
