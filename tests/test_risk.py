"""The envelope probability (ftc_verify.risk, ``ftc-verify risk``).

The closed-form loop (``examples/envelope_delay.toml`` with ``envelope_delay_gains.toml``): scalar plant, mode 1 ``x' = u``, mode 2 (the fault, rate ``lam``,
never repaired) ``x' = u + w`` with ``w = 1``; the controller holds ``u = 0`` in FDI mode
1 and ``u = -2 x`` in FDI mode 2. Undetected, ``x`` grows at slope 1 from the fault time
``tau``; detected after a delay ``d`` (exponential, rate ``beta``) the report is read at
the next sample ``s`` and ``x`` is pulled back towards ``0.5`` without overshoot
(``x_{k+1} - 0.5 = 0.8 (x_k - 0.5)`` at step 0.1). For a limit ``L > 0.5`` the largest
grid value is ``min(s, T) - tau``, so the probability is an integral over ``tau`` that
:func:`truth` sums exactly; as the step goes to 0 it tends to
``(1 - exp(-lam (T - L))) exp(-beta L)``.
"""

from __future__ import annotations

import json
import math
import subprocess
from pathlib import Path

import cli_inprocess
import numpy as np
import pytest
from scipy.stats import binom

from ftc_verify.controllers.files import load_controller
from ftc_verify.model.files import load_system
from ftc_verify.risk import Settings, output_envelope, run_risk, state_envelope
from ftc_verify.risk.envelope import region_envelope
from ftc_verify.risk.importance import rate_keys, sample_tilted
from ftc_verify.risk.run import path_scores
from ftc_verify.simulation.paths import sample_paths
from ftc_verify.simulation.spec import SimulationSpec

ROOT = Path(__file__).resolve().parents[1]
LAM, BETA, T = 0.1, 3.0, 10.0

SYSTEM = ROOT / "examples/envelope_delay.toml"
GAINS = ROOT / "examples/envelope_delay_gains.toml"


def truth(limit: float, h: float = 0.1) -> float:
    """P(max |x| >= limit on the grid within [0, T]) for the loop at step ``h`` (module
    docstring): the FDI report is read at the samples, so the pull-back starts at
    ``s = ceil((tau + d) / h) h`` and the envelope is left iff ``tau <= T - L`` and
    ``s >= tau + L``, i.e. ``d > (k - 1) h - tau`` with ``k = ceil((tau + L) / h)``.
    Integrated exactly piece by piece in ``tau`` (``k`` constant on each piece):
    ``lam exp(-beta (k - 1) h) [exp((beta - lam) tau) / (beta - lam)]_a^b``."""
    total = 0.0
    k = math.ceil(limit / h)  # the piece of tau = 0 (limit is no multiple of h)
    while True:
        a, b = max(0.0, (k - 1) * h - limit), min(T - limit, k * h - limit)
        if a >= T - limit:
            return total
        if b > a:
            total += (LAM * math.exp(-BETA * (k - 1) * h)
                      * (math.exp((BETA - LAM) * b) - math.exp((BETA - LAM) * a)) / (BETA - LAM))
        k += 1


@pytest.fixture(scope="module")
def files() -> tuple[Path, Path]:
    return SYSTEM, GAINS


@pytest.fixture(scope="module")
def loop(files: tuple[Path, Path]) -> tuple:
    system = load_system(files[0])
    return system, load_controller(files[1]).check(system)


def _estimate(loop: tuple, limit: float, seed: int, method: str = "importance", max_paths: int = 100_000):
    system, controller = loop
    return run_risk(system, controller, output_envelope(limit), horizon=T, step=0.1, disturbance="step",
                    settings=Settings(method=method, seed=seed, max_paths=max_paths)).estimate


