"""Bad numbers and too-deep files are bad input (exit 2), not internal errors (audit13
finding 06, found by an independent check).

``simulate --backend reference`` keeps few records, so the memory check it shared with
``verify`` let through a path count that does not fit an index (``OverflowError``), a step
whose grid does not fit an array (``ValueError``) and a horizon of ``1e300`` (a run that
never ends): each ended with exit 4, or not at all. Now the estimate counts one path's grid
and every path's summary, and refuses them before any work, as ``verify`` does. A TOML file
nested thousands of levels deep made the parser recurse past Python's limit
(``RecursionError``, exit 4): the loaders now refuse it naming the file.
"""

from __future__ import annotations

from pathlib import Path

import cli_inprocess
import pytest

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "examples" / "paper.toml"
GAINS = ROOT / "examples" / "paper_gains.toml"


def _one_error_line(args: list[str], cwd: Path, *needles: str) -> str:
    proc = cli_inprocess.run_cli(args, cwd)
    assert proc.returncode == 2, (proc.returncode, proc.stdout, proc.stderr)
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and proc.stdout == "", proc
    assert "internal error" not in lines[0] and "Traceback" not in proc.stderr
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])
    return lines[0]


@pytest.mark.parametrize("option, value, needle", [
    ("--paths", "99999999999999999999", "the summaries of 99999999999999999999 paths"),
    ("--paths", "1000000000", "the summaries of 1000000000 paths"),
    ("--step", "1e-300", "grid points each"),
    ("--horizon", "1e300", "grid points each"),
])
@pytest.mark.parametrize("command", ["simulate", "verify"])
def test_numbers_too_large_for_memory_are_refused(tmp_path: Path, command: str, option: str, value: str,
                                                   needle: str) -> None:
    """Exit 2 with the memory estimate and the limit, before any simulation (was, for
    simulate: exit 4 OverflowError / ValueError, or a run that never ended)."""
    args = [command, str(PAPER), "--gains", str(GAINS), option, value]
    args += ["--backend", "reference"] if command == "simulate" else ["--out", str(tmp_path / "rep")]
    line = _one_error_line(args, tmp_path, "of memory needed, above the limit")
    if command == "simulate":
        assert needle in line
    assert not (tmp_path / "rep").exists()


@pytest.mark.parametrize("which", ["system", "controller"])
def test_a_too_deeply_nested_toml_is_bad_input(tmp_path: Path, which: str) -> None:
    """A file of arrays nested 5000 deep, given as the system or the controller: one line
    naming the file (was: exit 4, RecursionError)."""
    deep = tmp_path / "deep.toml"
    deep.write_text("a = " + "[" * 5000 + "]" * 5000 + "\n")
    system, gains = (deep, GAINS) if which == "system" else (PAPER, deep)
    for command in (["simulate", "--backend", "reference"], ["analyze"]):
        _one_error_line([command[0], str(system), "--gains", str(gains), *command[1:]], tmp_path,
                        str(deep), "nested too deeply")
