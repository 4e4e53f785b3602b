"""Generic ODE FMUs (fmus/ode, ftc_verify.plants.ode_fmu) on the nonlinear DC motor plant:
validation, ME/CS trajectories against scipy, exact Jacobians, FMU state, reset, variable
communication steps, spec validation, compile errors, caching, error paths."""

from __future__ import annotations

import ctypes
import dataclasses
import math
import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

fmpy = pytest.importorskip("fmpy")
if shutil.which("gcc") is None:  # pragma: no cover - gcc is on every supported machine
    pytest.skip("gcc is needed to compile the FMU", allow_module_level=True)

from fmpy import calloc, extract, free, read_model_description, simulate_fmu
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import (
    FMU2Model,
    FMU2Slave,
    fmi2CallbackAllocateMemoryTYPE,
    fmi2CallbackFreeMemoryTYPE,
    fmi2CallbackFunctions,
    fmi2CallbackLoggerTYPE,
    fmi2Error,
    fmi2LastSuccessfulTime,
)
from fmpy.validation import validate_fmu

from ftc_verify.errors import FMUError, ValidationError
from ftc_verify.plants.ode_fmu import (
    OdeFmuSpec,
    OdeVariable,
    build_ode_binary,
    build_ode_fmu,
    motor_spec,
)

# value references of DCMotor (layout: states, der(states), inputs, parameters, outputs)
VR = {name: k for k, name in enumerate(
    ["omega", "i", "der(omega)", "der(i)", "V", "tau_load", "J", "b", "c", "R", "L", "K", "k_eff", "R_extra",
     "omega_meas", "omega_out", "i_meas"], start=1)}
NOMINAL = dict(J=0.01, b=5e-4, c=3e-5, R=1.0, L=0.05, K=0.05, k_eff=1.0, R_extra=0.0)


def motor_rhs(x: np.ndarray, u: tuple[float, float], p: dict[str, float]) -> np.ndarray:
    """The motor equations, written independently of the C source."""
    w, i = x
    V, tau = u
    kK = p["k_eff"] * p["K"]
    return np.array([(kK * i - p["b"] * w - p["c"] * w * abs(w) - tau) / p["J"],
                     (V - (p["R"] + p["R_extra"]) * i - kK * w) / p["L"]])


def reference(x0, pieces, p, t_eval) -> np.ndarray:
    """solve_ivp (DOP853, rtol 1e-10, atol 1e-12) over piecewise-constant inputs
    ``[(t0, t1, (V, tau_load)), ...]``, sampled at ``t_eval``."""
    t_eval = np.asarray(t_eval, dtype=float)
    out, x = np.full((len(t_eval), 2), np.nan), np.asarray(x0, dtype=float)
    for n, (t0, t1, u) in enumerate(pieces):
        upper = t_eval <= t1 if n == len(pieces) - 1 else t_eval < t1
        mask = (t_eval >= t0) & upper
        sol = solve_ivp(lambda t, x, u=u: motor_rhs(x, u, p), (t0, t1), x, method="DOP853", rtol=1e-10,
                        atol=1e-12, dense_output=True)
        assert sol.success
        out[mask] = sol.sol(t_eval[mask]).T
        x = sol.y[:, -1]
    assert not np.isnan(out).any()
    return out


