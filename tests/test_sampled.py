"""The sampled-data loop (:mod:`ftc_verify.analysis.moments.sampled`, ``sampled_proof``): the
one-period map against an independent Monte Carlo, its h -> 0 limit, the proofs over the
rate box, the paper example's h_max, the controller's period and the CLI's --period."""

from __future__ import annotations

import dataclasses
import itertools
import json
import math
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg
from hypothesis import HealthCheck, given, settings
from hypothesis.errors import InvalidArgument

from ftc_verify.analysis.closedloop import closed_loop
from ftc_verify.analysis.rigorous import Ball, midpoint
from ftc_verify.analysis.moments.sampled import (SampledLoop, h_max_bracket, one_period_map, sampled_analysis,
                                         spectral_radius)
from ftc_verify.analysis.moments.sampled_proof import ball_one_period_map, box_verdict, prove_point_unstable
from ftc_verify.analysis.moments.stability import spectral_abscissa, unvech_stack
from ftc_verify.cli.main import main
from ftc_verify.controllers.controller import Controller
from ftc_verify.controllers.files import dump_controller, load_controller
from ftc_verify.errors import ProblemFileError, ValidationError
from ftc_verify.model.chain import JointChain
from ftc_verify.model.files import load_system
from ftc_verify.model.system import FTCSystem
from ftc_verify.testing.loops import DrawnLoop, stable_loops
from ftc_verify.testing.strategies import periods

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "examples" / "paper.toml"
GAINS = ROOT / "examples" / "paper_gains.toml"


@pytest.fixture(scope="module")
def paper() -> tuple[FTCSystem, Controller]:
    return load_system(PAPER), load_controller(GAINS)


def _erlang_false_alarm(system: FTCSystem) -> FTCSystem:
    """The paper plant with Erlang-2 delays and false alarms."""
    chain = dataclasses.replace(system.chain, delay_phases=2, false_alarm_min=np.full((2, 2), 0.2),
                                false_alarm_max=np.full((2, 2), 0.4))
    return dataclasses.replace(system, chain=chain)


TWO_OUTPUTS = ROOT / "examples" / "paper_two_outputs.toml"


def _dynamic_controller() -> Controller:
    """A dynamic controller on y_m = x (``paper_two_outputs.toml``): the paper gains on
    0.8 y_m + 0.2 x_c, x_c a first-order filter of y_m with pole -20 (stabilising in
    continuous time, abscissa about -3.7)."""
    K = load_controller(GAINS).gains
    return Controller.dynamic(Ac=[-20 * np.eye(2)] * 2, Bc=[20 * np.eye(2)] * 2, Cc=[0.2 * k for k in K],
                              Dc=[0.8 * k for k in K])


# ------------------------------------------------------------------ independent Monte Carlo
def _mc_moments(system: FTCSystem, controller: Controller, h: float, rates: np.ndarray, periods: int,
                paths: int, rng: np.random.Generator) -> np.ndarray:
    """E|(x, x_c)|^2 at the samples 1..periods, by simulating the sampled loop path by path:
    a Gillespie walk of the joint chain (its generator at ``rates``), the plant integrated
    exactly between jumps with the input held (one expm of [[A, B], [0, 0]] per piece),
    the controller reading x and the FDI mode at the samples only. Written here without
    the package's simulators or moment code."""
    chain = system.chain
    Q = chain.generator(rates)
    states = chain.joint_modes
    n, nu = system.dims[0], system.dims[1]
    nc = controller.n_c
    x0 = np.ones(n)
    out = np.zeros(periods)

    def flow(i: int, u: np.ndarray, x: np.ndarray, tau: float) -> np.ndarray:
        M = np.zeros((n + nu, n + nu))
        M[:n, :n], M[:n, n:] = system.modes[i].A, system.modes[i].B
        return (scipy.linalg.expm(M * tau) @ np.concatenate([x, u]))[:n]

    for _ in range(paths):
        s, x, xc = 0, x0.copy(), np.zeros(nc)
        for k in range(periods):
            i, j = states[s]
            e = controller.index(i, j, system.m)
            v = x if controller.measures == "state" else system.modes[i].measured @ x
            u = controller.Dc[e] @ v + (controller.Cc[e] @ xc if nc else 0.0)
            if nc:
                V = np.zeros((nc + v.size, nc + v.size))
                V[:nc, :nc], V[:nc, nc:] = controller.Ac[e], controller.Bc[e]
                E = scipy.linalg.expm(V * h)
                xc = E[:nc, :nc] @ xc + E[:nc, nc:] @ v
            left = h
            while True:
                rate = -Q[s, s]
                tau = rng.exponential(1.0 / rate) if rate > 0 else math.inf
                if tau >= left:
                    x = flow(states[s][0], u, x, left)
                    break
                x = flow(states[s][0], u, x, tau)
                left -= tau
                p = np.clip(Q[s], 0, None)
                p[s] = 0.0
                s = int(rng.choice(len(p), p=p / p.sum()))
            out[k] += x @ x + xc @ xc
    return out / paths