def test_vectorised_peaks_agree_with_the_records() -> None:
    """The fast path (output peaks of the vectorised reference) gives every path's score
    of the per-path records, for the three envelope kinds, with random Delta and x0."""
    system = load_system(ROOT / "examples/paper.toml")
    controller = load_controller(ROOT / "examples/paper_gains.toml").check(system)
    paths = sample_paths(system.chain, 4.0, 120, 7)
    spec = SimulationSpec(step=0.05, horizon=4.0, seed=7, disturbance="paper", x0=(0.3, -0.2), delta="random")
    envelopes = [output_envelope(0.345), state_envelope(system, 1, 0.2035),
                 region_envelope(np.array([-1.0, -0.2035]), np.array([1.0, 1.0]), np.zeros(2), "box")]
    for env in envelopes:
        fast = path_scores(system, controller, env, spec, "reference")(paths)
        slow = path_scores(system, controller, env, spec, "records")(paths)
        assert np.max(np.abs(fast - slow)) < 1e-12, env.description
        assert 0 < np.count_nonzero(slow >= 1.0) < len(paths), env.description  # the limits are in the range


def test_likelihood_ratio_has_mean_one(loop: tuple) -> None:
    """Under any tilt E[W] = 1 (the weights are a density ratio). 4000 paths under a strong
    tilt; the check allows 4.5 standard errors (false failure < 1e-5 under the CLT)."""
    system, _ = loop
    beta = system.chain.midpoint()
    keys = rate_keys(system.chain, beta)
    tilt = np.array([3.0 if k.startswith("alpha") else 0.5 for k in keys.labels])
    sample = sample_tilted(system.chain, keys, tilt, beta, T, 11, 0, 4000)
    w = np.exp(sample.log_weight)
    assert abs(w.mean() - 1.0) < 4.5 * w.std(ddof=1) / math.sqrt(w.size)
    untilted = sample_tilted(system.chain, keys, np.ones(len(keys.labels)), beta, T, 11, 0, 50)
    assert np.all(untilted.log_weight == 0.0)


def test_likelihood_ratio_with_erlang_delays_and_false_alarms() -> None:
    """E[W] = 1 also for a chain with 4-phase detection delays and false alarms (every
    rate key tilted differently); 4.5 standard errors (false failure < 1e-5)."""
    chain = load_system(ROOT / "examples/paper_phase_type.toml").chain
    beta = chain.midpoint()
    keys = rate_keys(chain, beta)
    assert {k.split("[")[0] for k in keys.labels} == {"alpha", "beta", "false_alarm"}
    tilt = np.linspace(0.4, 2.5, len(keys.labels))
    sample = sample_tilted(chain, keys, tilt, beta, 5.0, 12, 0, 4000)
    w = np.exp(sample.log_weight)
    assert abs(w.mean() - 1.0) < 4.5 * w.std(ddof=1) / math.sqrt(w.size)
    assert {p.true.size for p in sample.paths} != {1}  # the paths jump


def test_a_1e7_event_to_20_percent_within_1e5_paths(loop: tuple) -> None:
    """The goal: a 1.4e-7 event estimated to +-20 % at 95 % with at most 1e5 paths."""
    est = _estimate(loop, 5.0, seed=1)
    assert est.converged and est.relative_error <= 0.2
    assert est.paths + est.pilot_paths <= 100_000
    assert est.ci[0] <= truth(5.0) <= est.ci[1]


@pytest.mark.slow(20)  # seconds on 2 busy cores (--durations at load 9, / 4): scheduled first
def test_intervals_cover_the_closed_form_at_the_stated_rate(loop: tuple) -> None:
    """Coverage at three rarity levels (1.6e-3, 1.5e-5, 1.4e-7), 12 seeds each: the 95 %
    intervals must cover the closed form in at least 30 of the 36 runs. With coverage
    0.95 the chance of fewer is binom.cdf(29, 36, 0.95) = 0.0021 (false failure), with
    coverage 0.80 the chance to pass is 0.11. Also the mean estimate is within 10 % of the
    truth at every level (each run has relative error <= 0.2, so 12 runs average to ~6 %)."""
    covered = 0
    for limit in (2.0, 3.5, 5.0):
        p = truth(limit)
        estimates = [_estimate(loop, limit, seed=100 + k) for k in range(12)]
        covered += sum(e.ci[0] <= p <= e.ci[1] for e in estimates)
        assert abs(np.mean([e.probability for e in estimates]) / p - 1.0) < 0.1, limit
    assert binom.cdf(29, 36, 0.95) < 0.003
    assert covered >= 30, covered


