"""The supervisor on broken or hostile FMUs: one clear error each, no crash, no stray files.

Cases: not a zip; no binary for this platform; an unloadable binary; FMI 1.0 / 3.0
model descriptions; no modelDescription.xml; a map naming a variable that is not there
(or one of the wrong type/causality); an FMU that refuses to instantiate; an FMU call
failing during the loop (the plant rejecting an out-of-range mode with fmi2Error; a C stub
whose fmi2DoStep returns fmi2Error); zip-slip members. Every test runs with
``tempfile.tempdir`` pointed into its own ``tmp_path`` and checks that the supervisor's
extraction folder is gone afterwards and nothing appeared elsewhere.

The C stub (compiled here with gcc and fmpy's FMI 2.0 headers) is also a user FMU in its
own right: a scalar plant ``x' = a x + e u + w``, ``y = x + u / 2`` with a Real
``actuatorEffectiveness`` input ``e`` as the fault variable and a direct feedthrough
(undeclared output dependencies), so it also checks those two paths of the supervisor.
"""

from __future__ import annotations

import dataclasses
import math
import os
import re
import shutil
import subprocess
import tempfile
import zipfile
from pathlib import Path

import numpy as np
import pytest

fmpy = pytest.importorskip("fmpy")
if shutil.which("gcc") is None:  # pragma: no cover
    pytest.skip("gcc is needed to compile the FMUs", allow_module_level=True)

from ftc_verify.errors import ValidationError
from ftc_verify.plants.build import fmi2_include_dir
from ftc_verify.plants.linear_jump import FMUError, build_fmu
from ftc_verify.model.system import FTCSystem
from ftc_verify.simulation.paths import ChainPath, sample_paths
from ftc_verify.model.files import load_system
from ftc_verify.controllers import Controller, load_gains
from ftc_verify.simulation.supervisor import FaultInjectionMap, Supervisor

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
LIB = f"binaries/{fmpy.platform}/LinearJumpPlant{fmpy.sharedLibraryExtension}"


# ------------------------------------------------------------------------------------------
# Fixtures: isolated cache, isolated temp folder, the paper FMU
# ------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def cache_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("ftc-verify-cache")


@pytest.fixture(autouse=True)
def isolated_root(cache_root: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    """FMU cache in a temp folder; ``tempfile`` writes only below ``tmp_path/tmp``; the
    working directory is unchanged and the temp folder is empty after each test."""
    monkeypatch.setenv("FTC_VERIFY_CACHE", str(cache_root))
    scratch = tmp_path / "tmp"
    scratch.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(scratch))
    cwd = os.getcwd()
    yield scratch
    assert os.getcwd() == cwd
    assert list(scratch.iterdir()) == [], "the supervisor left files in the temp folder"


@pytest.fixture(scope="module")
def paper() -> FTCSystem:
    return load_system(EXAMPLES / "paper.toml")


@pytest.fixture(scope="module")
def gains():
    return load_gains(EXAMPLES / "paper_gains.toml")


@pytest.fixture(scope="module")
def controller(gains) -> Controller:
    return Controller.state_feedback(gains)


@pytest.fixture(scope="module")
def paper_fmu(paper: FTCSystem, cache_root: Path) -> Path:
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("FTC_VERIFY_CACHE", str(cache_root))
        return build_fmu(paper, cache_root / "paper.fmu")


def one_jump_path(horizon: float = 1.0, at: float = 0.35) -> ChainPath:
    """Mode 0 until ``at``, then fault mode 1 with the FDI lagging until ``at + 0.2``."""
    return ChainPath(np.array([0.0, at, at + 0.2]), np.array([0, 1, 1]), np.array([0, 0, 1]),
                     np.zeros((2, 2)), horizon)


