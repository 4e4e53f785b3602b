"""The three-tank benchmark (examples/three_tank): physics of the built FMU and the
tutorial's recipe end to end.

* mass balance: with two accumulator states added to the model (integrated inflow and
  outflow), stored volume + outflow - inflow stays constant to 1e-8 relative on the
  co-simulation FMU (tolerance 1e-12), in every fault mode, with inputs that change;
* model exchange (fmpy's CVode, rtol 1e-10) and co-simulation (the FMU's Dormand-Prince
  5(4), tolerance 1e-10) agree to 1e-7 relative;
* exact directional derivatives equal central differences of the model-exchange
  derivatives (1e-6 relative), also at equal levels where the regularised square root acts;
* the tutorial's recipe (``docs/tutorials/three-tank.md``: build-fmu, linearize --trim,
  synthesize, verify --plant --measure incremental, state and output feedback) passes
  with reduced paths (in two tests, the state- and the output-feedback part, which the
  pytest-xdist workers share).
"""

from __future__ import annotations

import itertools
import json
import shutil
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pymoca")
pytest.importorskip("casadi")
fmpy = pytest.importorskip("fmpy")
if shutil.which("gcc") is None:  # pragma: no cover
    pytest.skip("gcc is needed to compile the FMUs", allow_module_level=True)

from fmpy import extract, read_model_description, simulate_fmu
from fmpy.fmi2 import FMU2Model, fmi2Real

from tutorials import DOCS, PARTS, run_tutorial

from ftc_verify.plants.modelica import build_modelica_fmu

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "three_tank"
PAGE = DOCS / "tutorials" / "three-tank.md"
AREA = 0.0154
FAULTS = [{}, {"f_pump1": 0.6}, {"leak1": 1e-5}, {"clog13": 0.5}]
#: pump commands stepping at t = 20 s and 40 s, a disturbance pulse from 10 s to 30 s
SIGNAL = np.array([(0.0, 3.5e-5, 2.4e-5, 0.0), (10.0, 3.5e-5, 2.4e-5, 2.0), (20.0, 6.0e-5, 2.4e-5, 2.0),
                   (30.0, 6.0e-5, 1.0e-5, 0.0), (40.0, 1.0e-5, 8.0e-5, 0.0), (60.0, 1.0e-5, 8.0e-5, 0.0)],
                  dtype=[("time", float), ("q1", float), ("q2", float), ("q_d", float)])


def _steps(signal: np.ndarray) -> np.ndarray:
    """Piecewise-constant form for fmpy: each change as two rows at the same time."""
    rows = [tuple(signal[0])]
    for prev, row in itertools.pairwise(signal):
        rows.append((row["time"],) + tuple(prev)[1:])
        rows.append(tuple(row))
    return np.array(rows, dtype=signal.dtype)


