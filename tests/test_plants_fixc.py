"""``plant --check`` and ``linearize`` on a plant FMU that hangs or crashes (audit13
findings 04 and 05, found by an independent check): their FMU calls run in a watched child
(:func:`ftc_verify.simulation.isolated.call_isolated`), so

* a SIGTERM / SIGINT while the FMU hangs ends the command with 143 / 130 and one line
  (it used to run on until SIGKILL, leaving the extracted FMU in the temporary folder);
* a segfault of the FMU's code is a failed check / no linearisation: exit 1, the verdict
  line naming the FMU and the signal, nothing left in the temporary folder (it used to end
  the process with 139, printing nothing).

The plants are the one-state test plant of ``tests/fmu_plants.py`` with a right-hand side
that loops forever, or dereferences NULL, once ``t > 0.005`` (inside the first
``fmi2DoStep`` of both commands).

Finding 03: ``verify --plant`` on a plant whose ``fmi2DoStep`` returns ``fmi2Error`` (the
``fail`` plant, at t = 2) said every path "left [region]" and "diverged": it now counts
the paths that failed in the plant FMU apart.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import cli_inprocess
import pytest

from plant_stages import wait_for_fmu_steps
from session_cache import computed_once, one_state_spec, shared_plant

if shutil.which("gcc") is None:  # pragma: no cover
    pytest.skip("gcc is needed to compile the FMUs", allow_module_level=True)

_BAD = {
    "hang": "if (t > 0.005) { volatile unsigned long k = 0; for (;;) k++; }",
    "crash": "if (t > 0.005) { volatile double *nowhere = 0; dx[0] = *nowhere; return; }",
}
_COMMANDS = {
    "plant": ["plant", "plant.toml", "--check"],
    "linearize": ["linearize", "plant.toml", "--route", "identification", "-o", "out.toml"],
}


@pytest.fixture(scope="module")
def bad_plants(shared_tmp: Path) -> dict[str, Path]:
    """The ``ok`` test plant's folder with its FMU rebuilt from a right-hand side that hangs
    or crashes after t = 0.005 (built once per session)."""
    from fmu_plants import _RHS, _SOURCE

    from ftc_verify.plants.ode_fmu import build_ode_fmu

    ok = shared_plant(shared_tmp, "ok")

    def build(kind: str, folder: Path) -> Path:
        shutil.copytree(ok, folder, dirs_exist_ok=True)
        spec = dataclasses.replace(one_state_spec("ok"), model_name=f"Plant_{kind}",
                                   c_source=_SOURCE.format(nx=1, rhs=_BAD[kind] + "\n    " + _RHS["ok"]))
        build_ode_fmu(spec, folder / "plant.fmu")
        return folder

    return {kind: computed_once(shared_tmp, f"fixc-plant-{kind}", lambda f, k=kind: build(k, f)) for kind in _BAD}


def _start(src: Path, cwd: Path, command: str, extra: tuple[str, ...] = ()) -> subprocess.Popen[str]:
    """``ftc-verify COMMAND`` on a copy of the plant in ``cwd``, with ``cwd/.tmp`` as TMPDIR."""
    for name in ("plant.fmu", "plant.toml"):
        shutil.copy(src / name, cwd / name)
    (cwd / ".tmp").mkdir()
    return subprocess.Popen([sys.executable, "-m", "ftc_verify", *_COMMANDS[command], *extra], cwd=cwd,
                            env=os.environ | {"TMPDIR": str(cwd / ".tmp")}, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)


def _left(cwd: Path) -> list[str]:
    return sorted(str(p.relative_to(cwd)) for p in (cwd / ".tmp").rglob("*"))


@pytest.mark.slow(4)
@pytest.mark.parametrize("command", list(_COMMANDS))
@pytest.mark.parametrize("sig, code, line", [(signal.SIGTERM, 143, "ftc-verify: terminated"),
                                             (signal.SIGINT, 130, "ftc-verify: interrupted")])
def test_a_signal_while_the_plant_fmu_hangs_ends_the_command(bad_plants: dict[str, Path], tmp_path: Path,
                                                             command: str, sig: int, code: int, line: str) -> None:
    """The signal is sent once the FMU has looped for 0.2 s of CPU (``tests/plant_stages.py``);
    the command must end with the documented code and line well within 30 s (it ran on for
    60 s and more before), leaving nothing in the temporary folder and no output file."""
    proc = _start(bad_plants["hang"], tmp_path, command)
    try:
        wait_for_fmu_steps(proc, tmp_path / ".tmp", 0.2)
        if sig == signal.SIGINT:
            os.killpg(proc.pid, sig)
        else:
            proc.send_signal(sig)
        out, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == code, (out, err)
    assert err.strip() == line and out == ""
    assert _left(tmp_path) == [] and not (tmp_path / "out.toml").exists()


@pytest.mark.slow(3)
@pytest.mark.parametrize("command", list(_COMMANDS))
@pytest.mark.parametrize("json_out", [False, True])
def test_a_crashing_plant_fmu_is_a_failed_command(bad_plants: dict[str, Path], tmp_path: Path, command: str,
                                                  json_out: bool) -> None:
    """Exit 1 with one verdict line (or one JSON object) naming the FMU and SIGSEGV, nothing
    on stderr, nothing written, nothing left in the temporary folder (was: 139, silence)."""
    proc = _start(bad_plants["crash"], tmp_path, command, ("--json",) if json_out else ())
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 1 and err == "", (proc.returncode, out, err)
    if json_out:
        d = json.loads(out)
        assert d["verdict"] == "fail" and "plant FMU" in d["reason"] and d["output"] is None
        text = d["detail"]
    else:
        verdict = [ln for ln in out.splitlines() if "verdict:" in ln]
        assert len(verdict) == 1 and "fail" in verdict[0], out
        text = out
    assert "plant.fmu" in text and "SIGSEGV" in text and f"during {command}" in text
    assert _left(tmp_path) == [] and not (tmp_path / "out.toml").exists()


@pytest.mark.slow(4)
def test_region_check_says_the_paths_failed_in_the_plant(shared_tmp: Path, tmp_path: Path) -> None:
    """Every path fails in the FMU at t = 2, well inside a [region] of +-100 around the
    operating point: the region check fails saying 10 paths failed in the plant FMU and 0
    left the region, and the FMU-vs-linear comparison says why it measured nothing (was:
    "10 of 10 paths left [region]", "every compared path diverged"). Verdict fail, exit 1."""
    plant = Path(shutil.copytree(shared_plant(shared_tmp, "fail"), tmp_path / "p"))
    text = (plant / "plant.toml").read_text()
    (plant / "plant.toml").write_text(text.replace("[[fault]]", "[region]\nstates_min = [-100.0]\n"
                                                   "states_max = [100.0]\n\n[[fault]]", 1))
    (tmp_path / ".tmp").mkdir()
    out = cli_inprocess.run_cli(["verify", "system.toml", "--gains", "K.toml", "--plant", "plant.toml", "--paths",
                                 "10", "--horizon", "4", "--seed", "1", "--out", "rep"], plant,
                                {"TMPDIR": str(tmp_path / ".tmp")})
    assert out.returncode == 1 and out.stderr == "", out
    report = json.loads((plant / "rep" / "report.json").read_text())
    region = next(c for c in report["checks"] if c["name"] == "plant region")
    assert not region["ok"] and report["verdict"] == "fail"
    assert region["detail"].startswith("0 of 10 paths left [region]; 10 of 10 paths failed in the plant FMU")
    assert "none measured (every path failed in the plant FMU)" in region["detail"]
    assert "FMU vs linear reference: every compared path failed in the plant FMU" in region["detail"]
    assert "diverged" not in region["detail"]
    assert report["plant"]["left_region"] == 0 and report["plant"]["failed_in_plant"] == 10
    assert "failed in the plant FMU" in out.stdout and "left [region] (paths" not in out.stdout
    md = (plant / "rep" / "report.md").read_text()
    assert "| paths that left [region] (states or input limits) | 0 of 10 |" in md
    assert "| paths that failed in the plant FMU (not counted above) | 10 of 10 |" in md
