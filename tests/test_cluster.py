"""Monte Carlo on Dask (ftc_verify.simulation.cluster, ``simulate``/``verify --workers/--scheduler``):
serial, a local cluster of 2 workers and an existing scheduler's address give identical
numbers for a seed (every batch carries the generator state of a serial run), on the
reference backend and on FMUs loaded once per worker; misuse is one error, exit 2."""

from __future__ import annotations

import json
import logging
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

distributed = pytest.importorskip("distributed")

from ftc_verify.controllers import load_controller  # noqa: E402
from ftc_verify.model.files import load_system  # noqa: E402
from ftc_verify.simulation.batches import fmu_monte_carlo  # noqa: E402
from ftc_verify.simulation.cluster import open_client  # noqa: E402
from ftc_verify.simulation.delta import DeltaSchedule  # noqa: E402
from ftc_verify.simulation.paths import sample_paths  # noqa: E402
from ftc_verify.simulation.streaming import simulate_streaming  # noqa: E402
from ftc_verify.simulation.supervisor import simulate_fmu  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "examples" / "paper.toml"
GAINS = ROOT / "examples" / "paper_gains.toml"


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "ftc_verify", "simulate", str(PAPER), "--gains", str(GAINS),
                           *args], capture_output=True, text=True, timeout=600)


def test_serial_and_two_workers_give_identical_numbers() -> None:
    system, gains = load_system(PAPER), load_controller(GAINS)
    paths = sample_paths(system.chain, 6.0, 30, 4)
    serial = simulate_streaming(system, gains, paths, step=0.01, delta="random", rng=np.random.default_rng(9),
                                batch=7)
    with open_client(workers=2) as client:
        assert len(client.scheduler_info()["workers"]) == 2
        spread = simulate_streaming(system, gains, paths, step=0.01, delta="random", rng=np.random.default_rng(9),
                                    batch=7, client=client)
    np.testing.assert_array_equal(spread.y_norm, serial.y_norm)
    np.testing.assert_array_equal(spread.w_norm, serial.w_norm)


def test_cli_scheduler_address_equals_serial() -> None:
    args = ["--backend", "reference", "--paths", "40", "--horizon", "5", "--seed", "6", "--delta", "random", "--json"]
    serial = _cli(*args)
    assert serial.returncode == 0, serial.stderr
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
                                  silence_logs=logging.ERROR) as cluster:
        remote = _cli(*args, "--scheduler", cluster.scheduler_address)
    assert remote.returncode == 0, remote.stderr
    a, b = json.loads(serial.stdout), json.loads(remote.stdout)
    assert a["y_norm"] == b["y_norm"] and a["w_norm"] == b["w_norm"] and a["switches"] == b["switches"]


def _verify(out: Path, *args: str) -> tuple[subprocess.CompletedProcess[str], dict]:
    run = subprocess.run([sys.executable, "-m", "ftc_verify", "verify", str(PAPER), "--gains", str(GAINS), "--paths", "30",
                          "--horizon", "5", "--seed", "3", "--out", str(out), *args],
                         capture_output=True, text=True, timeout=600)
    report = json.loads((out / "report.json").read_text()) if run.returncode == 0 else {}
    return run, report


def _without_timings(value: object) -> object:
    if isinstance(value, dict):
        return {k: _without_timings(v) for k, v in value.items() if not k.endswith("seconds")}
    if isinstance(value, list):
        return [_without_timings(v) for v in value]
    return value


@pytest.mark.slow(13)  # seconds measured on 2 busy cores: scheduled first
def test_verify_serial_two_workers_and_scheduler_give_identical_reports(tmp_path: Path) -> None:
    """The FMU Monte Carlo of ``verify`` (random Delta per segment, so every batch needs
    its generator state) serially, on 2 local workers and on an existing scheduler:
    report.json identical apart from timings."""
    serial, a = _verify(tmp_path / "serial")
    two, b = _verify(tmp_path / "two", "--workers", "2")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
                                  silence_logs=logging.ERROR) as cluster:
        remote, c = _verify(tmp_path / "remote", "--scheduler", cluster.scheduler_address)
    for run in (serial, two, remote):
        assert run.returncode == 0, run.stderr
    assert load_system(PAPER).uncertain  # so Delta is drawn per segment and the batches need their states
    assert a["mc"]["paths"] == 30 and a["verdict"] == "pass"
    assert _without_timings(a) == _without_timings(b) == _without_timings(c)


