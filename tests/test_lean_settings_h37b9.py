"""Clarabel's lean settings on hinf_gamma's one-solve path (analysis.solvers.LEAN_SETTINGS):
the certified gammas those solves give are the full settings' to well under 1e-3 relative,
still certified, and a lean solve that gives no point or no certificate is solved again
with the full settings (issue 37 item 3)."""

from __future__ import annotations

import dataclasses
from typing import Any

import pytest

from ftc_verify.analysis import lmi_analysis, solvers
from ftc_verify.analysis.lmi_analysis import hinf_gamma


def _full(monkeypatch: pytest.MonkeyPatch) -> None:
    """The one-solve path with the full settings (no lean solve at all)."""
    monkeypatch.setattr(lmi_analysis, "LEAN_SETTINGS", solvers.SETTINGS["clarabel"])


@pytest.mark.parametrize("robust", [False, True])
def test_lean_gammas_are_the_full_settings_ones_and_certified(paper_loop: Any, robust: bool,
                                                              monkeypatch: pytest.MonkeyPatch) -> None:
    lean = hinf_gamma(paper_loop, robust=robust, lean=True)
    assert lean.certified and lean.certificate is not None and lean.certificate.ok
    assert len(lean.attempts) == 1 and "iterative_refinement_enable=False" in lean.attempts[0].message
    _full(monkeypatch)
    full = hinf_gamma(paper_loop, robust=robust, lean=True)
    assert full.certified and full.attempts[0].message == ""
    assert lean.gamma is not None and full.gamma is not None
    assert abs(lean.gamma - full.gamma) <= 1e-6 * full.gamma


def test_a_failed_lean_solve_is_solved_again_with_the_full_settings(paper_loop: Any,
                                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    """A lean solve stopped after one iteration gives no point (``user_limit``): the same
    program is solved again with the full settings, whose answer is the full path's own."""
    _full(monkeypatch)
    full = hinf_gamma(paper_loop, robust=True, lean=True)
    monkeypatch.setattr(lmi_analysis, "LEAN_SETTINGS", solvers.SETTINGS["clarabel"] | {"max_iter": 1})
    again = hinf_gamma(paper_loop, robust=True, lean=True)
    assert [a.status for a in again.attempts] == ["user_limit", "optimal"]
    assert "max_iter=1" in again.attempts[0].message and again.attempts[1].message == ""
    assert again.certified and again.gamma == full.gamma


def test_a_lean_point_without_certificate_is_solved_again(paper_loop: Any, monkeypatch: pytest.MonkeyPatch) -> None:
    """The first certificate check (the lean point's) refused: the full settings' point is
    checked and kept, the margin unchanged (no ``100 tau`` step)."""
    _full(monkeypatch)
    full = hinf_gamma(paper_loop, robust=False, lean=True)
    monkeypatch.undo()
    check = lmi_analysis.check_certificate
    calls: list[float] = []

    def refuse_first(*args: Any, **kwargs: Any) -> Any:
        cert = check(*args, **kwargs)
        calls.append(args[4])
        return cert if len(calls) > 1 else dataclasses.replace(cert, ok=False)

    monkeypatch.setattr(lmi_analysis, "check_certificate", refuse_first)
    again = hinf_gamma(paper_loop, robust=False, lean=True)
    assert len(again.attempts) == 2 and "settings" in again.attempts[0].message and again.attempts[1].message == ""
    assert again.certified and again.gamma == full.gamma and len(calls) == 2


def test_without_lean_only_the_full_settings_run(paper_loop: Any) -> None:
    """The synthesis certifies its iterates without ``lean``: one solve, the full settings
    (lean answers, 1e-8 apart on badly scaled plants, steered the three-tank iterative
    design to another controller)."""
    res = hinf_gamma(paper_loop, robust=True)
    assert res.certified and all(a.message == "" for a in res.attempts)
    lean = hinf_gamma(paper_loop, robust=True, lean=True)
    assert res.gamma is not None and lean.gamma is not None and abs(res.gamma - lean.gamma) <= 1e-6 * res.gamma


def test_only_the_commands_analysis_is_lean(paper_loop: Any) -> None:
    """``analyze(..., lean=True)`` (the ``analyze`` and ``verify`` commands) names the lean
    settings in its attempts; the default, as the synthesis's certifications
    (``synthesis.results.verify_controller``), solves with the full settings only."""
    from ftc_verify.analysis.analyze import analyze

    lean = analyze(paper_loop, cross_validation=False, lower_bounds=False, lean=True)
    full = analyze(paper_loop, cross_validation=False, lower_bounds=False)
    assert any("settings" in a.message for a in lean.robust.attempts + lean.nominal.attempts)
    assert all(a.message == "" for a in full.robust.attempts + full.nominal.attempts)
    assert lean.robust.gamma is not None and full.robust.gamma is not None
    assert abs(lean.robust.gamma - full.robust.gamma) <= 1e-6 * full.robust.gamma
