"""The loop runs the exported controller: ``simulate``/``verify --controller-fmu``.

The supervisor with an exported FMU (FMI 2.0 and 3.0) as the controller gives path records
(``x``, ``u``, ``x_c``, ``y``, ``y_m``) equal to those of the built-in controller to 1e-10
on the same paths (a dynamic controller, random ``Delta``, seeds fixed); jump times move to
the controller's step grid (the FMU refuses any other step); mismatches are refused (exit 2).
"""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from session_cache import computed_once

from ftc_verify.cli.main import main
from ftc_verify.controllers.controller import Controller
from ftc_verify.controllers.files import load_controller, save_controller
from ftc_verify.model.files import load_system, save_system
from ftc_verify.plants.controller_session import controller_of_fmu
from ftc_verify.simulation.paths import snap_to_grid
from ftc_verify.simulation.spec import SimulationSpec
from ftc_verify.simulation.supervisor import open_supervisor

ROOT = Path(__file__).resolve().parents[1]
PAPER = str(ROOT / "examples" / "paper.toml")
GAINS = str(ROOT / "examples" / "paper_gains.toml")

pytestmark = pytest.mark.skipif(shutil.which("gcc") is None, reason="gcc is needed to compile exported code")


def _export(folder: Path) -> dict[str, str]:
    """The paper's plant measured in full and a certified order-2 controller, exported as
    FMI 2.0 and 3.0 FMUs (``--step 0.01``) into ``folder``."""
    s = load_system(PAPER)
    s2 = dataclasses.replace(s, name="paper, y_m = x", modes=tuple(dataclasses.replace(m, Cy=np.eye(2)) for m in s.modes))
    K = load_controller(GAINS).Dc
    c = Controller.dynamic([np.array([[-1.0, 0.5], [-0.5, -2.0]]) - 0.3 * k * np.eye(2) for k in range(2)],
                           [np.array([[1.0, 0.2], [0.0, 1.0]]), np.eye(2)],
                           [np.array([[0.05, 0.0], [0.0, -0.05]]), np.array([[0.02, 0.01], [0.0, 0.03]])],
                           list(K), name="dynamic test controller")
    save_system(s2, folder / "sys.toml")
    save_controller(c, folder / "dyn.toml")
    out = {"system": str(folder / "sys.toml"), "controller": str(folder / "dyn.toml"), "folder": str(folder)}
    for fmi in ("2.0", "3.0"):
        out[fmi] = str(folder / f"K{fmi[0]}.fmu")
        assert main(["export-controller", out["controller"], "--system", out["system"], "--fmi", fmi,
                     "-o", out[fmi]]) == 0
    return out


@pytest.fixture(scope="module")
def case(shared_tmp: Path) -> dict[str, str]:
    """:func:`_export` run once per session (``tests/session_cache.py``: pytest-xdist's
    order re-created a module fixture each time it came back to this module, 2.3-2.6 s
    each); the tests only read its files."""
    return computed_once(shared_tmp, "controller-fmu-loop", _export)


@pytest.mark.parametrize("fmi", ["2.0", "3.0"])
def test_supervisor_records_equal_the_builtin_controller(fmi: str, case: dict[str, str]) -> None:
    system, builtin = load_system(case["system"]), load_controller(case["controller"])
    exported = controller_of_fmu(case[fmi])
    assert exported == builtin  # the matrices the FMU carries are the file's
    spec = SimulationSpec(step=0.01, horizon=6.0, n_paths=4, seed=7, delta="random").with_seed()
    raw = spec.sample_paths(system.chain)
    snapped = [snap_to_grid(p, 0.01)[0] for p in raw]
    with open_supervisor(system) as sup:
        a = sup.run(snapped, builtin, spec=spec)
        b = sup.run(raw, exported, spec=spec)  # the supervisor moves the jumps to the controller's grid
    assert b.options["controller_fmu"] == case[fmi] and b.options["timing_error"] > 0
    assert sum(len(p.times) for p in raw) > len(raw)  # the paths switch: several controller entries run
    for ra, rb in zip(a.records, b.records):
        np.testing.assert_array_equal(ra.t, rb.t)
        for key in ("x", "u", "xc", "y", "ym"):
            np.testing.assert_allclose(getattr(rb, key), getattr(ra, key), rtol=0, atol=1e-10, err_msg=key)
        assert np.abs(ra.xc).max() > 0.01 and len(np.unique(ra.fdi)) == 2


@pytest.mark.slow(21)  # seconds on 2 busy cores (--durations at load 9, / 4): scheduled first
def test_simulate_and_verify_run_the_fmu(case: dict[str, str], capsys: pytest.CaptureFixture[str],
                                         tmp_path: Path) -> None:
    assert main(["simulate", case["system"], "--controller-fmu", case["3.0"], "--paths", "3", "--horizon", "2",
                 "--seed", "4", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["verdict"] == "done" and d["options"]["controller_fmu"] == case["3.0"]
    out = tmp_path / "rep"
    assert main(["verify", case["system"], "--controller-fmu", case["2.0"], "--paths", "8", "--horizon", "2",
                 "--seed", "4", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "[pass] FMU vs reference" in text
    report = json.loads((out / "report.json").read_text())
    assert report["options"]["controller_fmu"] == case["2.0"]


@pytest.mark.parametrize("extra, needle", [
    (["--step", "0.02"], "sampling period 0.01 s, but --step is 0.02"),
    (["--backend", "reference"], "needs --backend fmu"),
    (["--controller", GAINS], "not both"),
])
def test_mismatches_are_refused(extra: list[str], needle: str, case: dict[str, str],
                                capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["simulate", case["system"], "--controller-fmu", case["2.0"], *extra]) == 2
    assert needle in capsys.readouterr().err


def test_controller_fmu_of_another_system_is_refused(case: dict[str, str], capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["simulate", PAPER, "--controller-fmu", case["2.0"]]) == 2
    err = capsys.readouterr().err
    assert case["2.0"] in err and "measured outputs" in err
    assert main(["simulate", PAPER]) == 2
    assert "--controller-fmu" in capsys.readouterr().err