def doctor(src: Path, dest: Path, *, xml=None, rename=None, drop=(), extra=()) -> Path:
    """Copy the FMU ``src`` to ``dest`` with ``modelDescription.xml`` passed through
    ``xml``, members renamed by ``rename`` (old -> new), members in ``drop`` left out and
    ``(name, bytes)`` members in ``extra`` added."""
    rename = rename or {}
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dest, "w") as zout:
        for item in zin.infolist():
            if item.filename in drop:
                continue
            data = zin.read(item)
            if item.filename == "modelDescription.xml" and xml is not None:
                data = xml(data.decode()).encode()
            zout.writestr(rename.get(item.filename, item.filename), data)
        for name, data in extra:
            zout.writestr(zipfile.ZipInfo(name), data)
    return dest


def raises_fmu_error(fmu: Path, *fragments: str):
    """``pytest.raises(FMUError)`` whose message starts with the FMU file and contains every fragment."""
    pattern = "^" + re.escape(str(fmu)) + ":" + "".join(f"(?s:.*){re.escape(f)}" for f in fragments)
    return pytest.raises(FMUError, match=pattern)


# ------------------------------------------------------------------------------------------
# The archive and the model description
# ------------------------------------------------------------------------------------------


def test_not_a_zip(tmp_path: Path, paper: FTCSystem) -> None:
    junk = tmp_path / "junk.fmu"
    junk.write_text("this is not an FMU")
    with raises_fmu_error(junk, "not a zip archive"):
        Supervisor(junk, system=paper)
    with raises_fmu_error(tmp_path / "missing.fmu", "no such FMU file"):
        Supervisor(tmp_path / "missing.fmu", system=paper)


def test_no_model_description(tmp_path: Path, paper: FTCSystem, paper_fmu: Path) -> None:
    bad = doctor(paper_fmu, tmp_path / "nomd.fmu", drop={"modelDescription.xml"})
    with raises_fmu_error(bad, "modelDescription.xml is missing"):
        Supervisor(bad, system=paper)


def test_no_binary_for_this_platform(tmp_path: Path, paper: FTCSystem, paper_fmu: Path) -> None:
    bad = doctor(paper_fmu, tmp_path / "win.fmu", rename={LIB: "binaries/win64/LinearJumpPlant.dll"})
    with raises_fmu_error(bad, "no binary for this platform", LIB, "win64", "rebuild"):
        Supervisor(bad, system=paper)


def test_unloadable_binary(tmp_path: Path, paper: FTCSystem, paper_fmu: Path) -> None:
    bad = doctor(paper_fmu, tmp_path / "garbage.fmu", drop={LIB}, extra=[(LIB, b"\x7fELF not really")])
    with raises_fmu_error(bad, "cannot load the FMU binary"):
        Supervisor(bad, system=paper)
    # fmpy changes into the binaries folder to load the library and does not change back
    # on failure; the autouse fixture checks the supervisor restored the working directory


@pytest.mark.parametrize("version", ["1.0", "3.0"])
def test_wrong_fmi_version(tmp_path: Path, paper: FTCSystem, paper_fmu: Path, version: str) -> None:
    bad = doctor(paper_fmu, tmp_path / f"fmi{version[0]}.fmu",
                 xml=lambda s: s.replace('fmiVersion="2.0"', f'fmiVersion="{version}"'))
    with raises_fmu_error(bad, f"fmiVersion '{version}'", "FMI 2.0"):
        Supervisor(bad, system=paper)


def test_instantiate_failure_reports_the_fmu_message(tmp_path: Path, paper: FTCSystem, paper_fmu: Path) -> None:
    """A resource file from another build: the plant refuses fmi2Instantiate and says why."""
    def swap_guid(text: str) -> str:
        return re.sub(r'guid="\{[^}]*\}"', 'guid="{00000000-0000-0000-0000-000000000000}"', text)

    bad = doctor(paper_fmu, tmp_path / "guid.fmu", xml=swap_guid)
    with raises_fmu_error(bad, "fmi2Instantiate failed", "the FMU reported", "guid"):
        Supervisor(bad, system=paper)


# ------------------------------------------------------------------------------------------
# The map against the model description
# ------------------------------------------------------------------------------------------


