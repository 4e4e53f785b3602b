"""The documentation's tutorials are run, and its API reference covers every public module.

* Every command in a ```sh block of ``docs/tutorials/*.md`` is run, in order, from a
  temporary copy of ``examples/`` (so the files the commands write stay there): lines
  ``ftc-verify ...`` as ``python -m ftc_verify ...``, lines ``python ...`` with this
  interpreter, ``cd DIR`` changes the folder of the next lines, a trailing ``\\`` joins
  lines. A command exits 0 unless its line ends with ``# exit N``; nothing prints a
  traceback.
* Where a tutorial shows a command's output (a plain fenced block starting with
  ``ftc-verify COMMAND:`` right after a ```sh block), the command prints that text: word
  for word, with each number within 1e-3 relative of the one shown (the last printed
  digit of a solver's answer may differ between machines; numbers below 1e-10 are
  rounding noise and only have to stay below it).
* Long commands run shortened: :data:`REDUCED` lists, per page, each replacement; the page
  must show the full form and say that the tests run the shortened one.
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
TUTORIALS = sorted(p for p in (DOCS / "tutorials").glob("*.md") if p.name != "index.md")

#: Per tutorial page: (what the page shows, what the test runs). The three-tank Monte
#: Carlo runs with the reduction tests/test_three_tank.py uses (10 paths of 300 s).
REDUCED = {
    "three-tank.md": [("--paths 200 --horizon 600", "--paths 10 --horizon 300")],
}

FENCE = re.compile(r"^```([^\n`]*)\n(.*?)^```\s*$", flags=re.S | re.M)


@dataclass(frozen=True)
class Step:
    """One line of a tutorial's ```sh block."""

    line: str
    folder: str  # relative to the temporary copy's root
    expected_exit: int
    expected_stdout: str | None  # the output block shown after the command, if any


def fenced_blocks(text: str) -> list[tuple[str, str]]:
    """(info string, body) of every fenced block of a markdown page, in order."""
    return [(m.group(1).strip(), m.group(2)) for m in FENCE.finditer(text)]


def _lines(body: str) -> list[str]:
    """The commands of a ```sh block: continuations joined, blank and comment lines dropped."""
    joined = re.sub(r"\\\n\s*", "", body)
    return [line.strip() for line in joined.splitlines() if line.strip() and not line.strip().startswith("#")]


def tutorial_steps(text: str) -> list[Step]:
    """The commands of a tutorial page, with the folder each runs in and what it must give."""
    blocks = fenced_blocks(text)
    steps: list[Step] = []
    folder = "."
    for k, (info, body) in enumerate(blocks):
        if info != "sh":
            continue
        following = blocks[k + 1] if k + 1 < len(blocks) else ("-", "")
        lines = _lines(body)
        for n, line in enumerate(lines):
            if line.startswith("cd "):
                folder = os.path.normpath(os.path.join(folder, line[3:].strip()))
                continue
            match = re.search(r"\s+#\s*exit (\d+)\s*$", line)
            command = line[: match.start()] if match else line
            shown = None
            if n == len(lines) - 1 and following[0] == "" and re.match(r"ftc-verify [\w-]+: ", following[1]):
                shown = following[1]
            steps.append(Step(command, folder, int(match.group(1)) if match else 0, shown))
    return steps


NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")


def same_output(printed: str, shown: str) -> bool:
    """``printed`` is ``shown`` up to the last digits of its numbers (see the module docstring)."""
    if NUMBER.sub("#", printed) != NUMBER.sub("#", shown):
        return False
    for a, b in zip(NUMBER.findall(printed), NUMBER.findall(shown), strict=True):
        x, y = float(a), float(b)
        if not (abs(x - y) <= 1e-3 * max(abs(x), abs(y)) or max(abs(x), abs(y)) < 1e-10):
            return False
    return True


def test_same_output_tells_digits_from_words() -> None:
    assert same_output("gamma 0.360844, 2.07e-14 on 5 paths", "gamma 0.360846, 2.04e-14 on 5 paths")
    assert not same_output("gamma 0.3612", "gamma 0.3608")
    assert not same_output("verdict: pass", "verdict: fail")
    assert not same_output("a\n  FDI: exponential\nb", "a\nb")