def _exact_moments(system: FTCSystem, controller: Controller, h: float, rates: np.ndarray, periods: int) -> np.ndarray:
    loop = SampledLoop.build(system, controller)
    T = one_period_map(loop, h, rates)
    r = loop.r
    y0 = np.zeros((loop.states, r, r))
    y0[0, :system.dims[0], :system.dims[0]] = 1.0  # x0 = (1, ..., 1), x_c = 0, in joint state 0
    rows, cols = np.tril_indices(r)
    order = np.lexsort((rows, cols))
    vec = y0[:, rows[order], cols[order]].reshape(-1)
    out = []
    for _ in range(periods):
        vec = T @ vec
        out.append(sum(np.trace(Y) for Y in unvech_stack(vec, loop.states, r)))
    return np.array(out)


@pytest.mark.parametrize("case", ["paper-stable", "paper-unstable", "erlang-false-alarm", "dynamic"])
def test_one_period_map_matches_independent_monte_carlo(paper: tuple[FTCSystem, Controller], case: str) -> None:
    """E|(x, x_c)|^2 at samples 1..4 from T^k against 1500 simulated paths (seed 31).

    Per sample the Monte Carlo mean is compared with the exact value within 5 standard
    errors of the mean (the sample standard deviation over the paths); by the central
    limit theorem each comparison fails by chance with probability about 6e-7, the 16
    comparisons of this test together below 1e-5."""
    system, gains = paper
    controller = gains
    h = {"paper-stable": 0.05, "paper-unstable": 0.1, "erlang-false-alarm": 0.06, "dynamic": 0.08}[case]
    if case == "erlang-false-alarm":
        system = _erlang_false_alarm(system)
    if case == "dynamic":
        system, controller = load_system(TWO_OUTPUTS), _dynamic_controller()
    rates = system.chain.midpoint()
    exact = _exact_moments(system, controller, h, rates, 4)
    rng = np.random.default_rng(31)
    samples = np.array([_mc_moments(system, controller, h, rates, 4, 1, rng) for _ in range(1500)])
    mean, sem = samples.mean(axis=0), samples.std(axis=0, ddof=1) / math.sqrt(samples.shape[0])
    assert np.all(np.abs(mean - exact) <= 5 * sem), (mean, exact, sem)


# ------------------------------------------------------------------ limits and the paper example
@pytest.mark.parametrize("case", ["paper", "dynamic", "observer"])
def test_small_period_tends_to_the_continuous_loop(paper: tuple[FTCSystem, Controller], case: str) -> None:
    """log rho(T(h)) / h -> the continuous loop's spectral abscissa (h = 1e-3: within 1 %)
    -- also for the observer of ``paper_observer.toml``, whose continuous loop is not
    mean-square stable (abscissa about +124)."""
    system, controller = paper
    if case == "dynamic":
        system, controller = load_system(TWO_OUTPUTS), _dynamic_controller()
    if case == "observer":
        controller = load_controller(ROOT / "examples" / "paper_observer.toml")
    rates = system.chain.midpoint()
    loop = SampledLoop.build(system, controller)
    h = 1e-3
    sampled_rate = math.log(spectral_radius(loop, h, rates)) / h
    continuous = spectral_abscissa(closed_loop(system, controller), rates)
    assert sampled_rate == pytest.approx(continuous, rel=1e-2)


