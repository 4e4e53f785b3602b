"""A plant that crashes, fails or is interrupted never takes the tool's truthfulness with it (issue 22).

Reproductions, each on a plant FMU built here (:mod:`tests.fmu_plants`):

* item 1: a signal handler's exception raised while the FMU is inside its logger
  callback is not dropped by ctypes; SIGTERM and Ctrl-C during an FMU Monte Carlo on a
  stiff plant (whose ``fmi2DoStep`` dominates) end the run with 143 / 130, one line, and
  nothing left in the temporary folder;
* item 2: a plant whose C code segfaults after t = 2 is reported (FMU, path, time;
  exit 1; the report written) instead of ending the process with 139, and nothing is
  left behind;
* item 7: a plant whose ``fmi2DoStep`` returns ``fmi2Error`` after t = 2 (``sqrt`` of a
  negative number) is a result: failed paths in the JSON and in the report, exit 1;
* item 12: ``--delta random`` on an uncertain system whose map has no Delta inputs is
  refused, and ``verify`` says which Delta it used;
* item 14: the report of a run whose every path failed says so instead of printing None.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import cli_inprocess
import numpy as np
import pytest

from plant_stages import wait_for_fmu_steps
from session_cache import copied_plants
from ftc_verify.controllers import load_controller
from ftc_verify.errors import PlantRunError
from ftc_verify.model.files import load_system
from ftc_verify.plants.plant_map import load_plant_map
from ftc_verify.simulation.batches import fmu_monte_carlo
from ftc_verify.simulation.delta import DeltaSchedule
from ftc_verify.simulation.paths import sample_paths
from ftc_verify.simulation.supervisor import Supervisor

if shutil.which("gcc") is None:  # pragma: no cover
    pytest.skip("gcc is needed to compile the FMUs", allow_module_level=True)


@pytest.fixture(scope="module", autouse=True)
def _isolated_cache(tmp_path_factory: pytest.TempPathFactory):
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("FTC_VERIFY_CACHE", str(tmp_path_factory.mktemp("ftc-verify-cache")))
        yield


@pytest.fixture(scope="module")
def plants(tmp_path_factory: pytest.TempPathFactory, shared_tmp: Path) -> dict[str, Path]:
    """This process's copies of the plants built once per session (``tests/session_cache.py``)."""
    return copied_plants(shared_tmp, tmp_path_factory.mktemp("plants"),
                         {kind: (kind, "2.0") for kind in ("ok", "crash", "fail", "stiff")})


