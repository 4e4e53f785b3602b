"""Path sampling, the simulators and the exact moments on the joint (true, FDI, phase)
chain of issue 23 (``ftc_verify.model.chain``: Erlang-k detection delays, false alarms).

Statistical tests and their false-failure probabilities (seeds fixed, so every outcome
is deterministic; the probabilities are those of a correct implementation failing with a
fresh seed):

* Erlang delays, per ``k`` in (1, 3, 8): a Kolmogorov-Smirnov test at level 1e-6 (exact,
  distribution-free) and two-sided z-tests of the mean and of the variance at 1e-6 each
  (CLT; the variance test uses the gamma's fourth moment) -- at most about 9e-6 in all;
* false alarms: a two-sided z-test at 1e-6 of the alarm count against its compensator
  (a martingale CLT) and one of the mean withdrawal time -- about 2e-6, plus 1e-7 for a
  fault that the tiny fault rates allow;
* exact energy against Monte Carlo: the two-sided Student-t interval at 1e-6 per side of
  :func:`~ftc_verify.verification.montecarlo.estimate` -- about 2e-6 under the CLT.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import scipy.stats

from ftc_verify.analysis.closedloop import closed_loop, state_feedback_loop
from ftc_verify.controllers.files import load_controller, load_gains
from ftc_verify.errors import ValidationError
from ftc_verify.model.files import load_system
from ftc_verify.model.system import FTCSystem, JointChain
from ftc_verify.simulation.paths import DRAW_BLOCK, ChainPath, sample_paths
from ftc_verify.simulation.reference import energies_reference, simulate_continuous
from ftc_verify.analysis.moments.energy import exact_energy, worst_case_disturbance

ROOT = Path(__file__).resolve().parents[1]
PAPER = load_system(ROOT / "examples" / "paper.toml")
GAINS = load_gains(ROOT / "examples" / "paper_gains.toml")
LEVEL = 1e-6
Z = float(scipy.stats.norm.isf(LEVEL / 2))  # two-sided critical value at LEVEL


def with_chain(**options) -> FTCSystem:
    """The paper's plant on its own rates with the given chain options."""
    c = PAPER.chain
    return FTCSystem(PAPER.name, PAPER.modes, JointChain(c.alpha, c.beta_min, c.beta_max, **options))


def plain_paths(chain: JointChain, horizon: float, count: int, seed: int, beta, start=(0, 0),
                drawn: bool = False) -> list[tuple]:
    r"""The sampler written path by path with the full generator rows (the specification
    of :func:`sample_paths`): holding time :math:`E/(-Q_{ss})`, next state the first whose
    cumulative jump probability exceeds :math:`U`, both drawn in blocks of ``DRAW_BLOCK``
    from the path's own stream (after the rate array's uniforms when ``drawn``: the
    rates were drawn per path); states reported as ``(true, fdi)``, equal ones merged."""
    q = chain.generator(beta)
    out = []
    for stream in np.random.SeedSequence(seed).spawn(count):
        g = np.random.default_rng(stream)
        if drawn:
            g.random(chain.rate_shape)
        s, t, k = chain.state_index(*start), 0.0, 0
        times, states = [0.0], [s]
        while True:
            if k % DRAW_BLOCK == 0:
                E, U = g.standard_exponential(DRAW_BLOCK), g.random(DRAW_BLOCK)
            rate = -q[s, s]
            if rate <= 0.0:
                break
            t = t + E[k % DRAW_BLOCK] / rate
            if not t < horizon:
                break
            row = np.clip(q[s], 0.0, None)
            row[s] = 0.0
            cdf = np.cumsum(row)
            cdf /= cdf[-1]
            s = int(np.count_nonzero(cdf <= U[k % DRAW_BLOCK]))
            times.append(t)
            states.append(s)
            k += 1
        modes = [chain.joint_modes[v] for v in states]
        keep = [0] + [i for i in range(1, len(modes)) if modes[i] != modes[i - 1]]
        out.append((np.array(times)[keep], [modes[i] for i in keep]))
    return out


def same_path(p: ChainPath, ref: tuple) -> bool:
    return np.array_equal(p.times, ref[0]) and list(zip(p.true.tolist(), p.fdi.tolist())) == ref[1]