def test_map_names_a_missing_variable(paper: FTCSystem, paper_fmu: Path) -> None:
    good = FaultInjectionMap.for_linear_jump_plant(paper)
    bad = FaultInjectionMap(fault="mode", inputs=("u[1]", "u[3]"), states=good.states)
    with raises_fmu_error(paper_fmu, "'u[3]'", "control input u", "not declared", "u[1]"):
        Supervisor(paper_fmu, bad, system=paper)
    bad = FaultInjectionMap(fault="faultMode", inputs=good.inputs, states=good.states)
    with raises_fmu_error(paper_fmu, "'faultMode'", "fault mode", "not declared", "mode"):
        Supervisor(paper_fmu, bad, system=paper)


@pytest.mark.parametrize(
    "change, fragments",
    [
        (dict(fault=("x[1]",)), ("'x[1]'", "fault mode", "causality 'output'")),
        (dict(fault=("u[1]",), inputs=("mode", "u[2]")), ("'mode'", "control input u", "type Integer", "Real")),
        (dict(states=("systemFile", "x[2]")), ("'systemFile'", "state x", "type String")),
        (dict(delta1=("x0[1]",)), ("'x0[1]'", "Delta input", "'fixed'", "tunable parameter")),
    ],
)
def test_map_variable_of_the_wrong_kind(paper: FTCSystem, paper_fmu: Path, change, fragments) -> None:
    base = FaultInjectionMap.for_linear_jump_plant(paper)
    fields = {k: getattr(base, k) for k in ("fault", "inputs", "states", "disturbances", "outputs")}
    fields.update(change)
    with raises_fmu_error(paper_fmu, *fragments):
        Supervisor(paper_fmu, FaultInjectionMap(**fields), system=paper)


def test_map_and_argument_errors(paper: FTCSystem, paper_fmu: Path, gains, controller) -> None:
    with pytest.raises(ValidationError, match="more than one role"):
        FaultInjectionMap(fault="mode", inputs=("u[1]",), states=("x[1]",), disturbances=("u[1]",))
    with pytest.raises(ValidationError, match=r"fault_values\[1\]: expected 1 value"):
        FaultInjectionMap(fault="mode", inputs=("u[1]",), states=("x[1]",), fault_values=(1, (2, 3)))
    path = one_jump_path()
    with Supervisor(paper_fmu, system=paper) as sup:
        with pytest.raises(ValidationError, match=r"gain\[2\]\.K: expected shape 2 x 2"):
            sup.run([path], Controller.state_feedback([gains[0], np.eye(3)]), step=0.1)
        with pytest.raises(ValidationError, match=r"gain\[1\]\.K: 3 rows, but the system has 2 inputs"):
            sup.run([path], Controller.state_feedback([np.eye(3), np.eye(3)]), step=0.1)
        with pytest.raises(ValidationError, match="3 entries given"):
            sup.run([path], Controller.state_feedback(list(gains) + [gains[0]]), step=0.1)
        with pytest.raises(ValidationError, match="controller: expected a Controller"):
            sup.run([path], list(gains), step=0.1)  # no bare gain lists
        with pytest.raises(ValidationError, match="x0: expected 2 finite numbers"):
            sup.run([path], controller, step=0.1, x0=[1.0, math.nan])
        with pytest.raises(ValidationError, match="step: must be a positive"):
            sup.run([path], controller, step=0.0)
        assert sup.stats["paths"] == 0  # nothing ran
    with pytest.raises(FMUError, match="closed"):
        sup.run([path], controller, step=0.1)