def _cli(args: list[str], cwd: Path, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    tmp = cwd / ".tmp"
    tmp.mkdir(exist_ok=True)
    env = os.environ | {"TMPDIR": str(tmp)}
    return subprocess.run([sys.executable, "-m", "ftc_verify", *args], capture_output=True, text=True, cwd=cwd,
                          env=env, timeout=timeout)


def _cli_here(args: list[str], cwd: Path) -> subprocess.CompletedProcess[str]:
    """:func:`_cli` in this process (``tests/cli_inprocess.py``), for the cases whose claim
    is the output and the files, not the process (the crashes, signals and Dask workers
    stay subprocesses)."""
    tmp = cwd / ".tmp"
    tmp.mkdir(exist_ok=True)
    return cli_inprocess.run_cli(args, cwd, {"TMPDIR": str(tmp)})


def _left(cwd: Path) -> list[str]:
    return sorted(str(p.relative_to(cwd)) for p in (cwd / ".tmp").rglob("*"))


def _loaded(folder: Path) -> tuple:
    return (load_system(folder / "system.toml"), load_controller(folder / "K.toml"),
            load_plant_map(folder / "plant.toml"))


# ------------------------------------------------------------------------------------------ item 1


def test_a_signal_inside_the_logger_callback_is_not_dropped(plants: dict[str, Path]) -> None:
    """The handler's exception raised inside the FMU's logger callback (here: the log sink
    raises KeyboardInterrupt at the 50th message, as a SIGINT handler would) ends the run
    after the FMI call returns; ctypes used to print it and drop it, and the run went on."""
    system, controller, plant = _loaded(plants["ok"])
    count = {"n": 0}

    def log(status: str, category: str, message: str) -> None:
        count["n"] += 1
        if count["n"] == 50:
            raise KeyboardInterrupt

    paths = sample_paths(system.chain, 4.0, 3, 1)
    with Supervisor(plant.fmu, plant.injection_map(), system=system, log=log) as sup:
        with pytest.raises(KeyboardInterrupt):
            sup.run(paths, controller, step=0.01)
        assert sup.stats["paths"] == 0 and count["n"] < 200  # stopped within the first path


@pytest.mark.slow(8)
@pytest.mark.parametrize("sig, code, line", [(signal.SIGTERM, 143, "ftc-verify: terminated"),
                                             (signal.SIGINT, 130, "ftc-verify: interrupted")])
def test_a_signal_during_an_fmu_monte_carlo_ends_it(plants: dict[str, Path], tmp_path: Path, sig: int, code: int,
                                                    line: str) -> None:
    """``simulate --plant`` on the stiff plant (about 1 s of FMU time per 10 s of horizon):
    the signal (to the process group, as a terminal's Ctrl-C, or SIGTERM to the process)
    ends it with the documented code, one line, no JSON, nothing in the temporary folder.
    Sent once the plant process has stepped the FMU for 0.2 s of CPU (``tests/plant_stages.py``)."""
    for name in ("plant.fmu", "plant.toml", "system.toml", "K.toml"):
        shutil.copy(plants["stiff"] / name, tmp_path / name)
    (tmp_path / ".tmp").mkdir()
    proc = subprocess.Popen([sys.executable, "-m", "ftc_verify", "simulate", "system.toml", "--gains", "K.toml",
                             "--plant", "plant.toml", "--paths", "40", "--horizon", "30", "--seed", "1", "--json"],
                            cwd=tmp_path, env=os.environ | {"TMPDIR": str(tmp_path / ".tmp")},
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    wait_for_fmu_steps(proc, tmp_path / ".tmp", 0.2)  # inside the Monte Carlo, the FMU stepping (a 1 s sleep before)
    assert proc.poll() is None
    if sig == signal.SIGINT:
        os.killpg(proc.pid, sig)
    else:
        proc.send_signal(sig)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == code, (out, err)
    assert err.strip() == line and out == ""
    assert _left(tmp_path) == []


# ------------------------------------------------------------------------------------------ item 2


@pytest.mark.slow(8)  # seconds on 2 busy cores (--durations at load 9, / 4): scheduled first
def test_a_crashing_plant_is_reported_not_fatal(plants: dict[str, Path], tmp_path: Path) -> None:
    """The plant segfaults in fmi2DoStep after t = 2: simulate exits 1 naming the FMU, the
    signal, the path and the time (JSON too); verify writes its report with the failure;
    nothing is left in the temporary folder (the process used to die with 139, silently,
    leaving the extracted FMU). The first run is a real process (its exit code is the
    claim); the JSON and the report, from the same watched child, in this process."""
    cwd = plants["crash"]
    out = _cli(["simulate", "system.toml", "--gains", "K.toml", "--plant", "plant.toml", "--paths", "3",
                "--horizon", "4", "--seed", "1"], cwd)
    assert out.returncode == 1 and out.stderr == "", out
    assert "PLANT FMU FAILED" in out.stdout and "SIGSEGV" in out.stdout and "paths[0] at t = 2" in out.stdout
    assert str(cwd / "plant.fmu") in out.stdout
    out = _cli_here(["simulate", "system.toml", "--gains", "K.toml", "--plant", "plant.toml", "--paths", "3",
                     "--horizon", "4", "--seed", "1", "--json"], cwd)
    d = json.loads(out.stdout)
    assert out.returncode == 1 and d["verdict"] == "fail" and d["plant_failure"]["path"] == 0
    assert d["plant_failure"]["time"] == pytest.approx(2.0, abs=0.011)
    out = _cli_here(["verify", "system.toml", "--gains", "K.toml", "--plant", "plant.toml", "--paths", "10",
                     "--horizon", "4", "--seed", "1", "--out", "rep"], cwd)
    assert out.returncode == 1 and "Traceback" not in out.stderr, out
    report = json.loads((cwd / "rep" / "report.json").read_text())
    assert report["verdict"] == "fail" and "SIGSEGV" in report["plant_failure"]["detail"]
    assert "## The plant FMU failed" in (cwd / "rep" / "report.md").read_text()
    assert _left(cwd) == []


def test_the_watched_child_locates_the_crash(plants: dict[str, Path]) -> None:
    """API: fmu_monte_carlo raises PlantRunError with the path (0-based, counted over every
    batch) and the time; paths that end before t = 2 never reach the crash."""
    system, controller, plant = _loaded(plants["crash"])
    short = sample_paths(system.chain, 1.5, 4, 2)
    long = sample_paths(system.chain, 4.0, 2, 3)
    res = fmu_monte_carlo(system, controller, short, step=0.01, delta=DeltaSchedule("zero"), plant=plant, batch=3)
    assert len(res.records) == 4 and all(r.diverged_at is None for r in res.records)
    with pytest.raises(PlantRunError) as caught:
        fmu_monte_carlo(system, controller, short + long, step=0.01, delta=DeltaSchedule("zero"), plant=plant,
                        batch=3)
    err = caught.value
    assert err.path == 4 and 2.0 <= err.time < 2.011 and "SIGSEGV" in err.detail and err.fmu == str(plant.fmu)


# ------------------------------------------------------------------------------------------ item 7


@pytest.mark.slow(8)  # seconds on 2 busy cores (--durations at load 9, / 4): scheduled first
def test_a_plant_failing_in_do_step_is_a_result(plants: dict[str, Path]) -> None:
    """fmi2DoStep returns fmi2Error after t = 2 (sqrt of a negative number): simulate
    prints its JSON with every path failed there and the FMU's message, exit 1 (it used to
    exit 2, "bad input", with no JSON); verify writes the report, exit 1."""
    cwd = plants["fail"]
    out = _cli_here(["simulate", "system.toml", "--gains", "K.toml", "--plant", "plant.toml", "--paths", "3",
                "--horizon", "4", "--seed", "1", "--json"], cwd)
    assert out.returncode == 1 and out.stderr == "", out
    d = json.loads(out.stdout)
    assert d["verdict"] == "fail" and [x["t"] for x in d["diverged"]] == [2.0, 2.0, 2.0]
    assert all("der(x) is not finite" in x["fmu_failure"] for x in d["diverged"])
    assert "failed in the plant FMU" in d["divergence"] and d["y_norm"] == [None, None, None]
    out = _cli_here(["verify", "system.toml", "--gains", "K.toml", "--plant", "plant.toml", "--paths", "10",
                "--horizon", "4", "--seed", "1", "--out", "rep"], cwd)
    assert out.returncode == 1 and out.stderr == "", out
    report = json.loads((cwd / "rep" / "report.json").read_text())
    mc = next(c for c in report["checks"] if c["name"] == "Monte Carlo (FMU)")
    assert not mc["ok"] and "10 of 10 paths failed in the plant FMU" in mc["detail"]
    region = next(c for c in report["checks"] if c["name"] == "plant region")
    assert "None" not in region["detail"] and "none measured" in region["detail"]  # item 14
    assert _left(cwd) == []


# ------------------------------------------------------------------------------------------ item 12


@pytest.mark.slow(11)  # seconds on 2 busy cores (--durations at load 9, / 4): scheduled first
def test_delta_is_never_silently_zero(plants: dict[str, Path], tmp_path: Path) -> None:
    """An uncertain system on a plant map without Delta inputs: ``--delta random`` is refused
    (it ran with Delta = 0 and said "Delta zero"); verify says in its output and report that
    the uncertainty is not exercised on the FMU."""
    for name in ("plant.fmu", "plant.toml", "K.toml"):
        shutil.copy(plants["ok"] / name, tmp_path / name)
    text = (plants["ok"] / "system.toml").read_text().replace("D = [[1.0]]\n", "D = [[1.0]]\nA1 = [[0.1]]\nA2 = [[0.1]]\n")
    (tmp_path / "system.toml").write_text(text)
    assert load_system(tmp_path / "system.toml").uncertain
    out = _cli_here(["simulate", "system.toml", "--gains", "K.toml", "--plant", "plant.toml", "--paths", "2",
                "--horizon", "1", "--delta", "random"], tmp_path)
    assert out.returncode == 2 and out.stdout == "" and out.stderr.count("\n") == 1, out
    assert "--delta random" in out.stderr and "names no Delta inputs" in out.stderr
    out = _cli_here(["verify", "system.toml", "--gains", "K.toml", "--plant", "plant.toml", "--paths", "10",
                "--horizon", "2", "--seed", "2", "--out", "rep"], tmp_path)
    assert out.returncode in (0, 1) and "Delta in the Monte Carlo: zero: the plant map names no Delta inputs" in out.stdout
    report = json.loads((tmp_path / "rep" / "report.json").read_text())
    assert "not exercised" in report["options"]["delta"]
    assert "Delta in the Monte Carlo: zero" in (tmp_path / "rep" / "report.md").read_text()


def test_failed_records_keep_what_was_recorded(plants: dict[str, Path]) -> None:
    """In process (no child): the failed record ends at the failing step's start with every
    array the same length, and its energy is infinite."""
    system, controller, plant = _loaded(plants["fail"])
    paths = sample_paths(system.chain, 4.0, 2, 5)
    res = fmu_monte_carlo(system, controller, paths, step=0.01, delta=DeltaSchedule("zero"), plant=plant,
                          isolate=False)
    for r in res.records:
        assert r.failure is not None and r.diverged_at == r.t[-1] == 2.0
        assert len(r.t) == len(r.x) == len(r.u) == len(r.y) == len(r.true) + 1
        assert np.all(np.isfinite(r.x)) and r.y_norm == float("inf")


# ------------------------------------------------------------------------------------------ items 2, 7 on Dask


@pytest.mark.slow(20)
def test_crashing_and_failing_plants_on_two_workers(plants: dict[str, Path]) -> None:
    """``--workers 2``: the segfaulting plant kills its workers; the batch is run again in a
    watched child, which names the path and the time (it was exit 4 "KilledWorker" with 8
    folders left); the plant failing in fmi2DoStep gives the same JSON as the serial run,
    nothing on stderr (it was 85 lines and 12 tracebacks)."""
    pytest.importorskip("distributed")
    cwd = plants["crash"]
    out = _cli(["simulate", "system.toml", "--gains", "K.toml", "--plant", "plant.toml", "--paths", "4",
                "--horizon", "4", "--seed", "1", "--workers", "2", "--json"], cwd)
    assert out.returncode == 1 and "Traceback" not in out.stderr, out
    failure = json.loads(out.stdout)["plant_failure"]
    assert failure["path"] == 0 and 2.0 <= failure["time"] < 2.011 and "SIGSEGV" in failure["detail"]
    assert _left(cwd) == []
    cwd = plants["fail"]
    args = ["simulate", "system.toml", "--gains", "K.toml", "--plant", "plant.toml", "--paths", "30",
            "--horizon", "4", "--seed", "1", "--json"]
    serial, spread = _cli_here(args, cwd), _cli(args + ["--workers", "2"], cwd)  # the serial run in this process
    assert serial.returncode == spread.returncode == 1 and spread.stderr == "", spread
    assert json.loads(serial.stdout) == json.loads(spread.stdout)
    assert _left(cwd) == []
