"""A user's own FMU through a plant map (issue 11).

- The ``LinearJumpPlant`` through the map ``build_fmu`` writes reproduces the co-simulation
  of the hand-built map bit for bit, and ``linearize`` recovers its matrices to 1e-7 by the
  step-response identification route (its only route: no derivatives exposed).
- The nonlinear DC-motor test FMU (built here by ``ftc_verify.plants.ode_fmu``) linearised by
  each of its three routes agrees with python-control's ``linearize`` of the same FMU wrapped
  as a ``control.NonlinearIOSystem`` (1e-6 relative to the largest entry, also in the faulty
  mode, whose operating point is not an equilibrium).
- ``--trim`` finds the nominal stationary point; the loop runs in deviation variables;
  a failing ``fmi2Reset`` is recovered by re-instantiation; fixed-step FMUs get snapped jumps.
- Map errors each give one clear error and exit 2 on the command line (the commands run
  in process, ``tests/cli_inprocess.py``).
"""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import cli_inprocess
import numpy as np
import pytest

from ftc_verify.controllers import Controller
from ftc_verify.errors import FMUError, ProblemFileError
from ftc_verify.model.files import load_system
from ftc_verify.plants.fault_map import FaultInjectionMap
from ftc_verify.plants.linear_jump import build_fmu
from ftc_verify.plants.linearize import _Probe, linearize_plant, trim_plant
from ftc_verify.plants.ode_fmu import build_ode_fmu, motor_spec
from ftc_verify.plants.plant_map import load_plant_map, map_path_for
from ftc_verify.plants.fmu_session import FMUSession
from ftc_verify.simulation.paths import sample_paths, snap_to_grid
from ftc_verify.simulation.supervisor import Supervisor, open_supervisor, simulate_fmu

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "examples" / "paper.toml"
MAP = ROOT / "examples" / "motor.plant.toml"

if shutil.which("gcc") is None:  # pragma: no cover
    pytest.skip("gcc is needed to compile the FMUs", allow_module_level=True)


@pytest.fixture(scope="module", autouse=True)
def _isolated_cache(tmp_path_factory: pytest.TempPathFactory):
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("FTC_VERIFY_CACHE", str(tmp_path_factory.mktemp("ftc-verify-cache")))
        yield


@pytest.fixture(scope="module")
def motor_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("motor")
    build_ode_fmu(motor_spec(), d / "Motor.fmu")
    shutil.copy(MAP, d / "motor.plant.toml")
    return d


def _write_map(folder: Path, text: str) -> Path:
    p = folder / "plant.toml"
    p.write_text(text)
    return p


def run_cli(args: list[str], cwd: Path) -> subprocess.CompletedProcess[str]:
    """``ftc-verify ARGS`` in ``cwd``, in this process (``tests/cli_inprocess.py``: what a
    subprocess would get and print, the FMU's own output at the file descriptors too)."""
    return cli_inprocess.run_cli(args, cwd)


# ---------------------------------------------------------------------------------- LinearJumpPlant


def test_linear_jump_plant_through_its_map_is_bit_for_bit() -> None:
    system = load_system(PAPER)
    ctrl = Controller.state_feedback([np.array([[-1.0, -2.0], [0.5, -3.0]]), np.array([[-2.0, 0.0], [0.0, -2.0]])])
    paths = sample_paths(system.chain, 3.0, 4, 5)
    via_map = simulate_fmu(system, ctrl, paths, step=0.01, seed=1)
    with Supervisor(build_fmu(system), FaultInjectionMap.for_linear_jump_plant(system), system=system) as sup:
        direct = sup.run(paths, ctrl, step=0.01, seed=1)
    for a, b in zip(via_map.records, direct.records):
        for key in ("x", "u", "y", "w", "ym"):
            np.testing.assert_array_equal(getattr(a, key), getattr(b, key))
    assert via_map.options["model_identifier"] == "LinearJumpPlant"
    assert via_map.to_dict()["fmu"].endswith(".fmu")


def test_linearize_recovers_the_linear_jump_plant() -> None:
    system = load_system(PAPER)
    pm = load_plant_map(map_path_for(build_fmu(system)))
    lin = linearize_plant(pm)
    assert lin.route == "identification"
    back = lin.system(system.name, pm.chain)
    for got, want in zip(back.modes, system.modes):
        for key in ("A", "B", "C", "D"):
            np.testing.assert_allclose(getattr(got, key), getattr(want, key), rtol=0, atol=1e-7, err_msg=key)
    assert not lin.notes  # the origin is an equilibrium of every mode


# ---------------------------------------------------------------------------------- nonlinear motor