def test_map_measured_role_is_checked(paper: FTCSystem, paper_fmu: Path, controller) -> None:
    """The ``measured`` role is resolved like the others: a missing name gives one FMUError
    naming it (with the close matches); a non-Real one is refused; an output-feedback
    controller needs the role."""
    base = FaultInjectionMap.for_linear_jump_plant(paper)
    assert base.measured == ("ym[1]",)
    bad = dataclasses.replace(base, measured=("ym[1]", "ym[2]"))
    with raises_fmu_error(paper_fmu, "'ym[2]'", "measured output y_m", "not declared", "ym[1]") as info:
        Supervisor(paper_fmu, bad, system=paper)
    assert str(info.value).count("ym[2]") == 1 and "\n" not in str(info.value)
    with raises_fmu_error(paper_fmu, "'mode'", "measured output y_m", "type Integer", "Real"):
        Supervisor(paper_fmu, dataclasses.replace(base, measured=("mode",)), system=paper)
    observer = Controller.dynamic([-np.eye(1)] * 2, [np.zeros((1, 1))] * 2, [np.zeros((2, 1))] * 2,
                                  [np.ones((2, 1))] * 2)
    with Supervisor(paper_fmu, dataclasses.replace(base, measured=()), system=paper) as sup:
        with pytest.raises(ValidationError, match=r"FaultInjectionMap\.measured names no FMU variable"):
            sup.run([one_jump_path()], observer, step=0.1)
        assert sup.run([one_jump_path()], controller, step=0.1).records[0].ym.shape[1] == 2  # x itself


# ------------------------------------------------------------------------------------------
# FMU calls failing during the loop
# ------------------------------------------------------------------------------------------


def test_plant_rejects_an_out_of_range_mode(tmp_path: Path, paper: FTCSystem, paper_fmu: Path, controller) -> None:
    """The model description claims ``mode`` may be 5, the plant has 2 modes: the plant's
    fmi2SetInteger returns fmi2Error at the fault time; the error names the file, the
    call, the variable, the value and the time, and the instance is usable afterwards."""
    lying = doctor(paper_fmu, tmp_path / "lying.fmu",
                   xml=lambda s: s.replace('<Integer start="1" min="1" max="2"', '<Integer start="1" min="1" max="5"'))
    base = FaultInjectionMap.for_linear_jump_plant(paper)
    fmap = FaultInjectionMap(fault="mode", fault_values=(1, 5), inputs=base.inputs, states=base.states,
                             disturbances=base.disturbances, outputs=base.outputs,
                             initial_states=base.initial_states, delta1=base.delta1, delta2=base.delta2)
    with Supervisor(lying, fmap, system=paper) as sup:
        with raises_fmu_error(lying, "fmi2SetInteger", "mode = 5", "returned Error", "t = 0.35",
                              "out of range 1..2"):
            sup.run([one_jump_path()], controller, step=0.1)
        # a path that stays in mode 0 still runs on the same instance (fmi2Reset after the error)
        res = sup.run([ChainPath(np.array([0.0]), np.array([0]), np.array([0]), np.zeros((2, 2)), 1.0)],
                      controller, step=0.1, x0=[1.0, 0.0])
        assert np.all(np.isfinite(res.records[0].x)) and sup.stats["instantiations"] == 1
    # the declared range is checked before the FMU is called
    with Supervisor(paper_fmu, fmap, system=paper) as sup:
        with raises_fmu_error(paper_fmu, "fault variable 'mode'", "maps to 5", "[1, 2]"):
            sup.run([one_jump_path()], controller, step=0.1)