def test_paper_gains_unstable_at_ten_hertz_and_h_max(paper: tuple[FTCSystem, Controller]) -> None:
    """The issue's numbers: proved unstable at h = 0.1, h_max about 0.0843, bracket proved."""
    system, controller = paper
    res = sampled_analysis(system, controller, 0.1)
    assert res.verdict == "not stable"
    assert res.spectral_radius > 1.5
    assert res.h_max is not None and res.h_max_unstable is not None
    assert 0.0835 < res.h_max < res.h_max_unstable < 0.0850
    assert (res.h_max_unstable - res.h_max) / res.h_max_unstable <= 1e-3
    loop = SampledLoop.build(system, controller)
    assert box_verdict(loop, res.h_max).verdict == "stable"
    assert box_verdict(loop, res.h_max_unstable).verdict == "not stable"
    assert res.stability_intervals[0][0] == res.scan[0]
    assert res.stability_intervals[0][1] == pytest.approx(res.h_max, rel=1e-3)


def test_ball_map_contains_float_map(paper: tuple[FTCSystem, Controller]) -> None:
    system, controller = paper
    loop = SampledLoop.build(system, controller)
    rates = system.chain.rate_max
    T = one_period_map(loop, 0.07, rates, scaled=True)
    B = ball_one_period_map(loop, 0.07, rates, rates)
    assert np.allclose(midpoint(B), T, rtol=1e-10, atol=1e-12)
    radius = max(float(e.rad()) for e in B.value.entries())
    assert radius < 1e-12
    wide = ball_one_period_map(loop, 0.07, system.chain.rate_min, system.chain.rate_max)
    assert max(float(e.rad()) for e in wide.value.entries()) > 1e3 * radius  # the box is covered, not a point


def test_box_verdict_never_proves_by_vertices(paper: tuple[FTCSystem, Controller]) -> None:
    """Near the stability limit a budget of one sub-box can leave the verdict undecided
    (naming the sub-box); with a larger budget the same period is proved either way,
    and a stable verdict there agrees with the float radius below 1 at every vertex."""
    system, controller = paper
    loop = SampledLoop.build(system, controller)
    res = sampled_analysis(system, controller, 0.05, h_max=False)
    assert res.verdict == "stable" and res.h_max is None and res.h_max_note == "not requested"
    h = 0.084240
    one = box_verdict(loop, h, max_boxes=1)
    many = box_verdict(loop, h, max_boxes=64)
    assert one.verdict in ("stable", "undecided")
    if one.verdict == "undecided":
        assert isinstance(one.where, tuple) and "budget" in one.detail
    if many.verdict == "stable":
        assert all(spectral_radius(loop, h, v) < 1 for v in system.chain.vertices())


def test_erlang_and_false_alarm_box_proofs(paper: tuple[FTCSystem, Controller]) -> None:
    system = _erlang_false_alarm(paper[0])
    loop = SampledLoop.build(system, paper[1])
    assert box_verdict(loop, 0.03).verdict == "stable"
    rho = max(spectral_radius(loop, 0.12, v) for v in (system.chain.rate_min, system.chain.rate_max))
    assert rho > 1 and box_verdict(loop, 0.12).verdict == "not stable"


def test_dynamic_controllers_proved_both_ways(paper: tuple[FTCSystem, Controller]) -> None:
    """The filtered controller is proved stable at h = 0.05 over the box; the observer of
    ``paper_observer.toml`` (continuous loop unstable) is proved unstable at h = 0.002."""
    system, controller = load_system(TWO_OUTPUTS), _dynamic_controller()
    loop = SampledLoop.build(system, controller)
    assert box_verdict(loop, 0.05).verdict == "stable"
    observer = SampledLoop.build(paper[0], load_controller(ROOT / "examples" / "paper_observer.toml"))
    rates = paper[0].chain.midpoint()
    assert spectral_radius(observer, 0.002, rates) > 1
    assert prove_point_unstable(observer, 0.002, rates)
    assert box_verdict(observer, 0.002).verdict == "not stable"


