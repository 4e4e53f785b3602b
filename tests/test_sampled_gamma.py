"""The sampled loop's proved L2 gain (:mod:`ftc_verify.analysis.moments.sampled_gamma`):
its h -> 0 limit, the lower estimate below it on random loops, dynamic controllers,
Erlang delays with false alarms, rescaled coordinates, a period with no certificate, and
the ``sampled.*`` JSON of ``analyze --period``."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings

from ftc_verify.analysis.closedloop import closed_loop
from ftc_verify.analysis.lmi_analysis import hinf_gamma
from ftc_verify.analysis.moments.sampled import sampled_analysis
from ftc_verify.analysis.moments.sampled_gamma import (attach_performance, gain_lower_estimate,
                                                       sampled_gamma)
from ftc_verify.analysis.moments.sampled_lower import _Blocks, _blocks, _Ops, _ratio, sampled_lower_bound
from ftc_verify.cli.main import main
from ftc_verify.cli.sampled_lines import performance_lines
from ftc_verify.controllers.controller import Controller
from ftc_verify.controllers.files import load_controller
from ftc_verify.model.files import load_system
from ftc_verify.model.system import FTCSystem
from ftc_verify.testing.loops import DrawnLoop, stable_loops

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "examples" / "paper.toml"
GAINS = ROOT / "examples" / "paper_gains.toml"
SLACK = 1e-6  # the lower estimate is float64 rounding of an exact energy; the bound is proved


@pytest.fixture(scope="module")
def paper() -> tuple[FTCSystem, Controller]:
    return load_system(PAPER), load_controller(GAINS)


@pytest.mark.parametrize("robust", [False, True])
def test_tends_to_the_continuous_gamma(paper: tuple[FTCSystem, Controller], robust: bool) -> None:
    """At h = 1e-3 the proved sampled gamma is within 1 % of the continuous certificate
    (Theorem 3.2 / Lemma 4.1), and it is above the lower estimate."""
    system, controller = paper
    cont = hinf_gamma(closed_loop(system, controller), robust=robust)
    assert cont.certified and cont.gamma is not None
    cert = sampled_gamma(system, controller, 1e-3, robust=robust)
    assert cert.gamma is not None, cert.note
    assert abs(cert.gamma / cont.gamma - 1.0) < 0.01
    lower, _ = gain_lower_estimate(system, controller, 1e-3, robust=robust)
    assert lower is not None and 0 < lower <= cert.gamma * (1 + SLACK)


def test_no_certificate_where_the_sampled_loop_is_unstable(paper: tuple[FTCSystem, Controller]) -> None:
    """h = 0.1 (the paper's gains are proved unstable there, h_max 0.0842): no gamma, a
    note, no exception; the lower estimate says the loop is not stable."""
    system, controller = paper
    cert = sampled_gamma(system, controller, 0.1, robust=False, pieces=(2,))
    assert cert.gamma is None and cert.note
    lower, where = gain_lower_estimate(system, controller, 0.1, robust=False)
    assert lower is None and "not mean-square stable" in where
    res = attach_performance(sampled_analysis(system, controller, 0.1, h_max=False), system, controller)
    d = res.to_dict()
    assert d["verdict"] == "not stable" and d["nominal_gamma"] is None and d["robust_gamma"] is None
    assert "NOT mean-square stable" in d["nominal_gamma_note"]
    assert any("NOT certified" in line for line in performance_lines(res.performance))


def test_erlang_delays_and_false_alarms(paper: tuple[FTCSystem, Controller]) -> None:
    """Erlang-2 delays with false alarms (rates 0.2..0.4) at h = 0.02: a proved gamma,
    above the lower estimate."""
    system, controller = paper
    chain = dataclasses.replace(system.chain, delay_phases=2, false_alarm_min=np.full((2, 2), 0.2),
                                false_alarm_max=np.full((2, 2), 0.4))
    erlang = dataclasses.replace(system, chain=chain)
    cert = sampled_gamma(erlang, controller, 0.02, robust=False)
    assert cert.gamma is not None, cert.note
    lower, _ = gain_lower_estimate(erlang, controller, 0.02, robust=False)
    assert lower is not None and lower <= cert.gamma * (1 + SLACK)


def test_dynamic_controller() -> None:
    """A filtered dynamic controller on ``paper_two_outputs.toml`` (exact discretisation of
    the filter in the jump, enclosed by the rigorous exponential): a proved gamma near the
    continuous one at h = 2e-3, above the lower estimate."""
    system = load_system(ROOT / "examples" / "paper_two_outputs.toml")
    K = load_controller(GAINS).gains
    controller = Controller.dynamic(Ac=[-20 * np.eye(2)] * 2, Bc=[20 * np.eye(2)] * 2, Cc=[0.2 * k for k in K],
                                    Dc=[0.8 * k for k in K])
    cont = hinf_gamma(closed_loop(system, controller), robust=False)
    assert cont.certified and cont.gamma is not None
    cert = sampled_gamma(system, controller, 2e-3, robust=False)
    assert cert.gamma is not None, cert.note
    assert abs(cert.gamma / cont.gamma - 1.0) < 0.05
    lower, _ = gain_lower_estimate(system, controller, 2e-3, robust=False)
    assert lower is not None and lower <= cert.gamma * (1 + SLACK)


@pytest.mark.parametrize("c", [1e-3, 1e3])
def test_rescaled_coordinates_keep_gamma(paper: tuple[FTCSystem, Controller], c: float) -> None:
    """x = diag(c, 1/c) x~ (the same loop in coordinates scaled by 1e-3 and 1e3 at once,
    condition 1e6): the proved gamma moves by less than 1 %."""
    system, controller = paper
    d = np.array([c, 1.0 / c])
    modes = tuple(dataclasses.replace(m, A=m.A * d[None, :] / d[:, None], B=m.B / d[:, None], C=m.C * d[None, :],
                                      D=m.D / d[:, None], A1=m.A1 / d[:, None], A2=m.A2 * d[None, :],
                                      B1=m.B1 / d[:, None]) for m in system.modes)
    scaled = dataclasses.replace(system, modes=modes)
    gains = Controller.state_feedback([K * d[None, :] for K in controller.gains])
    a = sampled_gamma(system, controller, 0.01, robust=False)
    b = sampled_gamma(scaled, gains, 0.01, robust=False)
    assert a.gamma is not None and b.gamma is not None, b.note
    assert b.gamma == pytest.approx(a.gamma, rel=0.01)


@settings(max_examples=3, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
@given(drawn=stable_loops(n=(1, 2), m=2, nu=1, nw=1, uncertain=None, period=(2e-3, 0.03)))
def test_gamma_above_the_lower_estimate_on_random_loops(drawn: DrawnLoop) -> None:
    """Random loops at a drawn period: whenever a gamma is proved, the exact energy ratio
    of every tried disturbance (the lower estimate) and the proved lower bound lie below it."""
    system, controller = drawn.system, drawn.controller
    h = controller.period
    assert h is not None
    cert = sampled_gamma(system, controller, h, robust=system.uncertain)
    assume(cert.gamma is not None)
    assert cert.gamma is not None and math.isfinite(cert.gamma)
    lower, where = gain_lower_estimate(system, controller, h, robust=system.uncertain)
    assert lower is not None, where
    assert lower <= cert.gamma * (1 + SLACK)
    proved = sampled_lower_bound(system, controller, h, robust=system.uncertain)
    assert proved.value is None or proved.value <= cert.gamma  # both proved: no slack


@pytest.mark.slow(6)  # seconds on 2 busy cores (--durations at load 9, / 4): scheduled first
def test_cli_analyze_period_reports_the_gains(capsys: pytest.CaptureFixture[str]) -> None:
    """``analyze --period 0.01 --json``: sampled.nominal_gamma / robust_gamma proved, their
    lower estimates below them, the robust one not below the nominal one's lower estimate."""
    code = main(["analyze", str(PAPER), "--gains", str(GAINS), "--period", "0.01", "--json"])
    out = json.loads(capsys.readouterr().out)
    assert code == 0
    s = out["sampled"]
    assert s["nominal_gamma"] is not None and s["robust_gamma"] is not None
    assert s["nominal_gamma_lower"] <= s["nominal_gamma"]
    assert s["robust_gamma_lower"] <= s["robust_gamma"]
    assert s["robust_gamma"] >= s["nominal_gamma"] * (1 - 1e-3)
    assert s["gamma_lower_kind"] == "proved"
    assert s["nominal_gamma_lower_kind"] == "proved" and s["robust_gamma_lower_kind"] == "proved"
    assert s["nominal_gamma_lower"] > 0.97 * s["nominal_gamma"]  # tight: 0.4727 against 0.4757


@pytest.mark.slow(9)  # seconds on 2 busy cores (--durations at load 9, / 4): scheduled first
def test_verify_step_reports_the_sampled_gains(paper_verify_run: SimpleNamespace) -> None:
    """``verify --step 0.01``: the report's ``sampled`` holds the proved gains of the loop
    it simulates, within 1 % of the continuous certificate at this short period. The run is
    the session's ``verify examples/paper.toml --gains examples/paper_gains.toml --paths 30
    --horizon 15 --step 0.01 --seed 3`` (``paper_verify_run`` in conftest.py; the sampled
    gains depend on the step, not on the paths or the seed)."""
    proc = paper_verify_run
    assert proc.returncode in (0, 1), proc.stderr  # (a Monte Carlo bound too wide to pass is not this test's)
    d = json.loads((proc.out / "report.json").read_text())
    assert d["options"]["step"] == 0.01
    s = d["sampled"]
    assert s["nominal_gamma"] is not None and s["robust_gamma"] is not None
    assert abs(s["robust_gamma"] / d["gamma_certified"] - 1) < 0.01
    assert s["robust_gamma_lower"] <= s["robust_gamma"]


def test_proved_lower_bound_brackets_the_gain_tightly(paper: tuple[FTCSystem, Controller]) -> None:
    """h = 0.05: the proved lower bound lies below the proved gamma, within 3 % of it, and
    above the old float64 estimate (held sinusoids)."""
    system, controller = paper
    cert = sampled_gamma(system, controller, 0.05, robust=False)
    low = sampled_lower_bound(system, controller, 0.05, robust=False)
    assert cert.gamma is not None and low.value is not None, (cert.note, low.where)
    assert low.kind == "proved"
    assert 0.97 * cert.gamma < low.value <= cert.gamma
    est, _ = gain_lower_estimate(system, controller, 0.05, robust=False)
    assert est is not None and low.value > est


def _stepped_ratio(b: _Blocks, resets: list[np.ndarray], F: list[np.ndarray], h: float, periods: int) -> float:
    """The same energies summed period by period (no doubling): an independent check."""
    ops = _Ops(False)
    from ftc_verify.analysis.moments.sampled_lower import _weights

    lift = ops.diag([b.Ld @ np.kron(np.vstack([R, f]), np.vstack([R, f])) @ b.Dr for R, f in zip(resets, F)])
    T = b.restrict @ b.Fm @ lift
    fw = np.concatenate([_weights(f.T @ f) for f in F])
    num, den = (b.lg @ b.m0).item(), h
    v = b.restrict @ b.Fm @ b.m0
    for _ in range(periods - 1):
        num += (b.lg @ lift @ v).item()
        den += h * (fw @ v).item()
        v = T @ v
    return num / den


def test_doubling_matches_stepping(paper: tuple[FTCSystem, Controller]) -> None:
    """The doubling sums of a random held feedback (fixed seed) equal the period-by-period
    sums (K = 2^5 + 1 periods) to 1e-10."""
    from ftc_verify.analysis.moments.sampled import SampledLoop
    from ftc_verify.analysis.moments.sampled_gamma import sample_jumps, augmented_loop

    system, controller = paper
    h = 0.03
    loop = SampledLoop.build(system, controller)
    aug = augmented_loop(loop, system).nominal()
    P = loop.restriction()
    resets = [J @ P.T for J in sample_jumps(loop, h)]
    rng = np.random.default_rng(7)
    F = [rng.normal(size=(1, loop.r)) for _ in resets]
    Q = system.chain.generator(system.chain.midpoint())
    b = _blocks(_Ops(False), aug, P, Q, h, 0.0, 1)
    num, den = _ratio(_Ops(False), b, resets, F, h, 5)
    assert float(num[0, 0] / den[0, 0]) == pytest.approx(_stepped_ratio(b, resets, F, h, 2 ** 5 + 1), rel=1e-10)
