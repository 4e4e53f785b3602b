"""The plant commands' contract (issue 22, items 8-11, 13, 14): ``plant``, ``linearize``,
``build-fmu`` and ``synthesize`` run with the folder, environment and streams a user's
``python -m ftc_verify`` has, in the test process (``tests/cli_inprocess.py``; the
umask and SIGTERM cases, which are about the process, run as subprocesses).

Each case asserts the exit code, the answer (one verdict line or one JSON object; for bad
input one stderr line naming the file, key and value), no traceback, and that nothing is
written that should not be (no output file, nothing left in the temporary folder).
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import cli_inprocess
import pytest

from session_cache import shared_plant

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "examples" / "paper.toml"
THREE_TANK = ROOT / "examples" / "three_tank" / "ThreeTank.mo"


def run_cli(args: list[str], cwd: Path, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    """``ftc-verify ARGS`` in ``cwd`` with the temporary folder ``cwd/.tmp``, in this process
    (``tests/cli_inprocess.py``: what a subprocess would get and print)."""
    (cwd / ".tmp").mkdir(exist_ok=True)
    return cli_inprocess.run_cli(args, cwd, {"TMPDIR": str(cwd / ".tmp")} | (env or {}))


def strict_json(text: str) -> Any:
    def refuse(name: str) -> None:
        raise AssertionError(f"non-standard JSON constant {name}")
    return json.loads(text, parse_constant=refuse)


def files_under(folder: Path) -> set[str]:
    return {str(p.relative_to(folder)) for p in folder.rglob("*")}


def no_traceback(proc: subprocess.CompletedProcess[str]) -> None:
    assert "Traceback" not in proc.stderr and "internal error" not in proc.stderr, proc.stderr


def one_error_line(proc: subprocess.CompletedProcess[str], *needles: str) -> str:
    assert proc.returncode == 2, (proc.returncode, proc.stdout, proc.stderr)
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    no_traceback(proc)
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])
    return lines[0]


@pytest.fixture(scope="module")
def plants(shared_tmp: Path) -> dict[str, Path]:
    """The test plants of ``tests/fmu_plants.py`` this file needs, built once per session
    (``tests/session_cache.py``; the tests copy them before writing)."""
    return {kind: shared_plant(shared_tmp, kind) for kind in ("ok", "fail", "early", "kink")}


def copy_plant(src: Path, dest: Path, edit: tuple[str, str] | None = None) -> Path:
    """``src``'s FMU and files in ``dest`` (the map edited by ``edit = (old, new)``)."""
    shutil.copytree(src, dest)
    if edit is not None:
        text = (dest / "plant.toml").read_text()
        assert edit[0] in text
        (dest / "plant.toml").write_text(text.replace(edit[0], edit[1], 1))
    return dest


# ------------------------------------------------------------------------------------------
# Item 8: a plant whose fmi2DoStep fails is a failed check / no linearisation (exit 1)
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("step", ["5", "1e6"])
def test_plant_check_on_a_failing_do_step_is_a_failed_check(tmp_path: Path, plants: dict[str, Path],
                                                            step: str) -> None:
    """The step crosses t = 2, where the FMU's doStep returns fmi2Error: exit 1 with the
    verdict line naming the FMU and its own log message (was: exit 4, FMICallException)."""
    plant = copy_plant(plants["fail"], tmp_path / "p")
    before = files_under(tmp_path)
    proc = run_cli(["plant", str(plant / "plant.toml"), "--check", "--step", step], tmp_path)
    assert proc.returncode == 1, (proc.stdout, proc.stderr)
    no_traceback(proc)
    assert proc.stderr == ""
    verdict = [line for line in proc.stdout.splitlines() if "verdict:" in line]
    assert len(verdict) == 1 and "fail" in verdict[0] and "FMU failed" in verdict[0], proc.stdout
    assert "plant.fmu" in proc.stdout and "fmi2DoStep" in proc.stdout and "not finite" in proc.stdout
    assert files_under(tmp_path) - {".tmp"} == before - {".tmp"} and not any((tmp_path / ".tmp").iterdir())

    proc = run_cli(["plant", str(plant / "plant.toml"), "--check", "--step", step, "--json"], tmp_path)
    assert proc.returncode == 1, proc.stderr
    d = strict_json(proc.stdout)
    assert d["verdict"] == "fail" and "FMU failed" in d["reason"]
    assert all(row["error"] and "plant.fmu" in row["error"] and "fmi2DoStep" in row["error"]
               and "not finite" in row["error"] for row in d["check"])


