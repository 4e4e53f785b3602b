"""Monte Carlo on Dask (ftc_verify.simulation.cluster, ``simulate``/``verify --workers/--scheduler``):
serial, a local cluster of 2 workers and an existing scheduler's address give identical
numbers for a seed (every batch carries the generator state of a serial run), on the
reference backend and on FMUs loaded once per worker; misuse is one error, exit 2."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import cli_inprocess
import numpy as np
import pytest

distributed = pytest.importorskip("distributed")

from paper_run import PAPER_VERIFY_OPTIONS

from ftc_verify.controllers import load_controller
from ftc_verify.model.files import load_system
from ftc_verify.simulation.batches import fmu_monte_carlo
from ftc_verify.simulation.cluster import open_client, start_fork_server
from ftc_verify.simulation.delta import DeltaSchedule
from ftc_verify.simulation.paths import sample_paths
from ftc_verify.simulation.streaming import simulate_streaming
from ftc_verify.simulation.supervisor import simulate_fmu

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "examples" / "paper.toml"
GAINS = ROOT / "examples" / "paper_gains.toml"


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    """``simulate`` of the paper's gains with ``args``: with ``--workers`` or ``--scheduler``
    as a user runs it (a subprocess: its Dask cluster or client is the process's own), the
    serial runs they are compared with in this process (``tests/cli_inprocess.py``)."""
    argv = ["simulate", str(PAPER), "--gains", str(GAINS), *args]
    if "--workers" in args or "--scheduler" in args:
        return subprocess.run([sys.executable, "-m", "ftc_verify", *argv], capture_output=True, text=True, timeout=600)
    return cli_inprocess.run_cli(argv)


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


@pytest.fixture(scope="module")
def scheduler() -> Iterator[str]:
    """The address of an existing 2-worker cluster, started once for the tests that reach
    it by ``--scheduler`` (each command connects as a new client). Module-scoped, not one
    per session: an idle 2-worker cluster costs about 12 % of a core (3.5 s of CPU per
    30 s, measured), which over a session outweighs the 2-3 s of CPU of a start. Started
    by ``open_client`` (no client of its own: ``wait=False``), so its workers are forked
    from the test process's fork server like every local cluster's here."""
    with open_client(workers=2, wait=False) as start:
        yield start.cluster().scheduler_address


@pytest.mark.slow(6)  # seconds on 2 busy cores (--durations at load 9, / 4): scheduled first
def test_cli_scheduler_address_equals_serial(scheduler: str) -> None:
    args = ["--backend", "reference", "--paths", "40", "--horizon", "5", "--seed", "6", "--delta", "random", "--json"]
    serial = _cli(*args)
    assert serial.returncode == 0, serial.stderr
    remote = _cli(*args, "--scheduler", scheduler)
    assert remote.returncode == 0, remote.stderr
    a, b = json.loads(serial.stdout), json.loads(remote.stdout)
    assert a["y_norm"] == b["y_norm"] and a["w_norm"] == b["w_norm"] and a["switches"] == b["switches"]


def _verify(out: Path, serial: SimpleNamespace, *args: str) -> tuple[subprocess.CompletedProcess[str], dict]:
    """``verify`` of the paper's gains with the options and the FMU cache (its path is in the
    report) of the session's serial run ``serial`` (``paper_verify_run`` in conftest.py), and ``args``."""
    run = subprocess.run([sys.executable, "-m", "ftc_verify", "verify", str(PAPER), "--gains", str(GAINS),
                          *PAPER_VERIFY_OPTIONS, "--out", str(out), *args], capture_output=True, text=True, timeout=600,
                         env=os.environ | {"FTC_VERIFY_CACHE": str(serial.cache)})
    report = json.loads((out / "report.json").read_text()) if run.returncode == 0 else {}
    return run, report


def _without_timings(value: object) -> object:
    if isinstance(value, dict):
        return {k: _without_timings(v) for k, v in value.items() if not (k.endswith("seconds") or k == "timings")}
    if isinstance(value, list):
        return [_without_timings(v) for v in value]
    return value


