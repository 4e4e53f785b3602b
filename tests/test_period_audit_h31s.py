"""Issue 31 items closed by the audit of branch h31s: the ``synthesize`` warning when the
certified controller's ``h_max`` is below ten times the simulator's default step
(:func:`ftc_verify.cli.sampled_lines.warn_short_h_max`), and ``--period`` against the
horizon and the step in every form (:func:`ftc_verify.cli.sampled_lines.check_period_option`,
:func:`ftc_verify.cli.sampled_lines.resolve_step`)."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pytest

from ftc_verify.cli.export_commands import DEFAULT_STEP
from ftc_verify.cli.sampled_lines import check_period_option, resolve_step, warn_short_h_max
from ftc_verify.controllers.controller import Controller
from ftc_verify.controllers.files import load_controller
from ftc_verify.errors import FTCError
from ftc_verify.model.files import load_system
from ftc_verify.model.system import FTCSystem

ROOT = Path(__file__).resolve().parents[1]


def _stable_plant() -> FTCSystem:
    """Two modes of ``x' = -x + u + w`` (stable open loop): with ``K = 0`` the sampled loop
    is stable at every period."""
    md = {"A": -np.eye(2), "B": np.eye(2), "C": np.ones((1, 2)), "D": np.ones((2, 1))}
    return FTCSystem.from_arrays(name="stable", modes=[md, dict(md)], alpha=[[-0.5, 0.5], [1.0, -1.0]],
                                 beta_min=[[0.0, 2.0], [2.5, 0.0]], beta_max=[[0.0, 3.0], [3.5, 0.0]])


def test_warning_names_a_period_below_ten_default_steps(capsys: pytest.CaptureFixture[str]) -> None:
    """The paper's gains (``h_max`` 0.0842 < 10 x 0.01): one warning line on stderr naming an
    unstable period at most 0.1, its radius above 1, and ``--period``; nothing on stdout."""
    system = load_system(ROOT / "examples" / "paper.toml")
    warn_short_h_max(system, load_controller(ROOT / "examples" / "paper_gains.toml"))
    out = capsys.readouterr()
    assert out.out == ""
    lines = out.err.strip().splitlines()
    assert len(lines) == 1 and "warning" in lines[0] and "--period" in lines[0]
    period = float(lines[0].split("at period ")[1].split()[0])
    radius = float(lines[0].split("spectral radius ")[1].split(")")[0])
    assert 0.0842 < period <= 10 * DEFAULT_STEP and radius > 1.0


def test_no_warning_for_a_loop_stable_at_every_period(capsys: pytest.CaptureFixture[str]) -> None:
    system = _stable_plant()
    warn_short_h_max(system, Controller.state_feedback([np.zeros((2, 2)), np.zeros((2, 2))]))
    assert capsys.readouterr().err == ""


def _args(**kw: float | None) -> argparse.Namespace:
    base: dict[str, object] = {"period": None, "step": None, "horizon": 30.0, "controller": "K.toml"}
    base.update(kw)
    return argparse.Namespace(**base)


@pytest.mark.parametrize("kw, word", [
    ({"period": 31.0}, "--horizon"),
    ({"period": 0.1, "step": 0.01}, "--step"),
])
def test_period_against_horizon_and_step(kw: dict[str, float], word: str) -> None:
    """A period longer than the horizon, or one that disagrees with ``--step``: an
    :class:`FTCError` whose one line names ``--period``, the value and the
    other option (the CLI exits 2 on it: ``tests/test_sampled.py``)."""
    with pytest.raises(FTCError) as err:
        check_period_option(_args(**kw))
    text = str(err.value)
    assert "--period" in text and word in text and len(text.splitlines()) == 1


def test_step_resolution_order(paper_controller_with_period: Controller) -> None:
    """``--period``, else ``--step``, else the controller file's ``period``, else the default."""
    c = paper_controller_with_period
    assert resolve_step(_args(period=0.02), c) == 0.02
    assert resolve_step(_args(step=0.03), c) == 0.03
    assert resolve_step(_args(), c) == c.period
    assert resolve_step(_args(), None) == DEFAULT_STEP
    with pytest.raises(FTCError, match=r"period 0\.05 is longer than --horizon 0\.01"):
        resolve_step(_args(horizon=0.01), c)


@pytest.fixture
def paper_controller_with_period() -> Controller:
    return load_controller(ROOT / "examples" / "paper_gains.toml").with_period(0.05)
