"""The proved upper bound of the probability of leaving the envelope (ftc_verify.risk.bound):
never below the truth (Monte Carlo of exact chain paths on a scalar loop, solved exactly
between jumps), sound over the rate box, None with a reason when nothing is certified,
invariant under rescaling."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from conftest import scalar_system
from ftc_verify.analysis.closedloop import state_feedback_loop
from ftc_verify.analysis.lmi_analysis import mes_lmi
from ftc_verify.errors import ValidationError
from ftc_verify.risk.bound import envelope_upper_bound
from ftc_verify.simulation.paths import sample_paths

ALPHA = [[-0.5, 0.5], [0.5, -0.5]]
GAINS = [np.array([[-2.0]]), np.array([[2.0]])]
#: x' = a x + b u + w with a = 0, b = (1, -1) and u = K_fdi x: slope -2 when the FDI is
#: right, +2 while it lags (the slope of the pair (true, fdi)).
SLOPE = {(0, 0): -2.0, (0, 1): 2.0, (1, 0): 2.0, (1, 1): -2.0}
PATHS = 20000


def _loop(beta_lo: float, beta_hi: float):
    beta_min = [[0.0, beta_lo], [beta_lo, 0.0]]
    beta_max = [[0.0, beta_hi], [beta_hi, 0.0]]
    system = scalar_system((0.0, 0.0), (1.0, -1.0), alpha=ALPHA, beta_min=beta_min, beta_max=beta_max)
    return state_feedback_loop(system, GAINS)


def _escapes(loop, beta: float, x0: float, limit: float, w_scale: float, seed: int, count: int = PATHS,
             horizon: float = 12.0) -> float:
    """Fraction of ``count`` exact chain paths on which |x| reaches ``limit`` before
    ``horizon``, with w(t) = w_scale exp(-t) (energy w_scale^2 / 2): a lower estimate of
    the probability of ever reaching it.

    Without w, log|x| is piecewise linear (slope of the segment's pair): its maximum is
    at a jump. With w, x is the exact solution between jumps, x(t) = e^{a(t-t0)} x(t0) +
    w_scale (e^{a(t-t0)-t0} - e^{-t}) / (a + 1), checked at the jumps and on a grid of
    step 0.01."""
    b = np.array([[0.0, beta], [beta, 0.0]])
    paths = sample_paths(loop.chain, horizon, count, seed, beta=b)
    if not w_scale:
        lengths = np.array([p.times.size for p in paths])
        starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
        times = np.concatenate([p.times for p in paths])
        ends = np.concatenate([np.append(p.times[1:], p.horizon) for p in paths])
        slope = np.where(np.concatenate([p.true for p in paths]) == np.concatenate([p.fdi for p in paths]), -2.0, 2.0)
        climb = np.cumsum(slope * (ends - times))
        before = np.concatenate([[0.0], climb])[starts]  # the climb of the earlier paths
        peak = np.maximum.reduceat(climb, starts) - before
        return float(np.mean(np.maximum(peak, 0.0) + math.log(abs(x0)) >= math.log(limit)))
    hits = 0
    for path in paths:
        ends = np.append(path.times[1:], path.horizon)
        x, hit = x0, abs(x0) >= limit
        for t0, t1, i, j in zip(path.times, ends, path.true, path.fdi):
            if hit:
                break
            a = SLOPE[(int(i), int(j))]
            t = np.append(np.arange(t0, t1, 0.01), t1)
            xs = np.exp(a * (t - t0)) * x + w_scale * (np.exp(a * (t - t0) - t0) - np.exp(-t)) / (a + 1.0)
            hit = bool(np.max(np.abs(xs)) >= limit)
            x = float(xs[-1])
        hits += hit
    return hits / count


def _assert_not_below(bound: float, p_hat: float, count: int = PATHS) -> None:
    """bound >= p_hat - 5 sigma: a sound bound fails this with probability < 3e-7
    (one-sided normal approximation), whatever the seed."""
    sigma = math.sqrt(max(p_hat * (1 - p_hat), 1.0 / count) / count)
    assert bound >= p_hat - 5 * sigma, (bound, p_hat)


def test_never_below_the_truth_without_disturbance() -> None:
    loop = _loop(6.0, 6.0)
    H = [np.array([[1.0]])] * loop.chain.n_states
    out = envelope_upper_bound(loop, [(H, 1.2)], x0=np.array([1.0]), disturbance_energy=0.0)
    assert out.value is not None and out.condition == "theorem-3.1", out.reason
    assert 0.0 < out.value < 1.0
    p_hat = _escapes(loop, 6.0, 1.0, 1.2, 0.0, seed=3)
    assert p_hat > 0.02  # the event is not trivial, so the comparison can fail
    _assert_not_below(out.value, p_hat)
    # the proved pieces: the level set {V < c} is inside |x| < 1.5, the start value is V(x0)
    assert out.start is not None and out.level is not None
    assert out.value >= out.start / out.level * (1 - 1e-15)


def test_never_below_the_truth_with_disturbance() -> None:
    loop = _loop(10.0, 10.0)
    H = [np.array([[1.0]])] * loop.chain.n_states
    w_scale = 0.6
    energy = w_scale ** 2 / 2
    out = envelope_upper_bound(loop, [(H, 1.0)], x0=np.array([0.7]), disturbance_energy=energy)
    assert out.value is not None and out.condition == "theorem-3.2", out.reason
    assert out.gamma is not None and out.gamma > 0
    quiet = envelope_upper_bound(loop, [(H, 1.0)], x0=np.array([0.7]), disturbance_energy=0.0)
    assert quiet.value is not None and quiet.value < out.value  # the energy term counts
    p_hat = _escapes(loop, 10.0, 0.7, 1.0, w_scale, seed=5, count=5000, horizon=8.0)
    assert p_hat > 0.01
    _assert_not_below(out.value, p_hat, 5000)


@pytest.mark.parametrize("beta", [5.0, 12.0, 20.0])
def test_sound_at_rates_inside_the_box(beta: float) -> None:
    loop = _loop(5.0, 20.0)
    H = [np.array([[1.0]])] * loop.chain.n_states
    out = envelope_upper_bound(loop, [(H, 1.2)], x0=np.array([1.0]), disturbance_energy=0.0)
    assert out.value is not None, out.reason
    _assert_not_below(out.value, _escapes(loop, beta, 1.0, 1.2, 0.0, seed=int(beta)))


def test_uncertified_loop_gives_none_with_a_reason() -> None:
    loop = _loop(0.5, 0.5)  # the FDI lags too long: not mean-square stable
    H = [np.array([[1.0]])] * loop.chain.n_states
    out = envelope_upper_bound(loop, [(H, 1.5)], x0=np.array([1.0]), disturbance_energy=0.0)
    assert out.value is None
    assert "not certified" in out.reason or "no certificate" in out.reason
    assert out.to_dict()["value"] is None


def test_sampled_loop_and_useless_bound_give_none() -> None:
    loop = _loop(10.0, 10.0)
    H = [np.array([[1.0]])] * loop.chain.n_states
    out = envelope_upper_bound(loop, [(H, 1.5)], x0=np.array([1.0]), disturbance_energy=0.0, period=0.1)
    assert out.value is None and "sampled" in out.reason
    outside = envelope_upper_bound(loop, [(H, 0.9)], x0=np.array([1.0]), disturbance_energy=0.0)
    assert outside.value is None and "not below 1" in outside.reason


def test_given_certificate_and_mixture_start() -> None:
    loop = _loop(10.0, 10.0)
    H = [np.array([[1.0]])] * loop.chain.n_states
    cert = mes_lmi(loop)
    a = envelope_upper_bound(loop, [(H, 2.0)], x0=np.array([1.0]), disturbance_energy=0.0, certificate=cert)
    assert a.value is not None and a.solver == cert.solver
    # a mixture of start states: E V(x0, s0) = sum p0_s V(x0, s). Each bound minimises over P
    # for its own start, and the mixture's P is admissible for every single start, so
    # sum p0_s (best bound from s) <= (best bound from the mixture).
    p0 = np.full(loop.chain.n_states, 1.0 / loop.chain.n_states)
    mix = envelope_upper_bound(loop, [(H, 2.0)], x0=np.array([1.0]), disturbance_energy=0.0, initial=p0,
                               certificate=cert)
    assert mix.start is not None and mix.value is not None and mix.level is not None
    assert mix.value >= mix.start / mix.level * (1 - 1e-15)
    singles = []
    for s in range(loop.chain.n_states):
        e = np.zeros(loop.chain.n_states)
        e[s] = 1.0
        one = envelope_upper_bound(loop, [(H, 2.0)], x0=np.array([1.0]), disturbance_energy=0.0, initial=e,
                                   certificate=cert)
        assert one.value is not None
        singles.append(one.value)
    assert float(np.dot(p0, singles)) <= mix.value * (1 + 1e-6)
    assert max(singles) > min(singles)  # the start state matters, so the mixture is exercised
    assert json.loads(json.dumps(mix.to_dict()))["value"] == mix.value


@pytest.mark.parametrize("exponent", [-3, 3])
def test_rescaled_loops(paper_loop, exponent: int) -> None:
    """The bound is invariant under x = diag(d) x~ (H~ = H D, x0~ = D^-1 x0) up to the
    solver's answer; the uncertain paper loop uses Lemma 4.1's certificate."""
    n, S = paper_loop.n, paper_loop.chain.n_states
    H = [np.eye(n)[:1]] * S
    x0 = np.full(n, 0.1)
    base = envelope_upper_bound(paper_loop, [(H, 1.0)], x0=x0, disturbance_energy=0.0)
    assert base.value is not None and base.condition == "lemma-4.1", base.reason
    d = np.logspace(exponent, -exponent, n)
    scaled = envelope_upper_bound(paper_loop.scaled(d), [([h * d[None, :] for h in H], 1.0)], x0=x0 / d,
                                  disturbance_energy=0.0)
    assert scaled.value is not None, scaled.reason
    assert abs(scaled.value / base.value - 1.0) < 1e-2


def test_bad_input_names_the_field() -> None:
    loop = _loop(10.0, 10.0)
    H = [np.array([[1.0]])] * loop.chain.n_states
    cases = [
        (dict(constraints=[(H[:2], 1.0)]), "constraints\\[0\\]"),
        (dict(constraints=[(H, -1.0)]), "limit"),
        (dict(constraints=[([np.ones((1, 2))] * 4, 1.0)]), "H\\[0\\]"),
        (dict(x0=np.ones(3)), "x0"),
        (dict(disturbance_energy=-1.0), "disturbance_energy"),
        (dict(initial=[1.0, 1.0, 0.0, 0.0]), "initial"),
    ]
    for change, field in cases:
        args = dict(constraints=[(H, 1.0)], x0=np.array([0.1]), disturbance_energy=0.0) | change
        with pytest.raises(ValidationError, match=field):
            envelope_upper_bound(loop, args["constraints"], x0=args["x0"],
                                 disturbance_energy=args["disturbance_energy"], initial=args.get("initial"))
