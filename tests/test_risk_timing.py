"""The FDI timing view (ftc_verify.risk.timing): closed forms, the rate box, Monte Carlo of
chain paths."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from ftc_verify.errors import ValidationError
from ftc_verify.model.chain import JointChain
from ftc_verify.risk.timing import delay_exceedance
from ftc_verify.simulation.paths import sample_paths

ALPHA = np.array([[-0.1, 0.1], [0.05, -0.05]])


def _erlang_tail(rate: float, k: int, tau: float) -> float:
    """P(Erlang-k with phase rate ``rate`` > tau)."""
    x = rate * tau
    return sum(math.exp(-x) * x ** n / math.factorial(n) for n in range(k))


@pytest.mark.parametrize("tau", [0.0, 0.1, 0.5, 2.0, 10.0])
def test_exponential_delay_is_exp_minus_beta_tau(tau: float) -> None:
    beta = np.array([[0.0, 2.0], [3.0, 0.0]])  # [fdi, true]
    out = delay_exceedance(JointChain(ALPHA, beta, beta), tau)
    by_label = {e.label: e for e in out.events}
    # fault 1->2: state (true 2, fdi 1), rate beta[fdi 1, true 2] = 2
    for label, rate in (("fault 1->2", 2.0), ("fault 2->1", 3.0)):
        e = by_label[label]
        exact = math.exp(-rate * tau)
        assert e.enclosure[0] <= exact * (1 + 1e-15) and exact <= e.enclosure[1] * (1 + 1e-15)
        assert e.probability >= exact * (1 - 1e-15)
        assert e.probability - exact <= 1e-14
    assert out.worst == max(e.probability for e in out.events)
    assert out.worst_event == "fault 1->2"


@pytest.mark.parametrize("k", [2, 3, 7])
def test_erlang_delay_is_the_erlang_tail(k: int) -> None:
    beta = np.array([[0.0, 1.5], [0.7, 0.0]])
    fa = np.array([[0.0, 0.01], [0.02, 0.0]])
    chain = JointChain(ALPHA, beta, beta, delay_phases=k, false_alarm_min=fa, false_alarm_max=fa)
    tau = 1.3
    out = delay_exceedance(chain, tau)
    for e in out.events:
        true = e.target if e.kind == "fault" else e.source
        fdi = e.source if e.kind == "fault" else e.target
        exact = _erlang_tail(k * beta[fdi - 1, true - 1], k, tau)
        assert abs(e.probability - exact) <= 1e-13 * max(1.0, exact), e.label
        assert e.enclosure[0] * (1 - 1e-13) <= exact <= e.enclosure[1] * (1 + 1e-13)  # float closed form
    kinds = sorted({e.kind for e in out.events})
    assert kinds == ["false alarm", "fault"]


def test_worst_case_over_the_box_is_the_lower_corner() -> None:
    lo = np.array([[0.0, 1.0], [0.5, 0.0]])
    hi = np.array([[0.0, 4.0], [2.0, 0.0]])
    chain = JointChain(ALPHA, lo, hi, delay_phases=2, fault_during_delay=True)
    tau = 0.8
    out = delay_exceedance(chain, tau)
    rng = np.random.default_rng(7)
    for e in out.events:
        assert e.best <= e.probability
        for _ in range(5):  # points inside the box never exceed the reported worst case
            point = lo + rng.random((2, 2)) * (hi - lo)
            inner = delay_exceedance(JointChain(ALPHA, point, point, delay_phases=2, fault_during_delay=True), tau)
            value = {x.label: x.probability for x in inner.events}[e.label]
            assert e.best * (1 - 1e-12) <= value <= e.probability * (1 + 1e-12)


def test_missed_detection_never_ends() -> None:
    lo = np.array([[0.0, 0.0], [0.5, 0.0]])
    hi = np.array([[0.0, 1.0], [0.5, 0.0]])
    out = delay_exceedance(JointChain(ALPHA, lo, hi), 3.0)
    e = {x.label: x for x in out.events}["fault 1->2"]
    assert e.probability == 1.0
    assert e.best < 0.06


def test_monte_carlo_of_chain_paths_agrees() -> None:
    """Erlang-3 delays with faults during the delay (no closed form); 20000 paths, seed 11.
    The check |p_hat - p| <= 5 sigma fails with probability < 6e-7 per event (normal
    approximation; n p (1 - p) > 1000 here)."""
    beta = np.array([[0.0, 1.2], [0.8, 0.0]])
    alpha = np.array([[-0.6, 0.6], [0.9, -0.9]])
    chain = JointChain(alpha, beta, beta, delay_phases=3, fault_during_delay=True)
    tau = 1.5
    out = delay_exceedance(chain, tau)
    n = 20000
    for e in out.events:
        paths = sample_paths(chain, tau, n, 11, beta=beta, start=(e.target - 1, e.source - 1))
        still = sum(bool(np.all(p.true != p.fdi)) for p in paths)
        p_hat, p = still / n, e.probability
        assert abs(p_hat - p) <= 5 * math.sqrt(p * (1 - p) / n), (e.label, p_hat, p)
    # faults during the delay change the answer (so the test exercises them)
    plain = delay_exceedance(JointChain(alpha, beta, beta, delay_phases=3), tau)
    assert abs(plain.events[0].probability - out.events[0].probability) > 0.01


def test_json_ready_and_bad_input() -> None:
    beta = np.array([[0.0, 2.0], [3.0, 0.0]])
    out = delay_exceedance(JointChain(ALPHA, beta, beta), 1.0)
    data = json.loads(json.dumps(out.to_dict()))
    assert data["worst"] == out.worst and len(data["events"]) == 2
    for bad in (-1.0, math.inf, math.nan, "1", True):
        with pytest.raises(ValidationError, match="interval"):
            delay_exceedance(JointChain(ALPHA, beta, beta), bad)  # type: ignore[arg-type]
    with pytest.raises(ValidationError, match="chain"):
        delay_exceedance(ALPHA, 1.0)  # type: ignore[arg-type]