# ------------------------------------------------------------------ (a) the paper's model unchanged
def test_paper_paths_as_before_issue_23() -> None:
    """Explicit ``delay_phases=1`` is the default chain, draws bitwise the same paths, and
    both reproduce fingerprints recorded with the sampler before issue 23 (commit 04c2491:
    200 paths, horizon 30, seed 12345; segment count, sums of the times, the modes and the
    drawn beta)."""
    explicit = with_chain(delay_phases=1, fault_during_delay=False).chain
    assert explicit == PAPER.chain and explicit.is_paper_model
    recorded = {True: (6670, 98581.02096179422, 3311, 3231, 1101.0769771563498),
                False: (6669, 98948.02064888211, 3305, 3232, 1100.0)}
    for beta in (None, PAPER.chain.midpoint()):
        a = sample_paths(PAPER.chain, 30.0, 200, 12345, beta=beta)
        b = sample_paths(explicit, 30.0, 200, 12345, beta=beta)
        for p, r in zip(a, b):
            for name in ("times", "true", "fdi", "beta"):
                x, y = getattr(p, name), getattr(r, name)
                assert np.array_equal(x, y) and x.dtype == y.dtype
        count, tsum, tr, fd, bsum = recorded[beta is None]
        assert sum(p.times.size for p in a) == count
        assert float(sum(p.times.sum() for p in a)) == pytest.approx(tsum, rel=1e-13)
        assert (sum(int(p.true.sum()) for p in a), sum(int(p.fdi.sum()) for p in a)) == (tr, fd)
        assert float(sum(p.beta.sum() for p in a)) == pytest.approx(bsum, rel=1e-13)


@pytest.mark.parametrize("options", [{}, {"delay_phases": 3},
                                     {"delay_phases": 2, "false_alarm_min": [[0, 0.4], [0.3, 0]],
                                      "false_alarm_max": [[0, 0.4], [0.3, 0]]},
                                     {"delay_phases": 4, "fault_during_delay": True}])
def test_vectorised_sampler_is_the_plain_one_bitwise(options) -> None:
    """At a fixed rate array the vectorised sampler equals :func:`plain_paths` bit for bit
    (paper's model, Erlang delays, false alarms, faults during a delay); every reported
    segment differs from the previous one in ``true`` or ``fdi``."""
    chain = with_chain(**options).chain
    beta = chain.midpoint()
    got = sample_paths(chain, 12.0, 60, 99, beta=beta, start=(1, 0))
    for p, ref in zip(got, plain_paths(chain, 12.0, 60, 99, beta, start=(1, 0))):
        assert same_path(p, ref)
        change = (np.diff(p.true) != 0) | (np.diff(p.fdi) != 0)
        assert np.all(change)
        assert p.beta.shape == chain.rate_shape


def test_rates_drawn_per_path_from_the_stream() -> None:
    """``beta=None``: the first ``m*m`` uniforms of a path's stream give ``beta``, the next
    ``m*m`` the false-alarm rates (only when the chain has them); diagonals are zero, and
    the path is the one the plain sampler draws at that rate array (to rounding of the
    affine generator: same modes, times to 1e-12)."""
    lo, hi = [[0, 0.1], [0.2, 0]], [[0, 0.5], [0.6, 0]]
    for chain in (PAPER.chain, with_chain(delay_phases=3, false_alarm_min=lo, false_alarm_max=hi).chain):
        paths = sample_paths(chain, 10.0, 20, 5)
        for q, p in enumerate(paths):
            g = np.random.default_rng(p.stream)
            u = np.concatenate([g.random((2, 2))] + ([g.random((2, 2))] if chain.has_false_alarms else []))
            want = chain.rate_min + u.reshape(chain.rate_shape) * (chain.rate_max - chain.rate_min)
            want[..., [0, 1], [0, 1]] = 0.0
            assert np.array_equal(p.beta, want)
            t, modes = plain_paths(chain, 10.0, q + 1, 5, p.beta, drawn=True)[q]
            assert list(zip(p.true.tolist(), p.fdi.tolist())) == modes
            np.testing.assert_allclose(p.times, t, rtol=1e-12)