def test_simulate_fmu_backend_on_two_workers_equals_serial() -> None:
    """``simulate --backend fmu --workers 2``: batches of 25 paths on workers that each load
    the FMU once; the JSON equals the serial run's (random Delta, so the generator states
    matter), including the FMU's file and model identifier."""
    args = ["--backend", "fmu", "--paths", "60", "--horizon", "4", "--seed", "2", "--delta", "random", "--json"]
    serial, spread = _cli(*args), _cli(*args, "--workers", "2")
    assert serial.returncode == 0 and spread.returncode == 0, serial.stderr + spread.stderr
    a, b = json.loads(serial.stdout), json.loads(spread.stdout)
    assert a["paths"] == 60 and a == b


@pytest.mark.slow(12)  # seconds measured on 2 busy cores: scheduled first
def test_cluster_misuse_is_one_error() -> None:
    out = _cli("--backend", "fmu", "--workers", "2", "--fmu-log")
    assert out.returncode == 2 and "--fmu-log" in out.stderr and out.stderr.count("\n") == 1
    out = _cli("--backend", "reference", "--scheduler", "tcp://127.0.0.1:9", "--paths", "2")
    assert out.returncode == 2 and "--scheduler" in out.stderr and "Traceback" not in out.stderr
    out = subprocess.run([sys.executable, "-m", "ftc_verify", "verify", str(PAPER), "--gains", str(GAINS), "--workers",
                          "2", "--fmu-log"], capture_output=True, text=True, timeout=600)
    assert out.returncode == 2 and "--fmu-log" in out.stderr and out.stderr.count("\n") == 1


def _with_one_worker_killed(run: Callable[[Any], Any], after: float) -> Any:
    """``run(client)`` on a local cluster of two workers, one of which is killed (SIGKILL
    to its process) ``after`` seconds into the run; what ``run`` returned."""
    found: dict[str, Any] = {}
    with open_client(workers=2) as client:
        victim = sorted(client.run(os.getpid).items())[0][1]
        worker = threading.Thread(target=lambda: found.update(result=run(client)))
        worker.start()
        time.sleep(after)
        running = worker.is_alive()
        os.kill(victim, signal.SIGKILL)
        worker.join(timeout=300)
        assert running, "the run ended before the kill: make it longer"
        assert not worker.is_alive()
    return found["result"]


@pytest.mark.slow(5)  # seconds measured on 2 busy cores: scheduled first
def test_a_lost_worker_costs_a_retry_not_the_run() -> None:
    """One of two workers is killed while the batches run; its tasks are rescheduled, the
    nanny restarts it, and the numbers equal a serial run."""
    system, gains = load_system(PAPER), load_controller(GAINS)
    paths = sample_paths(system.chain, 20.0, 240, 5)
    serial = simulate_streaming(system, gains, paths, step=0.01, rng=np.random.default_rng(1), batch=4)
    spread = _with_one_worker_killed(  # 60 tasks of about 0.1 s each, under way after 1 s
        lambda client: simulate_streaming(system, gains, paths, step=0.01, rng=np.random.default_rng(1), batch=4,
                                          client=client), after=1.0)
    np.testing.assert_array_equal(spread.y_norm, serial.y_norm)


@pytest.mark.slow(9)  # seconds measured on 2 busy cores: scheduled first
def test_a_lost_fmu_worker_costs_a_retry_not_the_run(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The FMU backend: one of two workers is killed mid-run; its batches are retried on
    the other worker or on the nanny's replacement (which gets the FMU from the plugin the
    scheduler keeps), and the records equal a serial run's. The killed worker cannot remove
    its FMU folders: the workers' temporary folder is this test's."""
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    system, gains = load_system(PAPER), load_controller(GAINS)
    paths = sample_paths(system.chain, 20.0, 200, 5)
    delta = DeltaSchedule("random")
    serial = simulate_fmu(system, gains, paths, step=0.01, delta=delta, rng=np.random.default_rng(1))
    spread = _with_one_worker_killed(  # 40 tasks of about 0.1 s each, under way after 1.5 s
        lambda client: fmu_monte_carlo(system, gains, paths, step=0.01, delta=delta, rng=np.random.default_rng(1),
                                       batch=5, client=client), after=1.5)
    assert len(spread.records) == 200
    for a, b in zip(spread.records, serial.records):
        np.testing.assert_array_equal(a.x, b.x)
