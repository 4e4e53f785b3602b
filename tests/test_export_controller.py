"""``ftc-verify export-controller``: the C99 file, the FMI 2.0 / 3.0 FMUs, bad input.

The exported controller is checked against the sampled controller computed here from
:meth:`Controller.discretise` (the simulators' update, ``u = Cc xc + Dc v``,
``xc+ = Phi xc + Gamma v``) on drawn inputs and FDI-mode sequences (fixed seeds), in
compiled C (a harness built with ``-Wall -Werror -std=c99 -pedantic``) and in a plain
FMPy loop over each FMU, to 1e-12 relative.
"""

from __future__ import annotations

import dataclasses
import os
import shutil
import subprocess
import zipfile
from pathlib import Path
from xml.etree import ElementTree as ET

import numpy as np
import pytest

from ftc_verify.cli.main import main
from ftc_verify.controllers.controller import Controller
from ftc_verify.controllers.files import load_controller, save_controller
from ftc_verify.model.files import load_system, save_system

ROOT = Path(__file__).resolve().parents[1]
PAPER = str(ROOT / "examples" / "paper.toml")
GAINS = str(ROOT / "examples" / "paper_gains.toml")
OBSERVER = str(ROOT / "examples" / "paper_observer.toml")
STEP = 0.01

pytestmark = pytest.mark.skipif(shutil.which("gcc") is None, reason="gcc is needed to compile exported code")


@pytest.fixture(scope="module")
def dynamic_case(tmp_path_factory: pytest.TempPathFactory) -> tuple[str, str, Controller]:
    """The paper's plant measured in full (``Cy = I``) and a certified order-2 dynamic
    controller on ``y_m`` (the paper's gains as ``Dc``, a stable ``Ac`` per FDI mode)."""
    folder = tmp_path_factory.mktemp("dyn")
    s = load_system(PAPER)
    s2 = dataclasses.replace(s, name="paper, y_m = x", modes=tuple(dataclasses.replace(m, Cy=np.eye(2)) for m in s.modes))
    K = load_controller(GAINS).Dc
    c = Controller.dynamic([np.array([[-1.0, 0.5], [-0.5, -2.0]]) - 0.3 * k * np.eye(2) for k in range(2)],
                           [np.array([[1.0, 0.2], [0.0, 1.0]]), np.eye(2)],
                           [np.array([[0.05, 0.0], [0.0, -0.05]]), np.array([[0.02, 0.01], [0.0, 0.03]])],
                           list(K), name="dynamic test controller").check(s2)
    save_system(s2, folder / "sys.toml")
    save_controller(c, folder / "dyn.toml")
    return str(folder / "sys.toml"), str(folder / "dyn.toml"), c