def test_start_is_validated() -> None:
    chain = with_chain(delay_phases=3).chain
    with pytest.raises(ValidationError, match="start"):
        sample_paths(chain, 1.0, 2, 0, start=(2, 0))
    with pytest.raises(ValidationError, match="beta"):
        sample_paths(chain, 1.0, 2, 0, beta=np.zeros((2, 2, 2)))


# ------------------------------------------------------------------ (b) Erlang detection delays
@pytest.mark.parametrize("k", [1, 3, 8])
def test_detection_delays_are_erlang(k: int) -> None:
    r"""Time from the first fault (true 0 -> 1) to the FDI reporting mode 1, at
    ``beta[0][1] = 2``: Erlang-``k`` with mean :math:`1/\beta = 0.5` and variance
    :math:`1/(k\beta^2)` (the ``k`` phases at rate :math:`k\beta`). 20,000 paths; faults at
    rate 5, repairs at 0.01, horizon 20 (a censored delay has probability below 1e-15).
    KS at 1e-6, z-tests of the mean (known variance under H0) and of the sample variance
    (:math:`\mathrm{Var}(s^2) \approx (\mu_4 - \sigma^4)/N = (2 + 6/k)\sigma^4/N` for the
    gamma law) at 1e-6 each."""
    chain = JointChain([[-5.0, 5.0], [0.01, -0.01]], [[0, 1.0], [1.0, 0]], [[0, 4.0], [4.0, 0]],
                       delay_phases=k)
    beta = np.array([[0.0, 2.0], [3.0, 0.0]])
    n = 20_000
    delays = np.empty(n)
    for q, p in enumerate(sample_paths(chain, 20.0, n, 2300 + k, beta=beta)):
        f = int(np.argmax(p.true == 1))
        assert p.true[f] == 1 and (p.true[f], p.fdi[f]) == (1, 0) and f + 1 < p.times.size
        assert (p.true[f + 1], p.fdi[f + 1]) == (1, 1)  # phases are not segments
        delays[q] = p.times[f + 1] - p.times[f]
    mean, var = 1.0 / beta[0, 1], 1.0 / (k * beta[0, 1] ** 2)
    res = scipy.stats.kstest(delays, scipy.stats.gamma(a=k, scale=1.0 / (k * beta[0, 1])).cdf)
    assert res.pvalue > LEVEL, res
    assert abs(delays.mean() - mean) / math.sqrt(var / n) < Z
    assert abs(delays.var(ddof=1) - var) / (var * math.sqrt((2.0 + 6.0 / k) / n)) < Z


# ------------------------------------------------------------------ (c) false alarms
def test_false_alarm_rate_and_withdrawal() -> None:
    r"""Faults at rate 1e-12 (none expected: 1e-7 over all paths), false alarms 0 -> 1 at
    ``f = 0.3``, withdrawn through 3 phases at ``beta[1][0] = 4``. An alarm is an FDI
    switch away from the true mode while the true mode stays. ``N(t) - f \int 1\{(0,0)\}``
    is a martingale with quadratic variation ``f T_m``, so
    :math:`(N - f T_m)/\sqrt{f T_m}` is standard normal in the limit (2,000 paths, horizon
    50: about 28,000 alarms). Alarms that start before ``horizon - 20`` are withdrawn
    within the horizon (probability of a miss below 1e-15); their durations are Erlang-3
    with mean 1/4 (strong Markov property: independent of the start time)."""
    f = 0.3
    fa = [[0.0, f], [0.2, 0.0]]
    chain = JointChain([[-1e-12, 1e-12], [1e-12, -1e-12]], [[0, 1.0], [1.0, 0]], [[0, 5.0], [5.0, 0]],
                       delay_phases=3, false_alarm_min=fa, false_alarm_max=fa)
    beta = np.stack([np.array([[0.0, 3.0], [4.0, 0.0]]), np.array(fa)])
    horizon = 50.0
    alarms, exposure, durations = 0, 0.0, []
    for p in sample_paths(chain, horizon, 2000, 4242, beta=beta):
        assert p.fault_switches == 0
        ends = np.append(p.times[1:], horizon)
        matched = (p.true == 0) & (p.fdi == 0)
        exposure += float(np.sum((ends - p.times)[matched]))
        raised = np.flatnonzero((p.true[1:] == 0) & (p.fdi[:-1] == 0) & (p.fdi[1:] == 1)) + 1
        alarms += raised.size
        early = raised[p.times[raised] < horizon - 20.0]
        assert np.all(early + 1 < p.times.size) and np.all(p.fdi[early + 1] == 0)
        durations.extend((p.times[early + 1] - p.times[early]).tolist())
    assert alarms > 20_000
    assert abs(alarms - f * exposure) / math.sqrt(f * exposure) < Z
    d = np.array(durations)
    assert abs(d.mean() - 0.25) / math.sqrt(1.0 / (3 * 16.0) / d.size) < Z


