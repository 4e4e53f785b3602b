"""The programs beside the spectral stage (issue 37, item 3).

Without uncertainty Theorem 3.2 runs in a forked child started before the spectral stage;
with uncertainty channels (n = 12, m = 4) Lemma 4.1 does, and Theorem 3.2 and Theorem 3.1
(on Theorem 3.2's ``P``) run here meanwhile. Every answer is the one the same calls give in
this process, to the last bit, and a loop proved unstable gets no solve."""

from __future__ import annotations

import dataclasses
import importlib
import os
from typing import Any

import numpy as np
import pytest

from ftc_verify.analysis.lmi_analysis import hinf_gamma, mes_known, mes_lmi

analyze_module = importlib.import_module("ftc_verify.analysis.analyze")
needs_fork = pytest.mark.skipif(not hasattr(os, "fork"), reason="POSIX fork")


@pytest.fixture
def forked(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """The names of the forked children ``analyze`` starts, in order."""
    started: list[str] = []
    real = analyze_module.ForkedCall

    def spy(fn: Any, what: str, **kwargs: Any) -> Any:
        started.append(what)
        return real(fn, what, **kwargs)

    monkeypatch.setattr(analyze_module, "ForkedCall", spy)
    return started


@needs_fork
def test_the_nominal_program_beside_the_spectral_stage_gives_the_answer_solved_here(
        paper_loop: Any, forked: list[str]) -> None:
    loop = paper_loop.nominal()  # no uncertainty channels
    rep = analyze_module.analyze(loop, cross_validation=False, lower_bounds=False)
    assert forked == ["Theorem 3.2"]
    here = hinf_gamma(loop, robust=False)
    assert rep.nominal.certified and here.certified and rep.nominal.gamma == here.gamma
    assert rep.robust is rep.nominal and rep.certified_stable
    np.testing.assert_array_equal(np.asarray(rep.nominal.P), np.asarray(here.P))


def test_a_loop_proved_unstable_gets_no_solve(paper_loop: Any) -> None:
    loop = paper_loop.nominal()
    unstable = dataclasses.replace(loop, A=tuple(a + 5.0 * np.eye(loop.n) for a in loop.A), source=None)
    rep = analyze_module.analyze(unstable, cross_validation=False)
    assert rep.mss.verdict == "not stable" and rep.nominal.outcome == "skipped" and not rep.certified_stable


@needs_fork
def test_the_robust_program_beside_the_spectral_stage_gives_the_answers_solved_here(
        paper_loop: Any, forked: list[str]) -> None:
    assert paper_loop.uncertain
    rep = analyze_module.analyze(paper_loop, cross_validation=False)
    assert forked == ["Lemma 4.1", "Theorem 3.2"]  # both programs in children started before the spectral stage
    nominal, robust = hinf_gamma(paper_loop, robust=False), hinf_gamma(paper_loop, robust=True)
    for got, here in ((rep.nominal, nominal), (rep.robust, robust)):
        assert got.certified and here.certified and got.gamma == here.gamma
        np.testing.assert_array_equal(np.asarray(got.P), np.asarray(here.P))
        assert got.multipliers == here.multipliers
    mes = mes_lmi(paper_loop, known=(nominal, robust))
    assert rep.mes_lmi.certified and rep.mes_lmi.message == mes.message
    np.testing.assert_array_equal(np.asarray(rep.mes_lmi.P), np.asarray(mes.P))
    assert rep.certified_stable and "lower_bounds_beside" in rep.seconds and "gammas_wall" in rep.seconds


def test_mes_known_takes_the_first_known_p_that_passes_and_never_solves(paper_loop: Any) -> None:
    nominal = hinf_gamma(paper_loop, robust=False)
    assert mes_known(paper_loop, ()) is None
    broken = dataclasses.replace(nominal, P=tuple(-np.eye(paper_loop.n) for _ in nominal.P), P_conditioned=None,
                                 similarity=None)  # still labelled certified, but its P is not positive
    assert broken.certified and mes_known(paper_loop, (broken,)) is None
    found = mes_known(paper_loop, (broken, nominal))
    assert found is not None and found.certified and "theorem-3.2" in found.message
    assert found.message == mes_lmi(paper_loop, known=(broken, nominal)).message


@needs_fork
def test_theorem_3_1_from_lemma_4_1_when_theorem_3_2_p_fails(paper_loop: Any, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(analyze_module, "mes_known", lambda loop, known: None)  # as if Theorem 3.2's P failed
    rep = analyze_module.analyze(paper_loop, cross_validation=False, lower_bounds=False)
    assert rep.mes_lmi.certified and "lemma-4.1" in rep.mes_lmi.message and rep.certified_stable


def test_an_uncertain_loop_proved_unstable_gets_no_answer_from_the_child(paper_loop: Any) -> None:
    unstable = dataclasses.replace(paper_loop, A=tuple(a + 5.0 * np.eye(paper_loop.n) for a in paper_loop.A), source=None)
    rep = analyze_module.analyze(unstable, cross_validation=False)  # the Lemma 4.1 child is cancelled, not waited for
    assert rep.mss.verdict == "not stable" and not rep.certified_stable
    assert rep.robust.outcome == rep.nominal.outcome == rep.mes_lmi.outcome == "skipped"