@pytest.fixture(scope="module")
def cache(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    folder = tmp_path_factory.mktemp("tt-cache")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("FTC_VERIFY_CACHE", str(folder))
        yield folder


@pytest.fixture(scope="module")
def three_tank_fmu(cache: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return build_modelica_fmu(EXAMPLE / "ThreeTank.mo", dest=tmp_path_factory.mktemp("tt") / "ThreeTank.fmu")


@pytest.fixture(scope="module")
def balance_fmu(cache: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The model with two accumulator states added (integrated inflow and outflow), built
    once for the four fault modes (a fault is a start value, not a model change)."""
    text = (EXAMPLE / "ThreeTank.mo").read_text()
    text = text.replace("equation\n", '  Real V_in(start = 0, fixed = true, unit = "m3") "integrated inflow";\n'
                        '  Real V_out(start = 0, fixed = true, unit = "m3") "integrated outflow";\nequation\n'
                        "  der(V_in) = f_pump1*q1 + q2 + q_unit*q_d;\n  der(V_out) = q20 + q_leak;\n", 1)
    assert "der(V_out)" in text
    folder = tmp_path_factory.mktemp("tt-balance")
    mo = folder / "ThreeTank.mo"
    mo.write_text(text)
    return build_modelica_fmu(mo, dest=folder / "Balance.fmu")


@pytest.mark.parametrize("fault", FAULTS, ids=["nominal", "pump", "leak", "clog"])
def test_mass_balance(balance_fmu: Path, fault: dict[str, float]) -> None:
    res = simulate_fmu(str(balance_fmu), fmi_type="CoSimulation", stop_time=60.0, output_interval=0.5,
                       relative_tolerance=1e-12, input=_steps(SIGNAL), start_values=fault,
                       output=["h1", "h2", "h3", "V_in", "V_out"])
    stored = AREA * (res["h1"] + res["h2"] + res["h3"])
    balance = stored + res["V_out"] - res["V_in"]
    assert res["V_in"][-1] > 1e-3 and res["V_out"][-1] > 1e-3  # something flowed
    assert np.max(np.abs(balance - balance[0])) <= 1e-8 * stored[0]


@pytest.mark.parametrize("fault", FAULTS[::3], ids=["nominal", "clog"])
def test_model_exchange_and_co_simulation_agree(three_tank_fmu: Path, fault: dict[str, float]) -> None:
    runs = {kind: simulate_fmu(str(three_tank_fmu), fmi_type=kind, stop_time=60.0, output_interval=0.5,
                               relative_tolerance=1e-10, input=_steps(SIGNAL), start_values=fault,
                               output=["h1", "h2", "h3"], **({"solver": "CVode"} if kind == "ModelExchange" else {}))
            for kind in ("ModelExchange", "CoSimulation")}
    me, cs = runs["ModelExchange"], runs["CoSimulation"]
    for t in (me["time"], cs["time"]):
        assert t[-1] == 60.0
    grid = np.linspace(0.0, 60.0, 121)

    def at(res: np.ndarray, name: str) -> np.ndarray:  # fmpy may record both sides of an input step
        t, v = res["time"], res[name]
        last = np.r_[t[1:] != t[:-1], True]
        return np.interp(grid, t[last], v[last])

    for name in ("h1", "h2", "h3"):
        a, b = at(me, name), at(cs, name)
        assert np.max(np.abs(a - b)) <= 1e-7 * np.max(np.abs(b)), name


def test_directional_derivatives_equal_finite_differences(three_tank_fmu: Path, tmp_path: Path) -> None:
    md = read_model_description(str(three_tank_fmu))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    unzipdir = extract(str(three_tank_fmu), str(tmp_path / "unzip"))
    fmu = FMU2Model(guid=md.guid, unzipDirectory=unzipdir, modelIdentifier=md.modelExchange.modelIdentifier,
                    instanceName="dd")
    fmu.instantiate()
    try:
        fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode()
        fmu.exitInitializationMode()
        fmu.enterContinuousTimeMode()
        states = [vr["h1"], vr["h2"], vr["h3"]]
        derivs = [vr["der(h1)"], vr["der(h2)"], vr["der(h3)"]]
        known = states + [vr["q1"], vr["q2"], vr["q_d"]]
        for clog, point in ((0.0, [0.4, 0.2, 0.3, 3.5e-5, 2.4e-5, 0.5]), (0.5, [0.3, 0.3, 0.3, 5e-5, 1e-5, 0.0]),
                            (0.0, [0.3, 0.2, 0.3, 0.0, 0.0, 1.0])):
            fmu.setReal([vr["clog13"]], [clog])

            def f(z: np.ndarray) -> np.ndarray:
                fmu.setContinuousStates((fmi2Real * 3)(*z[:3]), 3)
                fmu.setReal(known[3:], list(z[3:]))
                return np.array(fmu.getReal(derivs))

            z0 = np.array(point)
            f(z0)
            exact = np.column_stack([fmu.getDirectionalDerivative(derivs, [k], [1.0]) for k in known])
            fd = np.empty_like(exact)
            for j in range(len(known)):
                h = 1e-6 * max(1e-5 if j in (3, 4) else 1.0, abs(z0[j]))
                e = np.zeros_like(z0)
                e[j] = h
                fd[:, j] = (f(z0 + e) - f(z0 - e)) / (2 * h)
            scale = np.max(np.abs(exact), axis=0)
            assert np.all(scale > 0)
            assert np.max(np.abs(fd - exact) / scale) <= 1e-6, (clog, point, exact, fd)
    finally:
        fmu.terminate()
        fmu.freeInstance()


@pytest.mark.slow(45)  # seconds measured on 2 busy cores: scheduled first
def test_tutorial_recipe_state_feedback_passes_with_reduced_paths(tmp_path: Path, shared_tmp: Path) -> None:
    """The commands of ``docs/tutorials/three-tank.md`` up to the state-feedback ``verify``
    (build-fmu -> linearize --trim -> synthesize -> verify --plant --measure incremental),
    run by :func:`tutorials.run_tutorial` with 10 paths of 300 s (the page: 200 paths of
    600 s); the first three are shared with three-tank-risk, the output-feedback commands
    are the next test's (``tutorials.PARTS``). The Monte Carlo's false failure probability
    is at most its alpha, 1e-6, per verify, for a controller whose incremental gain really
    is below the certified gamma; the seed is fixed."""
    after, run = PARTS["three-tank.md"]["state-feedback"]
    root, results = run_tutorial(PAGE, tmp_path, shared_tmp, after=after, run=run)
    work = root / "examples" / "three_tank"
    lin = next(out for line, out in results.items() if line.startswith("ftc-verify linearize three_tank.plant.toml"))
    assert "drift" in lin.stdout
    rep = json.loads((work / "report" / "report.json").read_text())
    assert rep["gamma_certified"] is not None and (work / "K.toml").is_file()  # the synthesized design, certified
    plant = rep["plant"]
    assert rep["verdict"] == "pass" and plant["measure"] == "incremental" and plant["left_region"] == 0
    assert plant["upper_bound"] <= rep["gamma_certified"] ** 2
    assert plant["fault_response_energy"] > 0.0
    lo, hi = plant["input_range"]
    assert min(lo) >= 0.0 and max(hi) <= 1e-4  # the pumps stayed within 0 .. 100 ml/s
    assert (work / "report" / "fig1_path.png").stat().st_size > 0


@pytest.mark.slow(45)  # seconds measured on 2 busy cores: scheduled first
def test_tutorial_recipe_output_feedback_passes_with_reduced_paths(tmp_path: Path, shared_tmp: Path) -> None:
    """The output-feedback commands of ``docs/tutorials/three-tank.md`` (synthesize
    --output-feedback --method observer -> verify --plant --measure incremental), after the
    page's first three commands (restored from their one run in the session), with 10 paths
    of 300 s; the same false failure probability as above."""
    after, run = PARTS["three-tank.md"]["output-feedback"]
    root, _ = run_tutorial(PAGE, tmp_path, shared_tmp, after=after, run=run)
    work = root / "examples" / "three_tank"
    of = json.loads((work / "report_of" / "report.json").read_text())
    assert of["verdict"] == "pass" and of["plant"]["left_region"] == 0