def test_ill_conditioned_coordinates_keep_the_verdict(paper: tuple[FTCSystem, Controller]) -> None:
    """x = diag(1e3, 1e-3) x~: the same loop in badly scaled coordinates, same radius and verdicts."""
    system, controller = paper
    d = np.array([1e3, 1e-3])
    modes = tuple(dataclasses.replace(m, A=m.A * d[None, :] / d[:, None], B=m.B / d[:, None], C=m.C * d[None, :],
                                      D=m.D / d[:, None], A1=m.A1 / d[:, None], A2=m.A2 * d[None, :],
                                      B1=m.B1 / d[:, None]) for m in system.modes)
    scaled = dataclasses.replace(system, modes=modes)
    gains = Controller.state_feedback([K * d[None, :] for K in controller.gains])
    a, b = SampledLoop.build(system, controller), SampledLoop.build(scaled, gains)
    rates = system.chain.midpoint()
    for h in (0.05, 0.1):
        assert spectral_radius(b, h, rates) == pytest.approx(spectral_radius(a, h, rates), rel=1e-8)
    assert box_verdict(b, 0.05).verdict == "stable"
    assert box_verdict(b, 0.1).verdict == "not stable"


def test_h_max_bracket_needs_a_crossing(paper: tuple[FTCSystem, Controller]) -> None:
    system, controller = paper
    loop = SampledLoop.build(system, controller)
    lo, hi, note = h_max_bracket(loop, 0.08, 0.09)
    assert lo is not None and hi is not None and lo < hi and "proved" in note


# ------------------------------------------------------------------ the controller's period
def test_controller_period_round_trip(tmp_path: Path, paper: tuple[FTCSystem, Controller]) -> None:
    c = paper[1].with_period(0.02)
    path = tmp_path / "c.toml"
    path.write_text(dump_controller(c))
    back = load_controller(path)
    assert back.period == 0.02 and back == c and back != paper[1]
    assert "period = 0.02" in path.read_text()
    for bad in ("0", "-0.1", "nan", "\"fast\"", "true"):
        path.write_text(f"period = {bad}\n" + dump_controller(paper[1]))
        with pytest.raises(ProblemFileError, match="period"):
            load_controller(path)
    with pytest.raises(ValidationError, match=r"controller\.period"):
        paper[1].with_period(float("inf"))


# ------------------------------------------------------------------ the CLI
def test_cli_analyze_period_json(capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["analyze", str(PAPER), "--controller", str(GAINS), "--period", "0.1", "--no-lmi", "--json"])
    d = json.loads(capsys.readouterr().out)
    assert code == 1
    s = d["sampled"]
    assert s["period"] == 0.1 and s["verdict"] == "not stable" and s["spectral_radius"] > 1
    assert s["h_max"] < s["h_max_unstable"] and s["stability_intervals"]


def test_cli_analyze_period_from_the_controller_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "gains.toml"
    path.write_text(dump_controller(load_controller(GAINS).with_period(0.05)))
    code = main(["analyze", str(PAPER), "--controller", str(path), "--no-lmi"])
    out = capsys.readouterr().out
    assert code == 0
    assert "period h = 0.05" in out and "sampled loop is mean-square stable" in out


@pytest.mark.parametrize("argv", [
    ["analyze", str(PAPER), "--controller", str(GAINS), "--period", "0"],
    ["analyze", str(PAPER), "--controller", str(GAINS), "--period", "-0.1"],
    ["analyze", str(PAPER), "--controller", str(GAINS), "--period", "nan"],
    ["simulate", str(PAPER), "--controller", str(GAINS), "--period", "31", "--horizon", "30"],
    ["verify", str(PAPER), "--controller", str(GAINS), "--period", "50"],
    ["simulate", str(PAPER), "--controller", str(GAINS), "--period", "0.1", "--step", "0.01"],
    ["simulate", str(PAPER), "--controller", str(GAINS), "--period", "5", "--horizon", "30"],
])
def test_cli_bad_periods_exit_2_naming_period(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse's own errors (the option's type)
        code = int(exc.code or 0)
    assert code == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    err = captured.err.strip()
    assert "--period" in err and len(err.splitlines()) == 1 and "Traceback" not in err