@pytest.mark.slow(13)  # seconds measured on 2 busy cores: scheduled first
@pytest.mark.parametrize("where", ["two-workers", "scheduler"])
def test_verify_serial_two_workers_and_scheduler_give_identical_reports(tmp_path: Path, where: str,
                                                                        paper_verify_run: SimpleNamespace,
                                                                        request: pytest.FixtureRequest) -> None:
    """The FMU Monte Carlo of ``verify`` (random Delta per segment, so every batch needs
    its generator state) serially, on 2 local workers and on an existing scheduler (one
    case each, so that the two pytest-xdist workers share them): report.json identical
    apart from timings. The serial run is the session's (``paper_verify_run``: the same
    command without ``--workers``/``--scheduler``)."""
    serial = paper_verify_run
    a = json.loads((serial.out / "report.json").read_text()) if serial.returncode == 0 else {}
    options = ["--workers", "2"] if where == "two-workers" else ["--scheduler", request.getfixturevalue("scheduler")]
    spread, b = _verify(tmp_path / where, serial, *options)
    for run in (serial, spread):
        assert run.returncode == 0, run.stderr
    assert load_system(PAPER).uncertain  # so Delta is drawn per segment and the batches need their states
    assert a["mc"]["paths"] == 30 and a["verdict"] == "pass"
    assert _without_timings(a) == _without_timings(b)


@pytest.mark.slow(12)  # seconds on 2 busy cores (--durations at load 9, / 4): scheduled first
def test_simulate_fmu_backend_on_two_workers_equals_serial() -> None:
    """``simulate --backend fmu --workers 2``: batches of 25 paths on workers that each load
    the FMU once; the JSON equals the serial run's (random Delta, so the generator states
    matter), including the FMU's file and model identifier."""
    args = ["--backend", "fmu", "--paths", "60", "--horizon", "4", "--seed", "2", "--delta", "random", "--json"]
    serial, spread = _cli(*args), _cli(*args, "--workers", "2")
    assert serial.returncode == 0 and spread.returncode == 0, serial.stderr + spread.stderr
    a, b = json.loads(serial.stdout), json.loads(spread.stdout)
    assert a["paths"] == 60 and a == b


def test_cluster_misuse_is_one_error() -> None:
    """Refused before any cluster is started or reached, so in this process
    (``tests/cli_inprocess.py``: the exit code and the lines a subprocess gives)."""
    run = cli_inprocess.run_cli
    out = run(["simulate", str(PAPER), "--gains", str(GAINS), "--backend", "fmu", "--workers", "2", "--fmu-log"])
    assert out.returncode == 2 and "--fmu-log" in out.stderr and out.stderr.count("\n") == 1
    out = run(["simulate", str(PAPER), "--gains", str(GAINS), "--backend", "reference", "--scheduler",
               "tcp://127.0.0.1:9", "--paths", "2"])
    assert out.returncode == 2 and "--scheduler" in out.stderr and "Traceback" not in out.stderr
    out = run(["verify", str(PAPER), "--gains", str(GAINS), "--workers", "2", "--fmu-log"])
    assert out.returncode == 2 and "--fmu-log" in out.stderr and out.stderr.count("\n") == 1
    out = run(["simulate", str(PAPER), "--gains", str(GAINS), "--workers", "2", "--connect-timeout", "2"])
    assert out.returncode == 2 and out.stderr.count("\n") == 1 and "--connect-timeout 2: only with --scheduler" \
        in out.stderr


def _die_if_first(marker: str) -> None:
    """In a worker: SIGKILL this process if it takes (removes) the marker file first."""
    try:
        os.unlink(marker)
    except FileNotFoundError:
        return
    os.kill(os.getpid(), signal.SIGKILL)


def _arm_reference(marker: str) -> None:
    """Run on the workers: the first reference batch a worker process starts after taking
    the marker kills the process (one process in all)."""
    from ftc_verify.simulation import streaming

    batch = streaming._energies_batch

    def dying(*args: Any) -> Any:
        _die_if_first(marker)
        return batch(*args)

    streaming._energies_batch = dying


