"""``verify --h-max-work`` with a controller known only after the synthesis, and the
printed periods of the ``h_max`` bracket (issue 31; review of the refinement)."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from ftc_verify.analysis.moments import sampled_refine
from ftc_verify.analysis.moments.sampled import SampledResult
from ftc_verify.analysis.moments.sampled_refine import period_text, refinement_note
from ftc_verify.controllers.files import load_controller
from ftc_verify.model.files import load_system

ROOT = Path(__file__).resolve().parents[1]


def test_printed_periods_keep_the_claim() -> None:
    """A proved-stable period is printed rounded down, a proved-unstable one rounded up
    (to 6 significant digits): the printed number is never on the wrong side."""
    assert period_text(0.5455146, down=True) == "0.545514" and period_text(0.5455146, down=False) == "0.545515"
    assert period_text(0.5455144, down=True) == "0.545514" and period_text(0.5455144, down=False) == "0.545515"
    assert period_text(0.5, down=True) == period_text(0.5, down=False) == "0.5"
    rng = np.random.default_rng(20261126)
    for x in 10.0 ** rng.uniform(-7, 3, 400):
        lo, hi = float(period_text(x, down=True)), float(period_text(x, down=False))
        assert lo <= x <= hi and (hi - lo) <= 1.0001e-5 * x


def test_refinement_note_is_the_refinements_part_only() -> None:
    res = SampledResult(0.05, "stable", 0.5, [[0.0]], "by test", 0, 0.08, 0.0843,
                        "bracket; 2 clock attempts; refinement (--h-max-work 5000): 2 cubic clock certificate(s)",
                        (), (0.01, 1.0), 0.0)
    assert refinement_note(res) == "refinement (--h-max-work 5000): 2 cubic clock certificate(s)"
    assert refinement_note(dataclasses.replace(res, h_max_note="bracket; 2 clock attempts")) is None


def test_refinement_over_the_memory_limit_is_a_note_when_the_controller_comes_from_the_synthesis(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """``verify --h-max-work`` without ``--gains``: the controller exists only after the
    synthesis, so the memory check runs in the sampled stage; over the limit the
    refinement is not run and the check line and the note say why (the default bracket
    stands)."""
    from ftc_verify.verification.sampled_stage import sampled_stage

    monkeypatch.setenv("FTC_VERIFY_MEMORY_LIMIT", "100M")  # below the program's estimate (0.2 GB)
    calls: list[float] = []

    def refine(system: Any, controller: Any, result: SampledResult, work: float, *, loop: Any = None) -> SampledResult:
        calls.append(work)
        return result

    monkeypatch.setattr(sampled_refine, "refine_result", refine)
    system = load_system(ROOT / "examples" / "paper.toml")
    controller = load_controller(ROOT / "examples" / "paper_gains.toml")
    res, check = sampled_stage(system, controller, 0.05, here=True, h_max_work=1000.0)
    assert res is not None and calls == []
    assert "refinement not run: --h-max-work 1000: the refinement's clock program needs about" in res.h_max_note
    assert "refinement not run" in check.detail and check.ok
    monkeypatch.setenv("FTC_VERIFY_MEMORY_LIMIT", "64G")
    res, check = sampled_stage(system, controller, 0.05, here=True, h_max_work=1000.0)
    assert calls == [1000.0] and "refinement not run" not in check.detail
