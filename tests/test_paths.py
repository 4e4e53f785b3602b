"""The joint-chain sampler and the communication grid (``ftc_verify.simulation.paths``).

Goodness-of-fit tests run at level alpha = 1e-3 each (false-failure probability 1e-3
per test if the sampler is right; the seeds are fixed, so the outcome is deterministic):
Kolmogorov-Smirnov for the exponential holding times (>= 2000 samples, censoring by the
horizon below 1e-12) and a chi-square test of the next-state frequencies.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.stats

from ftc_verify.errors import ValidationError
from ftc_verify.model.system import JointChain
from ftc_verify.simulation.paths import DRAW_BLOCK, ChainPath, communication_grid, sample_paths

ALPHA = 1e-3
SAMPLES = 2500


def first_sojourn(path: ChainPath, state: tuple[int, int]) -> float | None:
    """Duration of the first complete stay of ``path`` in joint mode ``state``."""
    for k in range(len(path.times) - 1):
        if (path.true[k], path.fdi[k]) == state:
            return float(path.times[k + 1] - path.times[k])
    return None


@pytest.fixture(scope="module")
def slow_return_chain() -> JointChain:
    """Paper-like chain whose repair rate is small, so that paths are short in jumps."""
    return JointChain(np.array([[-0.5, 0.5], [0.01, -0.01]]), np.array([[0.0, 2.0], [2.5, 0.0]]),
                      np.array([[0.0, 3.0], [3.5, 0.0]]))


def test_dwell_time_in_the_fault_free_mode_is_exponential(slow_return_chain) -> None:
    """Stay in (1, 1): Exp with rate sum_k alpha[1][k] (k != 1) = -alpha[1][1] = 0.5."""
    chain = slow_return_chain
    rate = -chain.alpha[0, 0]
    horizon = 60.0 / rate  # P(censored) = exp(-60)
    samples = [first_sojourn(p, (0, 0)) for p in sample_paths(chain, horizon, SAMPLES, 101, beta=chain.midpoint())]
    assert None not in samples
    res = scipy.stats.kstest(samples, scipy.stats.expon(scale=1.0 / rate).cdf)
    assert res.pvalue > ALPHA, res


@pytest.mark.parametrize("true, fdi", [(1, 0), (0, 1)])
def test_detection_delay_is_exponential_with_rate_beta_fdi_true(true, fdi) -> None:
    """Stay in (i, j), i != j (FDI shows j, system in i): Exp(beta[j][i]) in the paper's
    model. The state is entered by a fault from (j, j) (fast, rate 5); its first visit
    is used; the way back from (i, i) is slow, so paths have few jumps."""
    alpha = np.zeros((2, 2))
    alpha[fdi, true], alpha[true, fdi] = 5.0, 0.01
    np.fill_diagonal(alpha, -alpha.sum(axis=1))
    chain = JointChain(alpha, np.array([[0.0, 2.0], [2.5, 0.0]]), np.array([[0.0, 3.0], [3.5, 0.0]]))
    beta = np.array([[0.0, 2.2], [3.1, 0.0]])
    rate = beta[fdi, true]
    horizon = 40.0 / rate + 60.0 / 5.0  # P(censored) < 2 exp(-40)
    samples = []
    for p in sample_paths(chain, horizon, SAMPLES, 202 + true, beta=beta, start=(fdi, fdi)):
        assert (p.true[1], p.fdi[1]) == (true, fdi)  # from (j, j) the only move is a fault to (i, j)
        samples.append(first_sojourn(p, (true, fdi)))
    assert None not in samples
    res = scipy.stats.kstest(samples, scipy.stats.expon(scale=1.0 / rate).cdf)
    assert res.pvalue > ALPHA, res


def test_detection_delay_with_beta_drawn_per_path(slow_return_chain) -> None:
    """``beta=None`` draws beta uniformly in its box per path: with each path's own rate,
    ``1 - exp(-beta[0][1] * delay)`` is uniform on [0, 1] (probability integral transform)."""
    chain = slow_return_chain
    u = []
    for p in sample_paths(chain, 80.0, SAMPLES, 303, start=(0, 0)):
        b = p.beta[0, 1]
        assert chain.beta_min[0, 1] <= b <= chain.beta_max[0, 1] and np.all(np.diag(p.beta) == 0)
        u.append(1.0 - np.exp(-b * first_sojourn(p, (1, 0))))
    res = scipy.stats.kstest(u, "uniform")
    assert res.pvalue > ALPHA, res


def test_next_state_frequencies_m3_with_fault_during_delay() -> None:
    """m = 3, named variant fault_during_delay=True: from each joint mode s the next mode
    s' is drawn with probability Q[s, s'] / -Q[s, s]. Pearson chi-square over all modes
    (df = sum over s of (number of possible s') - 1), level 1e-3; impossible moves never."""
    alpha = np.array([[-1.0, 0.6, 0.4], [0.5, -1.2, 0.7], [0.9, 0.3, -1.2]])
    bmin = np.array([[0.0, 1.0, 1.5], [2.0, 0.0, 1.2], [1.1, 1.8, 0.0]])
    chain = JointChain(alpha, bmin, bmin + 0.5, fault_during_delay=True)
    beta = chain.midpoint()
    Q = chain.generator(beta)
    m = 3
    counts = np.zeros((m * m, m * m))
    paths = sample_paths(chain, 150.0, 40, 404, beta=beta)
    assert min(len(p.times) for p in paths) > 3 * DRAW_BLOCK  # several blocks of draws per path
    for p in paths:
        s = p.true * m + p.fdi
        np.add.at(counts, (s[:-1], s[1:]), 1)
    off = ~np.eye(m * m, dtype=bool)
    possible = (Q > 0) & off
    assert np.all(counts[~possible] == 0)
    stat, df = 0.0, 0
    for s in range(m * m):
        total = counts[s].sum()
        probs = Q[s, possible[s]] / -Q[s, s]
        expected = total * probs
        assert np.all(expected >= 5), (s, expected)
        stat += float(np.sum((counts[s, possible[s]] - expected) ** 2 / expected))
        df += int(possible[s].sum()) - 1
    assert df == 3 * 1 + 6 * 2  # (i,i): 2 faults; (i,j): detection or 2 faults
    pvalue = scipy.stats.chi2.sf(stat, df)
    assert pvalue > ALPHA, (stat, df, pvalue)


def test_every_path_has_its_own_stream() -> None:
    """Path ``k`` is child ``k`` of ``SeedSequence(seed)``: the same whatever is drawn with
    it (a longer run, or a ``SeedSequence`` spawned from in two calls), and its ``Delta``
    stream is the same at every call and differs from the other paths'."""
    chain = JointChain(np.array([[-2.0, 2.0], [3.0, -3.0]]), np.array([[0, 4.0], [5.0, 0]]),
                       np.array([[0, 6.0], [7.0, 0]]))
    full = sample_paths(chain, 30.0, 9, 77)
    assert max(len(p.times) for p in full) > DRAW_BLOCK  # a path that takes a second block
    root = np.random.SeedSequence(77)
    parts = sample_paths(chain, 30.0, 4, root) + sample_paths(chain, 30.0, 5, root)
    for a, b in zip(full, parts, strict=True):
        assert np.array_equal(a.times, b.times) and np.array_equal(a.true, b.true)
        assert np.array_equal(a.fdi, b.fdi) and np.array_equal(a.beta, b.beta)
        assert a.stream is not None and a.stream.spawn_key == b.stream.spawn_key
    assert [p.stream.spawn_key for p in full] == [(k,) for k in range(9)]
    draws = [p.delta_generator().random(3) for p in full]
    assert np.array_equal(draws[2], full[2].delta_generator().random(3))
    assert len({tuple(d) for d in draws}) == len(draws)
    assert len({float(p.times[1]) for p in full}) == len(full)  # independent, not copies
    assert ChainPath(np.zeros(1), np.zeros(1, int), np.zeros(1, int), np.zeros((2, 2)), 1.0).delta_generator() is None


@pytest.mark.parametrize("seed", [-1, 1.5, "7", True, None])
def test_bad_seed_is_refused(slow_return_chain, seed) -> None:
    with pytest.raises(ValidationError, match="seed"):
        sample_paths(slow_return_chain, 1.0, 2, seed)


# ----------------------------------------------------------------------------- grid
def check_grid(path: ChainPath, step: float) -> None:
    t, true, fdi = communication_grid(path, step)
    tol = 1e-12 * step
    assert t[0] == 0.0 and t[-1] == path.horizon
    assert np.all(np.diff(t) > 0)
    assert true.shape == fdi.shape == (t.size - 1,)
    jumps = path.times[1:]
    assert np.all(np.isin(jumps, t))
    count = int(np.floor(path.horizon / step + 1e-9))
    for k in range(1, count + 1):
        kt = k * step
        if kt >= path.horizon * (1 - 1e-12):
            continue
        near_jump = jumps.size and np.min(np.abs(jumps - kt)) <= tol
        assert near_jump or np.any(t == kt), (k, kt)
    # nothing else: every point is 0, the horizon, a jump or a multiple of the step
    others = t[~np.isin(t, jumps)]
    ks = np.rint(others / step)
    assert np.all((ks * step == others) | (others == path.horizon))
    for k in range(t.size - 1):
        assert (true[k], fdi[k]) == path.mode_at(t[k])
        mid = 0.5 * (t[k] + t[k + 1])
        assert (true[k], fdi[k]) == path.mode_at(mid)  # the mode is constant on the interval


def test_communication_grid_on_sampled_paths() -> None:
    chain = JointChain(np.array([[-2.0, 2.0], [3.0, -3.0]]), np.array([[0, 4.0], [5.0, 0]]),
                       np.array([[0, 6.0], [7.0, 0]]))
    for seed, (horizon, step) in enumerate(((3.0, 0.01), (2.35, 0.1), (1.0, 0.3), (0.7, 1.0))):
        for p in sample_paths(chain, horizon, 20, 505 + seed):
            check_grid(p, step)


def test_communication_grid_edge_cases() -> None:
    z = np.zeros((2, 2))
    h = 0.1
    cases = [
        ChainPath(np.array([0.0, 0.3]), np.array([0, 1]), np.array([0, 0]), z, 1.0),  # on a multiple (float 0.3)
        ChainPath(np.array([0.0, 3 * h]), np.array([0, 1]), np.array([0, 0]), z, 1.0),  # exactly k * step
        ChainPath(np.array([0.0, 5 * h + 1e-14, 7 * h - 1e-14]), np.array([0, 1, 1]), np.array([0, 0, 1]), z, 1.0),
        ChainPath(np.array([0.0, 1e-15, 0.55, 0.56, 1.0 - 1e-14]), np.array([0, 1, 1, 0, 1]),
                  np.array([0, 0, 1, 1, 1]), z, 1.0),
        ChainPath(np.array([0.0]), np.array([1]), np.array([0]), z, 0.95),  # horizon no multiple of the step
    ]
    for p in cases:
        check_grid(p, h)
    t, _, _ = communication_grid(cases[2], h)
    assert 5 * h not in t and 5 * h + 1e-14 in t  # a multiple within 1e-12 step of a jump is merged
    assert np.array_equal(communication_grid(cases[4], h)[0][-2:], [0.9, 0.95])
    with pytest.raises(ValidationError, match="step"):
        communication_grid(cases[0], 0.0)