def test_plant_check_on_a_good_plant_still_passes(tmp_path: Path, plants: dict[str, Path]) -> None:
    plant = copy_plant(plants["ok"], tmp_path / "p", ("[operating_point]\n", "[operating_point]\ninputs = [1.0]\n"))
    proc = run_cli(["plant", str(plant / "plant.toml"), "--check", "--json"], tmp_path)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    d = strict_json(proc.stdout)
    assert d["verdict"] == "checked" and [r["error"] for r in d["check"]] == [None, None]


@pytest.mark.parametrize("json_out", [False, True])
def test_linearize_identification_on_a_failing_do_step(tmp_path: Path, plants: dict[str, Path],
                                                       json_out: bool) -> None:
    """``linearize --route identification`` on a plant whose every doStep fails: exit 1,
    one clear verdict (or one JSON object) naming the FMU and its message; nothing written."""
    plant = copy_plant(plants["early"], tmp_path / "p")
    before = files_under(tmp_path)
    proc = run_cli(["linearize", str(plant / "plant.toml"), "--route", "identification", "-o", "sys.toml"]
                   + (["--json"] if json_out else []), tmp_path)
    assert proc.returncode == 1, (proc.stdout, proc.stderr)
    no_traceback(proc)
    assert proc.stderr == ""
    if json_out:
        d = strict_json(proc.stdout)
        assert d["verdict"] == "fail" and "could not be computed" in d["reason"] and d["output"] is None
        assert "plant.fmu" in d["detail"] and "fmi2DoStep" in d["detail"] and "not finite" in d["detail"]
    else:
        verdict = [line for line in proc.stdout.splitlines() if "verdict:" in line]
        assert len(verdict) == 1 and "could not be computed" in verdict[0] and "FMU failed" in verdict[0]
        assert "plant.fmu" in proc.stdout and "fmi2DoStep" in proc.stdout and "not finite" in proc.stdout
    assert files_under(tmp_path) - {".tmp"} == before - {".tmp"} and not any((tmp_path / ".tmp").iterdir())


# ------------------------------------------------------------------------------------------
# Item 10: linearize --trim --json without an equilibrium prints one JSON object
# ------------------------------------------------------------------------------------------


def test_trim_without_equilibrium_json_is_one_object(tmp_path: Path, plants: dict[str, Path]) -> None:
    plant = copy_plant(plants["early"], tmp_path / "p")
    proc = run_cli(["linearize", str(plant / "plant.toml"), "--trim", "--json"], tmp_path)
    assert proc.returncode == 1, (proc.stdout, proc.stderr)
    no_traceback(proc)
    d = strict_json(proc.stdout)  # the whole of stdout is one JSON object
    assert d["verdict"] == "fail" and d["reason"] == "no stationary point" and "trim failed" in d["detail"]
    text = run_cli(["linearize", str(plant / "plant.toml"), "--trim"], tmp_path)
    assert text.returncode == 1 and "verdict: fail (no stationary point)" in text.stdout
    assert all("\n" not in line for line in text.stdout.splitlines())


# ------------------------------------------------------------------------------------------
# Item 11: role mismatches refused; inaccurate linearisations not written silently
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("variable, kind", [("k", "'parameter' and variability 'tunable'"),
                                            ("u", "'input' and variability 'continuous'")])