@pytest.mark.slow(5)  # seconds measured on 2 busy cores: scheduled first
def test_a_lost_worker_costs_a_retry_not_the_run(tmp_path: Path) -> None:
    """Without depending on timing: one of two workers is killed before the run and the
    other kills itself in its first batch; the tasks are rescheduled on the workers the
    nannies start in their place, and the numbers equal a serial run. 80 paths of 5 s in
    20 batches of 4 (the deaths are set off by the run, not by its length: 20 s paths,
    from when a worker was killed after a sleep, cost 3x the simulation for the same claim)."""
    system, gains = load_system(PAPER), load_controller(GAINS)
    paths = sample_paths(system.chain, 5.0, 80, 5)
    serial = simulate_streaming(system, gains, paths, step=0.01, rng=np.random.default_rng(1), batch=4)
    marker = tmp_path / "die-once"
    marker.touch()
    with open_client(workers=2) as client:
        pids = client.run(os.getpid)
        client.run(_arm_reference, str(marker))
        os.kill(min(pids.values()), signal.SIGKILL)
        spread = simulate_streaming(system, gains, paths, step=0.01, rng=np.random.default_rng(1), batch=4,
                                    client=client)
    assert not marker.exists(), "no worker died in a batch"
    np.testing.assert_array_equal(spread.y_norm, serial.y_norm)


def _arm(marker: str, phase: str) -> None:
    """Run on the workers: from now on, the first FMU supervisor this worker process opens
    (``phase`` "setup") or runs a batch on ("run") kills the process with SIGKILL -- if it
    takes the marker file first (one process in all does: the marker is removed by it)."""
    from ftc_verify.simulation import fmu_workers

    base = fmu_workers.Supervisor

    def die_if_first() -> None:
        _die_if_first(marker)

    class Dying(base):  # type: ignore[misc, valid-type]
        def __init__(self, fmu: Any, mapping: Any, *, system: Any, tolerance: Any) -> None:
            if phase == "setup":
                die_if_first()
            super().__init__(fmu, mapping, system=system, tolerance=tolerance)

        def run(self, paths: Any, controller: Any, *, spec: Any, rng: Any) -> Any:
            if phase == "run":
                die_if_first()
            return super().run(paths, controller, spec=spec, rng=rng)

    fmu_workers.Supervisor = Dying


def _fmu_run_with_losses(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, phase: str, kill_first: bool) -> None:
    """The FMU backend on two workers armed with :func:`_arm` (``phase``), one of them
    SIGKILLed before the run with ``kill_first``: the marker is taken (a worker died in
    that phase), the records equal a serial run's and the temporary folder is empty (the
    process's fork server for local workers, whose socket ``multiprocessing`` keeps in a
    folder of the temporary folder of the moment for the life of the process, started first)."""
    start_fork_server()
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    monkeypatch.setenv("TMPDIR", str(tmp))
    monkeypatch.setattr(tempfile, "tempdir", str(tmp))
    system, gains = load_system(PAPER), load_controller(GAINS)
    paths = sample_paths(system.chain, 5.0, 40, 5)
    delta = DeltaSchedule("random")
    serial = simulate_fmu(system, gains, paths, step=0.01, delta=delta, rng=np.random.default_rng(1))
    marker = tmp_path / "die-once"
    marker.touch()
    with open_client(workers=2) as client:
        pids = client.run(os.getpid)
        client.run(_arm, str(marker), phase)
        if kill_first:
            os.kill(min(pids.values()), signal.SIGKILL)
        spread = fmu_monte_carlo(system, gains, paths, step=0.01, delta=delta, rng=np.random.default_rng(1),
                                 batch=5, client=client)
    assert not marker.exists(), f"no worker died in the {phase} phase"
    assert len(spread.records) == 40
    for a, b in zip(spread.records, serial.records):
        np.testing.assert_array_equal(a.x, b.x)
        np.testing.assert_array_equal(a.y, b.y)
    assert list(tmp.iterdir()) == []  # the run folder, with what the killed workers left, is gone


@pytest.mark.slow(9)  # seconds measured on 2 busy cores: scheduled first
def test_a_lost_fmu_worker_costs_a_retry_not_the_run(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The FMU backend, without depending on timing: one worker is killed before the run
    and the other kills itself in its first batch; the batches are retried on the
    workers the nannies start in their place (each writes and opens the FMU itself), and
    the records equal a serial run's."""
    _fmu_run_with_losses(tmp_path, monkeypatch, "run", kill_first=True)


@pytest.mark.slow(9)  # seconds measured on 2 busy cores: scheduled first
def test_a_worker_lost_while_it_opens_the_fmu_costs_a_retry(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The set-up phase (issue 22, item 6: a worker lost while the FMU was being
    registered killed the run): the first worker to open the FMU dies doing it; its
    batch is retried and the records equal a serial run's."""
    _fmu_run_with_losses(tmp_path, monkeypatch, "setup", kill_first=False)
