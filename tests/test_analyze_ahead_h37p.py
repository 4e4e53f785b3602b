"""With uncertainty channels ``analyze`` solves Theorem 3.2 in a second forked child
started with Lemma 4.1's, before the spectral stage (analysis.analyze._gamma_ahead,
issue 37 item 3): the answers are those of the programs solved in this process, bit for
bit, with and without the lower bounds, and a loop proved unstable waits for neither."""

from __future__ import annotations

import dataclasses
import importlib
import os
from typing import Any

import numpy as np
import pytest

from ftc_verify.analysis.lmi_analysis import hinf_gamma

analyze_module = importlib.import_module("ftc_verify.analysis.analyze")
pytestmark = pytest.mark.skipif(not hasattr(os, "fork"), reason="POSIX fork")


@pytest.fixture
def forked(monkeypatch: pytest.MonkeyPatch) -> list[tuple[str, int]]:
    """The forked children ``analyze`` starts, in order: name and process id."""
    started: list[tuple[str, int]] = []
    real = analyze_module.ForkedCall

    def spy(fn: Any, what: str, **kwargs: Any) -> Any:
        call = real(fn, what, **kwargs)
        started.append((what, call.pid))
        return call

    monkeypatch.setattr(analyze_module, "ForkedCall", spy)
    return started


def test_without_lower_bounds_theorem_3_2_comes_from_its_child(paper_loop: Any, forked: list[tuple[str, int]]) -> None:
    assert paper_loop.uncertain
    rep = analyze_module.analyze(paper_loop, cross_validation=False, lower_bounds=False)
    assert [what for what, _ in forked] == ["Lemma 4.1", "Theorem 3.2"]
    nominal = hinf_gamma(paper_loop, robust=False)
    assert rep.nominal.certified and rep.nominal.gamma == nominal.gamma
    np.testing.assert_array_equal(np.asarray(rep.nominal.P), np.asarray(nominal.P))
    assert rep.nominal.message == nominal.message and rep.certified_stable
    assert rep.nominal_lower is None and rep.robust_lower is None


def test_the_lower_bounds_beside_use_the_childs_nominal_gamma(paper_loop: Any, forked: list[tuple[str, int]]) -> None:
    """The same brackets as the stages run one after the other in this process."""
    from ftc_verify.analysis.lower_bound import gain_lower_bound
    from ftc_verify.analysis.moments.stability import mean_square_stability
    from ftc_verify.analysis.worst_delta import robust_lower_bound

    rep = analyze_module.analyze(paper_loop, cross_validation=False)
    assert len(forked) == 2
    mss = mean_square_stability(paper_loop, root_lmi=False)
    nominal = hinf_gamma(paper_loop, robust=False)
    low = gain_lower_bound(paper_loop, worst_rates=mss.worst_beta, upper=nominal.gamma)
    assert low is not None and rep.nominal_lower is not None and rep.nominal_lower.value == low.value
    high = robust_lower_bound(paper_loop, low.rates, worst_rates=mss.worst_beta, upper=nominal.gamma)[1]
    best = max((b for b in (low, high) if b is not None), key=lambda b: b.value or 0.0)
    assert rep.robust_lower is not None and rep.robust_lower.value == best.value
    assert rep.robust_lower.value <= rep.robust.gamma and rep.nominal_lower.value <= rep.nominal.gamma


def test_a_loop_proved_unstable_cancels_both_children(paper_loop: Any, forked: list[tuple[str, int]]) -> None:
    unstable = dataclasses.replace(paper_loop, A=tuple(a + 5.0 * np.eye(paper_loop.n) for a in paper_loop.A),
                                   source=None)
    rep = analyze_module.analyze(unstable, cross_validation=False)
    assert rep.mss.verdict == "not stable" and not rep.certified_stable
    assert rep.robust.outcome == rep.nominal.outcome == "skipped"
    assert [what for what, _ in forked] == ["Lemma 4.1", "Theorem 3.2"]
    for _, pid in forked:  # killed and reaped: no child left behind
        with pytest.raises(ChildProcessError):
            os.waitpid(pid, os.WNOHANG)
