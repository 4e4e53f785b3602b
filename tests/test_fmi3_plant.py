"""FMI 3.0 co-simulation plants through the same plant maps (issue 24, item 4).

The FMI 3.0 FMUs are built here: the test plants of :mod:`tests.fmu_plants`
(``x' = -x + k u + w``) and the DC motor, compiled with ``fmus/ode/ode_glue3.c`` (the FMI
3.0 glue over the FMI 2.0 ODE glue) by :func:`ftc_verify.plants.ode_fmu.build_ode_fmu`
with ``fmi_version="3.0"``; each is compared with the FMI 2.0 FMU of the same model:

- the supervisor gives the same paths to 1e-8 (the same integrator behind both APIs);
- ``plant`` says FMI 3.0; ``simulate --plant``, ``verify --plant`` and ``linearize`` (every
  route, including ``directional`` through ``fmi3GetDirectionalDerivative``) run and agree
  with the FMI 2.0 FMU;
- a map naming a ``Float32`` or ``Int32`` variable as a state is refused with one error;
- ``fmi3DoStep`` returning ``fmi3Error`` ends the path as a failed record naming the FMU and
  the call, as on FMI 2.0; a signal's exception inside the FMI 3.0 logger is not dropped.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import zipfile
from pathlib import Path

import cli_inprocess
import numpy as np
import pytest

from session_cache import copied_plants
from ftc_verify.controllers import load_controller
from ftc_verify.errors import FMUError
from ftc_verify.model.files import load_system
from ftc_verify.plants.fmu_session import FMUSession
from ftc_verify.plants.linearize import linearize_plant
from ftc_verify.plants.ode_fmu import build_ode_fmu, motor_spec
from ftc_verify.plants.plant_map import load_plant_map
from ftc_verify.simulation.paths import sample_paths
from ftc_verify.simulation.supervisor import Supervisor

ROOT = Path(__file__).resolve().parents[1]

if shutil.which("gcc") is None:  # pragma: no cover
    pytest.skip("gcc is needed to compile the FMUs", allow_module_level=True)


@pytest.fixture(scope="module", autouse=True)
def _isolated_cache(tmp_path_factory: pytest.TempPathFactory):
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("FTC_VERIFY_CACHE", str(tmp_path_factory.mktemp("ftc-verify-cache")))
        yield


@pytest.fixture(scope="module")
def plants(tmp_path_factory: pytest.TempPathFactory, shared_tmp: Path) -> dict[str, Path]:
    """``{"ok2": FMI 2.0 folder, "ok3": the same with an FMI 3.0 plant.fmu, "fail3": ...}``:
    copies (this process's own) of the plants built once per session
    (``tests/session_cache.py``)."""
    return copied_plants(shared_tmp, tmp_path_factory.mktemp("plants"),
                         {"ok2": ("ok", "2.0"), "ok3": ("ok", "3.0"), "fail3": ("fail", "3.0")})


def _cli(args: list[str], cwd: Path) -> subprocess.CompletedProcess[str]:
    """``ftc-verify ARGS`` in ``cwd`` (also its temporary folder), in this process
    (``tests/cli_inprocess.py``: exit code, stdout and stderr as a subprocess gives them)."""
    return cli_inprocess.run_cli(args, cwd, {"TMPDIR": str(cwd)})


def _loaded(folder: Path) -> tuple:
    return (load_system(folder / "system.toml"), load_controller(folder / "K.toml"),
            load_plant_map(folder / "plant.toml"))


def _run(folder: Path, paths: list, **kw) -> tuple:
    system, controller, plant = _loaded(folder)
    with Supervisor(plant.fmu, plant.injection_map(), system=system, tolerance=plant.tolerance, **kw) as sup:
        res = sup.run(paths, controller, step=0.01, seed=3)
        return res, sup.session.fmi_version, dict(sup.stats)


# ------------------------------------------------------------------------------------------ the FMU


def test_the_built_fmu_is_fmi3_and_valid(plants: dict[str, Path]) -> None:
    from fmpy import platform_tuple, read_model_description
    from fmpy.validation import validate_fmu

    fmu = plants["ok3"] / "plant.fmu"
    assert validate_fmu(str(fmu)) == []
    md = read_model_description(str(fmu))
    assert md.fmiVersion == "3.0" and md.coSimulation is not None and md.modelExchange is None
    assert {v.type for v in md.modelVariables} == {"Float64"}
    with zipfile.ZipFile(fmu) as zf:
        assert f"binaries/{platform_tuple}/Plant_ok.so" in zf.namelist()


def test_supervisor_equals_the_fmi2_plant_path_by_path(plants: dict[str, Path]) -> None:
    """The same paths, controller and disturbance on the FMI 2.0 and FMI 3.0 FMUs of one
    model: every record agrees to 1e-8 (x, u, y, y_m on the same grid)."""
    system = load_system(plants["ok2"] / "system.toml")
    paths = sample_paths(system.chain, 4.0, 6, 11)
    res2, v2, _ = _run(plants["ok2"], paths)
    res3, v3, stats3 = _run(plants["ok3"], paths)
    assert (v2, v3) == ("2.0", "3.0")
    assert stats3["paths"] == 6 and stats3["instantiations"] == 1 and stats3["resets"] == 5
    assert len(res2.records) == len(res3.records) == 6
    for r2, r3 in zip(res2.records, res3.records):
        assert r2.failure is None and r3.failure is None
        np.testing.assert_array_equal(r2.t, r3.t)
        for name in ("x", "u", "y", "ym"):
            np.testing.assert_allclose(getattr(r3, name), getattr(r2, name), rtol=0, atol=1e-8)
        assert abs(r2.y_norm - r3.y_norm) <= 1e-8
    assert res3.options["model_identifier"] == "Plant_ok"


# ------------------------------------------------------------------------------------------ the CLI


def test_plant_command_says_fmi3(plants: dict[str, Path]) -> None:
    out = _cli(["plant", "plant.toml"], plants["ok3"])
    assert out.returncode == 0 and out.stderr == "", out
    assert "FMI 3.0" in out.stdout and "x: Float64 local/continuous" in out.stdout
    out = _cli(["plant", "plant.toml", "--json"], plants["ok3"])
    assert out.returncode == 0 and json.loads(out.stdout)["fmi_version"] == "3.0"


def test_simulate_and_linearize_agree_with_fmi2(plants: dict[str, Path]) -> None:
    sim = ["simulate", "system.toml", "--controller", "K.toml", "--plant", "plant.toml", "--paths", "4",
           "--horizon", "3", "--seed", "5", "--json"]
    got = {}
    for key in ("ok2", "ok3"):
        out = _cli(sim, plants[key])
        assert out.returncode == 0 and out.stderr == "", out
        got[key] = json.loads(out.stdout)
    assert got["ok3"]["options"]["fmu"].endswith("ok3/plant.fmu")
    np.testing.assert_allclose(got["ok3"]["y_norm"], got["ok2"]["y_norm"], rtol=0, atol=1e-8)
    for route in ("finite-differences", "identification"):
        lins = [linearize_plant(load_plant_map(plants[key] / "plant.toml"), route=route) for key in ("ok2", "ok3")]
        for m2, m3 in zip(lins[0].modes, lins[1].modes):
            for name in ("A", "B", "D", "C", "Cy"):
                np.testing.assert_allclose(getattr(m3, name), getattr(m2, name), rtol=0, atol=1e-8)
    out = _cli(["linearize", "plant.toml", "-o", "lin.toml"], plants["ok3"])
    assert out.returncode == 0 and "verdict: done" in out.stdout, out
    assert (plants["ok3"] / "lin.toml").is_file()


def test_verify_runs_on_the_fmi3_plant(plants: dict[str, Path]) -> None:
    out = _cli(["verify", "system.toml", "--controller", "K.toml", "--plant", "plant.toml", "--paths", "20",
                "--horizon", "3", "--seed", "1", "--out", "rep"], plants["ok3"])
    assert out.returncode == 0 and out.stderr == "", out
    report = json.loads((plants["ok3"] / "rep" / "report.json").read_text())
    mc = next(c for c in report["checks"] if c["name"] == "Monte Carlo (FMU)")
    assert mc["ok"], mc


def test_directional_route_through_fmi3(tmp_path: Path) -> None:
    """The DC motor (exact Jacobians): ``providesDirectionalDerivatives`` of FMI 3.0 offers
    the directional route, whose matrices equal those of the FMI 2.0 motor."""
    shutil.copy(ROOT / "examples" / "motor.plant.toml", tmp_path / "motor.plant.toml")
    lins = []
    for version in ("2.0", "3.0"):
        build_ode_fmu(motor_spec(), tmp_path / "Motor.fmu", fmi_version=version)
        lins.append(linearize_plant(load_plant_map(tmp_path / "motor.plant.toml")))
    assert [lin.route for lin in lins] == ["directional", "directional"]
    for m2, m3 in zip(*(lin.modes for lin in lins)):
        np.testing.assert_allclose(np.hstack([m3.A, m3.B, m3.D]), np.hstack([m2.A, m2.B, m2.D]), rtol=1e-12, atol=0)


def _retype(folder: Path, dest: Path, element: str) -> Path:
    """A copy of the FMI 3.0 plant with one more variable ``bad`` of type ``element``
    (in the model description only) and a map naming it as the state."""
    dest.mkdir()
    extra = {"Float32": '<Float32 name="bad" valueReference="100" causality="local" variability="continuous" '
                        'initial="exact" start="0.0"/>',
             "Int32": '<Int32 name="bad" valueReference="100" causality="local" variability="discrete" '
                      'initial="exact" start="0"/>'}[element]
    with zipfile.ZipFile(folder / "plant.fmu") as src, zipfile.ZipFile(dest / "plant.fmu", "w") as out:
        for info in src.infolist():
            data = src.read(info.filename)
            if info.filename == "modelDescription.xml":
                data = data.replace(b"</ModelVariables>", extra.encode() + b"\n  </ModelVariables>")
            out.writestr(info, data)
    for name in ("system.toml", "K.toml"):
        shutil.copy(folder / name, dest / name)
    text = (folder / "plant.toml").read_text()
    (dest / "plant.toml").write_text(text.replace('states = ["x"]', 'states = ["bad"]', 1)
                                     .replace('initial_states = ["x"]', "initial_states = []", 1))
    return dest


@pytest.mark.parametrize("element", ["Float32", "Int32"])
def test_a_state_that_is_not_float64_is_refused(plants: dict[str, Path], tmp_path: Path, element: str) -> None:
    folder = _retype(plants["ok3"], tmp_path / element, element)
    for args in (["plant", "plant.toml"],
                 ["simulate", "system.toml", "--controller", "K.toml", "--plant", "plant.toml", "--paths", "2"]):
        out = _cli(args, folder)
        assert out.returncode == 2 and out.stdout == "" and out.stderr.count("\n") == 1, out
        assert "plant.fmu" in out.stderr and f"'bad' (state x) has type {element}; expected Float64" in out.stderr
    with pytest.raises(FMUError, match=f"has type {element}; expected Float64"):
        FMUSession(folder / "plant.fmu", load_plant_map(folder / "plant.toml").injection_map())


# ------------------------------------------------------------------------------------------ failures


def test_fmi3_error_in_do_step_is_a_failed_path(plants: dict[str, Path]) -> None:
    """``fmi3DoStep`` returns ``fmi3Error`` once t > 2 (sqrt of a negative number): each path
    becomes a failed record at t = 2 naming the FMU file, the call and the FMU's message,
    and the next path runs on the same instance (reset)."""
    system = load_system(plants["fail3"] / "system.toml")
    paths = sample_paths(system.chain, 4.0, 3, 1)
    res, version, stats = _run(plants["fail3"], paths)
    assert version == "3.0" and stats["paths"] == 3 and stats["instantiations"] == 1
    for r in res.records:
        assert r.diverged_at == r.t[-1] == 2.0
        assert str(plants["fail3"] / "plant.fmu") in r.failure
        assert "fmi3DoStep returned Error at t = 2.0" in r.failure and "der(x) is not finite" in r.failure
        assert "fmi2" not in r.failure


def test_a_signal_inside_the_fmi3_logger_is_not_dropped(plants: dict[str, Path]) -> None:
    """The log sink raises KeyboardInterrupt at the 50th message (as a SIGINT handler
    would, inside the FMI 3.0 logMessage callback): the run ends after the FMI call returns."""
    system, controller, plant = _loaded(plants["ok3"])
    count = {"n": 0}

    def log(status: str, category: str, message: str) -> None:
        count["n"] += 1
        if count["n"] == 50:
            raise KeyboardInterrupt

    paths = sample_paths(system.chain, 4.0, 3, 1)
    with Supervisor(plant.fmu, plant.injection_map(), system=system, log=log) as sup:
        with pytest.raises(KeyboardInterrupt):
            sup.run(paths, controller, step=0.01)
        assert sup.stats["paths"] == 0 and count["n"] < 200
        assert any("fmi3DoStep to t = " in text for _, _, text in sup.messages)