def _argv(command: str) -> list[str]:
    words = shlex.split(command)
    if words[0] == "ftc-verify":
        return [sys.executable, "-m", "ftc_verify", *words[1:]]
    if words[0] == "python":
        return [sys.executable, *words[1:]]
    raise AssertionError(f"a tutorial command that the test cannot run: {command!r}")


def test_every_tutorial_has_commands_and_no_unknown_ones() -> None:
    assert {p.name for p in TUTORIALS} >= {"paper-example.md", "dc-motor.md", "three-tank.md", "output-feedback.md"}
    for page in TUTORIALS:
        steps = tutorial_steps(page.read_text(encoding="utf-8"))
        assert steps, f"{page.name} shows no command"
        for step in steps:
            _argv(step.line)


def test_reductions_are_shown_and_said() -> None:
    for name, replacements in REDUCED.items():
        text = (DOCS / "tutorials" / name).read_text(encoding="utf-8")
        commands = " ".join(step.line for step in tutorial_steps(text))
        for full, short in replacements:
            assert full in commands, f"{name}: the page no longer shows {full!r}"
            assert f"`{short}`" in text and "tests run" in text, f"{name} must say the tests run {short!r}"


def test_readme_tour_is_the_tutorials_output() -> None:
    """The README's main-job output is the block the paper tutorial checks against the program."""
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    tour = [body for info, body in fenced_blocks(readme) if body.startswith("ftc-verify verify: ")]
    steps = tutorial_steps((DOCS / "tutorials" / "paper-example.md").read_text(encoding="utf-8"))
    checked = {step.line: step.expected_stdout for step in steps if step.expected_stdout}
    assert len(tour) == 1 and checked.get("ftc-verify verify examples/paper.toml --seed 1") == tour[0]


def _page_params() -> list[object]:
    # Seconds measured on 2 busy cores, for the scheduler in conftest.py (longest first).
    seconds = {"three-tank.md": 125, "paper-example.md": 40, "output-feedback.md": 45, "dc-motor.md": 17}
    return [pytest.param(p, id=p.stem, marks=pytest.mark.slow(seconds.get(p.name, 10))) for p in TUTORIALS]


@pytest.mark.parametrize("page", _page_params())
def test_tutorial_commands_run(page: Path, tmp_path: Path) -> None:
    work = tmp_path / "work"
    shutil.copytree(ROOT / "examples", work / "examples", ignore=shutil.ignore_patterns("*.fmu", "__pycache__"))
    env = os.environ | {"FTC_VERIFY_CACHE": str(tmp_path / "cache")}
    for step in tutorial_steps(page.read_text(encoding="utf-8")):
        command = step.line
        for full, short in REDUCED.get(page.name, []):
            command = command.replace(full, short)
        out = subprocess.run(_argv(command), cwd=work / step.folder, capture_output=True, text=True, env=env,
                             timeout=900, check=False)
        assert out.returncode == step.expected_exit, (page.name, command, out.stdout, out.stderr)
        assert "Traceback" not in out.stderr, (page.name, command, out.stderr)
        if step.expected_stdout is not None:
            assert same_output(out.stdout, step.expected_stdout), (page.name, command, out.stdout)


def test_every_public_module_has_an_api_page() -> None:
    """Each module of ftc_verify whose name does not start with an underscore is on an API page."""
    api = "\n".join(p.read_text(encoding="utf-8") for p in (DOCS / "reference" / "api").glob("*.rst"))
    documented = set(re.findall(r"^\.\. automodule:: (\S+)$", api, flags=re.M))
    modules = {"ftc_verify"}
    for path in (ROOT / "ftc_verify").rglob("*.py"):
        parts = path.relative_to(ROOT).with_suffix("").parts
        if any(part.startswith("_") and part != "__init__" for part in parts) or parts[-1] == "__main__":
            continue
        modules.add(".".join(parts[:-1] if parts[-1] == "__init__" else parts))
    assert modules - documented == set(), "modules without an API page entry"
    assert documented - modules == set(), "API page entries for modules that do not exist"
