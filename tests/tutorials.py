"""The tutorials of ``docs/tutorials``: their commands read from the pages and run.

Every command in a ```sh block is run, in order, from a temporary copy of ``examples/``
(so the files the commands write stay there): lines ``ftc-verify ...`` as
``python -m ftc_verify ...``, lines ``python ...`` with this interpreter, ``cd DIR``
changes the folder of the next lines, a trailing ``\\`` joins lines. A command exits 0
unless its line ends with ``# exit N``; nothing prints a traceback. Where a page shows a
command's output (a plain fenced block starting with ``ftc-verify COMMAND:`` right after
a ```sh block), the command prints that text up to the last digits of its numbers
(:func:`same_output`). Long commands run shortened (:data:`REDUCED`).

Used by ``tests/test_docs.py`` (every page) and ``tests/test_three_tank.py`` (the
three-tank page, with its own checks of the report).
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

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
TUTORIALS = sorted(p for p in (DOCS / "tutorials").glob("*.md") if p.name != "index.md")

#: Per tutorial page: (what the page shows, what the test runs). The three-tank Monte
#: Carlo runs 10 paths of 300 s.
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


def argv(command: str) -> list[str]:
    words = shlex.split(command)
    if words[0] == "ftc-verify":
        return [sys.executable, "-m", "ftc_verify", *words[1:]]
    if words[0] == "python":
        return [sys.executable, *words[1:]]
    raise AssertionError(f"a tutorial command that the test cannot run: {command!r}")


def run_tutorial(page: Path, tmp_path: Path) -> tuple[Path, dict[str, subprocess.CompletedProcess[str]]]:
    """Run every command of ``page`` (module docstring) in a copy of ``examples/`` under
    ``tmp_path``; the copy's root and each command's result, by the command as shown."""
    work = tmp_path / "work"
    shutil.copytree(ROOT / "examples", work / "examples", ignore=shutil.ignore_patterns("*.fmu", "__pycache__"))
    env = os.environ | {"FTC_VERIFY_CACHE": str(tmp_path / "cache")}
    results = {}
    for step in tutorial_steps(page.read_text(encoding="utf-8")):
        command = step.line
        for full, short in REDUCED.get(page.name, []):
            command = command.replace(full, short)
        out = subprocess.run(argv(command), cwd=work / step.folder, capture_output=True, text=True, env=env,
                             timeout=900, check=False)
        assert out.returncode == step.expected_exit, (page.name, command, out.stdout, out.stderr)
        assert "Traceback" not in out.stderr, (page.name, command, out.stderr)
        if step.expected_stdout is not None:
            assert same_output(out.stdout, step.expected_stdout), (page.name, command, out.stdout)
        results[step.line] = out
    return work, results