STUB_C = r"""
/* A scalar FMI 2.0 co-simulation stub: x' = a x + e u + w, y = x + u/2 (feedthrough).
   fmi2DoStep fails (fmi2Error) when the actuator effectiveness e is negative. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "fmi2Functions.h"

enum { VR_A = 1, VR_X0, VR_U, VR_W, VR_E, VR_X, VR_Y };
typedef struct {
    fmi2CallbackFunctions cb;
    char name[64];
    double a, x0, u, w, e, x, t;
} Stub;

static void reset_values(Stub *s) { s->a = -1.0; s->x0 = 0.0; s->u = s->w = 0.0; s->e = 1.0; s->x = 0.0; s->t = 0.0; }
static fmi2Status fail(Stub *s, const char *msg) {
    if (s->cb.logger) s->cb.logger(s->cb.componentEnvironment, s->name, fmi2Error, "logStatusError", msg);
    return fmi2Error;
}

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }
fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n, const fmi2String cat[]) { return fmi2OK; }
fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid, fmi2String res,
                              const fmi2CallbackFunctions *cb, fmi2Boolean vis, fmi2Boolean log) {
    if (type != fmi2CoSimulation || !cb) return NULL;
    Stub *s = (Stub *)calloc(1, sizeof(Stub));
    if (!s) return NULL;
    s->cb = *cb;
    strncpy(s->name, name ? name : "stub", sizeof s->name - 1);
    reset_values(s);
    return s;
}
void fmi2FreeInstance(fmi2Component c) { free(c); }
fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean td, fmi2Real tol, fmi2Real t0, fmi2Boolean sd, fmi2Real t1) {
    ((Stub *)c)->t = t0; return fmi2OK;
}
fmi2Status fmi2EnterInitializationMode(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2ExitInitializationMode(fmi2Component c) { Stub *s = (Stub *)c; s->x = s->x0; return fmi2OK; }
fmi2Status fmi2Terminate(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2Reset(fmi2Component c) { reset_values((Stub *)c); return fmi2OK; }
fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real v[]) {
    Stub *s = (Stub *)c;
    for (size_t i = 0; i < n; i++) switch (vr[i]) {
        case VR_A: v[i] = s->a; break;   case VR_X0: v[i] = s->x0; break;
        case VR_U: v[i] = s->u; break;   case VR_W: v[i] = s->w; break;
        case VR_E: v[i] = s->e; break;   case VR_X: v[i] = s->x; break;
        case VR_Y: v[i] = s->x + 0.5 * s->u; break;
        default: return fail(s, "fmi2GetReal: unknown value reference");
    }
    return fmi2OK;
}
fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real v[]) {
    Stub *s = (Stub *)c;
    for (size_t i = 0; i < n; i++) switch (vr[i]) {
        case VR_A: s->a = v[i]; break;   case VR_X0: s->x0 = v[i]; break;
        case VR_U: s->u = v[i]; break;   case VR_W: s->w = v[i]; break;
        case VR_E: s->e = v[i]; break;
        default: return fail(s, "fmi2SetReal: not a settable value reference");
    }
    return fmi2OK;
}
fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Integer v[]) { return n ? fmi2Error : fmi2OK; }
fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Boolean v[]) { return n ? fmi2Error : fmi2OK; }
fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2String v[]) { return n ? fmi2Error : fmi2OK; }
fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer v[]) { return n ? fmi2Error : fmi2OK; }
fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Boolean v[]) { return n ? fmi2Error : fmi2OK; }
fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2String v[]) { return n ? fmi2Error : fmi2OK; }
fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *st) { return fmi2Error; }
fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate st) { return fmi2Error; }
fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *st) { return fmi2Error; }
fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate st, size_t *n) { return fmi2Error; }
fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate st, fmi2Byte b[], size_t n) { return fmi2Error; }
fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte b[], size_t n, fmi2FMUstate *st) { return fmi2Error; }
fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference u[], size_t nu,
    const fmi2ValueReference z[], size_t nz, const fmi2Real dv[], fmi2Real dz[]) { return fmi2Error; }
fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
    const fmi2Integer o[], const fmi2Real v[]) { return fmi2Error; }
fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
    const fmi2Integer o[], fmi2Real v[]) { return fmi2Error; }
fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean noSet) {
    Stub *s = (Stub *)c;
    char msg[160];
    if (s->e < 0) {
        snprintf(msg, sizeof msg, "fmi2DoStep at t = %g: actuatorEffectiveness = %g is negative", t, s->e);
        return fail(s, msg);
    }
    double eah = exp(s->a * h), phi = s->a != 0.0 ? expm1(s->a * h) / s->a : h;
    s->x = eah * s->x + phi * (s->e * s->u + s->w);
    s->t = t + h;
    return fmi2OK;
}
fmi2Status fmi2CancelStep(fmi2Component c) { return fmi2Error; }
fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind k, fmi2Status *v) { return fmi2Error; }
fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind k, fmi2Real *v) { return fmi2Error; }
fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind k, fmi2Integer *v) { return fmi2Error; }
fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind k, fmi2Boolean *v) { return fmi2Error; }
fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind k, fmi2String *v) { return fmi2Error; }
"""