@pytest.fixture(scope="module", autouse=True)
def cache_root(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    root = tmp_path_factory.mktemp("ode-cache")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("FTC_VERIFY_CACHE", str(root))
        yield root


@pytest.fixture(scope="module")
def motor_fmu(cache_root: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return build_ode_fmu(motor_spec(), tmp_path_factory.mktemp("fmu") / "DCMotor.fmu")


@pytest.fixture(scope="module")
def unzipped(motor_fmu: Path, tmp_path_factory: pytest.TempPathFactory) -> str:
    return extract(str(motor_fmu), unzipdir=str(tmp_path_factory.mktemp("unzipped")))


@contextmanager
def instance(unzipdir: str, kind: str = "CS", setup: bool = True, **start: float) -> Iterator[tuple[object, list]]:
    """An initialised instance (``kind`` 'CS' or 'ME') and the list its log messages go to."""
    md = read_model_description(unzipdir)
    cls = FMU2Slave if kind == "CS" else FMU2Model
    fmu = cls(guid=md.guid, unzipDirectory=unzipdir, modelIdentifier=md.coSimulation.modelIdentifier,
              instanceName=f"test{kind}")
    messages: list[str] = []
    cb = fmi2CallbackFunctions()
    cb.logger = fmi2CallbackLoggerTYPE(lambda env, name, status, cat, msg: messages.append(msg.decode()))
    cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
    cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
    fmu.instantiate(callbacks=cb)
    try:
        if setup:
            fmu.setupExperiment(tolerance=1e-10, startTime=0.0)
            fmu.setReal([VR[k] for k in start], list(start.values()))
            fmu.enterInitializationMode()
            fmu.exitInitializationMode()
            if kind == "ME":
                fmu.newDiscreteStates()
                fmu.enterContinuousTimeMode()
        yield fmu, messages
    finally:
        fmu.freeInstance()


def get(fmu, *names: str) -> list[float]:
    return fmu.getReal([VR[n] for n in names])


# ------------------------------------------------------------------------------------------
# Model description and validation
# ------------------------------------------------------------------------------------------


def test_fmu_validates_and_declares_both_interfaces(motor_fmu: Path) -> None:
    assert validate_fmu(str(motor_fmu)) == []
    md = read_model_description(str(motor_fmu))
    assert md.modelExchange is not None and md.coSimulation is not None
    for iface in (md.modelExchange, md.coSimulation):
        assert iface.providesDirectionalDerivative and iface.canGetAndSetFMUstate
    assert md.coSimulation.canHandleVariableCommunicationStepSize
    assert [(v.name, v.valueReference) for v in md.modelVariables] == list(VR.items())
    by = {v.name: v for v in md.modelVariables}
    assert (by["omega"].causality, by["omega"].initial, by["omega"].unit) == ("local", "exact", "rad/s")
    assert by["der(omega)"].derivative is by["omega"]
    assert by["V"].causality == "input" and float(by["V"].start) == 12.0
    assert (by["k_eff"].variability, by["J"].variability) == ("tunable", "fixed")
    knowns = {by[n] for n in ("omega", "i", "V", "tau_load")}
    for u in md.outputs + md.derivatives:
        assert set(u.dependencies) == knowns
    assert {u.variable.name for u in md.initialUnknowns} == {"der(omega)", "der(i)", "omega_meas", "omega_out",
                                                            "i_meas"}
    assert md.defaultExperiment.stopTime == "5.0"


# ------------------------------------------------------------------------------------------
# Trajectories against scipy
# ------------------------------------------------------------------------------------------

START = dict(omega=10.0, i=1.0, k_eff=0.8)
T_OUT = np.round(np.arange(0.0, 3.0 + 1e-9, 0.05), 10)


def _tau_input() -> np.ndarray:
    """V = 12; tau_load 0 until t = 1.5, then 0.05 N m (a step)."""
    return np.array([(0.0, 12.0, 0.0), (1.5, 12.0, 0.0), (1.5, 12.0, 0.05), (3.0, 12.0, 0.05)],
                    dtype=[("time", float), ("V", float), ("tau_load", float)])


@pytest.mark.parametrize("fmi_type", ["ModelExchange", "CoSimulation"])
def test_trajectory_matches_scipy(motor_fmu: Path, fmi_type: str) -> None:
    kw = dict(solver="CVode", output_interval=0.05) if fmi_type == "ModelExchange" else dict(output_interval=0.05)
    res = simulate_fmu(str(motor_fmu), fmi_type=fmi_type, start_time=0.0, stop_time=3.0, relative_tolerance=1e-10,
                       start_values=START, input=_tau_input(), output=["omega", "i", "omega_meas", "i_meas"], **kw)
    p = {**NOMINAL, "k_eff": 0.8}
    # fmpy records both sides of the input step at t = 1.5: keep the last sample per time
    t = res["time"]
    keep = np.r_[t[1:] != t[:-1], True] & np.isin(np.round(t, 10), T_OUT)
    ref = reference([10.0, 1.0], [(0.0, 1.5, (12.0, 0.0)), (1.5, 3.0, (12.0, 0.05))], p, T_OUT)
    got = np.column_stack([res["omega"][keep], res["i"][keep]])
    assert got.shape == ref.shape
    scale = np.abs(ref).max(axis=0)
    err = np.abs(got - ref).max(axis=0) / scale
    # stated tolerance: 1e-8 of the signal's range (measured: <= 1e-9 for both at rtol 1e-10)
    assert np.all(err < 1e-8), (fmi_type, err)
    np.testing.assert_array_equal(res["omega_meas"], res["omega"])
    np.testing.assert_array_equal(res["i_meas"], res["i"])
    assert 70.0 < ref[-1, 0] < 100.0 and ref[0, 0] == 10.0  # spins up (k_eff = 0.8: below 100 rad/s)


def test_stationary_point_at_12V_is_100_rad_per_s(unzipped: str) -> None:
    with instance(unzipped, "ME", omega=100.0, i=7.0) as (fmu, _):
        assert get(fmu, "der(omega)", "der(i)") == pytest.approx([0.0, 0.0], abs=1e-12)


# ------------------------------------------------------------------------------------------
# Directional derivatives, FMU state, reset, variable steps
# ------------------------------------------------------------------------------------------


def _fd_jacobian(x: np.ndarray, u: tuple[float, float], p: dict[str, float]) -> np.ndarray:
    """Central differences of the rhs w.r.t. (x, u): 2 x 4."""
    z0 = np.r_[x, u]
    cols = []
    for j in range(4):
        hj = 1e-6 * max(1.0, abs(z0[j]))
        zp, zm = z0.copy(), z0.copy()
        zp[j] += hj
        zm[j] -= hj
        cols.append((motor_rhs(zp[:2], tuple(zp[2:]), p) - motor_rhs(zm[:2], tuple(zm[2:]), p)) / (2 * hj))
    return np.column_stack(cols)


@pytest.mark.parametrize("kind", ["ME", "CS"])
def test_directional_derivatives_equal_finite_differences(unzipped: str, kind: str) -> None:
    p = {**NOMINAL, "k_eff": 0.7, "R_extra": 0.3}
    with instance(unzipped, kind, omega=-35.0, i=4.0, V=9.0, tau_load=0.02, k_eff=0.7, R_extra=0.3) as (fmu, _):
        if kind == "CS":  # move along the trajectory first: the Jacobian is taken where the FMU is
            fmu.doStep(0.0, 0.01)
        x = np.array(get(fmu, "omega", "i"))
        unknowns = [VR[n] for n in ("der(omega)", "der(i)", "omega_meas", "omega_out", "i_meas")]
        knowns = [VR[n] for n in ("omega", "i", "V", "tau_load")]
        jac = np.column_stack([fmu.getDirectionalDerivative(unknowns, knowns, list(e)) for e in np.eye(4)])
        fd = _fd_jacobian(x, (9.0, 0.02), p)
        np.testing.assert_allclose(jac[:2], fd, rtol=1e-6, atol=1e-6 * np.abs(fd).max())
        np.testing.assert_array_equal(jac[2:], [[1, 0, 0, 0], [1, 0, 0, 0], [0, 1, 0, 0]])
        seed = [0.3, -1.2, 0.5, 2.0]  # any direction, any subset and order of knowns
        assert fmu.getDirectionalDerivative(unknowns[:2], knowns, seed) == pytest.approx(list(jac[:2] @ seed), rel=1e-12)
        assert fmu.getDirectionalDerivative([VR["der(i)"]], [VR["V"]], [1.0]) == [pytest.approx(1 / 0.05)]
        if kind == "ME":  # the FMU's own derivatives agree with the Python equations
            fmu.setTime(0.0)
            assert get(fmu, "der(omega)", "der(i)") == pytest.approx(list(motor_rhs(x, (9.0, 0.02), p)), rel=1e-13)


def test_fmu_state_round_trips(unzipped: str) -> None:
    with instance(unzipped, "CS", omega=20.0) as (fmu, _):
        fmu.doStep(0.0, 0.5)
        state = fmu.getFMUstate()
        at_half = get(fmu, "omega", "i")
        fmu.doStep(0.5, 0.7)
        first = get(fmu, "omega", "i", "omega_out")
        fmu.setReal([VR["k_eff"]], [0.5])
        fmu.setFMUstate(state)
        assert get(fmu, "omega", "i") == at_half and get(fmu, "k_eff") == [1.0]
        assert fmu.getRealStatus(fmi2LastSuccessfulTime) == 0.5
        fmu.doStep(0.5, 0.7)
        assert get(fmu, "omega", "i", "omega_out") == first  # bitwise: same state, same steps
        blob = fmu.serializeFMUstate(state)
        fmu.freeFMUstate(state)
        restored = fmu.deSerializeFMUstate(blob)
        fmu.setFMUstate(restored)
        assert get(fmu, "omega", "i") == at_half
        fmu.freeFMUstate(restored)
        with pytest.raises(FMICallException):
            fmu.deSerializeFMUstate(blob[:-8])


def test_reset_restores_start_values(unzipped: str) -> None:
    with instance(unzipped, "CS", omega=50.0, tau_load=0.01, k_eff=0.6) as (fmu, _):
        fmu.doStep(0.0, 1.0)
        fmu.setReal([VR["R_extra"]], [2.0])
        fmu.reset()
        assert get(fmu, "omega", "i", "V", "tau_load", "J", "k_eff", "R_extra") == [0.0, 0.0, 12.0, 0.0, 0.01, 1.0, 0.0]
        assert fmu.getRealStatus(fmi2LastSuccessfulTime) == 0.0
        fmu.setupExperiment(tolerance=1e-10, startTime=0.0)  # usable again from the start
        fmu.enterInitializationMode()
        fmu.exitInitializationMode()
        fmu.doStep(0.0, 0.25)
        ref = reference([0.0, 0.0], [(0.0, 0.25, (12.0, 0.0))], NOMINAL, [0.25])
        assert get(fmu, "omega", "i") == pytest.approx(list(ref[-1]), rel=1e-8)


def test_variable_communication_steps_land_exactly(unzipped: str) -> None:
    steps = [0.013, 0.1, 0.0007, 0.3, 1e-9, 0.25, 0.0333, 1.0]
    with instance(unzipped, "CS") as (fmu, log):
        fmu.setDebugLogging(True, [])
        t, times, states = 0.0, [], []
        for h in steps:
            fmu.doStep(t, h)
            t = t + h
            assert fmu.getRealStatus(fmi2LastSuccessfulTime) == t  # exactly t + h
            times.append(t)
            states.append(get(fmu, "omega", "i"))
        with pytest.raises(FMICallException):  # a communication point that is not the FMU's time
            fmu.doStep(t + 0.1, 0.1)
    assert sum("accepted" in m for m in log) == len(steps)  # one log line per step with logging on
    ref = reference([0.0, 0.0], [(0.0, t, (12.0, 0.0))], NOMINAL, times)
    np.testing.assert_allclose(states, ref, rtol=1e-8, atol=1e-8)


# ------------------------------------------------------------------------------------------
# Errors inside the FMU: logged, fmi2Error, never a crash
# ------------------------------------------------------------------------------------------


def test_non_finite_values_are_rejected_with_the_variable_named(unzipped: str) -> None:
    with instance(unzipped, "CS") as (fmu, log):
        with pytest.raises(FMICallException):
            fmu.setReal([VR["V"]], [math.nan])
        assert "V = nan" in log[-1] and "t = 0" in log[-1]
        with pytest.raises(FMICallException):
            fmu.setReal([VR["J"]], [0.5])  # fixed parameter in Step Mode
        assert "J" in log[-1] and "fixed parameter" in log[-1]
        with pytest.raises(FMICallException):
            fmu.setReal([VR["omega_out"]], [1.0])
        fmu.setReal([VR["k_eff"]], [0.9])  # tunable: fine
    with instance(unzipped, "CS", setup=False) as (fmu, log):
        fmu.setupExperiment(startTime=0.0)
        fmu.setReal([VR["J"]], [0.0])  # 0/0 in der(omega) at rest
        fmu.enterInitializationMode()
        with pytest.raises(FMICallException):
            fmu.exitInitializationMode()
        assert "der(omega)" in log[-1] and "not finite" in log[-1] and "t = 0" in log[-1]


def raw(fmu, name: str, *args: float) -> int:
    """Call an fmi2 function the fmpy class of the other interface does not wrap."""
    fn = getattr(fmu.dll, name)
    fn.argtypes = [ctypes.c_void_p] + [ctypes.c_double] * len(args)
    fn.restype = ctypes.c_int
    return fn(fmu.component, *args)


def test_failed_step_is_reported_and_leaves_the_fmu_in_error_state(unzipped: str) -> None:
    with instance(unzipped, "CS", omega=50.0, i=5.0) as (fmu, log):
        fmu.doStep(0.0, 0.5)
        fmu.setReal([VR["tau_load"]], [1e308])  # finite input, but der(omega) = -1e308 / J overflows
        with pytest.raises(FMICallException):
            fmu.doStep(0.5, 0.5)
        assert "der(omega) is not finite at t = 0.5" in log[-1]
        assert fmu.getRealStatus(fmi2LastSuccessfulTime) == 0.5
        with pytest.raises(FMICallException):
            fmu.doStep(0.5, 0.5)
        assert "must not be called in Error" in log[-1]
        fmu.reset()  # recovers
        fmu.setupExperiment(startTime=0.0)
        fmu.setReal([VR["k_eff"]], [1e150])  # absurdly stiff: the step size underflows
        fmu.enterInitializationMode()
        fmu.exitInitializationMode()
        with pytest.raises(FMICallException):
            fmu.doStep(0.0, 1.0)
        assert "step size underflow at t = 0" in log[-1]


def test_calls_of_the_other_interface_fail_cleanly(unzipped: str) -> None:
    with instance(unzipped, "ME") as (me, log):
        assert raw(me, "fmi2DoStep", 0.0, 0.1) == fmi2Error
        assert "fmi2DoStep is a Co-Simulation function" in log[-1]
        with pytest.raises(FMICallException):
            me.setReal([VR["omega"]], [1.0])  # states go through fmi2SetContinuousStates
        assert "fmi2SetContinuousStates" in log[-1]
        with pytest.raises(FMICallException):
            me.getDirectionalDerivative([VR["omega"]], [VR["i"]], [1.0])
        assert "neither a derivative nor an output" in log[-1]
    with instance(unzipped, "CS") as (cs, log):
        assert raw(cs, "fmi2SetTime", 1.0) == fmi2Error
        assert "fmi2SetTime is a Model Exchange function" in log[-1]
        assert raw(cs, "fmi2EnterContinuousTimeMode") == fmi2Error
        with pytest.raises(FMICallException):
            cs.fmi2EnterInitializationMode(cs.component)
        assert "must not be called in Step Mode" in log[-1]


def test_without_jacobian_directional_derivatives_fail(tmp_path: Path) -> None:
    base = motor_spec()
    src = base.c_source.replace("const int ODE_HAS_JACOBIAN = 1;", "const int ODE_HAS_JACOBIAN = 0;")
    spec = dataclasses.replace(base, model_name="DCMotorNoJac", c_source=src, has_jacobian=False)
    fmu = build_ode_fmu(spec, tmp_path)
    assert fmu == tmp_path / "DCMotorNoJac.fmu" and validate_fmu(str(fmu)) == []
    assert not read_model_description(str(fmu)).coSimulation.providesDirectionalDerivative
    with instance(extract(str(fmu)), "CS") as (cs, log):
        with pytest.raises(FMICallException):
            cs.getDirectionalDerivative([VR["der(i)"]], [VR["V"]], [1.0])
        assert "no exact Jacobian" in log[-1]


DECAY_C = """
#include "ode_model.h"
const int ODE_NX = 1, ODE_NU = 0, ODE_NP = 0, ODE_NY = 0, ODE_HAS_JACOBIAN = 1;
void ode_rhs(double t, const double *x, const double *u, const double *p, double *dx) {
    (void)u, (void)p;
    dx[0] = -x[0] + t;
}
void ode_out(double t, const double *x, const double *u, const double *p, double *y) {
    (void)t, (void)x, (void)u, (void)p, (void)y;
}
void ode_jac(double t, const double *x, const double *u, const double *p, double *dfdx, double *dfdu,
             double *dgdx, double *dgdu) {
    (void)t, (void)x, (void)u, (void)p, (void)dfdu, (void)dgdx, (void)dgdu;
    dfdx[0] = -1.0;
}
"""


def test_minimal_spec_without_inputs_parameters_outputs(tmp_path: Path) -> None:
    spec = OdeFmuSpec(model_name="Decay", states=[OdeVariable("x", 2.0)], c_source=DECAY_C, has_jacobian=True)
    assert spec.states == (OdeVariable("x", 2.0),) and spec.variable_names() == ["x", "der(x)"]
    fmu = build_ode_fmu(spec, tmp_path)
    assert validate_fmu(str(fmu)) == []
    for fmi_type in ("CoSimulation", "ModelExchange"):
        res = simulate_fmu(str(fmu), fmi_type=fmi_type, stop_time=2.0, relative_tolerance=1e-10, output=["x"])
        exact = res["time"] - 1.0 + 3.0 * np.exp(-res["time"])  # x' = -x + t, x(0) = 2
        np.testing.assert_allclose(res["x"], exact, rtol=1e-7, atol=1e-8)


# ------------------------------------------------------------------------------------------
# Spec validation, compile errors, contract mismatches, caching
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("change, needle", [
    (dict(model_name="DC-Motor"), "DC-Motor"),
    (dict(model_name=""), "model_name"),
    (dict(model_name="ode_glue"), "reserved"),
    (dict(outputs=(OdeVariable("omega"),)), "'omega' is used twice"),
    (dict(states=()), "states is empty"),
    (dict(tolerance=0.0), "tolerance"),
])
def test_invalid_spec_raises_validation_error(change: dict, needle: str) -> None:
    with pytest.raises(ValidationError, match=needle.replace("(", r"\(")):
        dataclasses.replace(motor_spec(), **change)


@pytest.mark.parametrize("args, needle", [
    (("der(x)", 0.0), "'der(x)' is not a C identifier"),
    (("x", math.nan), "'x': start = nan is not finite"),
    (("x", math.inf), "'x': start = inf"),
    (("x", "abc"), "'x': start 'abc' is not a number"),
])
def test_invalid_variable_raises_validation_error(args: tuple, needle: str) -> None:
    with pytest.raises(ValidationError) as info:
        OdeVariable(*args)
    assert needle in str(info.value)


def test_compile_error_carries_gccs_message() -> None:
    spec = dataclasses.replace(motor_spec(), model_name="Broken",
                               c_source=motor_spec().c_source.replace("dx[1] =", "dx[1] = undeclared_symbol +"))
    with pytest.raises(FMUError) as info:
        build_ode_binary(spec)
    msg = str(info.value)
    assert msg.startswith("Broken.c:") and "undeclared_symbol" in msg and "error" in msg


@pytest.mark.parametrize("change, needle", [
    (dict(has_jacobian=False), "ODE_HAS_JACOBIAN = 1 but the FMU spec has has_jacobian = False"),
    (dict(states=(OdeVariable("omega"),)), "ODE_NX (states) = 2 but the FMU spec has 1"),
])
def test_model_file_must_match_spec(change: dict, needle: str) -> None:
    with pytest.raises(FMUError) as info:
        build_ode_binary(dataclasses.replace(motor_spec(), model_name="Mismatch", **change))
    assert needle in str(info.value)


def test_missing_jacobian_function_is_a_link_error() -> None:
    src = motor_spec().c_source.replace("void ode_jac(", "static void unused_jac(")
    with pytest.raises(FMUError) as info:
        build_ode_binary(dataclasses.replace(motor_spec(), model_name="NoJacFn", c_source=src))
    assert "ode_jac" in str(info.value)


def test_rebuild_reuses_cached_binary(motor_fmu: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from ftc_verify.plants import ode_fmu
    runs: list[object] = []
    compiler = ode_fmu.run_compiler
    monkeypatch.setattr(ode_fmu, "run_compiler", lambda *args: runs.append(args) or compiler(*args))

    def compile_count() -> int:  # gcc runs (cache misses) in this test
        return len(runs)

    binary = build_ode_binary(motor_spec())
    mtime, count = binary.stat().st_mtime_ns, compile_count()
    again = build_ode_fmu(motor_spec(), tmp_path / "again.fmu")
    assert compile_count() == count and binary.stat().st_mtime_ns == mtime
    assert again.read_bytes() == motor_fmu.read_bytes()  # byte-identical FMU
    default = build_ode_fmu(motor_spec())  # default destination: the cache folder
    assert default.parent == binary.parent and default.suffix == ".fmu"
    changed = dataclasses.replace(motor_spec(), stop_time=7.0)  # any spec change: new GUID, new binary
    assert build_ode_binary(changed) != binary and compile_count() == count + 1
    binary.unlink()
    binary.write_bytes(b"corrupt")  # a corrupted cache entry is rebuilt
    assert build_ode_binary(motor_spec()) == binary and compile_count() == count + 2
    assert not [p.name for p in binary.parent.iterdir() if p.name.startswith(".")]  # no temporary left
