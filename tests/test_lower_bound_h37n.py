"""The averaged second moments of the lower bounds enclosed from a float solve and its
proved residual (analysis.lower_bound._residual_moments), against FLINT's certified
solve of the whole moment system."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ftc_verify.analysis import lower_bound
from ftc_verify.analysis.closedloop import closed_loop
from ftc_verify.analysis.rigorous import ball, precision
from ftc_verify.analysis.verdict import ball_lyapunov_solution
from ftc_verify.controllers.files import load_controller
from ftc_verify.model.files import load_system

ROOT = Path(__file__).resolve().parents[1]


def _stack(rng: np.random.Generator, n: int, S: int, shift: float) -> tuple[list[np.ndarray], np.ndarray]:
    A = [rng.normal(size=(n, n)) / np.sqrt(n) - shift * np.eye(n) for _ in range(S)]
    Q = rng.uniform(0.2, 1.0, (S, S))
    np.fill_diagonal(Q, 0.0)
    np.fill_diagonal(Q, -Q.sum(axis=1))
    return A, Q


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_residual_enclosure_holds_the_exact_solution(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n, S = 4, 3
    A, Q = _stack(rng, n, S, 1.5)
    R = [rng.normal(size=(n, n)) for _ in range(S)]
    with precision(128):
        At = [ball(a) for a in A]
        q = [[ball(np.array([[Q[s, t]]])).value[0, 0] for t in range(S)] for s in range(S)]
        G = [ball(r + r.T) for r in R]
        fast = lower_bound._residual_moments(At, q, G, Q)
        exact = ball_lyapunov_solution(At, q, 128, G)
        assert fast is not None and exact is not None
        for x, y in zip(fast, exact):
            for i in range(n):
                for j in range(n):
                    assert x.value[i, j].overlaps(y.value[i, j])  # both contain the exact solution
                    assert float(x.value[i, j].rad()) < 1e-9 * (1.0 + abs(float(y.value[i, j].mid())))


def test_no_enclosure_for_an_unstable_operator() -> None:
    """Not mean-square stable: the float stacks solve their equations, but no Y > 0 can
    have -L(Y) > 0, so nothing is returned (the caller's ball solve decides)."""
    rng = np.random.default_rng(7)
    n, S = 3, 2
    A, Q = _stack(rng, n, S, -1.0)
    with precision(128):
        At = [ball(a) for a in A]
        q = [[ball(np.array([[Q[s, t]]])).value[0, 0] for t in range(S)] for s in range(S)]
        assert lower_bound._residual_moments(At, q, [ball(np.eye(n))] * S, Q) is None


def test_paper_bound_is_the_same_by_both_enclosures(monkeypatch: pytest.MonkeyPatch) -> None:
    loop = closed_loop(load_system(ROOT / "examples/paper.toml"), load_controller(ROOT / "examples/paper_gains.toml"))
    fast = lower_bound.gain_lower_bound(loop, upper=2.0)
    monkeypatch.setattr(lower_bound, "_residual_moments", lambda *args: None)
    slow = lower_bound.gain_lower_bound(loop, upper=2.0)
    assert fast is not None and slow is not None and fast.value is not None and slow.value is not None
    assert "proved residual" in fast.method and "128-bit" in slow.method
    assert abs(fast.value - slow.value) <= 1e-9 * slow.value


def test_lower_bounds_found_beside_lemma_4_1() -> None:
    """With uncertainty the nominal bound and the robust one at a constant Delta are
    computed beside Lemma 4.1's program (which runs in a forked child); the robust bound
    is still proved, below the certified robust gamma and at least the nominal bound."""
    from ftc_verify.analysis.analyze import analyze

    loop = closed_loop(load_system(ROOT / "examples/paper.toml"), load_controller(ROOT / "examples/paper_gains.toml"))
    rep = analyze(loop, cross_validation=False)
    assert "lower_bounds_beside" in rep.seconds
    low, high = rep.nominal_lower, rep.robust_lower
    assert low is not None and high is not None and low.value is not None and high.value is not None
    assert low.value <= high.value <= rep.robust.gamma
    assert rep.nominal.gamma / low.value < 1.002 and rep.robust.gamma / high.value < 1.05