STUB_XML = """<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription fmiVersion="2.0" modelName="Stub" guid="{8c4e810f-3df3-4a00-8276-176fa3c9f000}"
  variableNamingConvention="flat" numberOfEventIndicators="0">
  <CoSimulation modelIdentifier="Stub" canHandleVariableCommunicationStepSize="true"/>
  <ModelVariables>
    <ScalarVariable name="a" valueReference="1" causality="parameter" variability="fixed" initial="exact"><Real start="-1.0"/></ScalarVariable>
    <ScalarVariable name="x0" valueReference="2" causality="parameter" variability="fixed" initial="exact"><Real start="0.0"/></ScalarVariable>
    <ScalarVariable name="u" valueReference="3" causality="input" variability="continuous"><Real start="0.0"/></ScalarVariable>
    <ScalarVariable name="w" valueReference="4" causality="input" variability="continuous"><Real start="0.0"/></ScalarVariable>
    <ScalarVariable name="actuatorEffectiveness" valueReference="5" causality="input" variability="continuous"><Real start="1.0"/></ScalarVariable>
    <ScalarVariable name="x" valueReference="6" causality="output" variability="continuous" initial="calculated"><Real/></ScalarVariable>
    <ScalarVariable name="y" valueReference="7" causality="output" variability="continuous" initial="calculated"><Real/></ScalarVariable>
  </ModelVariables>
  <ModelStructure>
    <Outputs>
      <Unknown index="6"/>
      <Unknown index="7"/>
    </Outputs>
    <InitialUnknowns>
      <Unknown index="6"/>
      <Unknown index="7"/>
    </InitialUnknowns>
  </ModelStructure>
</fmiModelDescription>
"""

STUB_MAP = dict(fault="actuatorEffectiveness", inputs=("u",), states=("x",), disturbances=("w",),
                outputs=("y",), initial_states=("x0",))


@pytest.fixture(scope="module")
def stub_fmu(tmp_path_factory: pytest.TempPathFactory) -> Path:
    work = tmp_path_factory.mktemp("stub")
    (work / "stub.c").write_text(STUB_C)
    lib = work / f"Stub{fmpy.sharedLibraryExtension}"
    subprocess.run(["gcc", "-std=c99", "-O2", "-fPIC", "-shared", "-I", str(fmi2_include_dir()),
                    str(work / "stub.c"), "-o", str(lib), "-lm"], check=True, capture_output=True)
    fmu = work / "Stub.fmu"
    with zipfile.ZipFile(fmu, "w") as zf:
        zf.writestr("modelDescription.xml", STUB_XML)
        zf.write(lib, f"binaries/{fmpy.platform}/Stub{fmpy.sharedLibraryExtension}")
    return fmu


def stub_exact(path: ChainPath, step: float, gains, eff, x0: float, a: float = -1.0):
    """The stub's loop by hand, purely periodic: at the control samples (the multiples of
    ``step``, :func:`~ftc_verify.simulation.paths.sample_points`) ``u = K[l] x`` and the
    paper disturbance ``w`` are taken and held over the grid's pieces (jump times inside a
    period change only the plant's mode)."""
    from ftc_verify.simulation.paths import communication_grid, sample_points

    t, true, fdi = communication_grid(path, step)
    sample = sample_points(path, step, t)
    w = np.exp(-0.1 * t) * np.sin(t)
    x = np.empty(len(t))
    u = np.empty(len(t))
    x[0] = x0
    u_held = w_held = 0.0
    for k in range(len(t)):
        if sample[k]:
            u_held, w_held = gains[fdi[min(k, len(t) - 2)]] * x[k], w[k]
        u[k] = u_held
        if k + 1 < len(t):
            h = t[k + 1] - t[k]
            x[k + 1] = math.exp(a * h) * x[k] + math.expm1(a * h) / a * (eff[true[k]] * u_held + w_held)
    return t, x, u, x + 0.5 * u


