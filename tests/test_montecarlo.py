"""Monte Carlo statistics: closed-form Clopper-Pearson limits, coverage of the t bound on
known distributions, and the sequential test's decisions. Fixed seeds throughout."""

from __future__ import annotations

import numpy as np
import pytest

from ftc_verify.errors import ValidationError
from ftc_verify.verification.montecarlo import clopper_pearson, estimate, sequential_estimate


@pytest.mark.parametrize("n", [5, 40, 1000])
def test_clopper_pearson_edge_cases_closed_form(n: int) -> None:
    """0 successes: upper = 1 - (alpha/2)^(1/n); n successes: lower = (alpha/2)^(1/n)."""
    alpha = 0.01
    assert clopper_pearson(0, n, alpha) == pytest.approx((0.0, 1 - (alpha / 2) ** (1 / n)), rel=1e-10)
    assert clopper_pearson(n, n, alpha) == pytest.approx(((alpha / 2) ** (1 / n), 1.0), rel=1e-10)


def test_clopper_pearson_contains_estimate() -> None:
    lo, hi = clopper_pearson(37, 100, 1e-3)
    assert lo < 0.37 < hi and 0.2 < lo and hi < 0.55


def test_t_bound_covers_known_mean() -> None:
    """Exponential energies with mean 2, W = 4: ratio 0.5. With alpha = 1e-6 per side the
    interval misses 0.5 with probability about 2e-6 (CLT approximation; n = 2000)."""
    rng = np.random.default_rng(20261121)
    y = rng.exponential(2.0, 2000)
    est = estimate(y, np.full(2000, 4.0), alpha=1e-6, gamma=1.0, seed=20261121)
    assert est.lower_bound < 0.5 < est.upper_bound
    assert est.mean_ratio == pytest.approx(np.mean(y) / 4.0)
    assert est.seed == 20261121 and est.paths == 2000
    # event Y <= gamma^2 W = 4: P = 1 - e^{-2} = 0.8647; Clopper-Pearson at 2e-6 covers it
    lo, hi = est.event_interval  # type: ignore[misc]
    assert lo < 1 - np.exp(-2.0) < hi


def test_t_bound_coverage_rate() -> None:
    """At alpha = 0.05 the one-sided upper bound should cover the mean in about 95 % of
    400 repetitions (n = 400 lognormal samples: skewed, as path energies are). The
    binomial(400, ~0.95) count falls below 360 with probability < 1e-4."""
    rng = np.random.default_rng(7)
    mean = np.exp(0.5)  # lognormal(0, 1)
    covered = sum(estimate(rng.lognormal(0.0, 1.0, 400), np.ones(400), alpha=0.05).upper_bound > mean for _ in range(400))
    assert covered >= 360


def test_sequential_decides_both_ways() -> None:
    """Mean ratio 0.5 vs gamma^2 = 1 -> pass; vs gamma^2 = 0.25 -> fail; equal -> undecided.
    A wrong decision has probability < 1e-6 by construction (alpha-spending)."""
    rng = np.random.default_rng(11)

    def draw(k: int) -> tuple[np.ndarray, np.ndarray]:
        return rng.exponential(1.0, k), np.full(k, 2.0)

    assert sequential_estimate(draw, gamma=1.0, batch=200, max_paths=4000).decided == "pass"
    assert sequential_estimate(draw, gamma=0.5, batch=200, max_paths=4000).decided == "fail"
    tie = sequential_estimate(draw, gamma=np.sqrt(0.5), batch=200, max_paths=1000)
    assert tie.decided == "undecided" and tie.paths == 1000


def test_diverged_paths_make_the_bounds_infinite() -> None:
    """A path energy of inf (or NaN) is a diverged path: bounds infinite, counted, a miss
    of the event, and strict JSON (null, with a note)."""
    import json

    from ftc_verify.analysis.analyze import json_ready

    est = estimate(np.array([1.0, np.inf, np.nan, 2.0]), np.ones(4), gamma=2.0)
    assert est.diverged == 2 and est.upper_bound == est.lower_bound == np.inf
    assert est.event_fraction == 0.5
    d = json.loads(json.dumps(json_ready(est.to_dict()), allow_nan=False))
    assert d["upper_bound"] is None and d["diverged"] == 2 and "2 of 4 paths diverged" in d["note"]
    assert estimate(np.ones(3), np.ones(3)).to_dict()["note"] is None
    diverging = sequential_estimate(lambda k: (np.full(k, np.inf), np.ones(k)), gamma=1.0, batch=10, max_paths=100)
    assert diverging.decided == "fail" and diverging.paths == 10


def test_bad_inputs() -> None:
    with pytest.raises(ValidationError, match="non-finite"):
        estimate(np.ones(2), np.array([1.0, np.inf]))
    with pytest.raises(ValidationError, match="alpha"):
        estimate(np.ones(3), np.ones(3), alpha=0.7)
    with pytest.raises(ValidationError, match="zero energy"):
        estimate(np.ones(3), np.zeros(3))


def test_monte_carlo_on_both_backends_agrees_and_records_seed() -> None:
    """Same seed, same paths and draws on both backends: identical estimates to 1e-8; the
    paper's gains keep the ratio below their certified gamma^2 = 0.4983^2 with room."""
    from pathlib import Path

    from ftc_verify.verification.montecarlo import monte_carlo
    from ftc_verify.model.files import load_system
    from ftc_verify.controllers.files import load_controller

    root = Path(__file__).resolve().parents[1]
    system = load_system(root / "examples" / "paper.toml")
    gains = load_controller(root / "examples" / "paper_gains.toml")
    ref = monte_carlo(system, gains, backend="reference", paths=20, horizon=10.0, seed=4, gamma=0.4983)
    fmu = monte_carlo(system, gains, backend="fmu", paths=20, horizon=10.0, seed=4, gamma=0.4983)
    assert ref.seed == fmu.seed == 4 and ref.paths == fmu.paths == 20
    assert fmu.mean_ratio == pytest.approx(ref.mean_ratio, rel=1e-8)
    assert ref.upper_bound < 0.4983 ** 2
    seq = monte_carlo(system, gains, backend="reference", paths=2000, horizon=10.0, seed=4, gamma=0.4983,
                      sequential=True, batch=100)
    assert seq.decided == "pass" and seq.paths <= 2000
    with pytest.raises(ValidationError, match="backend"):
        monte_carlo(system, gains, backend="gpu")
