"""The tutorials of ``docs/tutorials``: their commands read from the pages and run.

Every command in a ```sh block is run, in order, from a temporary copy of ``examples/``
(so the files the commands write stay there): lines ``ftc-verify ...`` by the CLI's
``main`` in the test process with the folder, environment and streams the shell would
give them (``tests/cli_inprocess.py``), lines ``python ...`` with this interpreter in a
subprocess, ``cd DIR``
changes the folder of the next lines, a trailing ``\\`` joins lines. A command exits 0
unless its line ends with ``# exit N``; nothing prints a traceback. Where a page shows a
command's output (a plain fenced block starting with ``ftc-verify COMMAND:`` right after
a ```sh block), the command prints that text up to the last digits of its numbers
(:func:`same_output`). Long commands run shortened (:data:`REDUCED`).

Commands that two pages share run once per test session: where pages start with the same
commands in the same folders (the three-tank pages: build-fmu, linearize --trim,
synthesize), the first test to reach them runs them and keeps the folder and the
results in a folder every pytest-xdist worker sees (``shared``, under a lock); the
other restores them and checks the same exit codes, tracebacks and shown outputs on
those results before running its own commands. A long page is run in parts
(:data:`PARTS`), by as many tests, which the two xdist workers share: each part restores
the page's first commands the same way and runs its own commands; every command runs
once per session.

Used by ``tests/test_docs.py`` (every page) and ``tests/test_three_tank.py`` (the
three-tank page, with its own checks of the report).
"""

from __future__ import annotations

import fcntl
import hashlib
import json
import os
import re
import shlex
import shutil
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import cli_inprocess

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
TUTORIALS = sorted(p for p in (DOCS / "tutorials").glob("*.md") if p.name != "index.md")

#: Per tutorial page: (what the page shows, what the test runs). The three-tank Monte
#: Carlo runs 10 paths of 300 s, the output-feedback page's `verify` 20 paths instead of
#: 200 (7 s of CPU less). alpha = 1e-6 bounds a false *pass* (the one-sided bound below the
#: true mean) for any number of paths; fewer paths widen the bound, so a false failure gets
#: likelier. The runs are deterministic (fixed seeds), and their margins are wide: the
#: output-feedback page's 20 paths give the bound 0.118 against gamma^2 = 0.182.
REDUCED = {
    "three-tank.md": [("--paths 200 --horizon 600", "--paths 10 --horizon 300")],
    "output-feedback.md": [("Kof.toml --seed 1 --out report-of", "Kof.toml --paths 20 --seed 1 --out report-of")],
}

