"""Theorem 3.2 beside the spectral stage (issue 37, item 3): without uncertainty the nominal
program runs in a forked child started before the spectral stage; its answer is the one
solved in this process, and a loop proved unstable gets no solve."""

from __future__ import annotations

import importlib
import os
from typing import Any

import numpy as np
import pytest

from ftc_verify.analysis.lmi_analysis import hinf_gamma

analyze_module = importlib.import_module("ftc_verify.analysis.analyze")


@pytest.mark.skipif(not hasattr(os, "fork"), reason="POSIX fork")
def test_the_nominal_program_beside_the_spectral_stage_gives_the_answer_solved_here(
        paper_loop: Any, monkeypatch: pytest.MonkeyPatch) -> None:
    loop = paper_loop.nominal()  # no uncertainty channels
    started: list[str] = []
    real = analyze_module.ForkedCall

    def spy(fn: Any, what: str, **kwargs: Any) -> Any:
        started.append(what)
        return real(fn, what, **kwargs)

    monkeypatch.setattr(analyze_module, "ForkedCall", spy)
    rep = analyze_module.analyze(loop, cross_validation=False, lower_bounds=False)
    assert started == ["Theorem 3.2"]
    here = hinf_gamma(loop, robust=False)
    assert rep.nominal.certified and here.certified and rep.nominal.gamma == here.gamma
    assert rep.robust is rep.nominal and rep.certified_stable
    np.testing.assert_array_equal(np.asarray(rep.nominal.P), np.asarray(here.P))


def test_a_loop_proved_unstable_gets_no_solve(paper_loop: Any) -> None:
    import dataclasses

    loop = paper_loop.nominal()
    unstable = dataclasses.replace(loop, A=tuple(a + 5.0 * np.eye(loop.n) for a in loop.A), source=None)
    rep = analyze_module.analyze(unstable, cross_validation=False)
    assert rep.mss.verdict == "not stable" and rep.nominal.outcome == "skipped" and not rep.certified_stable