def test_chain_generator_ball_covers_the_box(paper: tuple[FTCSystem, Controller]) -> None:
    from ftc_verify.analysis.moments.sampled_balls import ball_generator

    chain: JointChain = _erlang_false_alarm(paper[0]).chain
    B = ball_generator(chain, chain.rate_min, chain.rate_max)
    rng = np.random.default_rng(7)
    for _ in range(5):
        r = chain.rate_min + rng.random(chain.rate_shape) * (chain.rate_max - chain.rate_min)
        Q = chain.generator(r)
        for s, t in np.ndindex(*Q.shape):
            assert B.value[s, t].contains(float(Q[s, t]))


def test_first_order_form_proves_where_the_direct_ball_cannot(paper: tuple[FTCSystem, Controller]) -> None:
    """Gains of norm 10 (a bounded-gain design for the paper plant): at h = 0.2 the ball of
    T over the whole rate box is too wide for the direct proof, the first-order expansion
    with its quadratic remainder proves the whole box at once, and box_verdict says so
    with one sub-box."""
    from ftc_verify.analysis.rigorous import Ball, precision
    from ftc_verify.analysis.moments.sampled_balls import ball_generator
    from ftc_verify.analysis.moments.sampled_proof import MapParts, prove_stable
    from ftc_verify.analysis.moments.sampled_taylor import perron_first_order_stable

    system = paper[0]
    gains = Controller.state_feedback([[[2.9749, 9.5371], [-9.4142, 2.8536]], [[2.5399, 9.6565], [-9.5176, 2.3946]]])
    loop, chain = SampledLoop.build(system, gains), system.chain
    with precision(64):
        parts = MapParts.build(loop, 0.2)
        T_mid = one_period_map(loop, 0.2, chain.midpoint(), scaled=True)
        T = Ball(parts.map(ball_generator(chain, chain.rate_min, chain.rate_max).value))
        assert not prove_stable(T, T_mid, loop.states, loop.r)
        assert perron_first_order_stable(loop, parts, chain.rate_min, chain.rate_max, T_mid)
    v = box_verdict(loop, 0.2)
    assert v.verdict == "stable" and v.boxes == 1


def test_upper_envelope_dominates_every_rate_of_the_box(paper: tuple[FTCSystem, Controller]) -> None:
    """T_up - T(r) is a positive map for random rates r of the box (Erlang-2 delays and
    false alarms): applied to random positive semidefinite stacks it gives positive
    semidefinite stacks (float64, to rounding)."""
    from ftc_verify.analysis.rigorous import midpoint, precision
    from ftc_verify.analysis.moments.sampled_balls import envelope_generator
    from ftc_verify.analysis.moments.sampled_proof import MapParts

    system = _erlang_false_alarm(paper[0])
    loop, chain = SampledLoop.build(system, paper[1]), system.chain
    h = 0.05
    with precision(64):
        T_up = midpoint(Ball(MapParts.build(loop, h).map(envelope_generator(chain, chain.rate_min,
                                                                             chain.rate_max).value)))
    rng = np.random.default_rng(5)
    rows, cols = np.tril_indices(loop.r)
    order = np.lexsort((rows, cols))
    for _ in range(10):
        r = chain.rate_min + rng.random(chain.rate_shape) * (chain.rate_max - chain.rate_min)
        D = T_up - one_period_map(loop, h, r, scaled=True)
        G = rng.standard_normal((loop.states, loop.r, loop.r))
        X = G @ np.transpose(G, (0, 2, 1))
        out = unvech_stack(D @ X[:, rows[order], cols[order]].reshape(-1), loop.states, loop.r)
        assert all(np.linalg.eigvalsh(Y).min() >= -1e-9 * np.abs(Y).max() for Y in out)