def test_crude_monte_carlo_agrees_on_a_frequent_event(loop: tuple) -> None:
    """Crude Monte Carlo (Wilson interval) and importance sampling on a 3 % event: both
    intervals hold the closed form (fixed seeds)."""
    p = truth(1.0)
    crude = _estimate(loop, 1.0, seed=5, method="crude", max_paths=20_000)
    assert crude.method == "crude" and crude.interval == "wilson" and crude.converged
    assert crude.ci[0] <= p <= crude.ci[1]
    tilted = _estimate(loop, 1.0, seed=5)
    assert tilted.ci[0] <= p <= tilted.ci[1]
    assert tilted.paths < crude.paths


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    """``ftc-verify risk ARGS`` in this process (``tests/cli_inprocess.py``: exit code, stdout
    and stderr as a subprocess gives them)."""
    return cli_inprocess.run_cli(["risk", *args], env={"OPENBLAS_NUM_THREADS": "1"})


def test_cli_json(files: tuple[Path, Path]) -> None:
    system, gains = files
    r = _cli(str(system), "--controller", str(gains), "--limit", "3.5", "--horizon", "10", "--step", "0.1",
             "--disturbance", "step", "--seed", "4", "--ftti", "1", "--json")
    assert r.returncode == 0, r.stderr
    d = json.loads(r.stdout)
    assert d["timing"]["worst"] == pytest.approx(math.exp(-BETA), rel=1e-12)  # P(exponential delay > 1)
    assert d["upper_bound"]["reason"] and (d["upper_bound"]["value"] is None or d["upper_bound"]["value"] >= truth(3.5))
    assert d["method"] == "importance" and d["seed"] == 4 and d["verdict"] == "estimated"
    assert len(d["ci"]) == 2 and d["ci"][0] <= truth(3.5) <= d["ci"][1]
    assert d["relative_error"] <= 0.2 and d["paths"] >= 1 and d["tilt"]["beta[1,2]"] < 1.0


@pytest.mark.parametrize(("extra", "named"), [
    (["--limit", "2", "--x0", "1,2"], "--x0"),
    (["--state", "3"], "--limit"),
    (["--limit", "2", "--state", "3"], "--state"),
    (["--limit", "2", "--confidence", "1.5"], "--confidence"),
    (["--limit", "-1"], "--limit"),
    (["--limit", "2", "--step", "5"], "--horizon"),
    (["--limit", "2", "--workers", "2", "--scheduler", "localhost:1"], "--workers"),
    (["--limit", "2", "--scheduler", "no-port"], "--scheduler"),
    (["--limit", "2", "--pilot-paths", "1"], "--pilot-paths"),
    (["--limit", "2", "--max-paths", "1"], "--max-paths"),
    (["--limit", "2", "--plant", "x.plant.toml"], "--plant"),
])
def test_cli_bad_input(files: tuple[Path, Path], extra: list[str], named: str) -> None:
    system, gains = files
    r = _cli(str(system), "--controller", str(gains), "--horizon", "10", *extra)
    assert r.returncode == 2, (r.stdout, r.stderr)
    assert named in r.stderr and "Traceback" not in r.stderr
    assert r.stdout == ""


def test_cli_budget_spent_is_exit_5(files: tuple[Path, Path]) -> None:
    system, gains = files
    r = _cli(str(system), "--controller", str(gains), "--limit", "3", "--horizon", "10", "--step", "0.1",
             "--disturbance", "step", "--method", "crude", "--max-paths", "500")
    assert r.returncode == 5, r.stderr
    assert "imprecise" in r.stdout and "estimate:" in r.stdout