@pytest.mark.parametrize("route", ["directional", "finite-differences", "identification"])
def test_motor_routes_agree_with_python_control(motor_dir: Path, route: str) -> None:
    import control

    pm = load_plant_map(motor_dir / "motor.plant.toml")
    lin = linearize_plant(pm, route=route)
    assert lin.route == route
    for mode, m in enumerate(lin.modes):
        with FMUSession(pm.fmu, pm.injection_map(), tolerance=1e-12) as session:
            probe = _Probe(session, pm)
            sys_ = control.NonlinearIOSystem(
                lambda t, x, u, params, probe=probe, mode=mode: probe.derivative(mode, np.asarray(x, float), np.asarray(u, float)),
                lambda t, x, u, params, probe=probe, mode=mode: probe.outputs(mode, np.asarray(x, float), np.asarray(u, float)),
                states=2, inputs=2, outputs=2)
            ref = control.linearize(sys_, pm.states_op, np.concatenate([pm.inputs_op, pm.disturbances_op]))
        got = np.hstack([m.A, m.B, m.D])
        want = np.hstack([ref.A, ref.B])
        assert np.max(np.abs(got - want)) <= 1e-6 * np.max(np.abs(want)), (route, mode, got, want)
        np.testing.assert_allclose(np.vstack([m.C, m.Cy]), ref.C, rtol=0, atol=1e-6)
        assert m.errors["A"] <= max(1e-6, np.max(np.abs(got - want)) * 10) * np.max(np.abs(want))
    assert any("mode 2 (demagnetised): drift" in note for note in lin.notes)


def test_trim_finds_the_nominal_stationary_point(motor_dir: Path) -> None:
    pm = load_plant_map(motor_dir / "motor.plant.toml")
    x = trim_plant(pm, x_guess=np.array([80.0, 5.0]))
    np.testing.assert_allclose(x, [100.0, 7.0], rtol=1e-8)


def test_the_loop_runs_in_deviation_variables(motor_dir: Path) -> None:
    pm = load_plant_map(motor_dir / "motor.plant.toml")
    system = linearize_plant(pm).system("motor", pm.chain)
    ctrl = Controller.state_feedback([np.array([[-0.5, -0.1]])] * 2)
    one_mode = sample_paths(system.chain, 1.0, 1, 0, beta=system.chain.beta_min)
    one_mode = [type(p)(p.times[:1], p.true[:1], p.fdi[:1], p.beta, p.horizon) for p in one_mode]  # nominal only
    res = simulate_fmu(system, ctrl, one_mode, step=0.01, disturbance="zero", plant=pm)
    rec = res.records[0]
    # at the trim, with w = 0, the deviations stay zero: the controller adds u_op
    assert np.max(np.abs(rec.x)) < 1e-9 and np.max(np.abs(rec.u)) < 1e-9 and np.max(np.abs(rec.y)) < 1e-9
    # a disturbance moves the plant; records hold deviations, not absolute values near 100
    res = simulate_fmu(system, ctrl, one_mode, step=0.01, disturbance="step", plant=pm)
    assert 0 < np.max(np.abs(res.records[0].x[:, 0])) < 50


