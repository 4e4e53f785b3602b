"""The user-requested refinement of the ``h_max`` bracket
(:mod:`ftc_verify.analysis.moments.sampled_refine`, ``analyze --h-max-work``): the
ladder planned from the budget alone, the attempts in order, the refined period
proved stable independently, and the CLI's refusals before any work."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from ftc_verify.analysis.moments import sampled_refine
from ftc_verify.analysis.moments.sampled import SampledLoop
from ftc_verify.analysis.moments.sampled_proof import box_verdict
from ftc_verify.analysis.moments.sampled_refine import (REFINE_MEMORY, clock_memory, clock_work, refine_h_max,
                                                        refine_plan, refine_result)
from ftc_verify.cli.main import main
from ftc_verify.controllers.files import load_controller
from ftc_verify.model.files import load_system

ROOT = Path(__file__).resolve().parents[1]
PAPER_UNSTABLE = 0.0843  # above the paper loop's float64 crossing 0.08426 (h31c)


def _paper() -> SampledLoop:
    return SampledLoop.build(load_system(ROOT / "examples" / "paper.toml"),
                             load_controller(ROOT / "examples" / "paper_gains.toml"))


class _Clock:
    """A stand-in for :func:`clock_stable` proving every period at most ``limit``."""

    def __init__(self, limit: float) -> None:
        self.limit = limit
        self.asked: list[tuple[int, float]] = []

    def __call__(self, loop: SampledLoop, h: float, pieces: int, quadratic: bool) -> object:
        self.asked.append((pieces, h))
        return type("Cert", (), {"proved": h <= self.limit})()


def test_plan_doubles_pieces_halves_distance_within_the_budget() -> None:
    loop = _paper()
    costs = {n: 2 * clock_work(loop, n) for n in (4, 8, 16, 32)}
    assert costs[4] < costs[8] < costs[16] < costs[32]
    assert refine_plan(loop, 0.02, 0.99 * costs[4]) == ()
    assert refine_plan(loop, 0.02, costs[4] + costs[8] + costs[16]) == ((4, 0.01), (8, 0.005), (16, 0.0025))
    # stops at the first distance below rtol, however large the budget
    assert refine_plan(loop, 0.02, 1e12) == ((4, 0.01), (8, 0.005), (16, 0.0025), (32, 0.00125), (64, 0.000625))
    assert clock_memory(loop, 8) < clock_memory(loop, 64)


@pytest.mark.parametrize(("limit_f", "expected"), [
    (1.0, [(4, 0.01, False), (4, 0.02 ** 0.5 * 0.01 ** 0.5, False)]),  # nothing proved: one mid attempt
    (0.006, [(4, 0.01, True), (8, 0.005, False), (8, (0.005 * 0.01) ** 0.5, True)]),  # the mid attempt proved
    (0.0, [(4, 0.01, True), (8, 0.005, True), (16, 0.0025, True)]),  # every rung the budget planned
])
def test_attempts_in_order(monkeypatch: pytest.MonkeyPatch, limit_f: float,
                           expected: list[tuple[int, float, bool]]) -> None:
    loop = _paper()
    hu = PAPER_UNSTABLE
    monkeypatch.setattr(sampled_refine, "clock_stable", _Clock(hu * (1 - limit_f)))
    work = 2 * sum(clock_work(loop, n) for n in (4, 8, 16))
    got = refine_h_max(loop, hu * (1 - 0.02), hu, work)
    assert [(n, h, ok) for n, h, ok in got.tried] == [(n, pytest.approx(hu * (1 - f)), ok) for n, f, ok in expected]
    proved = [(n, f) for n, f, ok in expected if ok]
    assert got.h_max == (pytest.approx(hu * (1 - proved[-1][1])) if proved else None)
    assert got.pieces == (proved[-1][0] if proved else 0)
    assert got.work == pytest.approx(sum(clock_work(loop, n) for n, _, _ in expected))


def test_refined_period_is_proved_stable_over_the_box() -> None:
    """The paper loop from a 4 % bracket: the real certificate (4 pieces) proves 2 % below
    the unstable end; the sub-box proof confirms it independently (ball arithmetic)."""
    loop = _paper()
    hu = PAPER_UNSTABLE
    got = refine_h_max(loop, hu * 0.96, hu, 2 * clock_work(loop, 4))
    assert got.tried and got.tried[0][:2] == (4, pytest.approx(hu * 0.98))
    assert got.h_max is not None and got.h_max >= hu * 0.98 * (1 - 1e-12)
    assert box_verdict(loop, got.h_max, max_boxes=64, max_seconds=float("inf")).verdict == "stable"


def test_refine_result_only_when_wider_than_rtol(monkeypatch: pytest.MonkeyPatch) -> None:
    from ftc_verify.analysis.moments.sampled import SampledResult

    system = load_system(ROOT / "examples" / "paper.toml")
    controller = load_controller(ROOT / "examples" / "paper_gains.toml")
    fake = _Clock(PAPER_UNSTABLE * (1 - 0.01))
    monkeypatch.setattr(sampled_refine, "clock_stable", fake)
    base = SampledResult(0.05, "stable", 0.5, [[0.0]], "", 0, PAPER_UNSTABLE * 0.9995, PAPER_UNSTABLE, "narrow",
                         (), (0.01, 1.0), 0.0)
    assert refine_result(system, controller, base, 1e9) is base and fake.asked == []
    wide = dataclasses.replace(base, h_max=PAPER_UNSTABLE * 0.96, h_max_note="wide")
    got = refine_result(system, controller, wide, 1e9)
    assert got.h_max == pytest.approx(PAPER_UNSTABLE * 0.99) and "refinement (--h-max-work" in got.h_max_note
    assert "with 8 pieces" in got.h_max_note  # 4 at 2 % proved, 8 at 1 % proved, 16 at 0.5 % not
    fake.asked.clear()
    none = dataclasses.replace(base, h_max=None, h_max_note="not proved (time budget spent)")
    got = refine_result(system, controller, none, 2 * clock_work(_paper(), 4))
    assert fake.asked == [(4, pytest.approx(PAPER_UNSTABLE * 0.75))]  # from a 50 % bracket
    assert got.h_max == pytest.approx(PAPER_UNSTABLE * 0.75)
    assert refine_result(system, controller, dataclasses.replace(none, h_max_unstable=None), 1e9).h_max is None


@pytest.mark.parametrize(("argv", "needle"), [
    (["--h-max-work", "5000"], "--h-max-work 5000: refines the sampled loop's h_max bracket; give --period"),
    (["--period", "0.05", "--h-max-work", "1e13"], "--h-max-work 1e+13: its largest clock program needs about"),
    (["--period", "0.05", "--h-max-work", "-3"], "--h-max-work"),
])
def test_cli_refuses_before_any_work(capsys: pytest.CaptureFixture[str], argv: list[str], needle: str) -> None:
    try:
        code = main(["analyze", str(ROOT / "examples" / "paper.toml"), "--gains",
                     str(ROOT / "examples" / "paper_gains.toml"), *argv])
    except SystemExit as stop:  # argparse's own refusal of a bad number
        code = stop.code
    err = capsys.readouterr()
    assert code == 2 and needle in err.err and err.out == "" and "Traceback" not in err.err


def test_memory_limit_is_a_plan_property() -> None:
    loop = _paper()
    big = refine_plan(loop, 1.0, 1e13)
    assert max(clock_memory(loop, n) for n, _ in big) > REFINE_MEMORY


def test_text_output_names_the_refinement(capsys: pytest.CaptureFixture[str]) -> None:
    from ftc_verify.analysis.moments.sampled import SampledResult
    from ftc_verify.cli.sampled_lines import print_sampled

    res = SampledResult(0.05, "stable", 0.5, [[0.0]], "by test", 0, 0.08, 0.0843,
                        "wide; refinement (--h-max-work 5000): 2 clock attempt(s), 4000 units, proved stable",
                        (), (0.01, 1.0), 0.0)
    print_sampled(res)
    out = capsys.readouterr().out
    assert "      refinement (--h-max-work 5000): 2 clock attempt(s)" in out
    print_sampled(dataclasses.replace(res, h_max_note="narrow"))
    assert "refinement" not in capsys.readouterr().out