def test_real_eigenvalue_fallback() -> None:
    """The determinant sign change proves a real eigenvalue above 1, and only then."""
    from ftc_verify.analysis.rigorous import ball
    from ftc_verify.analysis.moments.sampled_proof import _real_eigenvalue_above_one

    for M, expected in ((np.diag([1.5, 0.5, 0.2]), True), (np.diag([0.9, 0.5, 0.2]), False),
                        (np.array([[0.9, 0.8, 0.0], [-0.8, 0.9, 0.0], [0.0, 0.0, 0.5]]), False),  # |complex| > 1
                        (np.diag([1.2, 1.1, 0.3]), True)):
        assert _real_eigenvalue_above_one(ball(M), np.linalg.eigvals(M)) is expected


def test_synthesize_period_designs_for_the_sampled_loop(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """At h = 0.2 the gain bound 30 gives a loop certified in continuous time but not
    stable sampled; synthesize --period tries smaller bounds and writes the first design
    proved stable at 0.2, with period = 0.2 in the file; analyze proves it again."""
    out = tmp_path / "K.toml"
    code = main(["synthesize", str(PAPER), "--method", "common", "--k-max", "30", "--period", "0.2", "-o", str(out),
                 "--json"])
    d = json.loads(capsys.readouterr().out)
    assert code == 0 and d["verdict"] == "certified"
    attempts = d["period_attempts"]
    assert attempts[0]["k_max"] == 30 and attempts[0]["sampled_verdict"] == "not stable"
    assert attempts[-1]["sampled_verdict"] == "stable" and d["sampled"]["verdict"] == "stable"
    controller = load_controller(out)
    assert controller.period == 0.2
    system = load_system(PAPER)
    assert box_verdict(SampledLoop.build(system, controller), 0.2).verdict == "stable"


# ------------------------------------------------------------------ exact energy of the sampled loop
def _mc_energy(system: FTCSystem, controller: Controller, h: float, rates: np.ndarray, horizon: float,
               rng: np.random.Generator) -> float:
    """One path of the sampled loop with u and w = e^{-0.1 t} sin t held over each period,
    int_0^horizon |C x|^2 dt by the trapezoid on a fine grid (8 pieces per period and at
    the jumps; the plant moved exactly between them). Independent of the package's
    simulators and moments."""
    chain = system.chain
    Q = chain.generator(rates)
    states = chain.joint_modes
    n, nu, _, nw = system.dims
    s, x, energy = 0, np.zeros(n), 0.0
    for k in range(round(horizon / h)):
        i, j = states[s]
        e = controller.index(i, j, system.m)
        u = controller.Dc[e] @ x
        w = math.exp(-0.1 * k * h) * math.sin(k * h) * np.ones(nw)
        marks = list(np.linspace(k * h, (k + 1) * h, 9))
        left, now = (k + 1) * h, k * h
        jumps = []
        while True:
            rate = -Q[s, s]
            tau = rng.exponential(1.0 / rate)
            if now + tau >= left:
                break
            now += tau
            p = np.clip(Q[s], 0, None)
            p[s] = 0.0
            jumps.append((now, int(rng.choice(len(p), p=p / p.sum()))))
        grid = sorted(set(marks) | {tj for tj, _ in jumps})
        seq = iter(jumps)
        nxt = next(seq, None)
        for a, b in itertools.pairwise(grid):
            while nxt is not None and nxt[0] <= a:
                s, nxt = nxt[1], next(seq, None)
            md = system.modes[states[s][0]]
            M = np.zeros((n + nu + nw, n + nu + nw))
            M[:n, :n], M[:n, n:n + nu], M[:n, n + nu:] = md.A, md.B, md.D
            y0 = md.C @ x
            x = (scipy.linalg.expm(M * (b - a)) @ np.concatenate([x, u, w]))[:n]
            energy += 0.5 * (b - a) * (y0 @ y0 + (md.C @ x) @ (md.C @ x))
        while nxt is not None:
            s, nxt = nxt[1], next(seq, None)
    return energy


def test_sampled_energy_against_independent_monte_carlo(paper: tuple[FTCSystem, Controller]) -> None:
    """E int_0^1.6 |y|^2 of the sampled loop (h = 0.08, nominal) against 300 simulated
    paths (seed 310): within 5 standard errors of the mean (false failure about 6e-7 by
    the central limit theorem; the trapezoid's bias, about 1e-3 relative, is far below)."""
    from ftc_verify.analysis.moments.sampled_energy import sampled_energy

    system, controller = paper[0].nominal(), paper[1]
    rates = system.chain.midpoint()
    exact = sampled_energy(system, controller, 0.08, beta=rates, horizon=1.6).y_energy
    rng = np.random.default_rng(310)
    samples = np.array([_mc_energy(system, controller, 0.08, rates, 1.6, rng) for _ in range(300)])
    sem = samples.std(ddof=1) / math.sqrt(samples.size)
    assert abs(samples.mean() - exact) <= 5 * sem, (samples.mean(), exact, sem)


def test_sampled_energy_tends_to_the_continuous_one(paper: tuple[FTCSystem, Controller]) -> None:
    """h = 1e-3: the sampled loop's exact energy ratio is the continuous one within 1e-3
    relative (infinite horizon and horizon 30), and it grows with h on the paper gains."""
    from ftc_verify.analysis.moments.energy import exact_energy
    from ftc_verify.analysis.moments.sampled_energy import perturbed_system, sampled_energy

    system, controller = paper
    loop = closed_loop(system, controller)
    for b in system.chain.vertices():
        for horizon in (math.inf, 30.0):
            cont = exact_energy(loop.nominal(), beta=b, horizon=horizon).ratio
            samp = sampled_energy(system.nominal(), controller, 1e-3, beta=b, horizon=horizon).ratio
            assert samp == pytest.approx(cont, rel=1e-3)
    b = system.chain.rate_max
    ratios = [sampled_energy(system.nominal(), controller, h, beta=b).ratio for h in (0.01, 0.05, 0.08)]
    assert ratios[0] < ratios[1] < ratios[2]
    delta = perturbed_system(system, np.eye(2), np.eye(2))
    assert delta.modes[0].A[0, 0] == pytest.approx(1.01) and not delta.uncertain
    with pytest.raises(ValidationError, match="infinite horizon"):
        sampled_energy(system.nominal(), controller, 0.1, beta=b)


# ------------------------------------------------------------------ drawn loops and periods
@settings(max_examples=12, deadline=None, derandomize=True, suppress_health_check=list(HealthCheck))
@given(drawn=stable_loops(n=2, m=2, margin=0.1), h=periods(low=1e-3, high=1.0))
def test_box_verdict_agrees_with_the_float_radius(drawn: DrawnLoop, h: float) -> None:
    """Drawn stable loops at drawn periods: "stable" only where the float64 radius is
    below 1 at every rate vertex and at 8 random rates inside the box (a proof over the
    box, not at its vertices), "not stable" only where it is at least 1 at the rate named
    (the verdicts never contradict the float radius by more than rounding)."""
    loop = SampledLoop.build(drawn.system, drawn.controller)
    chain = drawn.system.chain
    v = box_verdict(loop, h, max_boxes=8, max_seconds=5.0)
    rng = np.random.default_rng(0)
    inside = [chain.rate_min + rng.random(chain.rate_shape) * (chain.rate_max - chain.rate_min) for _ in range(8)]
    radii = [spectral_radius(loop, h, p) for p in [*chain.vertices(), *inside]]
    if v.verdict == "stable":
        assert max(radii) < 1.0
    if v.verdict == "not stable":
        assert spectral_radius(loop, h, v.where) > 1.0 - 1e-9


def test_periods_strategy_bounds() -> None:
    with pytest.raises(InvalidArgument):
        periods(low=0.2, high=0.1).example()

    @settings(max_examples=30, derandomize=True)
    @given(h=periods(low=1e-3, high=0.2))
    def inside(h: float) -> None:
        assert 1e-3 <= h <= 0.2

    inside()