def test_failed_reset_reinstantiates(motor_dir: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from fmpy.fmi1 import FMICallException

    pm = load_plant_map(motor_dir / "motor.plant.toml")
    system = linearize_plant(pm).system("motor", pm.chain)
    ctrl = Controller.state_feedback([np.array([[-0.5, -0.1]])] * 2)
    paths = sample_paths(system.chain, 1.0, 3, 2)
    with open_supervisor(system, pm) as sup:
        good = sup.run(paths, ctrl, step=0.01)

        def broken_reset() -> None:
            raise FMICallException("fmi2Reset", 3)

        monkeypatch.setattr(sup.session.slave, "reset", broken_reset)
        again = sup.run(paths, ctrl, step=0.01)
        assert sup.stats["reinstantiations"] >= 3
    for a, b in zip(good.records, again.records):
        np.testing.assert_allclose(a.x, b.x, rtol=0, atol=1e-12)


def test_fixed_step_fmus_get_jumps_on_their_grid() -> None:
    system = load_system(PAPER)
    path = sample_paths(system.chain, 5.0, 1, 7)[0]
    snapped, shift = snap_to_grid(path, 0.1)
    assert 0 < shift <= 0.05 + 1e-12
    assert np.allclose(snapped.times / 0.1, np.rint(snapped.times / 0.1))
    ctrl = Controller.state_feedback([np.zeros((2, 2))] * 2)
    with open_supervisor(system) as sup:
        sup.session.can_vary_step = False
        res = sup.run([path], ctrl, step=0.1)
    assert 0 < res.options["timing_error"] <= 0.05 + 1e-12
    np.testing.assert_array_equal(res.records[0].path.times, snapped.times)


# ---------------------------------------------------------------------------------- map errors

GOOD = """fmu = "Motor.fmu"
[variables]
inputs = ["V"]
disturbances = ["tau_load"]
states = ["omega", "i"]
performance = ["omega_out"]
[operating_point]
inputs = [12.0]
states = [100.0, 7.0]
[[fault]]
set = { k_eff = 1.0 }
[[fault]]
set = { k_eff = 0.5 }
"""


@pytest.mark.parametrize("edit, expect", [
    (lambda t: t.replace('"Motor.fmu"', '"Nope.fmu"'), "no such file"),
    (lambda t: t.replace('"omega_out"', '"omega_ot"'), "did you mean"),
    (lambda t: t.replace('inputs = ["V"]', 'inputs = ["omega_out"]'), "causality 'output'"),
    (lambda t: t.replace("k_eff", "J"), "variability 'fixed'"),
    (lambda t: t.replace('states = ["omega", "i"]\n', 'states = []\n').replace("states = [100.0, 7.0]", "states = []"),
     "states"),
    (lambda t: t + '[[fault]]\nset = { R_extra = 1.0 }\n', "fault[3].set names ['R_extra']"),
    (lambda t: t.replace("inputs = [12.0]", "inputs = [12.0, 1.0]"), "expected 1 numbers"),
])
def test_map_errors_exit_2_with_one_line(motor_dir: Path, edit, expect: str) -> None:
    folder = motor_dir / "bad"
    folder.mkdir(exist_ok=True)
    shutil.copy(motor_dir / "Motor.fmu", folder / "Motor.fmu")
    p = _write_map(folder, edit(GOOD))
    out = run_cli(["plant", str(p)], folder)
    assert out.returncode == 2, out
    assert expect in out.stderr and "Traceback" not in out.stderr and out.stderr.count("\n") == 1, out.stderr


def test_wrong_number_of_fault_tables_against_the_system(motor_dir: Path) -> None:
    from ftc_verify.model.system import FTCSystem, JointChain

    pm = load_plant_map(motor_dir / "motor.plant.toml")
    system = linearize_plant(pm).system("motor", pm.chain)
    off = np.ones((3, 3)) - np.eye(3)
    three = FTCSystem("three", system.modes + system.modes[:1], JointChain(0.5 * off - np.eye(3), off, 2 * off))
    with pytest.raises(ProblemFileError, match=r"2 \[\[fault\]\] tables, but the system 'three' has 3 modes"):
        open_supervisor(three, pm)


def test_empty_role_where_the_command_needs_it(motor_dir: Path) -> None:
    p = _write_map(motor_dir, GOOD.replace('inputs = ["V"]\n', "").replace("inputs = [12.0]\n", ""))
    with pytest.raises(ProblemFileError, match=r"\[variables\].inputs .* is empty, but linearize needs it"):
        linearize_plant(load_plant_map(p))


# ---------------------------------------------------------------------------------- commands


@pytest.mark.slow(8)  # seconds on 2 busy cores (--durations at load 9, / 4): scheduled first
def test_plant_linearize_simulate_verify_commands(motor_dir: Path) -> None:
    out = run_cli(["plant", "motor.plant.toml", "--check", "--json"], motor_dir)
    assert out.returncode == 0, out.stderr
    d = json.loads(out.stdout)
    assert d["model_identifier"] == "DCMotor" and d["provides_directional_derivative"]
    assert [r["changes_nothing"] for r in d["check"]] == [False, False]
    out = run_cli(["linearize", "motor.plant.toml"], motor_dir)
    assert out.returncode == 0 and "route directional" in out.stdout and "drift" in out.stdout, out
    _motor_files(motor_dir)
    out = run_cli(["simulate", "motor.toml", "--gains", "K.toml", "--plant", "motor.plant.toml", "--paths", "3",
                   "--horizon", "2", "--seed", "3", "--json"], motor_dir)
    assert out.returncode == 0, out.stderr
    d = json.loads(out.stdout)
    assert d["fmu"].endswith("Motor.fmu") and d["model_identifier"] == "DCMotor" and len(d["y_norm"]) == 3
    out = run_cli(["verify", "motor.toml", "--gains", "K.toml", "--plant", "motor.plant.toml", "--paths", "20",
                   "--horizon", "5", "--seed", "4", "--out", "rep"], motor_dir)
    assert out.returncode in (0, 1) and "plant region" in out.stdout, out
    plant = json.loads((motor_dir / "rep" / "report.json").read_text())["plant"]
    for key in ("fmu", "model_identifier", "mean_ratio", "upper_bound", "max_excursion", "linearisation_error",
                "left_region"):
        assert key in plant
    assert plant["model_identifier"] == "DCMotor" and len(plant["max_excursion"]) == 2
    assert 0 < plant["linearisation_error"] < 1  # nonlinear plant: nonzero, but the design holds near the point
    md = (motor_dir / "rep" / "report.md").read_text()
    assert "## Plant:" in md and "DCMotor" in md and "paths that left [region]" in md


def test_plant_check_flags_a_fault_that_changes_nothing(motor_dir: Path) -> None:
    p = _write_map(motor_dir, GOOD.replace("k_eff = 0.5", "k_eff = 1.0"))
    out = run_cli(["plant", str(p), "--check"], motor_dir)
    assert out.returncode == 1 and "CHANGES NOTHING" in out.stdout, out


def _motor_files(folder: Path) -> None:
    """The linearised system file and a small stabilising gain next to the map."""
    out = run_cli(["linearize", "motor.plant.toml", "-o", "motor.toml"], folder)
    assert out.returncode == 0, out.stderr
    (folder / "K.toml").write_text("[[gain]]\nK = [[-0.5, -0.1]]\n[[gain]]\nK = [[-0.5, -0.1]]\n")


def test_fmu_log_is_forwarded(motor_dir: Path) -> None:
    _motor_files(motor_dir)
    out = run_cli(["simulate", "motor.toml", "--gains", "K.toml", "--plant", "motor.plant.toml", "--paths", "2",
                   "--horizon", "0.5", "--seed", "3", "--fmu-log"], motor_dir)
    assert out.returncode == 0, out.stderr
    assert "[FMU OK]" in out.stderr and "DCMotor" in out.stdout


def test_trim_command(motor_dir: Path) -> None:
    text = (motor_dir / "motor.plant.toml").read_text().replace("states = [100.0, 7.0]", "")
    p = motor_dir / "untrimmed.toml"
    p.write_text(text)
    out = run_cli(["linearize", str(p), "--trim", "--json"], motor_dir)
    assert out.returncode == 0, out.stderr
    np.testing.assert_allclose(json.loads(out.stdout)["states_op"], [100.0, 7.0], rtol=1e-8)
    _motor_files(motor_dir)
    out = run_cli(["simulate", "motor.toml", "--gains", "K.toml", "--plant", str(p)], motor_dir)
    assert out.returncode == 2 and "[operating_point].states is missing" in out.stderr, out.stderr


def test_a_map_without_outputs_is_refused_not_read_as_zero() -> None:
    from ftc_verify.errors import ValidationError

    system = load_system(PAPER)
    base = FaultInjectionMap.for_linear_jump_plant(system)
    bare = FaultInjectionMap(fault=base.fault, inputs=base.inputs, states=base.states, disturbances=base.disturbances)
    ctrl = Controller.state_feedback([np.zeros((2, 2))] * 2)
    paths = sample_paths(system.chain, 1.0, 1, 0)
    with Supervisor(build_fmu(system), bare, system=system) as sup:
        with pytest.raises(ValidationError, match=r"names 0 outputs .* has 1; a missing role would read as zero"):
            sup.run(paths, ctrl, step=0.01)


def test_an_fmu_that_lags_behind_the_step_is_an_error(monkeypatch: pytest.MonkeyPatch) -> None:
    system = load_system(PAPER)
    ctrl = Controller.state_feedback([np.zeros((2, 2))] * 2)
    paths = sample_paths(system.chain, 1.0, 1, 0)
    with open_supervisor(system) as sup:
        monkeypatch.setattr(sup.session, "last_successful_time", lambda: 0.5)
        with pytest.raises(FMUError, match=r"fmi2LastSuccessfulTime = 0.5: it did not advance as asked"):
            sup.run(paths, ctrl, step=0.01)


def test_verify_plant_with_diverging_paths_reports_and_fails(motor_dir: Path) -> None:
    """High gains certified in continuous time diverge under sample-and-hold at h = 0.01
    (found by `synthesize --method iterative` without a gain bound): every plant path
    diverges; the verdict is fail (exit 1), and both reports are written with nulls."""
    _motor_files(motor_dir)
    (motor_dir / "K_high.toml").write_text("[[gain]]\nK = [[-20988.26, -96.37]]\n[[gain]]\nK = [[-5296.96, -53.65]]\n")
    out = run_cli(["verify", "motor.toml", "--gains", "K_high.toml", "--plant", "motor.plant.toml", "--paths", "5",
                   "--horizon", "2", "--seed", "4", "--out", "rep_high"], motor_dir)
    assert out.returncode == 1 and "Traceback" not in out.stderr, out
    assert "diverged" in out.stdout and "every compared path diverged" in out.stdout, out.stdout
    d = json.loads((motor_dir / "rep_high" / "report.json").read_text())
    assert d["verdict"] == "fail" and d["plant"]["left_region"] == 5 and d["plant"]["mean_ratio"] is None
    assert "| paths that left [region] (states or input limits) | 5 of 5 |" in (motor_dir / "rep_high" / "report.md").read_text()
    assert "| paths that failed in the plant FMU (not counted above) | 0 of 5 |" in (motor_dir / "rep_high" / "report.md").read_text()
