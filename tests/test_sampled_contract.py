"""Issue 32's contract on the sampled-data stages (issue 31): the one-period map's memory is
checked before any work, and every sampled-data analysis outside ``analyze`` runs in a
killable child (:func:`ftc_verify.analysis.solvers.interruptible`) so that a SIGTERM
during a long ``h_max`` scan does not wait for it."""

from __future__ import annotations

import dataclasses
import importlib
from pathlib import Path
from typing import Any

import cli_inprocess
import pytest

from ftc_verify.analysis.moments.sampled import SampledLoop, sampled_analysis
from ftc_verify.controllers.files import load_controller
from ftc_verify.errors import MemoryLimitError
from ftc_verify.limits import dense_generator_estimate
from ftc_verify.model.files import load_system

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "examples" / "paper.toml"
GAINS = ROOT / "examples" / "paper_gains.toml"


def test_the_one_period_maps_memory_is_checked_before_any_work(monkeypatch: pytest.MonkeyPatch) -> None:
    """Paper loop: d = n + n_u = 4, 4 joint states, 40 rows of the moment generator; the
    estimate is that of a dense generator of that size, refused under a 60 KB limit
    (the continuous loop's 12 rows pass) naming the sampled-data analysis."""
    system, controller = load_system(PAPER), load_controller(GAINS)
    estimate = dense_generator_estimate(4, 4)
    assert estimate == 8 * (8 * 40 ** 2 + 4 * 16 * 10)
    monkeypatch.setenv("FTC_VERIFY_MEMORY_LIMIT", "60K")
    with pytest.raises(MemoryLimitError, match=r"the sampled-data analysis \(one-period map on 4 joint states"):
        SampledLoop.build(system, controller)
    with pytest.raises(MemoryLimitError, match="FTC_VERIFY_MEMORY_LIMIT"):
        sampled_analysis(system, controller, 0.05)


def test_cli_period_over_the_memory_limit_exits_2_naming_it(tmp_path: Path) -> None:
    proc = cli_inprocess.run_cli(["analyze", str(PAPER), "--controller", str(GAINS), "--period", "0.05", "--no-lmi"],
                                 tmp_path, {"FTC_VERIFY_MEMORY_LIMIT": "60K"})
    assert proc.returncode == 2, proc.stderr
    err = proc.stderr.strip()
    assert "sampled-data analysis" in err and "FTC_VERIFY_MEMORY_LIMIT" in err and len(err.splitlines()) == 1, err
    assert "Traceback" not in err


@pytest.mark.parametrize("module, call", [
    ("ftc_verify.verification.sampled_stage",
     lambda m, s, c: m.sampled_stage(s, c, 0.05)),
    ("ftc_verify.synthesis.at_period",
     lambda m, s, c: m.synthesize_at_period(s, 0.05, lambda bound: _Certified(c), lambda res: res.controller,
                                        k_max=None, bounds=())),
    ("ftc_verify.export.certificate",
     lambda m, s, c: m.export_certificate(s, c, 0.05)),
])
def test_sampled_analyses_run_in_a_killable_child(module: str, call: Any, monkeypatch: pytest.MonkeyPatch) -> None:
    """verify's sampled stage, ``synthesize --period`` and ``export`` run the sampled-data
    analysis through ``interruptible`` (before issue 32's audit they called it directly:
    a SIGTERM waited for the whole scan)."""
    mod = importlib.import_module(module)
    seen = _spy_interruptible(monkeypatch, mod)
    call(mod, load_system(PAPER), load_controller(GAINS))
    assert "the sampled-data analysis" in seen


def test_analyze_refines_in_a_killable_child(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """``analyze --h-max-work`` runs the refinement, whatever its proofs compute (third-order
    forms included), in its own killable child after the sampled-data analysis's: a
    SIGTERM ends it as it ends any analysis child (``tests/test_issue32_contract.py``), not
    after the proof in progress."""
    from ftc_verify.analysis import solvers
    from ftc_verify.cli.main import main

    seen = _spy_interruptible(monkeypatch, solvers)
    code = main(["analyze", str(PAPER), "--gains", str(GAINS), "--period", "0.05", "--no-lmi", "--h-max-work", "5000"])
    assert code == 0, capsys.readouterr().err
    assert seen.index("the h_max refinement") == seen.index("the sampled-data analysis") + 1


def _spy_interruptible(monkeypatch: pytest.MonkeyPatch, mod: Any) -> list[str]:
    """The labels ``mod.interruptible`` is called with, in order (the calls go through)."""
    seen: list[str] = []
    real = mod.interruptible

    def spy(fn: Any, what: str) -> Any:
        seen.append(what)
        return real(fn, what)

    monkeypatch.setattr(mod, "interruptible", spy)
    return seen


class _Certified:
    """A synthesis result stand-in for ``design_at_period``: certified, with a controller."""

    certified = True
    gamma_certified = 0.5

    def __init__(self, controller: Any) -> None:
        self.controller = controller


# ------------------------------------------------------------------ issue 31 item 4: data as written
def test_sampled_proofs_enclose_the_files_decimals(tmp_path: Path) -> None:
    """From files, the balls of the sampled proofs contain the decimals as written (0.8 of
    A, the gain 2.4563, a written period "0.1" from the controller file) and not only
    their floats; a period the analysis chooses stays exact; without files the floats are
    the data (exact balls)."""
    import flint

    from ftc_verify.analysis.moments.sampled_proof import MapParts, ball_resets
    from ftc_verify.controllers import Controller

    from ftc_verify.analysis.rigorous import precision

    gains = tmp_path / "g.toml"
    gains.write_text("period = 0.1\n" + GAINS.read_text())
    system, controller = load_system(PAPER), load_controller(gains)
    loop = SampledLoop.build(system, controller)
    assert loop.literals is not None and "0.8" in loop.literals[0.8] and "0.1" in loop.literals[0.1]
    written = dataclasses.replace(loop, written=(0.1,))
    with precision(128):  # the decimals' balls are far narrower than the floats' distance to them
        h = written.period_ball(0.1)
        assert h.contains(flint.arb("0.1")) and not h.contains(flint.arb(0.1))
        assert written.period_ball(0.0842) == flint.arb(0.0842) and loop.period_ball(0.1).rad() == 0
        parts = MapParts.build(written, 0.1)
        assert parts.h.contains(flint.arb("0.1"))
        s = loop.scale
        a22 = parts.modes[4, 4]  # vech entry (x2, x2) (column-major lower triangle, d = 4): 2 A_22
        assert (a22 / 2).contains(flint.arb("0.8")) and not (a22 / 2).contains(flint.arb(0.8))
        R = ball_resets(loop, 0.1)[0].value  # joint state (1, 1): D_c = K_1, balanced
        k11 = R[2, 0] * float(s[2] / s[0])
        assert k11.contains(flint.arb("2.4563")) and not k11.contains(flint.arb(2.4563))
        plain = SampledLoop.build(_floats(system), Controller.state_feedback(list(controller.gains)))
        assert plain.literals is None and ball_resets(plain, 0.1)[0].value[2, 0].rad() == 0

def _floats(system: Any) -> Any:
    return dataclasses.replace(system, literals=None)
