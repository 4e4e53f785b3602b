"""Lemma 4.1's program with the channels that share an input matrix merged
(analysis.shared_channels): the same optimum as the full program, smaller blocks, and the
certificate still proved on the full blocks of Lemma 4.1."""

from __future__ import annotations

import dataclasses
import importlib
from typing import Any

import numpy as np
import pytest

from ftc_verify.analysis.closedloop import Channel
from ftc_verify.analysis.lmi import check_certificate
from ftc_verify.analysis.lmi_analysis import hinf_gamma
from ftc_verify.analysis.shared_channels import merged_loop, shared_input_groups

lmi_analysis = importlib.import_module("ftc_verify.analysis.lmi_analysis")


def _scaled_second(loop: Any, factor: Any) -> Any:
    """The loop with the second channel's ``E`` of every joint state replaced by ``factor(E)``."""
    chans = tuple((c[0], Channel(factor(c[1].E), c[1].F, c[1].name)) + tuple(c[2:]) for c in loop.channels)
    return dataclasses.replace(loop, channels=chans)


def test_the_papers_channels_share_their_input_matrix(paper_loop: Any) -> None:
    groups = shared_input_groups(paper_loop)  # A1 = B1 = 0.1 I: one group per joint state
    assert [g.s for g in groups] == list(range(len(paper_loop.A)))
    assert all(g.members == (0, 1) and g.scales == (1.0, 1.0) for g in groups)
    scaled = shared_input_groups(_scaled_second(paper_loop, lambda E: -3.0 * E))
    assert all(g.scales == pytest.approx((1.0, -3.0), rel=1e-15) for g in scaled)
    rng = np.random.default_rng(7)  # an E that is no multiple of the first: nothing merged
    assert shared_input_groups(_scaled_second(paper_loop, lambda E: E + 1e-6 * rng.normal(size=E.shape))) == ()
    merged = merged_loop(paper_loop, groups)
    assert all(len(c) == 3 and c[0].E.shape[1] == 0 and c[2].F.shape[0] == 0 for c in merged.channels)


@pytest.mark.parametrize("factor", [lambda E: E, lambda E: -3.0 * E], ids=["equal", "scaled"])
def test_the_merged_program_has_the_full_programs_optimum(paper_loop: Any, factor: Any,
                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    loop = _scaled_second(paper_loop, factor)
    merged = hinf_gamma(loop, robust=True)
    lay = lmi_analysis._layout(loop, True, True)
    small = max(d for kind, d in lmi_analysis._margin_problem(loop, lay, True, 1.0).cones if kind == "psd")
    monkeypatch.setattr(lmi_analysis, "shared_input_groups", lambda loop: ())
    full = hinf_gamma(loop, robust=True)
    lay = lmi_analysis._layout(loop, True, True)
    large = max(d for kind, d in lmi_analysis._margin_problem(loop, lay, True, 1.0).cones if kind == "psd")
    assert (small, large) == (paper_loop.n + 2 + 1 + 1, paper_loop.n + 4 + 1 + 1)  # n + E's columns + w + z
    assert merged.certified and full.certified
    assert merged.gamma == pytest.approx(full.gamma, rel=1e-6)
    # the multipliers are the loop's own (one per channel), proved again on the full blocks
    assert merged.multipliers is not None and all(len(m) == 2 for m in merged.multipliers)
    P = merged.P_conditioned if merged.P_conditioned is not None else merged.P
    again = check_certificate(loop, "lemma-4.1", P, merged.multipliers, merged.gamma ** 2,
                              similarity=merged.similarity)
    assert again.ok
    below = check_certificate(loop, "lemma-4.1", P, merged.multipliers, (0.999 * merged.gamma) ** 2,
                              similarity=merged.similarity)
    assert not below.ok  # the certificate is tight: 0.1 % lower is not proved


def test_the_full_program_is_solved_too_when_the_merged_one_does_not_end_cleanly() -> None:
    from ftc_verify.analysis.shared_channels import merged_first

    class R:
        def __init__(self, gamma: float) -> None:
            self.gamma = gamma

    calls: list[bool] = []

    def solve(answers: dict[bool, tuple[Any, bool]]) -> Any:
        def run(merge: bool, ended: list[bool]) -> Any:
            calls.append(merge)
            result, clean = answers[merge]
            if clean:
                ended.append(True)
            return result
        return run

    assert merged_first(solve({True: (R(2.0), False), False: (R(1.0), True)}), True).gamma == 1.0
    assert merged_first(solve({True: (R(1.0), False), False: (R(2.0), True)}), True).gamma == 1.0
    assert merged_first(solve({True: (None, False), False: (R(3.0), True)}), True).gamma == 3.0
    assert calls == [True, False] * 3
    calls.clear()
    assert merged_first(solve({True: (R(2.0), True)}), True).gamma == 2.0  # clean: the merged answer alone
    assert merged_first(solve({True: (None, False)}), False) is None  # nothing merged: no second solve
    assert calls == [True, True]