def test_a_parameter_or_input_as_state_is_refused(tmp_path: Path, plants: dict[str, Path], variable: str,
                                                  kind: str) -> None:
    plant = copy_plant(plants["ok"], tmp_path / "p", ('\nstates = ["x"]', f'\nstates = ["{variable}"]'))
    before = files_under(tmp_path)
    for args in (["linearize", str(plant / "plant.toml"), "-o", "sys.toml"],
                 ["linearize", str(plant / "plant.toml"), "--route", "finite-differences"],
                 ["plant", str(plant / "plant.toml")]):
        proc = run_cli(args, tmp_path)
        one_error_line(proc, "plant.toml", "[variables].states", repr(variable), kind, "ModelStructure/Derivatives")
        assert proc.stdout == ""
    assert files_under(tmp_path) - {".tmp"} == before - {".tmp"} and not any((tmp_path / ".tmp").iterdir())


def test_inaccurate_linearisation_is_said_and_not_written(tmp_path: Path, plants: dict[str, Path]) -> None:
    """A kink within the difference steps: error estimate 0.25 on entries of 0.08 and 1."""
    from ftc_verify.plants.linearize import ACCURACY_FRACTION

    plant = copy_plant(plants["kink"], tmp_path / "p")
    proc = run_cli(["linearize", str(plant / "plant.toml")], tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "warning: inaccurate linearisation: mode 1 (nominal): the error estimate of A" in proc.stdout
    proc = run_cli(["linearize", str(plant / "plant.toml"), "--json"], tmp_path)
    d = strict_json(proc.stdout)
    assert d["accuracy_fraction"] == ACCURACY_FRACTION and len(d["inaccurate"]) == 4
    before = files_under(tmp_path)
    proc = run_cli(["linearize", str(plant / "plant.toml"), "-o", "sys.toml"], tmp_path)
    assert proc.returncode == 1, proc.stdout + proc.stderr
    no_traceback(proc)
    assert "--accept-inaccurate" in proc.stdout.splitlines()[-1] and "not" in proc.stdout.splitlines()[-1]
    assert files_under(tmp_path) - {".tmp"} == before - {".tmp"}
    proc = run_cli(["linearize", str(plant / "plant.toml"), "-o", "sys.toml", "--accept-inaccurate", "--json"],
                   tmp_path)
    assert proc.returncode == 0 and (tmp_path / "sys.toml").is_file(), proc.stdout + proc.stderr
    assert strict_json(proc.stdout)["inaccurate"]
    # an accurate plant writes without the flag and says nothing
    good = copy_plant(plants["ok"], tmp_path / "good")
    proc = run_cli(["linearize", str(good / "plant.toml"), "-o", "good.toml", "--json"], tmp_path)
    assert proc.returncode == 0 and strict_json(proc.stdout)["inaccurate"] == [], proc.stderr


def test_inaccuracy_is_measured_per_matrix() -> None:
    from ftc_verify.plants.linearize import ACCURACY_FRACTION, ModeLinearisation, _inaccurate

    def mode(errors: dict[str, float], B: float = 1.0) -> ModeLinearisation:
        return ModeLinearisation("m", A=np.array([[-2.0]]), B=np.array([[B]]), D=np.array([[0.0]]),
                                 C=np.array([[1.0]]), Cy=None, drift=np.zeros(1), errors=errors)

    assert _inaccurate(1, mode({"A": 1e-15, "B": 1e-15, "C": 0.0})) == []
    assert _inaccurate(1, mode({"A": 1e-15, "B": 1e-15}, B=0.0)) == []  # a zero block, rounding-level error
    found = _inaccurate(2, mode({"A": 3 * ACCURACY_FRACTION, "B": 0.0}))
    assert len(found) == 1 and found[0].startswith("mode 2 (m): the error estimate of A")


# ------------------------------------------------------------------------------------------
# Item 13: an output that is one of the inputs is refused
# ------------------------------------------------------------------------------------------


def test_output_that_is_an_input_is_refused(tmp_path: Path, plants: dict[str, Path]) -> None:
    plant = copy_plant(plants["ok"], tmp_path / "p")
    (tmp_path / "paper.toml").write_text(PAPER.read_text())
    map_text, paper_text = (plant / "plant.toml").read_text(), (tmp_path / "paper.toml").read_text()
    before = files_under(tmp_path)
    proc = run_cli(["linearize", "p/plant.toml", "-o", "p/plant.toml"], tmp_path)
    one_error_line(proc, "-o p/plant.toml", "input file")
    proc = run_cli(["linearize", "p/plant.toml", "-o", str(plant / ".." / "p" / "plant.toml")], tmp_path)
    one_error_line(proc, "input file")
    proc = run_cli(["synthesize", "paper.toml", "--method", "two-step", "-o", "paper.toml"], tmp_path)
    one_error_line(proc, "-o/--output paper.toml", "input file")
    assert (plant / "plant.toml").read_text() == map_text and (tmp_path / "paper.toml").read_text() == paper_text
    assert files_under(tmp_path) - {".tmp"} == before - {".tmp"}


# ------------------------------------------------------------------------------------------
# Item 14: plain numbers in messages, FMUs follow the umask, controller vs map up front
# ------------------------------------------------------------------------------------------


def test_region_message_shows_plain_numbers(tmp_path: Path, plants: dict[str, Path]) -> None:
    plant = copy_plant(plants["ok"], tmp_path / "p", ("[[fault]]", "[region]\nstates_min = [200.0]\n"
                                                                    "states_max = [100.0]\n\n[[fault]]"))
    proc = run_cli(["plant", str(plant / "plant.toml")], tmp_path)
    line = one_error_line(proc, "plant.toml", "[region]", "states_min[0] = 200.0", "states_max[0] = 100.0")
    assert "np." not in line


def test_plant_map_messages_never_show_numpy_reprs(plants: dict[str, Path]) -> None:
    from ftc_verify.errors import ProblemFileError
    from ftc_verify.plants.plant_map import load_plant_map

    pm = load_plant_map(plants["ok"] / "plant.toml")
    with pytest.raises(ProblemFileError) as info:
        pm.with_states_op(np.array([1.0, np.float64(2.0)]))
    assert "np." not in str(info.value) and "array(" not in str(info.value) and "[1.0, 2.0]" in str(info.value)
    with pytest.raises(ProblemFileError) as info:
        pm.with_states_op(np.array([np.nan]))
    assert "np." not in str(info.value) and "nan" in str(info.value)


@pytest.mark.parametrize("umask", [0o022, 0o002])
def test_built_fmus_follow_the_umask(tmp_path: Path, umask: int) -> None:
    """``build-fmu -o`` and the cached FMU get ``0o666 & ~umask`` like every other output."""
    cache = tmp_path / "cache"
    code = ("import os, sys; os.umask(int(sys.argv[1], 8)); from ftc_verify.cli.main import main; "
            "sys.exit(main(sys.argv[2:]))")
    (tmp_path / ".tmp").mkdir()
    env = os.environ | {"FTC_VERIFY_CACHE": str(cache), "TMPDIR": str(tmp_path / ".tmp")}
    for args in (["-o", "out.fmu"], []):
        proc = subprocess.run([sys.executable, "-c", code, oct(umask), "build-fmu", str(THREE_TANK), *args],
                              capture_output=True, text=True, cwd=tmp_path, env=env, timeout=300)
        assert proc.returncode == 0, proc.stderr
    fmus = [tmp_path / "out.fmu", *cache.rglob("*.fmu")]
    assert len(fmus) == 2
    for fmu in fmus:
        assert stat.S_IMODE(fmu.stat().st_mode) == 0o666 & ~umask, (fmu, oct(fmu.stat().st_mode))


def test_check_controller_against_the_map(plants: dict[str, Path]) -> None:
    """``check_controller`` refuses a controller the map cannot feed, before any analysis."""
    from dataclasses import replace

    from ftc_verify.controllers.controller import Controller
    from ftc_verify.errors import ProblemFileError
    from ftc_verify.plants.plant_map import check_controller, load_plant_map

    pm = load_plant_map(plants["ok"] / "plant.toml")  # one state, one measured output
    z = np.zeros
    dynamic = Controller.dynamic([z((1, 1))] * 2, [z((1, 1))] * 2, [z((1, 1))] * 2, [z((1, 1))] * 2)
    check_controller(pm, dynamic, "Kof.toml")
    check_controller(pm, Controller.state_feedback([z((1, 1))] * 2), "K.toml")
    with pytest.raises(ProblemFileError) as info:
        check_controller(replace(pm, measured=()), dynamic, "Kof.toml")
    msg = str(info.value)
    assert "plant.toml" in msg and "[variables].measured" in msg and "is empty" in msg
    assert "Kof.toml" in msg and "reads 1 measured outputs" in msg
    two = Controller.dynamic([z((1, 1))] * 2, [z((1, 2))] * 2, [z((1, 1))] * 2, [z((1, 2))] * 2)
    with pytest.raises(ProblemFileError, match=r"\[variables\]\.measured .*names 1 variable.*reads 2 measured"):
        check_controller(pm, two, "Kof2.toml")
    with pytest.raises(ProblemFileError, match=r"\[variables\]\.states .*names 1 variable.*K2\.toml reads 2 states"):
        check_controller(pm, Controller.state_feedback([z((1, 2))] * 2), "K2.toml")


# ------------------------------------------------------------------------------------------
# Item 9: SIGTERM during build-fmu leaves no compiler process and no temporary file
# ------------------------------------------------------------------------------------------


def _children() -> dict[int, list[int]]:
    """Every process's children, from ``/proc/*/stat``."""
    kids: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            ppid = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
        except (OSError, IndexError, ValueError):
            continue
        kids.setdefault(ppid, []).append(int(entry.name))
    return kids


def _descendants(pid: int) -> list[int]:
    kids, out, todo = _children(), [], [pid]
    while todo:
        for child in kids.get(todo.pop(), []):
            out.append(child)
            todo.append(child)
    return out


def _comm(pid: int) -> str | None:
    try:
        return (Path("/proc") / str(pid) / "comm").read_text().strip()
    except OSError:
        return None


def _running(pid: int) -> bool:
    """Whether ``pid`` exists and is not a zombie (a killed process waiting to be reaped)."""
    try:
        state = (Path("/proc") / str(pid) / "stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return False
    return state not in ("Z", "X")


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc")
def test_sigterm_during_build_fmu_kills_the_compiler(tmp_path: Path) -> None:
    tmp = tmp_path / ".tmp"
    tmp.mkdir()
    env = os.environ | {"TMPDIR": str(tmp), "FTC_VERIFY_CACHE": str(tmp_path / "cache")}
    proc = subprocess.Popen([sys.executable, "-m", "ftc_verify", "build-fmu", str(THREE_TANK), "-o", "X.fmu"],
                            cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    cc1: list[int] = []
    deadline = time.monotonic() + 120
    while not cc1 and time.monotonic() < deadline and proc.poll() is None:
        cc1 = [p for p in _descendants(proc.pid) if _comm(p) == "cc1"]
        time.sleep(0.002)
    assert cc1, ("gcc's cc1 was never seen", proc.poll(), proc.communicate())
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 143, (out, err)
    assert err.strip() == "ftc-verify: terminated" and "Traceback" not in err
    assert [p for p in cc1 if _comm(p) == "cc1" and _running(p)] == []  # killed, not orphaned
    assert list(tmp.iterdir()) == []  # no cc*.s, no compiler folder
    assert not (tmp_path / "X.fmu").exists()
    cache_left = [p.name for p in (tmp_path / "cache").rglob("*") if p.is_file() and not p.name.endswith(".lock")]
    assert cache_left == []