#: Pages run in parts by several tests (so that the pytest-xdist workers share a long page):
#: per page, per part, (how many leading commands are restored from the session's run of
#: them, the commands the part runs itself). The parts of a page restore the same
#: commands and run the others once (``tests/test_docs.py`` checks it).
PARTS = {
    "three-tank.md": {"state-feedback": (3, range(3, 4)), "output-feedback": (3, range(4, 6))},
    "three-tank-risk.md": {"designed": (5, range(5, 6)), "nominal": (5, range(6, 7)), "region": (5, range(7, 8))},
    "paper-example.md": {"design": (0, range(3)), "verify": (0, range(3, 6))},
    "output-feedback.md": {"design": (0, range(3)), "observer": (0, range(3, 4))},
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


def _commands(page: Path) -> list[tuple[str, str, int]]:
    """(folder, command as run, expected exit) of each step of ``page``, reductions applied."""
    out = []
    for step in tutorial_steps(page.read_text(encoding="utf-8")):
        command = step.line
        for full, short in REDUCED.get(page.name, []):
            command = command.replace(full, short)
        out.append((step.folder, command, step.expected_exit))
    return out


def shared_prefix(page: Path) -> int:
    """How many leading commands of ``page`` another tutorial page starts with too."""
    mine, best = _commands(page), 0
    for other in TUTORIALS:
        if other != page:
            theirs = _commands(other)
            k = 0
            while k < min(len(mine), len(theirs)) and mine[k] == theirs[k]:
                k += 1
            best = max(best, k)
    return best


@contextmanager
def _locked(path: Path) -> Iterator[None]:
    """An exclusive lock on ``path`` (created), held by one test process at a time."""
    with open(path, "a") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def _check(page: Path, step: Step, command: str, out: subprocess.CompletedProcess[str]) -> None:
    assert out.returncode == step.expected_exit, (page.name, command, out.stdout, out.stderr)
    assert "Traceback" not in out.stderr, (page.name, command, out.stderr)
    if step.expected_stdout is not None:
        assert same_output(out.stdout, step.expected_stdout), (page.name, command, out.stdout)


def run_command(command: str, cwd: Path, env: dict[str, str]) -> subprocess.CompletedProcess[str]:
    """One command of a page: ``ftc-verify ...`` in this process (``tests/cli_inprocess.py``:
    the folder, environment and streams, the file descriptors included, that the command
    typed in a shell has; a fresh interpreter per command cost 0.4-1.4 s of CPU, mostly
    imports), ``python ...`` as a subprocess."""
    words = shlex.split(command)
    if words[0] == "ftc-verify":
        return cli_inprocess.run_cli(words[1:], cwd, env)
    return subprocess.run(argv(command), cwd=cwd, capture_output=True, text=True, env=env, timeout=900, check=False)


def _run_steps(page: Path, steps: list[tuple[Step, str]], work: Path, env: dict[str, str],
               results: dict[str, subprocess.CompletedProcess[str]]) -> None:
    for step, command in steps:
        out = run_command(command, work / step.folder, env)
        _check(page, step, command, out)
        results[step.line] = out


def _restore(page: Path, steps: list[tuple[Step, str]], k: int, work: Path, env: dict[str, str], shared: Path,
             results: dict[str, subprocess.CompletedProcess[str]]) -> None:
    """``work`` as the first ``k`` commands of ``page`` leave it, with their results: run
    once per session (the first test to need them, under a lock, from the snapshot of the
    commands the page shares with another page when that is shorter) and kept in ``shared``;
    restored and checked again by every other test."""
    key = hashlib.sha256(json.dumps(_commands(page)[:k]).encode()).hexdigest()[:16]
    snapshot = shared / f"tutorial-{key}"
    with _locked(shared / f"tutorial-{key}.lock"):
        if not (snapshot / "results.json").is_file():
            base = shared_prefix(page)
            if 0 < base < k:
                _restore(page, steps, base, work, env, shared, results)
            else:
                base = 0
                shutil.copytree(ROOT / "examples", work / "examples",
                                ignore=shutil.ignore_patterns("*.fmu", "__pycache__"))
            _run_steps(page, steps[base:k], work, env, results)
            shutil.copytree(work, snapshot / "work")
            rows = [[step.line, *_row(results[step.line])] for step, _ in steps[:k]]
            (snapshot / "results.json").write_text(json.dumps(rows), encoding="utf-8")
        else:
            shutil.copytree(snapshot / "work", work, dirs_exist_ok=True)
            for line, code, stdout, stderr in json.loads((snapshot / "results.json").read_text(encoding="utf-8")):
                results[line] = subprocess.CompletedProcess(argv(line), code, stdout, stderr)
            for step, command in steps[:k]:
                _check(page, step, command, results[step.line])


def _row(out: subprocess.CompletedProcess[str]) -> list[object]:
    return [out.returncode, out.stdout, out.stderr]


def run_tutorial(page: Path, tmp_path: Path, shared: Path | None = None, *, after: int | None = None,
                 run: range | None = None) -> tuple[Path, dict[str, subprocess.CompletedProcess[str]]]:
    """Run every command of ``page`` (module docstring) in a copy of ``examples/`` under
    ``tmp_path``; the copy's root and each command's result, by the command as shown.

    With ``shared`` (a folder all test processes of the session see), the first ``after``
    commands (by default those the page shares with another page, :func:`shared_prefix`)
    run once in the session and are restored from there (module docstring), and the test
    runs the commands ``run`` (default: all the others). A page split into parts this way
    (``tests/test_docs.py``'s ``PARTS``) runs each of its commands once per session.
    """
    work = tmp_path / "work"
    env = os.environ | {"FTC_VERIFY_CACHE": str(tmp_path / "cache")}
    steps = list(zip(tutorial_steps(page.read_text(encoding="utf-8")), (c for _, c, _ in _commands(page)),
                     strict=True))
    results: dict[str, subprocess.CompletedProcess[str]] = {}
    k = (shared_prefix(page) if after is None else after) if shared is not None else 0
    if k:
        assert shared is not None
        _restore(page, steps, k, work, env, shared, results)
    else:
        shutil.copytree(ROOT / "examples", work / "examples", ignore=shutil.ignore_patterns("*.fmu", "__pycache__"))
    todo = range(k, len(steps)) if run is None else run
    assert todo.start >= k and todo.stop <= len(steps), (page.name, k, todo)
    _run_steps(page, steps[todo.start:todo.stop], work, env, results)
    return work, results
