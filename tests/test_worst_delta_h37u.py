"""The cheaper float searches of the lower bounds (analysis.lower_bound, analysis.worst_delta):
the same levels decided with the early stop on a falling iterate and with warm starts from
another loop's feedback, and the robust bound at the constant Delta the search finds."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ftc_verify.analysis import lower_bound
from ftc_verify.analysis.bounded_real import SEARCH_RTOL, RateEnvelope, bounded_real_solution
from ftc_verify.analysis.closedloop import closed_loop
from ftc_verify.analysis.lmi_analysis import hinf_gamma
from ftc_verify.analysis.worst_delta import robust_lower_bound, worst_constant_delta
from ftc_verify.controllers.files import load_controller
from ftc_verify.model.files import load_system

ROOT = Path(__file__).resolve().parents[1]


def _loop(rng: np.random.Generator, n: int = 4, S: int = 3) -> tuple[list[np.ndarray], ...]:
    """A random mean-square stable stack (a shift of 1.5 against normal entries of scale
    n^-1/2), a disturbance input and an output per joint state, and a generator."""
    A = [rng.normal(size=(n, n)) / np.sqrt(n) - 1.5 * np.eye(n) for _ in range(S)]
    Bw = [rng.normal(size=(n, 2)) for _ in range(S)]
    Cz = [rng.normal(size=(1, n)) for _ in range(S)]
    Q = rng.uniform(0.2, 1.0, (S, S))
    np.fill_diagonal(Q, 0.0)
    np.fill_diagonal(Q, -Q.sum(axis=1))
    return A, Bw, Cz, [Q]


def _plain(A, Bw, Cz, Q, gamma, start=None):  # type: ignore[no-untyped-def]
    """The search's policy iteration without the early stop (dense solves only)."""
    return bounded_real_solution(A, Bw, Cz, RateEnvelope.at(Q), gamma, start=start, rtol=SEARCH_RTOL,
                                 solve=lower_bound._dense_adjoint)


@pytest.mark.parametrize("seed", [11, 12, 13])
def test_falling_iterates_decide_the_same_levels(seed: int, monkeypatch: pytest.MonkeyPatch) -> None:
    """Levels 0.5 % to 20 % on either side of the float gain: the iteration that stops at
    a falling iterate finds the same levels feasible as the one that runs to its stall
    test, and the same feedback where feasible; below the gain it takes fewer solves."""
    A, Bw, Cz, (Q,) = _loop(np.random.default_rng(seed))
    found = lower_bound.float_gain(A, Bw, Cz, Q)
    assert found is not None
    gain = found[0]
    solves = [0]
    solve = lower_bound.lyapunov_stack_solution

    def counted(*args):  # type: ignore[no-untyped-def]
        solves[0] += 1
        return solve(*args)

    monkeypatch.setattr(lower_bound, "lyapunov_stack_solution", counted)
    below = {"fast": 0, "slow": 0}
    for factor in (0.8, 0.95, 0.995, 1.005, 1.05, 1.2):
        solves[0] = 0
        fast = lower_bound.worst_case_feedback(A, Bw, Cz, Q, factor * gain, rtol=SEARCH_RTOL)
        fast_solves, solves[0] = solves[0], 0
        slow = _plain(A, Bw, Cz, Q, factor * gain)
        if factor < 1.0:
            below["fast"] += fast_solves
            below["slow"] += solves[0]
        assert (fast is None) == (slow is None) == (factor < 1.0)
        if fast is not None and slow is not None:
            for f, g in zip(fast, slow[1]):
                assert np.allclose(f, g, rtol=1e-5, atol=1e-8)
    assert below["fast"] < below["slow"]


@pytest.mark.parametrize("seed", [21, 22])
def test_warm_start_from_another_loop_decides_the_same(seed: int) -> None:
    """exceeds() from the feedback of a different loop (a feedback that need not stabilise
    this one) gives the answer of the test from F = 0 at every level."""
    rng = np.random.default_rng(seed)
    A, Bw, Cz, (Q,) = _loop(rng)
    other = [a + 0.3 * rng.normal(size=a.shape) for a in A]
    found_other = lower_bound.float_gain(other, Bw, Cz, Q)
    found = lower_bound.float_gain(A, Bw, Cz, Q)
    assert found is not None and found_other is not None
    for factor in (0.9, 0.99, 1.01, 1.1, 2.0):
        level = factor * found[0]
        cold = lower_bound.exceeds(A, Bw, Cz, Q, level)
        warm = lower_bound.exceeds(A, Bw, Cz, Q, level, found_other[1])
        assert cold == warm == (factor < 1.0)


def test_gain_from_an_infeasible_level_matches_the_plain_search() -> None:
    """float_gain going on from a level found infeasible, with a small first climb and a
    warm start, brackets the same gain as the plain search (both to 1e-3)."""
    A, Bw, Cz, (Q,) = _loop(np.random.default_rng(31))
    plain = lower_bound.float_gain(A, Bw, Cz, Q, rtol=1e-3)
    assert plain is not None
    below = 0.99 * plain[0]
    assert lower_bound.exceeds(A, Bw, Cz, Q, below)
    resumed = lower_bound.float_gain(A, Bw, Cz, Q, upper=below, rtol=1e-3, above=below, start=plain[1],
                                     climb=0.001, converge=False)
    assert resumed is not None
    assert abs(resumed[0] - plain[0]) <= 2e-3 * plain[0]


def test_robust_bound_at_the_searched_delta_is_proved_and_below_gamma() -> None:
    """The paper example: the robust bound at the search's Delta is proved, at most the
    certified robust gamma, at least 90 % of it, and its Delta is worst_constant_delta's."""
    loop = closed_loop(load_system(ROOT / "examples/paper.toml"), load_controller(ROOT / "examples/paper_gains.toml"))
    assert loop.uncertain
    nominal = hinf_gamma(loop, robust=False)
    robust = hinf_gamma(loop, robust=True)
    assert nominal.certified and robust.certified
    low = lower_bound.gain_lower_bound(loop, upper=nominal.gamma)
    assert low is not None
    (label, delta), high = robust_lower_bound(loop, low.rates, upper=nominal.gamma)
    assert high is not None and high.value is not None
    assert 0.9 * robust.gamma <= high.value <= robust.gamma
    assert high.delta == label
    assert worst_constant_delta(loop, low.rates, upper=nominal.gamma)[0] == label
    assert set(delta) == {ch.name for chans in loop.channels for ch in chans}