def test_stub_user_fmu_with_a_real_fault_variable(stub_fmu: Path) -> None:
    """Positive control for the stub: a Real effectiveness 1.0 / 0.2 per mode and a
    feedthrough output, on sampled paths of a two-mode chain."""
    chain_sys = FTCSystem.from_arrays(
        name="stub", modes=[dict(A=[[-1.0]], B=[[1.0]], C=[[1.0]], D=[[1.0]])] * 2,
        alpha=[[-1.0, 1.0], [2.0, -2.0]], beta_min=[[0, 2.0], [2.0, 0]], beta_max=[[0, 3.0], [3.0, 0]])
    paths = sample_paths(chain_sys.chain, 3.0, 4, 5)
    gains = [np.array([[-1.5]]), np.array([[-4.0]])]
    fmap = FaultInjectionMap(**STUB_MAP, fault_values=(1.0, 0.2))
    with Supervisor(stub_fmu, fmap) as sup:
        res = sup.run(paths, Controller.state_feedback(gains), step=0.05, x0=[0.7])
        assert sup.feedthrough  # undeclared dependencies: y is read after u is set
    assert res.backend == "fmu"
    for rec, path in zip(res.records, paths):
        t, x, u, y = stub_exact(path, 0.05, [-1.5, -4.0], (1.0, 0.2), 0.7)
        assert np.array_equal(rec.t, t)
        assert np.allclose(rec.x[:, 0], x, rtol=1e-12, atol=1e-14)
        assert np.allclose(rec.u[:, 0], u, rtol=1e-12, atol=1e-14)
        assert np.allclose(rec.y[:, 0], y, rtol=1e-12, atol=1e-14)


def test_stub_do_step_error(stub_fmu: Path) -> None:
    """Mode 1 maps to a negative effectiveness: the stub's fmi2DoStep returns fmi2Error
    at the fault time. That is a result of the plant, not bad input: the path is recorded
    as failed there, and its failure names the file, the call, the time and the FMU's
    message; the next path runs on the reset instance."""
    fmap = FaultInjectionMap(**STUB_MAP, fault_values=(1.0, -1.0))
    gains = [np.array([[-1.0]]), np.array([[-2.0]])]
    with Supervisor(stub_fmu, fmap) as sup:
        res = sup.run([one_jump_path(), one_jump_path()], Controller.state_feedback(gains), step=0.1, x0=[1.0])
        for rec in res.records:
            assert rec.diverged_at == pytest.approx(0.35) and rec.y_norm == float("inf")
            for part in (str(stub_fmu), "fmi2DoStep", "returned Error", "at t = 0.35", "true mode 1",
                         "actuatorEffectiveness = -1 is negative"):
                assert part in rec.failure, (part, rec.failure)
            assert rec.t[-1] == pytest.approx(0.35) and len(rec.t) == len(rec.x)
        assert "failed in the plant FMU" in res.to_dict()["divergence"]
        extraction = sup.extraction_dir
        assert extraction is not None and extraction.is_dir()
    assert not extraction.exists()  # removed on close


# ------------------------------------------------------------------------------------------
# Zip-slip
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("member", ["../evil.txt", "resources/../../evil.txt", "/tmp/evil.txt",
                                    "C:/evil.txt", "..\\evil.txt"])
def test_zip_slip_is_refused_before_extracting(tmp_path: Path, paper: FTCSystem, paper_fmu: Path,
                                              isolated_root: Path, member: str) -> None:
    inner = tmp_path / "a" / "b"
    inner.mkdir(parents=True)
    bad = doctor(paper_fmu, inner / "slip.fmu", extra=[(member, b"owned")])
    before = sorted(p for p in tmp_path.rglob("*"))
    outside = [Path("/tmp/evil.txt"), tmp_path.parent / "evil.txt", tmp_path / "a" / "evil.txt"]
    existed = [p.exists() for p in outside]
    with raises_fmu_error(bad, repr(member), "outside the extraction folder", "refusing to extract"):
        Supervisor(bad, system=paper)
    assert sorted(p for p in tmp_path.rglob("*")) == before  # nothing written anywhere below tmp_path
    assert [p.exists() for p in outside] == existed
    assert list(isolated_root.iterdir()) == []  # not even an extraction folder was created
