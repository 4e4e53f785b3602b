"""``ftc-verify export-loop``: the closed loop as an SSP 1.0 archive.

The archive is read by FMPy (which validates ``SystemStructure.ssd`` and the parameter set
against the SSP 1.0 schemas) and by ``pyssp-standard`` (schema compliance, connection
semantics), and simulated by FMPy's ``simulate_ssp`` for a fixed joint mode. FMPy's SSP
master exchanges the connections after every step (a Jacobi master): its loop is the
sampled loop with one sample of delay, which the project computes from the simulators'
discretisations (:func:`~ftc_verify.export.ssp.jacobi_reference`); FMPy matches it to
1e-10 of the state's size, for a static and a dynamic controller, with a disturbance
input. That no archive can give FMPy's master the undelayed loop is proved in
:mod:`ftc_verify.export.ssp`; the test checks the proof's first step (FMPy's
``x(h) = Phi x0``, the tool's loop ``Phi x0 + Gamma_B K x0``) and records the O(h)
distance (about 10 % of the state's size at h = 0.01 with the paper's fast gains, half of
that at h = 0.005).
"""

from __future__ import annotations

import dataclasses
import shutil
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from ftc_verify.cli.main import main
from ftc_verify.controllers.files import load_controller
from ftc_verify.export.ssp import jacobi_reference
from ftc_verify.model.files import load_system
from ftc_verify.simulation.discretise import zoh_matrices
from ftc_verify.simulation.paths import ChainPath
from ftc_verify.simulation.reference import simulate_reference

ROOT = Path(__file__).resolve().parents[1]
PAPER = str(ROOT / "examples" / "paper.toml")
GAINS = str(ROOT / "examples" / "paper_gains.toml")
OBSERVER = str(ROOT / "examples" / "paper_observer.toml")

pytestmark = pytest.mark.skipif(shutil.which("gcc") is None, reason="gcc is needed to compile exported code")


def export_loop(tmp_path: Path, *args: str, step: str = "0.01") -> Path:
    out = tmp_path / f"loop-{step}.ssp"
    assert main(["export-loop", PAPER, "--controller", GAINS, "--fault-mode", "2", "--fdi-mode", "2",
                 "--x0", "1,-1", "--step", step, "--stop-time", "2", "-o", str(out), *args]) == 0
    return out


def fmpy_ssp_run(ssp: Path, h: float, stop: float, w: Any = None, names: tuple[str, ...] = ("x[1]", "x[2]"),
                 ) -> np.ndarray:
    """FMPy's run of the archive: the plant's connectors ``names``, row j at t_{j+1}."""
    from fmpy.ssp.simulation import simulate_ssp
    from fmpy.ssp.ssd import read_ssv

    params = read_ssv(str(ssp), resource="resources/modes.ssv")
    rows = simulate_ssp(str(ssp), stop_time=stop, step_size=h, parameter_set=params,
                        input={} if w is None else {"w[1]": lambda t: w(t)[0]})
    return np.column_stack([rows[f"plant.{name}"] for name in names])


def disturbance(t: float) -> list[float]:
    return [np.sin(7.0 * t) + 0.5]


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.max(np.abs(a - b))) / float(np.max(np.abs(b)))


def test_ssp_is_read_by_standard_libraries(tmp_path: Path) -> None:
    from fmpy.ssp.ssd import read_ssd

    ssp = export_loop(tmp_path)
    with zipfile.ZipFile(ssp) as zf:
        assert sorted(zf.namelist()) == ["SystemStructure.ssd", "resources/controller.fmu", "resources/modes.ssv",
                                         "resources/plant.fmu"]
    ssd = read_ssd(str(ssp))  # validated against the SSP 1.0 schema by FMPy
    assert [c.name for c in ssd.system.elements] == ["plant", "controller"]
    assert len(ssd.system.connections) == 2 + 2 + 1 + 1  # x -> v, u -> u, w, y
    pyssp = pytest.importorskip("pyssp_standard.ssp")
    from pyssp_standard.standard import ModelicaStandard

    with pyssp.SSP(ssp, mode="r") as archive:
        structure = archive.system_structure
        structure.check_compliance(ModelicaStandard.schemas["ssd"], ModelicaStandard.namespaces)
        assert structure.check_connections() == []  # no forbidden or ambiguous connection
        assert sorted(str(r) for r in archive.resources) == ["controller.fmu", "modes.ssv", "plant.fmu"]


