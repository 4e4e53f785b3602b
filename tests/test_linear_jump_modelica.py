"""The LinearJumpPlant through the Modelica route against the hand-written C FMU.

``linear_jump_modelica`` writes the plant of a system as a flat Modelica model (mode as a
tunable Real parameter selecting if-expressions); ``build_modelica_fmu`` compiles it; the
supervisor co-simulates it through ``linear_jump_modelica_map`` on the same paths, the same
``Delta`` draws and the same gains as the C ``LinearJumpPlant`` (exact discretisation). The
Modelica FMU integrates with Dormand-Prince 5(4) at tolerance 1e-10, so the paths agree to
1e-8 relative (1e-14 seen), not to rounding.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pymoca")
pytest.importorskip("casadi")
if shutil.which("gcc") is None:  # pragma: no cover
    pytest.skip("gcc is needed to compile the FMUs", allow_module_level=True)

from ftc_verify.controllers import load_controller
from ftc_verify.model.files import load_system
from ftc_verify.plants.linear_jump_modelica import linear_jump_modelica, linear_jump_modelica_map
from ftc_verify.plants.modelica import build_modelica_fmu
from ftc_verify.simulation.paths import sample_paths
from ftc_verify.simulation.supervisor import Supervisor, simulate_fmu

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("delta", ["zero", "random"])
def test_modelica_linear_jump_plant_agrees_with_the_c_fmu(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                           delta: str) -> None:
    monkeypatch.setenv("FTC_VERIFY_CACHE", str(tmp_path / "cache"))
    system = load_system(ROOT / "examples" / "paper.toml")
    gains = load_controller(ROOT / "examples" / "paper_gains.toml")
    mo = ROOT / "fmus" / "modelica" / "LinearJumpPlant.mo"  # the project's own file, built as it is
    fmu = build_modelica_fmu(mo, dest=tmp_path / "LinearJumpPlant.fmu")
    paths = sample_paths(system.chain, 5.0, 3, 3)
    c_fmu = simulate_fmu(system, gains, paths, step=0.01, delta=delta, seed=5)
    with Supervisor(fmu, linear_jump_modelica_map(system), system=system, tolerance=1e-10) as sup:
        mo_fmu = sup.run(paths, gains, step=0.01, delta=delta, seed=5)
    assert mo_fmu.options["model_identifier"] == "LinearJumpPlant"
    for a, b in zip(c_fmu.records, mo_fmu.records):
        np.testing.assert_array_equal(a.t, b.t)
        for key in ("x", "y", "ym", "u"):
            ra, rb = getattr(a, key), getattr(b, key)
            assert np.max(np.abs(ra - rb)) <= 1e-8 * np.max(np.abs(ra)), key


def test_generated_model_selects_each_mode() -> None:
    system = load_system(ROOT / "examples" / "paper.toml")
    text = linear_jump_modelica(system, "P")
    assert "if mode < 1.5 then 1.0 else 0.2" in text  # B[0,1] differs between the modes
    assert text.startswith("model P") and text.rstrip().endswith("end P;")


def test_checked_in_model_is_the_generators_output() -> None:
    """``fmus/modelica/LinearJumpPlant.mo`` (after its comment header) is exactly what
    ``linear_jump_modelica`` writes for the paper's system, so it cannot drift."""
    system = load_system(ROOT / "examples" / "paper.toml")
    text = (ROOT / "fmus" / "modelica" / "LinearJumpPlant.mo").read_text()
    body = "".join(line for line in text.splitlines(keepends=True) if not line.startswith("//"))
    assert body == linear_jump_modelica(system, "LinearJumpPlant")