def test_fmu_backend_scores_the_same_paths(loop: tuple) -> None:
    """The FMU Monte Carlo (LinearJumpPlant, isolated child) gives the scores of the numpy
    reference on the same chain paths (the FMU integrates the same sampled loop)."""
    system, controller = loop
    paths = sample_paths(system.chain, T, 12, 3, beta=system.chain.midpoint())
    spec = SimulationSpec(step=0.1, horizon=T, seed=3, disturbance="step")
    env = output_envelope(1.0)
    ref = path_scores(system, controller, env, spec, "reference")(paths)
    fmu = path_scores(system, controller, env, spec, "fmu")(paths)
    assert np.max(np.abs(ref - fmu)) < 1e-6
    assert np.any(ref >= 1.0) and np.any(ref < 1.0)


def test_optional_stages_receive_the_envelope_constraints(loop: tuple) -> None:
    """The bound stage gets the closed loop, one H per joint state and the limit, x0 and the
    disturbance energy (step: T); the timing stage the chain and the interval; both
    results land in the JSON."""
    from dataclasses import dataclass

    from ftc_verify.analysis.closedloop import ClosedLoop

    @dataclass(frozen=True)
    class Fake:
        value: float
        reason: str

    seen: dict = {}

    def bound(loop: ClosedLoop, constraints: list, *, x0: np.ndarray, disturbance_energy: float) -> Fake:
        seen.update(n=loop.n, constraints=constraints, x0=x0, energy=disturbance_energy)
        return Fake(0.5, "fake")

    system, controller = loop
    res = run_risk(system, controller, output_envelope(2.0), horizon=T, step=0.1, disturbance="step",
                   settings=Settings(method="crude", max_paths=500), bound=bound,
                   timing=lambda chain, interval: Fake(interval, chain.describe()), interval=3.0)
    (hs, level), = seen["constraints"]
    assert level == 2.0 and len(hs) == system.chain.n_states and all(h.shape == (1, seen["n"]) for h in hs)
    assert seen["energy"] == T and seen["x0"].shape == (seen["n"],)
    d = res.to_dict()
    assert d["upper_bound"] == {"value": 0.5, "reason": "fake"} and d["timing"]["value"] == 3.0
    assert len(d["ci"]) == 2 and d["method"] == "crude"


@pytest.mark.parametrize("bad", [{"method": "smc"}, {"relative_error": 0.0}, {"confidence": 1.0},
                                 {"max_paths": 1}, {"seed": -1}])
def test_settings_refuse_bad_values(bad: dict) -> None:
    from ftc_verify.errors import ValidationError

    with pytest.raises(ValidationError, match=next(iter(bad)).split("_")[0]):
        Settings(**bad)


def test_cli_says_when_the_pilot_never_reached_the_limit(files: tuple[Path, Path]) -> None:
    """A limit no path can reach (|x| <= T - tau < 20): estimate 0, exit 5, and the note."""
    system, gains = files
    r = _cli(str(system), "--controller", str(gains), "--limit", "20", "--horizon", "10", "--step", "0.1",
             "--disturbance", "step", "--max-paths", "500", "--pilot-paths", "100")
    assert r.returncode == 5, r.stderr
    assert "estimate: 0 " in r.stdout and "no pilot round reached the limit" in r.stdout


def test_horizon_plot_is_written_whole_or_refused_naming_the_option(tmp_path: Path) -> None:
    """plot_risk_by_horizon writes a PNG (a zero estimate included) through
    verification.plots.save_figure, and a folder that does not exist is one error naming
    ``--plot`` with nothing left behind."""
    from ftc_verify.errors import ValidationError
    from ftc_verify.risk.estimate import Estimate
    from ftc_verify.risk.horizon import plot_risk_by_horizon

    def est(p: float) -> Estimate:
        return Estimate(p, (0.5 * p, 1.5 * p), 0.25 * p, 0.5, 100, int(p > 0), "importance", "normal", 0.95,
                        True, 1, {}, 0, ())

    out = tmp_path / "risk.png"
    plot_risk_by_horizon([1.0, 2.0, 4.0], [est(0.0), est(1e-6), est(1e-4)], out)
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and list(tmp_path.iterdir()) == [out]
    with pytest.raises(ValidationError, match=r"--plot .*cannot write"):
        plot_risk_by_horizon([1.0], [est(1e-3)], tmp_path / "missing" / "risk.png")
    assert list(tmp_path.iterdir()) == [out]