# ------------------------------------------------------------------ simulators on phase-type paths
def test_simulators_see_only_the_joint_mode() -> None:
    """A path of a phase-type chain with false alarms simulated on that system and on the
    paper's (same plant, same gains) gives the same records: every phase of a detection
    uses the loop matrices of its ``(true, fdi)`` (continuous simulator) and the sampled
    simulators never see the chain."""
    fa = [[0.0, 0.5], [0.5, 0.0]]
    system = with_chain(delay_phases=3, false_alarm_min=fa, false_alarm_max=fa)
    controller = load_controller(ROOT / "examples" / "paper_gains.toml")
    paths = sample_paths(system.chain, 6.0, 4, 17)
    assert sum(p.fdi_switches for p in paths) > 0
    for p in paths[:2]:
        a = simulate_continuous(system, controller, p, points_per_unit=50)
        b = simulate_continuous(PAPER, controller, p, points_per_unit=50)
        assert np.array_equal(a.y, b.y) and np.array_equal(a.x, b.x)
    ea = energies_reference(system, controller, paths, step=0.02)
    eb = energies_reference(PAPER, controller, paths, step=0.02)
    assert np.array_equal(ea[0], eb[0]) and np.array_equal(ea[1], eb[1])


# ------------------------------------------------------------------ (d) exact energy vs Monte Carlo
def scalar_system(chain: JointChain) -> FTCSystem:
    """Scalar plant ``a = -1`` (mode 1) and ``a = 0.5`` (mode 2, the fault), ``B = C = D = 1``;
    with the gains of :data:`SCALAR_GAINS` the mismatched loop (fault, FDI still on mode 1)
    is unstable (pole +0.5), so the energy depends on the whole law of the delay."""
    modes = [{"A": [[a]], "B": [[1.0]], "C": [[1.0]], "D": [[1.0]]} for a in (-1.0, 0.5)]
    built = FTCSystem.from_arrays(name="scalar", modes=modes, alpha=chain.alpha, beta_min=chain.beta_min,
                                  beta_max=chain.beta_max)
    return FTCSystem(built.name, built.modes, chain)


SCALAR_GAINS = [np.array([[0.0]]), np.array([[-2.0]])]


@pytest.mark.slow(6)
def test_exact_energy_on_a_phase_type_chain_against_monte_carlo() -> None:
    """:func:`scalar_system` on ``delay_phases = 3`` with false alarms in [0.3, 0.7]
    (faults 0.5 both ways, detection rates in [1, 3]), all rates at the box centre,
    Delta = 0, horizon 8, 20,000 paths. As in ``tests/test_moments.py``: Richardson
    ``2 E(h/2) - E(h)`` (h = 0.02; was 0.01, 1.3 times the simulation's CPU: on these paths
    the two extrapolations differ by 0.0095 % of the exact value, 0.02 standard errors,
    measured) on common paths removes the first-order sample-and-hold bias, and the exact
    value must lie in the two-sided Student-t interval at 1e-6 per side (with a residual
    bias of up to 0.05 standard errors, above the 0.02 measured, the false-failure
    probability is at most about 2.1e-6 under the CLT; fixed seed). The interval
    excludes the exact energies of the exponential delays and of the chain without false
    alarms (both more than 15 standard errors away), so it tests the phases and the
    alarms."""
    from ftc_verify.controllers import Controller
    from ftc_verify.verification.montecarlo import estimate

    alpha, lo, hi = [[-0.5, 0.5], [0.5, -0.5]], [[0, 1.0], [1.0, 0]], [[0, 3.0], [3.0, 0]]
    fa = {"false_alarm_min": [[0, 0.3], [0.3, 0]], "false_alarm_max": [[0, 0.7], [0.7, 0]]}
    controller = Controller.state_feedback(SCALAR_GAINS)
    horizon = 8.0

    def exact(**options) -> float:
        system = scalar_system(JointChain(alpha, lo, hi, **options))
        return exact_energy(closed_loop(system, controller).nominal(), beta=system.chain.midpoint(),
                            horizon=horizon).y_energy

    system = scalar_system(JointChain(alpha, lo, hi, delay_phases=3, **fa))
    rates = system.chain.midpoint()
    paths = sample_paths(system.chain, horizon, 20_000, 20261125, beta=rates)
    y_coarse, w = energies_reference(system, controller, paths, step=0.02)
    y_fine, _ = energies_reference(system, controller, paths, step=0.01)
    est = estimate(2.0 * y_fine - y_coarse, w, alpha=LEVEL, seed=20261125)
    low, high = est.lower_bound * est.w_energy, est.upper_bound * est.w_energy
    assert low <= exact(delay_phases=3, **fa) <= high
    assert (high - low) / exact(delay_phases=3, **fa) < 0.06
    for other in (exact(delay_phases=1, **fa), exact(delay_phases=3)):
        assert not low <= other <= high