def reference_run(c: Controller, modes: np.ndarray, V: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """``U[k] = Cc xc_k + Dc v_k``, ``XC[k+1] = Phi xc_k + Gamma v_k`` in FDI mode ``modes[k]`` (1-based)."""
    xc = np.zeros(c.n_c)
    U, XC = [], [xc]
    for mode, v in zip(modes, V):
        e = int(mode) - 1
        U.append(c.output(e, xc, v))
        phi, gamma = c.discretise(e, step)
        xc = phi @ xc + gamma @ v
        XC.append(xc)
    return np.array(U), np.array(XC)


def draw_inputs(c: Controller, steps: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    modes = np.repeat(rng.integers(1, c.entries + 1, size=steps // 10 + 1), 10)[:steps]
    return modes, rng.normal(size=(steps, c.n_v))


def export(*args: str) -> int:
    return main(["export-controller", *args])


# ------------------------------------------------------------------------------------------
# The C99 file
# ------------------------------------------------------------------------------------------


def _harness(modes: np.ndarray, V: np.ndarray, nc: int) -> str:
    rows = ",\n".join("{" + ", ".join(repr(float(x)) for x in v) + "}" for v in V)
    return f"""#include <stdio.h>
#include "K.c"
static const int MODES[{len(modes)}] = {{{", ".join(str(int(m)) for m in modes)}}};
static const double V[{len(V)}][FTC_CTRL_NV] = {{{rows}}};
int main(void) {{
    ftc_ctrl_state s;
    double u[FTC_CTRL_NU];
    int k, i;
    ftc_ctrl_init(&s);
    for (k = 0; k < {len(modes)}; k++) {{
        if (ftc_ctrl_output(&s, MODES[k], V[k], u) != FTC_CTRL_OK) return 3;
        for (i = 0; i < FTC_CTRL_NU; i++) printf("%.17g ", u[i]);
        if (ftc_ctrl_step(&s, MODES[k], V[k], FTC_CTRL_STEP) != FTC_CTRL_OK) return 4;
        for (i = 0; i < {nc}; i++) printf("%.17g ", s.xc[i]);
        printf("\\n");
    }}
    if (ftc_ctrl_step(&s, 1, V[0], 1.01 * FTC_CTRL_STEP) != FTC_CTRL_BAD_STEP) return 5;
    if (ftc_ctrl_output(&s, FTC_CTRL_MODES + 1, V[0], u) != FTC_CTRL_BAD_MODE) return 6;
    if (ftc_ctrl_step(&s, 0, V[0], FTC_CTRL_STEP) != FTC_CTRL_BAD_MODE) return 7;
    return 0;
}}
"""


@pytest.mark.parametrize("case", ["static", "dynamic"])
def test_c_file_compiles_strictly_and_equals_the_sampled_controller(case: str, dynamic_case: tuple[str, str, Controller],
                                                                    tmp_path: Path) -> None:
    system, path, c = (PAPER, GAINS, load_controller(GAINS)) if case == "static" else dynamic_case
    assert export(path, "--system", system, "--c", "-o", str(tmp_path / "K.c")) == 0
    modes, V = draw_inputs(c, 200, seed=11)
    (tmp_path / "main.c").write_text(_harness(modes, V, c.n_c))
    subprocess.run(["gcc", "-Wall", "-Wextra", "-Werror", "-std=c99", "-pedantic", "-c", "K.c", "-o", "K.o"],
                   cwd=tmp_path, check=True)
    subprocess.run(["gcc", "-Wall", "-Werror", "-std=c99", "-pedantic", "main.c", "-o", "harness"], cwd=tmp_path,
                   check=True)
    out = subprocess.run(["./harness"], cwd=tmp_path, capture_output=True, text=True)
    assert out.returncode == 0, out.returncode
    got = np.array([[float(x) for x in line.split()] for line in out.stdout.splitlines()])
    U, XC = reference_run(c, modes, V, STEP)
    np.testing.assert_allclose(got[:, :c.nu], U, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(got[:, c.nu:], XC[1:], rtol=1e-12, atol=1e-12)
    assert c.n_c == 0 or np.abs(XC).max() > 0.01  # the state moved: the comparison is not of zeros


# ------------------------------------------------------------------------------------------
# The FMUs, in a plain FMPy loop
# ------------------------------------------------------------------------------------------


def fmpy_loop(fmu: Path, modes: np.ndarray, V: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """A hand-written co-simulation loop over the controller FMU (the tutorial's)."""
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave
    from fmpy.fmi3 import FMU3Slave

    md = read_model_description(str(fmu))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    v_refs = [vr[f"v[{i}]"] for i in range(1, V.shape[1] + 1)]
    u_refs = [vr[n] for n in sorted((n for n in vr if n.startswith("u[")), key=lambda n: int(n[2:-1]))]
    xc_refs = [vr[n] for n in sorted((n for n in vr if n.startswith("xc[")), key=lambda n: int(n[3:-1]))]
    unzip = extract(str(fmu))
    fmi3 = md.fmiVersion == "3.0"
    slave = (FMU3Slave if fmi3 else FMU2Slave)(guid=md.guid, unzipDirectory=unzip,
                                                modelIdentifier=md.coSimulation.modelIdentifier, instanceName="K")
    slave.instantiate()
    if fmi3:
        slave.enterInitializationMode(startTime=0.0)
        set_real, get_real, set_int = slave.setFloat64, slave.getFloat64, slave.setInt32
    else:
        slave.setupExperiment(startTime=0.0)
        slave.enterInitializationMode()
        set_real, get_real, set_int = slave.setReal, slave.getReal, slave.setInteger
    slave.exitInitializationMode()
    U, XC, t = [], [], 0.0
    for k, (mode, v) in enumerate(zip(modes, V)):
        set_int([vr["fdi_mode"]], [int(mode)])
        set_real(v_refs, list(v))
        U.append(get_real(u_refs))
        slave.doStep(currentCommunicationPoint=t, communicationStepSize=step)
        t = (k + 1) * step
        XC.append(get_real(xc_refs) if xc_refs else [])
    slave.terminate()
    slave.freeInstance()
    shutil.rmtree(unzip, ignore_errors=True)
    return np.array(U), np.array(XC)


@pytest.mark.parametrize("fmi", ["2.0", "3.0"])
def test_fmu_validates_records_its_certificate_and_equals_the_sampled_controller(
        fmi: str, dynamic_case: tuple[str, str, Controller], tmp_path: Path) -> None:
    from fmpy import read_model_description
    from fmpy.validation import validate_fmu

    system, path, c = dynamic_case
    fmu = tmp_path / "K.fmu"
    assert export(path, "--system", system, "--fmi", fmi, "-o", str(fmu)) == 0
    assert validate_fmu(str(fmu)) == []
    md = read_model_description(str(fmu))
    assert md.fmiVersion == fmi and md.defaultExperiment.stepSize == repr(STEP)
    assert not md.coSimulation.canHandleVariableCommunicationStepSize
    with zipfile.ZipFile(fmu) as zf:
        root = ET.fromstring(zf.read("modelDescription.xml"))
        assert load_controller_text(zf.read("resources/controller.toml").decode()) == c
    cert = root.find(".//Certificate")
    assert cert is not None and cert.get("certified") == "true" and cert.get("period") == repr(STEP)
    assert 0 < float(cert.get("robustGamma")) < 1 and cert.get("systemName") == "paper, y_m = x"
    assert len(cert.get("systemSha256")) == 64
    modes, V = draw_inputs(c, 300, seed=5)
    U, XC = fmpy_loop(fmu, modes, V, STEP)
    U_ref, XC_ref = reference_run(c, modes, V, STEP)
    np.testing.assert_allclose(U, U_ref, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(XC, XC_ref[1:], rtol=1e-12, atol=1e-12)


def load_controller_text(text: str) -> Controller:
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        p = Path(tmp) / "c.toml"
        p.write_text(text)
        return load_controller(p)


@pytest.mark.parametrize("fmi", ["2.0", "3.0"])
def test_fmu_refuses_a_step_that_is_not_its_period(fmi: str, tmp_path: Path) -> None:
    from fmpy.fmi1 import FMICallException

    fmu = tmp_path / "K.fmu"
    assert export(GAINS, "--system", PAPER, "--fmi", fmi, "-o", str(fmu), "--step", "0.02") == 0
    modes, V = draw_inputs(load_controller(GAINS), 5, seed=1)
    U, _ = fmpy_loop(fmu, modes, V, 0.02)  # its own period runs
    assert U.shape == (5, 2)
    with pytest.raises(FMICallException):
        fmpy_loop(fmu, modes, V, 0.01)


# ------------------------------------------------------------------------------------------
# Bad input: exit 2 (or the analysis verdict), nothing written
# ------------------------------------------------------------------------------------------


def test_existing_output_is_refused_without_force(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "K.fmu"
    out.write_text("keep me")
    assert export(GAINS, "--system", PAPER, "--fmi", "2.0", "-o", str(out)) == 2
    assert "--force" in capsys.readouterr().err and out.read_text() == "keep me"
    assert export(GAINS, "--system", PAPER, "--fmi", "2.0", "-o", str(out), "--force") == 0
    assert zipfile.is_zipfile(out)


@pytest.mark.parametrize("args, needle", [
    (["--fmi", "2.0", "--c"], "exactly one of --fmi"),
    ([], "exactly one of --fmi"),
    (["--c", "--step", "-1"], "--step"),
])
def test_option_errors(args: list[str], needle: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) if "-1" in args else _nothing():
        assert export(GAINS, "--system", PAPER, "-o", str(tmp_path / ("K.c" if "--c" in args else "K.fmu")), *args) == 2
    assert needle in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


class _nothing:
    def __enter__(self) -> None:
        return None

    def __exit__(self, *exc: object) -> bool:
        return False


def test_dimension_mismatch_is_bad_input(dynamic_case: tuple[str, str, Controller], tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    _, path, _ = dynamic_case  # two measured signals; the paper's system measures one
    assert export(path, "--system", PAPER, "--fmi", "2.0", "-o", str(tmp_path / "K.fmu")) == 2
    err = capsys.readouterr().err
    assert "Dc" in err and "measured outputs" in err and path in err
    assert list(tmp_path.iterdir()) == []


def test_full_information_controller_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    K = load_controller(GAINS).Dc
    save_controller(Controller.state_feedback([K[0], K[1], K[0], K[1]]), tmp_path / "full.toml")
    assert export(str(tmp_path / "full.toml"), "--system", PAPER, "--c", "-o", str(tmp_path / "K.c")) == 2
    assert "full-information" in capsys.readouterr().err and not (tmp_path / "K.c").exists()


def test_uncertified_controller_is_refused_unless_allowed(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "K.fmu"
    assert export(OBSERVER, "--system", PAPER, "--fmi", "2.0", "-o", str(out)) == 1  # not stable (analyze: 1)
    assert "refused" in capsys.readouterr().out and not out.exists()
    assert export(OBSERVER, "--system", PAPER, "--fmi", "2.0", "-o", str(out), "--allow-uncertified") == 0
    with zipfile.ZipFile(out) as zf:
        cert = ET.fromstring(zf.read("modelDescription.xml")).find(".//Certificate")
    assert cert is not None and cert.get("certified") == "false" and cert.get("verdict") == "not stable"
    assert cert.get("robustGamma") == "none"


def test_missing_compiler_is_bad_input(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                       capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setenv("PATH", str(tmp_path / "empty"))
    out = tmp_path / "K.fmu"
    assert export(GAINS, "--system", PAPER, "--fmi", "2.0", "-o", str(out)) == 2
    assert "gcc not found" in capsys.readouterr().err and not out.exists()
    monkeypatch.setenv("PATH", os.environ["PATH"])


def test_failing_compiler_gives_its_first_error_line(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    gcc = bin_dir / "gcc"
    gcc.write_text("#!/bin/sh\necho 'ctrl_glue.c:1:1: error: this compiler always fails' >&2\n"
                   "echo 'second line' >&2\nexit 1\n")
    gcc.chmod(0o755)
    monkeypatch.setenv("PATH", f"{bin_dir}{os.pathsep}{os.environ['PATH']}")
    out = tmp_path / "K.fmu"
    assert export(GAINS, "--system", PAPER, "--fmi", "3.0", "-o", str(out)) == 2
    err = capsys.readouterr().err
    assert "error: this compiler always fails" in err and "second line" not in err
    assert not out.exists() and [p.name for p in tmp_path.iterdir()] == ["bin"]


def test_the_default_period_is_the_simulators_default_step() -> None:
    from ftc_verify.cli.export_commands import DEFAULT_STEP
    from ftc_verify.simulation.spec import SimulationSpec

    assert DEFAULT_STEP == SimulationSpec.__dataclass_fields__["step"].default


def test_the_certificate_is_the_sampled_loops(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The paper's gains: exported at 10 Hz their sampled loop is proved unstable, so the
    export is refused (exit 1); at 100 Hz the record carries the proved h_max (about
    0.0842 s); a --step that differs from a controller file's period is refused."""
    out = tmp_path / "K.fmu"
    assert export(GAINS, "--system", PAPER, "--fmi", "2.0", "--step", "0.1", "-o", str(out)) == 1
    assert "refused" in capsys.readouterr().out and not out.exists()
    assert export(GAINS, "--system", PAPER, "--fmi", "2.0", "-o", str(out)) == 0
    with zipfile.ZipFile(out) as zf:
        cert = ET.fromstring(zf.read("modelDescription.xml")).find(".//Certificate")
    assert cert is not None and cert.get("sampledVerdict") == "stable" and cert.get("certified") == "true"
    assert 0.083 < float(cert.get("hMax", "nan")) < 0.0843
    periodic = tmp_path / "periodic.toml"
    periodic.write_text("period = 0.02\n" + Path(GAINS).read_text())
    assert export(str(periodic), "--system", PAPER, "--fmi", "2.0", "--step", "0.01", "-o",
                  str(tmp_path / "P.fmu")) == 2
    assert "--step 0.01: differs from the controller's period 0.02" in capsys.readouterr().err
