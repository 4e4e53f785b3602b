"""Modelica -> FMI 2.0 FMU without a Modelica tool (ftc_verify.plants.modelica: pymoca ->
CasADi -> C -> ode_fmu): a nonlinear tank builds, validates, equals its CasADi functions,
and simulates like scipy in ME and CS; a linear mass-matrix/algebraic-loop model is solved;
refused constructs give one clear error naming the construct, the file and the line."""

from __future__ import annotations

import dataclasses
import math
import shutil
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

pytest.importorskip("pymoca")
ca = pytest.importorskip("casadi")
fmpy = pytest.importorskip("fmpy")
if shutil.which("gcc") is None:  # pragma: no cover - gcc is on every supported machine
    pytest.skip("gcc is needed to compile the FMU", allow_module_level=True)

from fmpy import extract, read_model_description, simulate_fmu
from fmpy.fmi2 import FMU2Model
from fmpy.validation import validate_fmu

from ftc_verify.errors import FMUError, ValidationError
from ftc_verify.plants.modelica import (
    build_modelica_fmu,
    check_modelica_fmu,
    modelica_spec,
    translate_modelica,
)

TANK = """\
model Tank "Cylindrical tank with free outflow and a leak"
  parameter Real A(unit = "m2") = 0.0154 "tank cross-section";
  parameter Real k(unit = "m2.5/s") = 1.5e-4 "outflow coefficient";
  parameter Real leak(unit = "m2") = 1e-6 "fault: leak area";
  final parameter Real g(unit = "m/s2") = 9.81 "gravity";
  parameter Real c_d = 0.6 "leak discharge coefficient" annotation(Evaluate = true);
  input Real q_in(unit = "m3/s", start = 1e-4) "inflow";
  Real h(start = 0.3, fixed = true, unit = "m") "level";
  Real q_out(unit = "m3/s") "outflow";
  output Real level(unit = "m") = h "measured level";
equation
  q_out = k*sqrt(h) + c_d*leak*sqrt(2*g*h);
  A*der(h) = q_in - q_out;
  annotation(experiment(StopTime = 60, Interval = 0.5));
end Tank;
"""
NOMINAL = dict(A=0.0154, k=1.5e-4, leak=1e-6, g=9.81, c_d=0.6)
# value references: h, der(h), q_in, A, k, leak, g, c_d, level
VR = {name: n for n, name in enumerate(["h", "der(h)", "q_in", "A", "k", "leak", "g", "c_d", "level"], start=1)}


def tank_rhs(h: float, q_in: float, p: dict[str, float]) -> float:
    """The tank equation, written independently of the Modelica text."""
    return (q_in - p["k"] * math.sqrt(h) - p["c_d"] * p["leak"] * math.sqrt(2 * p["g"] * h)) / p["A"]


