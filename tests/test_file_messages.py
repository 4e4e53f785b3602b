"""A file of the wrong kind, a misspelt key and a missing FMU each get one line that says
what happened and what to do (issue 33), through the command line with exit 2."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from ftc_verify.cli.common import EXIT_BAD_INPUT
from ftc_verify.cli.main import main
from ftc_verify.errors import ProblemFileError
from ftc_verify.model.files import load_system, unknown_keys

ROOT = Path(__file__).resolve().parents[1]
PAPER, GAINS = str(ROOT / "examples" / "paper.toml"), str(ROOT / "examples" / "paper_gains.toml")


def _one_line_error(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    assert main(argv) == EXIT_BAD_INPUT
    captured = capsys.readouterr()
    assert captured.out == "" and len(captured.err.strip().splitlines()) == 1, captured.err
    return captured.err


@pytest.mark.parametrize("argv, said", [
    (["analyze", PAPER, "--controller", PAPER],
     "paper.toml: this is a system file ([chain] and [[mode]] tables), not a controller file"),
    (["analyze", GAINS, "--controller", GAINS],
     "paper_gains.toml: this is a controller file ([[gain]] or [[controller]] tables), not a system file"),
    (["plant", PAPER], "paper.toml: this is a system file ([chain] and [[mode]] tables), not a plant map"),
    (["analyze", str(ROOT / "examples" / "motor.plant.toml"), "--gains", GAINS],
     "motor.plant.toml: this is a plant map (fmu and [variables]), not a system file"),
])
def test_a_file_of_another_kind_is_named(argv: list[str], said: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert said in _one_line_error(argv, capsys)


def test_a_misspelt_key_gets_the_key_it_resembles(tmp_path: Path) -> None:
    text = Path(PAPER).read_text().replace("beta_min", "beta_mni", 1)
    (tmp_path / "typo.toml").write_text(text)
    with pytest.raises(ProblemFileError, match=r"unknown key\(s\) \['beta_mni'\] \(did you mean 'beta_min'\?\)"):
        load_system(tmp_path / "typo.toml")


def test_several_typos_case_and_no_guess() -> None:
    with pytest.raises(ProblemFileError, match=r"\(did you mean 'alpha' for 'Alpha', 'beta_max' for 'beta_mx'\?\)"):
        unknown_keys(Path("f.toml"), "[chain]", ["Alpha", "beta_mx", "alpha"], {"alpha", "beta_min", "beta_max"})
    with pytest.raises(ProblemFileError) as info:
        unknown_keys(Path("f.toml"), "top level", ["zzz"], {"name", "chain", "mode"})
    assert "did you mean" not in str(info.value) and "allowed: ['chain', 'mode', 'name']" in str(info.value)


def test_a_missing_fmu_says_how_to_build_it(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    shutil.copy(ROOT / "examples" / "motor.plant.toml", tmp_path)  # Motor.fmu not built there
    err = _one_line_error(["plant", str(tmp_path / "motor.plant.toml")], capsys)
    assert "no such file" in err and "build_ode_fmu(motor_spec()" in err
    for name in ("three_tank.plant.toml", "ThreeTank.mo"):
        shutil.copy(ROOT / "examples" / "three_tank" / name, tmp_path)
    err = _one_line_error(["plant", str(tmp_path / "three_tank.plant.toml")], capsys)
    assert f"build it first: ftc-verify build-fmu {tmp_path / 'ThreeTank.mo'} -o {tmp_path / 'ThreeTank.fmu'}" in err