def test_fmpy_runs_the_jacobi_loop_and_not_the_undelayed_one(tmp_path: Path) -> None:
    """FMPy's run equals the project's Jacobi-master loop to 1e-10 (with a disturbance
    input, at two periods); its first step is ``Phi x0`` exactly where the tool's own loop
    has ``Phi x0 + Gamma_B K x0`` (the proof's first step); the O(h) distance to that
    loop is the delay's."""
    system, controller = load_system(PAPER), load_controller(GAINS)
    errors = []
    for h in (0.01, 0.005):
        ssp = export_loop(tmp_path, step=repr(h))
        X = fmpy_ssp_run(ssp, h, 2.0, disturbance)
        ref = jacobi_reference(system, controller, fault_mode=2, fdi_mode=2, x0=[1.0, -1.0], step=h, steps=len(X),
                               w=disturbance)
        assert _rel(X, ref) < 1e-10
        mode = system.modes[1]
        phi, gb, _ = zoh_matrices(mode.A, mode.B, mode.D, h)
        x0 = np.array([1.0, -1.0])
        np.testing.assert_allclose(X[0], phi @ x0, rtol=0, atol=1e-12)  # u = w = 0 over [0, h]
        X = fmpy_ssp_run(ssp, h, 2.0)
        path = ChainPath(np.array([0.0]), np.array([1]), np.array([1]), system.chain.rate_max, len(X) * h)
        own = simulate_reference(system, controller, path, step=h, disturbance="zero", delta="zero",
                                 x0=[1.0, -1.0]).records[0].x[1:len(X) + 1]
        np.testing.assert_allclose(own[0], phi @ x0 + gb @ controller.Dc[1] @ x0, rtol=1e-9)
        assert np.max(np.abs(own[0] - X[0])) > 1e-3  # Gamma_B K x0: the first-step gap no archive can close
        errors.append(_rel(X, own))
    assert errors[0] < 0.2 and errors[1] < 0.6 * errors[0], errors  # O(h): the one-sample delay


def test_fmpy_runs_the_jacobi_loop_of_a_dynamic_controller(tmp_path: Path) -> None:
    """The observer-based controller (order 2, reads y_m; exported uncertified on request):
    FMPy's measured output equals :func:`jacobi_reference`'s ``Cy x`` to 1e-10 with a
    disturbance input (the controller's state and its update at the step boundary)."""
    system, controller = load_system(PAPER), load_controller(OBSERVER)
    out = tmp_path / "observer.ssp"
    code = main(["export-loop", PAPER, "--controller", OBSERVER, "--fault-mode", "1", "--fdi-mode", "2", "--x0",
                 "0.5,0.2", "--step", "0.01", "--stop-time", "1", "--allow-uncertified", "-o", str(out)])
    assert code in (0, 1, 3, 5) and out.exists(), code
    Y = fmpy_ssp_run(out, 0.01, 1.0, disturbance, names=("ym[1]",))  # the plant exposes y_m, not x
    ref = jacobi_reference(system, controller, fault_mode=1, fdi_mode=2, x0=[0.5, 0.2], step=0.01, steps=len(Y),
                           w=disturbance)
    assert _rel(Y, ref @ system.modes[0].measured.T) < 1e-10


@pytest.mark.parametrize("args, needle", [
    (["--fdi-mode", "3"], "--fdi-mode 3: the system has modes 1..2"),
    (["--x0", "1,2,3"], "--x0: 3 values"),
])
def test_bad_input(args: list[str], needle: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "loop.ssp"
    assert main(["export-loop", PAPER, "--controller", GAINS, "-o", str(out), *args]) == 2
    assert needle in capsys.readouterr().err and not out.exists()


def test_existing_output_and_uncertified_controller_are_refused(tmp_path: Path,
                                                                capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "loop.ssp"
    out.write_text("keep")
    assert main(["export-loop", PAPER, "--controller", GAINS, "-o", str(out)]) == 2
    assert "--force" in capsys.readouterr().err and out.read_text() == "keep"
    assert main(["export-loop", PAPER, "--controller", OBSERVER, "-o", str(out), "--force"]) == 1
    assert "refused" in capsys.readouterr().out and out.read_text() == "keep"


def test_loop_spec_of_a_plant_map_with_real_fault_values() -> None:
    """A user's plant map: a Real fault variable with values per mode, fixed parameters,
    output feedback on the named measured outputs; an operating point is refused."""
    from ftc_verify.controllers.controller import Controller
    from ftc_verify.errors import ValidationError
    from ftc_verify.export.ssp import loop_spec, loop_ssd, loop_ssv
    from ftc_verify.plants.fault_map import FaultInjectionMap, OperatingPoint

    mapping = FaultInjectionMap(fault=("k_eff",), inputs=("V",), states=("omega", "i"), disturbances=("tau",),
                                outputs=("omega_out",), measured=("omega_meas",), fault_values=((1.0,), (0.6,)),
                                initial_states=("omega", "i"), parameters=(("R", 2.0),))
    ctrl = Controller.dynamic([np.array([[-1.0]])] * 2, [np.array([[1.0]])] * 2, [np.array([[0.5]])] * 2,
                              [np.array([[-0.1]])] * 2)
    types = {"k_eff": "Real", "R": "Real"}
    spec = loop_spec(mapping, types, ctrl, fault_mode=2, fdi_mode=1, x0=[100.0, 7.0], step=0.01, stop_time=5.0,
                     name="motor")
    assert spec.reads == ("omega_meas",)
    assert spec.parameters == (("k_eff", "Real", "0.6"), ("omega", "Real", "100.0"), ("i", "Real", "7.0"),
                               ("R", "Real", "2.0"))
    ssd, ssv = loop_ssd(spec), loop_ssv(spec)
    assert 'startConnector="omega_meas"' in ssd and 'endConnector="V"' in ssd and 'name="plant.k_eff"' in ssv
    assert 'name="controller.fdi_mode"' in ssv
    with_op = dataclasses.replace(mapping, operating_point=OperatingPoint(np.array([12.0]), np.array([100.0, 7.0]),
                                                                         np.zeros(1)))
    with pytest.raises(ValidationError, match="operating point"):
        loop_spec(with_op, types, ctrl, fault_mode=1, fdi_mode=1, x0=None, step=0.01, stop_time=5.0, name="motor")