@pytest.fixture(scope="module", autouse=True)
def cache_root(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    root = tmp_path_factory.mktemp("modelica-cache")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("FTC_VERIFY_CACHE", str(root))
        yield root


@pytest.fixture(scope="module")
def tank_mo(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("mo") / "Tank.mo"
    path.write_text(TANK, encoding="utf-8")
    return path


@pytest.fixture(scope="module")
def tank_fmu(cache_root: Path, tank_mo: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return build_modelica_fmu(tank_mo, dest=tmp_path_factory.mktemp("fmu"))


def write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / f"{name}.mo"
    path.write_text(text, encoding="utf-8")
    return path


# ------------------------------------------------------------------------------------------
# The tank
# ------------------------------------------------------------------------------------------


def test_tank_builds_and_validates(tank_fmu: Path) -> None:
    assert tank_fmu.name == "Tank.fmu"
    assert validate_fmu(str(tank_fmu)) == []
    md = read_model_description(str(tank_fmu))
    assert md.description == "Cylindrical tank with free outflow and a leak"
    assert md.modelExchange is not None and md.coSimulation is not None
    assert md.modelExchange.providesDirectionalDerivative
    assert (md.defaultExperiment.stopTime, md.defaultExperiment.stepSize) == ("60.0", "0.5")
    got = {v.name: (v.valueReference, v.causality, v.variability, v.unit, v.description) for v in md.modelVariables}
    assert got["h"] == (1, "local", "continuous", "m", "level")
    assert got["q_in"] == (3, "input", "continuous", "m3/s", "inflow")
    assert got["k"] == (5, "parameter", "tunable", "m2.5/s", "outflow coefficient")
    assert got["leak"][2] == "tunable"
    assert got["g"][2] == "fixed"  # final
    assert got["c_d"][2] == "fixed"  # annotation(Evaluate = true)
    assert got["level"] == (9, "output", "continuous", "m", "measured level")
    assert "q_out" not in got  # algebraic variables are eliminated
    assert {v.name: v.valueReference for v in md.modelVariables} == VR
    starts = {v.name: float(v.start) for v in md.modelVariables if v.start is not None}
    assert starts == {"h": 0.3, "q_in": 1e-4, **NOMINAL}


def test_spec_and_c_source(tank_mo: Path) -> None:
    spec = modelica_spec(tank_mo)
    assert spec.model_name == "Tank" and spec.has_jacobian
    assert [v.name for v in spec.states] == ["h"] and [v.name for v in spec.outputs] == ["level"]
    for needle in ("ode_rhs", "ode_out", "ode_jac", "ODE_NX = 1, ODE_NU = 1, ODE_NP = 5, ODE_NY = 1"):
        assert needle in spec.c_source


def fmu_point(unzipdir: str, x: float, u: float, p: dict[str, float], t: float) -> tuple[float, float, list[float]]:
    """``(der(h), level, [d der(h)/dh, d der(h)/dq_in])`` computed by the FMU (Model Exchange)."""
    md = read_model_description(unzipdir)
    fmu = FMU2Model(guid=md.guid, unzipDirectory=unzipdir, modelIdentifier=md.modelExchange.modelIdentifier,
                    instanceName="point")
    fmu.instantiate()
    try:
        fmu.setupExperiment(startTime=t)
        fmu.enterInitializationMode()
        fmu.setReal([VR["h"], VR["q_in"], *(VR[k] for k in p)], [x, u, *p.values()])
        fmu.exitInitializationMode()
        fmu.newDiscreteStates()
        fmu.enterContinuousTimeMode()
        fmu.setTime(t)
        dx = fmu.getReal([VR["der(h)"], VR["level"]])
        jac = [fmu.getDirectionalDerivative([VR["der(h)"]], [VR[k]], [1.0])[0] for k in ("h", "q_in")]
        return dx[0], dx[1], jac
    finally:
        fmu.terminate()
        fmu.freeInstance()


def test_casadi_equals_fmu(tank_mo: Path, tank_fmu: Path, tmp_path: Path) -> None:
    translation = translate_modelica(tank_mo)
    unzipdir = extract(str(tank_fmu), unzipdir=str(tmp_path / "unzipped"))
    rng = np.random.default_rng(12)
    points = [(0.3, 1e-4, NOMINAL, 0.0)]
    points += [(0.3 * (1 + 0.05 * rng.uniform(-1, 1)), 1e-4 * (1 + 0.05 * rng.uniform(-1, 1)),
                {k: v * (1 + 0.05 * rng.uniform(-1, 1)) for k, v in NOMINAL.items()}, 1.7) for _ in range(3)]
    for x, u, p, t in points:
        args = [t, x, u, list(p.values())]
        dx = float(translation.rhs(*args))
        y = float(translation.out(*args))
        dfdx, dfdu = (float(a) for a in translation.jac(*args)[:2])
        got = fmu_point(unzipdir, x, u, p, t)
        assert abs(got[0] - dx) <= 1e-12 * abs(dx)
        assert got[1] == y == x
        assert abs(got[2][0] - dfdx) <= 1e-12 * abs(dfdx) and abs(got[2][1] - dfdu) <= 1e-12 * abs(dfdu)
        assert dx == pytest.approx(tank_rhs(x, u, p), rel=1e-13)
        assert dfdu == pytest.approx(1 / p["A"], rel=1e-13)
    check_modelica_fmu(tank_fmu, translation, seed=3)  # the check build_modelica_fmu ran


def test_check_catches_a_wrong_fmu(tank_mo: Path, tank_fmu: Path) -> None:
    translation = translate_modelica(tank_mo)
    t, x, u, p = ca.SX.sym("t"), ca.SX.sym("x"), ca.SX.sym("u"), ca.SX.sym("p", 5)
    off = ca.Function("rhs", [t, x, u, p], [translation.rhs(t, x, u, p) * (1 + 1e-10)])
    with pytest.raises(FMUError, match="derivatives differ from CasADi"):
        check_modelica_fmu(tank_fmu, dataclasses.replace(translation, rhs=off))


def reference(t_out: np.ndarray) -> np.ndarray:
    """h(t) by solve_ivp (DOP853, rtol 1e-12): q_in = 1e-4 until t = 20, then 2e-4."""
    out, h = np.full(len(t_out), np.nan), np.array([0.3])
    for t0, t1, q in ((0.0, 20.0, 1e-4), (20.0, 60.0, 2e-4)):
        mask = (t_out >= t0) & ((t_out < t1) if t1 < 60.0 else (t_out <= t1))
        sol = solve_ivp(lambda t, h, q=q: [tank_rhs(h[0], q, NOMINAL)], (t0, t1), h, method="DOP853", rtol=1e-12,
                        atol=1e-14, dense_output=True)
        assert sol.success
        out[mask] = sol.sol(t_out[mask])[0]
        h = sol.y[:, -1]
    return out


@pytest.mark.parametrize("fmi_type", ["ModelExchange", "CoSimulation"])
def test_simulation_matches_scipy(tank_fmu: Path, fmi_type: str) -> None:
    signal = np.array([(0.0, 1e-4), (20.0, 1e-4), (20.0, 2e-4), (60.0, 2e-4)], dtype=[("time", float), ("q_in", float)])
    kw = dict(solver="CVode") if fmi_type == "ModelExchange" else {}
    res = simulate_fmu(str(tank_fmu), fmi_type=fmi_type, stop_time=60.0, output_interval=0.5, relative_tolerance=1e-10,
                       input=signal, output=["h", "level"], **kw)
    t = res["time"]
    keep = np.r_[t[1:] != t[:-1], True]  # fmpy records both sides of the input step
    ref = reference(t[keep])
    assert np.array_equal(res["h"], res["level"])
    err = np.abs(res["h"][keep] - ref).max() / np.abs(ref).max()
    assert err < 1e-8, (fmi_type, err)


def test_linear_blocks_are_solved(tmp_path: Path) -> None:
    """A 2x2 mass matrix (der(v1), der(v2)) and a linear algebraic loop (a, b)."""
    mo = write(tmp_path, "Coupled", """\
model Coupled
  parameter Real m1 = 1, m2 = 2, c = 0.5;
  Real x1(start = 1), x2(start = -1), v1, v2, a, b;
  output Real e "energy";
equation
  der(x1) = v1;
  der(x2) = v2;
  m1*der(v1) + c*der(v2) = -x1 + a;
  c*der(v1) + m2*der(v2) = -x2*abs(x2) + sin(time);
  a + b = x1;
  a - 2*b = x2;
  e = 0.5*m1*v1^2 + 0.5*m2*v2^2;
end Coupled;
""")
    translation = translate_modelica(mo)
    x, t = np.array([0.4, -0.3, 0.2, 0.1]), 0.5
    a = (2 * x[0] + x[1]) / 3
    M = np.array([[1.0, 0.5], [0.5, 2.0]])
    acc = np.linalg.solve(M, [-x[0] + a, -x[1] * abs(x[1]) + math.sin(t)])
    np.testing.assert_allclose(np.array(translation.rhs(t, x, [], [1, 2, 0.5])).ravel(), [x[2], x[3], *acc],
                               rtol=1e-14, atol=1e-15)
    fmu = build_modelica_fmu(mo, dest=tmp_path / "Coupled.fmu")
    assert validate_fmu(str(fmu)) == []


# ------------------------------------------------------------------------------------------
# Refusals
# ------------------------------------------------------------------------------------------

WHEN = """\
model Bounce
  Real h(start = 1), v;
equation
  der(h) = v;
  der(v) = -9.81;
  when h < 0 then
    reinit(v, -0.8*v);
  end when;
end Bounce;
"""
FUNCTION = """\
model Squared
  function sq "a user function"
    input Real u;
    output Real y;
  algorithm
    y := u*u;
  end sq;
  Real x(start = 1);
equation
  der(x) = -sq(x);
end Squared;
"""
UNBALANCED = """\
model Unbalanced
  Real x(start = 1);
  Real w "never determined";
equation
  der(x) = -x;
end Unbalanced;
"""


@pytest.mark.parametrize("name, text, needles", [
    ("Bounce", WHEN, ["Bounce.mo:6:", "'when' clause"]),
    ("Squared", FUNCTION, ["Squared.mo:2:", "user 'function' definition"]),
    ("Unbalanced", UNBALANCED, ["Unbalanced.mo", "not balanced: 1 equation for 2 unknowns", "w"]),
])
def test_refusals(tmp_path: Path, name: str, text: str, needles: list[str]) -> None:
    with pytest.raises(ValidationError) as info:
        build_modelica_fmu(write(tmp_path, name, text), dest=tmp_path)
    message = str(info.value)
    assert "\n" not in message and "Traceback" not in message
    for needle in needles:
        assert needle in message, message
    assert not list(tmp_path.glob("*.fmu"))


@pytest.mark.parametrize("body, needles", [
    ("  parameter Real k(start = 2);\n  Real x(start = 1);\nequation\n  der(x) = -k*x;\n",
     [":2:", "parameter 'k' has no finite value", "only a start value"]),
    ("  input Integer mode;\n  parameter Real a[2] = {1, 2};\n  Real x;\nequation\n  der(x) = a[mode];\n",
     [":6:", "indexing by the variable 'mode'"]),
    ("  Real x[2,2,2];\nequation\n  der(x) = -x;\n", [":2:", "3-D array"]),
    ("  Real x(start = 1);\nequation\n  der(x) = -noEvent(abs(x));\n", [":4:", "noEvent()"]),
    ("  Real x(start = 1), w;\nequation\n  w + w^3 = x;\n  der(x) = -w;\n", ["nonlinear in them", "w"]),
    ("  Real x(start = 1), y;\nequation\n  der(x) = y;\n  x = sin(time);\n", ["cannot be solved for der(x), y"]),
    ("  parameter Real k = -1;\n  Real x(start = 1);\nequation\n  der(x) = sqrt(k)*x;\n",
     ["der(x) is nan at the start point"]),
])
def test_more_refusals(tmp_path: Path, body: str, needles: list[str]) -> None:
    mo = write(tmp_path, "M", f"model M\n{body}end M;\n")
    with pytest.raises(ValidationError) as info:
        modelica_spec(mo)
    for needle in needles:
        assert needle in str(info.value), str(info.value)


def test_missing_backend_names_the_extra(tank_mo: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "pymoca", None)  # import pymoca now raises ImportError
    with pytest.raises(FMUError, match=r"pip install 'ftc-verify\[modelica\]'"):
        modelica_spec(tank_mo)


# ------------------------------------------------------------------------------------------
# The example: examples/three_tank/ThreeTank.mo
# ------------------------------------------------------------------------------------------

THREE_TANK = Path(__file__).resolve().parents[1] / "examples" / "three_tank" / "ThreeTank.mo"


def test_three_tank_builds(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Builds and validates (its build time is measured in benchmarks/modelica_build.py)."""
    monkeypatch.setenv("FTC_VERIFY_CACHE", str(tmp_path / "fresh-cache"))  # compile for real
    fmu = build_modelica_fmu(THREE_TANK, dest=tmp_path)
    assert validate_fmu(str(fmu)) == []
    md = read_model_description(str(fmu))
    kinds = {v.name: (v.causality, v.variability) for v in md.modelVariables}
    assert [n for n, k in kinds.items() if k[0] == "output"] == ["y1", "y2", "y3"]
    assert [n for n, k in kinds.items() if k[0] == "input"] == ["q1", "q2", "q_d"]
    for fault in ("f_pump1", "leak1", "clog13"):
        assert kinds[fault] == ("parameter", "tunable")
    assert kinds["g"] == kinds["delta"] == ("parameter", "fixed")
    translation = translate_modelica(THREE_TANK)
    p = [v.start for v in translation.spec.parameters]
    u = [v.start for v in translation.spec.inputs]
    assert np.abs(np.array(translation.rhs(0.0, [0.4, 0.2, 0.3], u, p))).max() < 1e-8  # a steady state
    for h in ([0.3, 0.2, 0.3], [0.3, 0.3, 0.3], [0.0, 0.0, 0.0]):  # equal levels, empty tanks
        dfdx = np.array(translation.jac(0.0, h, u, p)[0])
        assert np.all(np.isfinite(dfdx)) and np.abs(dfdx).max() < 10.0, (h, dfdx)


def test_build_fmu_command(tmp_path: Path) -> None:
    """The command as a user runs it: exit 0 with a verdict line; a refused construct exit 2, one line."""
    import subprocess
    import sys

    three_tank = Path(__file__).resolve().parents[1] / "examples" / "three_tank" / "ThreeTank.mo"
    out = subprocess.run([sys.executable, "-m", "ftc_verify", "build-fmu", str(three_tank), "-o", "tt.fmu"],
                         capture_output=True, text=True, cwd=tmp_path, timeout=300)
    assert out.returncode == 0 and "verdict: built" in out.stdout, out.stderr
    assert not fmpy.validation.validate_fmu(str(tmp_path / "tt.fmu"))
    bad = tmp_path / "Bad.mo"
    bad.write_text("model Bad\n  Real x;\nequation\n  when x > 1 then\n  end when;\n  der(x) = -x;\nend Bad;\n")
    out = subprocess.run([sys.executable, "-m", "ftc_verify", "build-fmu", str(bad), "-o", "bad.fmu"],
                         capture_output=True, text=True, cwd=tmp_path, timeout=300)
    assert out.returncode == 2 and "Bad.mo:4" in out.stderr and "'when'" in out.stderr, out.stderr
    assert out.stderr.count("\n") == 1 and not (tmp_path / "bad.fmu").exists()


def test_three_tank_plant_map_resolves_and_linearises(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The example map against the built FMU: every role resolves, every fault acts, the
    nominal mode is a trim (no drift) and the faulty modes shift the equilibrium (drift noted)."""
    import shutil

    from ftc_verify.plants.linearize import linearize_plant
    from ftc_verify.plants.plant_map import load_plant_map

    monkeypatch.setenv("FTC_VERIFY_CACHE", str(tmp_path / "cache"))
    build_modelica_fmu(THREE_TANK, dest=tmp_path / "ThreeTank.fmu")
    shutil.copy(THREE_TANK.parent / "three_tank.plant.toml", tmp_path / "three_tank.plant.toml")
    pm = load_plant_map(tmp_path / "three_tank.plant.toml")
    lin = linearize_plant(pm)
    assert lin.route == "directional" and len(lin.modes) == 4
    assert np.linalg.norm(lin.modes[0].drift) < 1e-8
    assert all(np.linalg.norm(m.drift) > 1e-5 for m in lin.modes[1:])
    a = 0.0154
    np.testing.assert_allclose(lin.modes[0].B, [[1 / a, 0], [0, 1 / a], [0, 0]], rtol=1e-12)
    np.testing.assert_allclose(lin.modes[0].D, [[0], [0], [1e-5 / a]], rtol=1e-12)
    assert len(lin.notes) == 3