# ------------------------------------------------------------------ (e) exact energies unchanged
#: exact_energy of the paper's gains before issue 23 (commit 04c2491): per beta (midpoint,
#: beta_min, beta_max) and start ((0,0), (1,0), (0,1)): (horizon 15, horizon inf).
RECORDED = [
    [(0.17177221578744456, 0.1807723899201533), (0.21305698991229363, 0.22205716404502351),
     (0.1626031074669471, 0.17160328159964894)],
    [(0.17209174742018457, 0.1811084847875793), (0.2152050261308328, 0.22422176349850406),
     (0.1607592512611637, 0.16977598862835858)],
    [(0.171482865885839, 0.18047203988330218), (0.2114426141842673, 0.22043178818173106),
     (0.1638868083580684, 0.1728759823555317)],
]


def test_exact_energy_of_the_paper_model_unchanged() -> None:
    """``delay_phases = 1`` without false alarms: the exact energies equal those recorded
    before issue 23 and those of the default chain (1e-12), and so does the worst case."""
    explicit = with_chain(delay_phases=1)
    loops = [state_feedback_loop(s, GAINS).nominal() for s in (PAPER, explicit)]
    c = PAPER.chain
    for b, row in zip((c.midpoint(), c.beta_min, c.beta_max), RECORDED):
        for start, (finite, infinite) in zip(((0, 0), (1, 0), (0, 1)), row):
            for loop in loops:
                assert exact_energy(loop, beta=b, horizon=15.0, start=start).y_energy == \
                    pytest.approx(finite, rel=1e-12, abs=0)
                assert exact_energy(loop, beta=b, start=start).y_energy == pytest.approx(infinite, rel=1e-12, abs=0)
    wc = [worst_case_disturbance(loop, beta=c.midpoint(), horizon=4.0, pieces=8, start=(1, 0)).ratio
          for loop in loops]
    assert wc[0] == pytest.approx(wc[1], rel=1e-12, abs=0)


def test_moments_on_a_phase_type_chain() -> None:
    """On a phase-type chain the moments run on all ``n_states`` states and start at phase
    0 of the given joint mode; a bad start is refused naming ``start``. Erlang delays with
    the same mean change the energy only a little; the exact energy and the worst case are
    positive and finite."""
    system = with_chain(delay_phases=4)
    loop = state_feedback_loop(system, GAINS).nominal()
    assert len(loop.A) == system.chain.n_states == 10
    mid = system.chain.midpoint()
    e = exact_energy(loop, beta=mid, horizon=15.0, start=(1, 0)).y_energy
    paper = exact_energy(state_feedback_loop(PAPER, GAINS).nominal(), beta=mid, horizon=15.0, start=(1, 0)).y_energy
    assert 0 < e < math.inf and e == pytest.approx(paper, rel=0.2) and e != pytest.approx(paper, rel=1e-6)
    wc = worst_case_disturbance(loop, beta=mid, horizon=3.0, pieces=6)
    assert 0 < wc.ratio < math.inf
    with pytest.raises(ValidationError, match="start"):
        exact_energy(loop, beta=mid, start=(0, 2))
