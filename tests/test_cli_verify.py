"""``simulate``, ``verify`` and ``build-fmus`` commands: outputs, reports, exit codes."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path
from types import SimpleNamespace

import cli_inprocess
import pytest

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "examples" / "paper.toml"
GAINS = ROOT / "examples" / "paper_gains.toml"
PNG = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(autouse=True)
def _cache(tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("FTC_VERIFY_CACHE", str(tmp_path_factory.getbasetemp() / "cache"))


def run_cli(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    """``ftc-verify ARGS`` in this process (``tests/cli_inprocess.py``: exit code, stdout and
    stderr as a subprocess gives them)."""
    return cli_inprocess.run_cli(args, cwd)


@pytest.mark.parametrize("backend", ["reference", "fmu"])
def test_simulate_json_and_plot(tmp_path: Path, backend: str) -> None:
    plot = tmp_path / "fig1.png"
    proc = run_cli("simulate", str(PAPER), "--gains", str(GAINS), "--backend", backend, "--paths", "3",
                   "--horizon", "10", "--seed", "5", "--json", "--plot", str(plot))
    assert proc.returncode == 0, proc.stderr
    d = json.loads(proc.stdout)
    assert d["paths"] == 3 and d["seed"] == 5 and d["backend"] == backend
    assert len(d["y_norm"]) == len(d["w_norm"]) == len(d["switches"]) == 3
    assert all(0 < y < w for y, w in zip(d["y_norm"], d["w_norm"]))  # attenuation below 1 on the paper's loop
    assert plot.read_bytes()[:8] == PNG


def test_simulate_backends_agree_on_same_seed() -> None:
    common = ("simulate", str(PAPER), "--gains", str(GAINS), "--paths", "2", "--horizon", "5", "--seed", "9",
              "--delta", "random", "--json")
    fmu = json.loads(run_cli(*common, "--backend", "fmu").stdout)
    ref = json.loads(run_cli(*common, "--backend", "reference").stdout)
    assert fmu["y_norm"] == pytest.approx(ref["y_norm"], rel=1e-8)
    assert fmu["switches"] == ref["switches"]


def test_simulate_bad_input_exit_2(tmp_path: Path) -> None:
    for args in (["--paths", "0"], ["--step", "-1"], ["--disturbance", "noise"], ["--seed", "x"]):
        proc = run_cli("simulate", str(PAPER), "--gains", str(GAINS), *args)
        assert proc.returncode == 2 and "Traceback" not in proc.stderr, args


@pytest.mark.slow(11)  # seconds on 2 busy cores (--durations at load 9, / 4): scheduled first
def test_verify_given_gains_writes_report(paper_verify_run: SimpleNamespace) -> None:
    """``verify examples/paper.toml --gains examples/paper_gains.toml --paths 30 --horizon 15
    --step 0.01 --seed 3`` (run once per session by the ``paper_verify_run`` fixture, which
    other tests read too; 0.01 is also the default step)."""
    out, proc = paper_verify_run.out, paper_verify_run
    assert proc.returncode == 0, proc.stdout + proc.stderr
    d = json.loads((out / "report.json").read_text())
    assert d["verdict"] == "pass"
    assert d["gamma_certified"] == pytest.approx(0.4983, abs=2e-3)
    assert d["exact_energy_ratio"] <= d["gamma_certified"] ** 2
    low = d["gamma_lower_bound"]
    assert low["proved"] and low["value"] <= d["gamma_certified"] <= 1.05 * low["value"]  # the bracket is tight
    assert d["mc"]["paths"] == 30 and d["mc"]["mean_ratio"] <= d["mc"]["upper_bound"] <= d["gamma_certified"] ** 2
    names = {c["name"] for c in d["checks"]}
    assert {"certified", "python-control per mode", "exact energy", "gamma bracket",
            "Monte Carlo (FMU)", "FMU vs reference"} <= names
    assert all(c["ok"] for c in d["checks"]) and d["seed"] == 3
    # the loop that runs (h = 0.01): its h_max, and its exact energy inside the simulated interval
    assert 0.08 < d["sampled"]["h_max"] < 0.09 and d["sampled"]["verdict"] == "stable"
    smc = d["sampled_mc"]
    assert smc["paths"] == 1000 and smc["decided"] and smc["seed"] == [3, 31] and smc["interval"][0] <= smc["exact"] <= smc["interval"][1]
    assert any(c["name"].startswith("Monte Carlo vs exact (sampled loop") for c in d["checks"])
    md = (out / "report.md").read_text()
    assert "Verdict: PASS" in md
    for png in ("fig1_path.png", "ratio_distribution.png", "gamma_bracket.png"):
        assert (out / png).read_bytes()[:8] == PNG
    assert not [p for p in out.iterdir() if p.name.startswith(".")]  # no staging leftovers
    assert [p.name for p in out.parent.iterdir() if p.name.startswith(".")] == [".tmp"]  # none beside it either
    assert not list((out.parent / ".tmp").iterdir())  # nor in its temporary folder


def test_verify_fails_for_unstable_gains(tmp_path: Path) -> None:
    gains = tmp_path / "zero.toml"
    gains.write_text("[[gain]]\nK = [[0.0, 0.0], [0.0, 0.0]]\n[[gain]]\nK = [[0.0, 0.0], [0.0, 0.0]]\n")
    out = tmp_path / "r"
    proc = run_cli("verify", str(PAPER), "--gains", str(gains), "--paths", "5", "--out", str(out))
    assert proc.returncode == 1
    d = json.loads((out / "report.json").read_text())
    assert d["verdict"] == "fail" and d["gamma_certified"] is None
    assert any(c["name"] == "certified" and not c["ok"] for c in d["checks"])


def test_verify_bad_input_exit_2(tmp_path: Path) -> None:
    out = tmp_path / "never"
    proc = run_cli("verify", str(tmp_path / "missing.toml"), "--out", str(out))
    assert proc.returncode == 2 and "missing.toml" in proc.stderr and "Traceback" not in proc.stderr
    assert not out.exists()


def test_build_fmus_validates(tmp_path: Path) -> None:
    proc = run_cli("build-fmus", str(PAPER))
    assert proc.returncode == 0, proc.stderr
    assert "validated, no problems" in proc.stdout


@pytest.mark.slow(14)  # seconds on 2 busy cores (--durations at load 9, / 4): scheduled first
def test_incremental_measure_equals_total_on_a_linear_plant() -> None:
    """Superposition: on the LinearJumpPlant (linear, starting at the origin) the run with
    ``w = 0`` stays at zero, so the incremental records are the paths themselves and both
    measures give the same Monte Carlo numbers, with the same Delta draws (uncertain plant)."""
    import numpy as np

    from ftc_verify.controllers import load_controller
    from ftc_verify.model.files import load_system
    from ftc_verify.verification.verify import run_verify

    system, gains = load_system(PAPER), load_controller(GAINS)
    runs = {m: run_verify(system, controller=gains, paths=4, horizon=5.0, step=0.01, seed=3, measure=m)
            for m in ("total", "incremental")}
    a, b = runs["total"], runs["incremental"]
    assert a.mc is not None and b.mc is not None and a.mc.mean_ratio > 0
    assert b.mc.mean_ratio == pytest.approx(a.mc.mean_ratio, rel=1e-12)
    for ra, rb in zip(a.records, b.records):
        np.testing.assert_array_equal(ra.y, rb.y)
    assert b.options["measure"] == "incremental" and a.verdict == b.verdict  # 4 paths: a loose bound either way
    with pytest.raises(ValueError, match="measure"):
        run_verify(system, controller=gains, paths=4, measure="peak")
