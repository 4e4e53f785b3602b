"""The Dask options' contract (issue 22, items 3-6): misuse refused up front and in bounded
time, a signal ends a cluster run with 143/130 and one line, leaving nothing in the temp
folder and no process behind, and a batch whose worker keeps dying is a PlantRunError."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from types import SimpleNamespace

import cli_inprocess
import numpy as np
import pytest

distributed = pytest.importorskip("distributed")

from ftc_verify.controllers import load_controller
from ftc_verify.errors import FMUError, PlantRunError, ValidationError
from ftc_verify.model.files import load_system
from ftc_verify.plants.plant_map import load_plant_map
from ftc_verify.simulation import cluster
from ftc_verify.simulation.cluster import check_cluster_options, max_workers, open_client
from ftc_verify.simulation.delta import DeltaSchedule
from ftc_verify.simulation.paths import sample_paths
from ftc_verify.simulation.spec import SimulationSpec

sys.path.insert(0, str(Path(__file__).resolve().parent))
from session_cache import shared_plant

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "examples" / "paper.toml"
GAINS = ROOT / "examples" / "paper_gains.toml"
SLACK = 8.0  # seconds of start-up and load on 2 busy cores on top of a time-box
BOX = 2.0  # the time box these tests give (--connect-timeout / connect_timeout; 10 s by default)


def _cli(*args: str, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    """``ftc-verify ARGS`` in this process (``tests/cli_inprocess.py``: the exit code and
    output a subprocess gives), for the refusals whose claim is the output; the signal
    tests below run real subprocesses."""
    return cli_inprocess.run_cli(args, timeout=timeout)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def temp_dir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """This test's temporary folder for this process (``tempfile``) and its children. The
    process's fork server for local workers is started first (``cluster.start_fork_server``):
    ``multiprocessing`` keeps its socket in a folder of the temporary folder of that moment
    for the life of the process, which is not what a run leaves behind."""
    cluster.start_fork_server()
    folder = tmp_path / "tmp"
    folder.mkdir()
    monkeypatch.setenv("TMPDIR", str(folder))
    monkeypatch.setattr(tempfile, "tempdir", str(folder))
    return folder


# ------------------------------------------------------------------ item 3: --scheduler
def test_scheduler_address_syntax_is_checked_without_dask() -> None:
    for good in ("tcp://10.0.0.5:8786", "10.0.0.5:8786", "tls://host.example:8786", "tcp://[::1]:8786"):
        check_cluster_options(None, good)
    for bad, why in (("10.0.0.5", "not a scheduler address"), ("http://h:80", "unknown protocol"),
                     ("tcp://h:99999", "not in 1..65535"), ("tcp://:8786", "not a scheduler address")):
        with pytest.raises(ValidationError, match=why) as err:
            check_cluster_options(None, bad)
        assert str(err.value).startswith(f"--scheduler {bad!r}")


@pytest.mark.slow(4)  # seconds measured on 2 busy cores: scheduled first
def test_an_http_server_is_not_a_scheduler(tmp_path: Path) -> None:
    """``--scheduler`` at an HTTP server's port: exit 2 within the time-box
    (``--connect-timeout``), one line naming the option and the address (it used to wait
    forever)."""
    port = _free_port()
    server = subprocess.Popen([sys.executable, "-m", "http.server", str(port), "--bind", "127.0.0.1"],
                              cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        for _ in range(100):
            try:
                socket.create_connection(("127.0.0.1", port), timeout=1).close()
                break
            except OSError:
                time.sleep(0.1)
        address = f"tcp://127.0.0.1:{port}"
        start = time.monotonic()
        out = _cli("simulate", str(PAPER), "--gains", str(GAINS), "--backend", "reference", "--paths", "2",
                   "--horizon", "1", "--scheduler", address, "--connect-timeout", f"{BOX:g}", timeout=120)
        took = time.monotonic() - start
    finally:
        server.terminate()
        server.wait(timeout=30)
    assert out.returncode == 2, out.stderr
    assert out.stderr.count("\n") == 1 and "Traceback" not in out.stderr
    assert "--scheduler" in out.stderr and address in out.stderr
    assert took < BOX + SLACK


def _silent_server() -> tuple[socket.socket, threading.Thread]:
    """A server that accepts connections and never answers (closed by the caller)."""
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen()
    held: list[socket.socket] = []

    def serve() -> None:
        while True:
            try:
                held.append(srv.accept()[0])
            except OSError:
                return

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    return srv, thread


@pytest.mark.slow(2)  # seconds measured on 2 busy cores: scheduled first
@pytest.mark.parametrize("kind", ["silent", "closed"])
def test_a_silent_server_or_a_closed_port_is_refused_within_the_time_box(kind: str) -> None:
    srv, _ = _silent_server()
    port = srv.getsockname()[1] if kind == "silent" else _free_port()
    address = f"tcp://127.0.0.1:{port}"
    start = time.monotonic()
    try:
        with pytest.raises(ValidationError, match="--scheduler") as err:
            with open_client(scheduler=address, connect_timeout=BOX):
                pytest.fail("connected to a server that is no scheduler")
    finally:
        try:
            srv.shutdown(socket.SHUT_RDWR)  # wakes the accepting thread
        except OSError:
            pass
        srv.close()
    assert address in str(err.value)
    took = time.monotonic() - start
    assert took < BOX + 3
    if kind == "closed":  # refused at once, not after Dask's connect retries for its timeout
        assert "connection refused" in str(err.value) and took < 5
    else:
        assert f"no Dask scheduler answered within {BOX:g} s" in str(err.value)


# ------------------------------------------------------------------ item 4: --workers
def test_workers_are_bounded_by_cores_and_memory(monkeypatch: pytest.MonkeyPatch) -> None:
    bound = max_workers()
    assert 1 <= bound <= (os.cpu_count() or 1) * cluster.WORKERS_PER_CORE
    check_cluster_options(bound, None)
    with pytest.raises(ValidationError, match=rf"^--workers 100000: above the bound of {bound} ") as err:
        check_cluster_options(100000, None)
    assert f"give at most {bound}" in str(err.value)
    with pytest.raises(ValidationError, match="--workers 0: must be at least 1"):
        check_cluster_options(0, None)
    monkeypatch.setenv("FTC_VERIFY_MEMORY_LIMIT", str(3 * cluster.WORKER_MEMORY))
    assert max_workers() == min(3, bound)
    monkeypatch.setenv("FTC_VERIFY_MEMORY_LIMIT", "1M")
    assert max_workers() == 1  # always room for one
    with pytest.raises(ValidationError, match="--workers 2: above the bound of 1"):
        with open_client(workers=2):
            pytest.fail("a cluster above the bound was started")


def test_cli_refuses_too_many_workers_at_once() -> None:
    start = time.monotonic()
    out = _cli("simulate", str(PAPER), "--gains", str(GAINS), "--backend", "reference", "--paths", "2",
               "--horizon", "1", "--workers", "100000", timeout=120)
    assert out.returncode == 2 and out.stderr.count("\n") == 1, out.stderr
    assert out.stderr.startswith("ftc-verify: --workers 100000: above the bound of") or "--workers 100000" in out.stderr
    assert time.monotonic() - start < 30


# ------------------------------------------------------------------ item 5: signals
def _session(pid: int) -> list[int]:
    """The processes still in the session led by ``pid`` (Linux /proc)."""
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[3]) == pid:  # field 6 of stat: the session id
                found.append(int(entry.name))
    return found


def _wait_for(condition: object, proc: subprocess.Popen[str], seconds: float, what: str) -> None:
    deadline = time.monotonic() + seconds
    while not condition():  # type: ignore[operator]
        if proc.poll() is not None:
            pytest.fail(f"the command ended ({proc.returncode}) before {what}: {proc.stderr.read() if proc.stderr else ''}")
        if time.monotonic() > deadline:
            proc.kill()
            pytest.fail(f"no {what} within {seconds} s")
        time.sleep(0.1)


def _interrupt(tmp: Path, cache: Path, args: list[str], ready: object, sig: int, group: bool) -> tuple[int, str]:
    """Run ``ftc-verify ARGS`` with TMPDIR ``tmp`` in a new session, send ``sig`` once
    ``ready(tmp)`` holds (to the whole process group with ``group``, as a terminal does);
    the exit code and stderr, after checking that no process of the session is left and
    that ``tmp`` is empty."""
    env = os.environ | {"TMPDIR": str(tmp), "FTC_VERIFY_CACHE": str(cache)}
    proc = subprocess.Popen([sys.executable, "-m", "ftc_verify", *args], stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True, env=env, start_new_session=True)
    try:
        _wait_for(lambda: ready(tmp), proc, 240, "cluster")  # type: ignore[operator]
        if group:
            os.killpg(proc.pid, sig)
        else:
            os.kill(proc.pid, sig)
        _, err = proc.communicate(timeout=90)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    deadline = time.monotonic() + 15
    while (_session(proc.pid) or list(tmp.iterdir())) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert _session(proc.pid) == [], "worker processes outlived the command"
    assert sorted(p.name for p in tmp.iterdir()) == [], f"left in the temporary folder: {sorted(tmp.rglob('*'))}, {proc.returncode}, {err!r}"
    return proc.returncode, err


def _cluster_started(tmp: Path) -> bool:
    return any(tmp.glob("ftc-verify-cluster-*"))


def _fmu_workers_busy(tmp: Path) -> bool:
    return len(list(tmp.glob("ftc-verify-cluster-*/ftc-verify-fmu-*"))) >= 2


@pytest.fixture(scope="module")
def fmu_cache(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("cache")


@pytest.mark.slow(20)  # seconds measured on 2 busy cores: scheduled first
def test_sigterm_while_the_local_cluster_starts(tmp_path: Path, fmu_cache: Path) -> None:
    """SIGTERM as soon as the cluster's run folder exists (the workers are starting):
    143, one line, no scheduler folder or process left."""
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    code, err = _interrupt(tmp, fmu_cache, ["simulate", str(PAPER), "--gains", str(GAINS), "--backend", "reference",
                                            "--paths", "100000", "--horizon", "5", "--workers", "2"],
                           _cluster_started, signal.SIGTERM, group=False)
    assert (code, err) == (143, "ftc-verify: terminated\n")


@pytest.mark.slow(40)  # seconds measured on 2 busy cores: scheduled first
@pytest.mark.parametrize("sig, code, line", [(signal.SIGTERM, 143, "ftc-verify: terminated"),
                                             (signal.SIGINT, 130, "ftc-verify: interrupted")])
def test_a_signal_during_an_fmu_run_on_workers(tmp_path: Path, fmu_cache: Path, sig: int, code: int,
                                               line: str) -> None:
    """SIGTERM to the command, or SIGINT to its process group (Ctrl-C), once both workers
    have extracted the FMU: the exit code and one line on stderr (no traceback, no Dask
    log), nothing left in TMPDIR (FMU copies, extracted FMUs, Dask folders), no process."""
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    got, err = _interrupt(tmp, fmu_cache, ["simulate", str(PAPER), "--gains", str(GAINS), "--backend", "fmu",
                                           "--workers", "2", "--paths", "400", "--horizon", "30", "--seed", "1"],
                          _fmu_workers_busy, sig, group=sig == signal.SIGINT)
    assert (got, err) == (code, line + "\n")


# ------------------------------------------------------------------ a crashing plant FMU on workers
@pytest.fixture(scope="module")
def crash_plant(shared_tmp: Path) -> Path:
    """The crashing plant, built once per session (``tests/session_cache.py``; read only)."""
    return shared_plant(shared_tmp, "crash")


@pytest.mark.slow(20)  # seconds measured on 2 busy cores: scheduled first
def test_a_batch_whose_worker_keeps_dying_is_a_plant_run_error(crash_plant: Path, temp_dir: Path) -> None:
    """The plant segfaults once t > 2: the batch of the paths of horizon 4 kills every
    worker that runs it; after the allowed deaths the run raises PlantRunError naming the
    FMU and that batch's path range (the batch of short paths is fine)."""
    from ftc_verify.simulation.fmu_workers import run_fmu_batches

    plant = load_plant_map(crash_plant / "plant.toml")
    system, controller = load_system(crash_plant / "system.toml"), load_controller(crash_plant / "K.toml")
    paths = sample_paths(system.chain, 1.5, 2, 1) + sample_paths(system.chain, 4.0, 2, 2)
    with open_client(workers=2) as client:
        with pytest.raises(PlantRunError) as err:
            run_fmu_batches(client, system, plant, controller, paths,
                            spec=SimulationSpec(step=0.01, delta=DeltaSchedule("zero"), batch=2),
                            rng=np.random.default_rng(0))
    assert err.value.batch == (2, 4) and err.value.path is None
    assert err.value.fmu == str(plant.fmu)
    assert f"died {cluster.ALLOWED_FAILURES + 1} times" in err.value.detail
    assert str(err.value).startswith(f"{plant.fmu}: the plant FMU failed on paths[2:4]")
    assert list(temp_dir.iterdir()) == []


def test_other_task_errors_come_back_as_themselves(crash_plant: Path, temp_dir: Path) -> None:
    """A task that raises (an FMU that is no FMU) gives that exception, not a PlantRunError."""
    from ftc_verify.simulation.fmu_workers import run_fmu_batches

    plant = load_plant_map(crash_plant / "plant.toml")
    bad = temp_dir.parent / "bad.fmu"
    bad.write_bytes(b"not a zip archive")
    fake = SimpleNamespace(fmu=bad, tolerance=plant.tolerance, injection_map=plant.injection_map)
    system, controller = load_system(crash_plant / "system.toml"), load_controller(crash_plant / "K.toml")
    with open_client(workers=1) as client:
        with pytest.raises(FMUError) as err:
            run_fmu_batches(client, system, fake, controller, sample_paths(system.chain, 1.0, 2, 1),
                            spec=SimulationSpec(step=0.01, delta=DeltaSchedule("zero"), batch=1),
                            rng=np.random.default_rng(0))
    assert not isinstance(err.value, PlantRunError)
    assert list(temp_dir.iterdir()) == []
