"""The documentation's tutorials are run, and its API reference covers every public module.

* Every command of every tutorial page is run (:mod:`tutorials`: in order, from a copy of
  ``examples/``, exit codes and shown outputs checked, long commands shortened as
  :data:`tutorials.REDUCED` says, which the page must show in full and say); the
  three-tank page by ``tests/test_three_tank.py``, which also checks its report.
* The README's main-job output is the output the paper tutorial checks.
* Every public module has an API page entry, and every entry a module.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from tutorials import (DOCS, PARTS, REDUCED, ROOT, TUTORIALS, argv, fenced_blocks, run_tutorial, same_output,
                       shared_prefix, tutorial_steps)

def test_same_output_tells_digits_from_words() -> None:
    assert same_output("gamma 0.360844, 2.07e-14 on 5 paths", "gamma 0.360846, 2.04e-14 on 5 paths")
    assert not same_output("gamma 0.3612", "gamma 0.3608")
    assert not same_output("verdict: pass", "verdict: fail")
    assert not same_output("a\n  FDI: exponential\nb", "a\nb")


def test_every_tutorial_has_commands_and_no_unknown_ones() -> None:
    assert {p.name for p in TUTORIALS} >= {"paper-example.md", "dc-motor.md", "three-tank.md", "output-feedback.md"}
    for page in TUTORIALS:
        steps = tutorial_steps(page.read_text(encoding="utf-8"))
        assert steps, f"{page.name} shows no command"
        for step in steps:
            argv(step.line)


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


def test_the_three_tank_pages_share_their_first_three_commands() -> None:
    """build-fmu, linearize --trim and synthesize run once for both pages (tutorials.py);
    pages whose commands differ share nothing."""
    pages = {p.name: p for p in TUTORIALS}
    assert shared_prefix(pages["three-tank.md"]) == shared_prefix(pages["three-tank-risk.md"]) == 3
    assert shared_prefix(pages["paper-example.md"]) == shared_prefix(pages["dc-motor.md"]) == 0


def test_every_command_of_a_page_in_parts_runs_once() -> None:
    """The parts of a page (tutorials.PARTS) restore the same leading commands (run once, by
    the first part to need them), at least those it shares with another page, and run
    every other command of the page exactly once between them."""
    pages = {p.name: p for p in TUTORIALS}
    for name, parts in PARTS.items():
        after = {k for k, _ in parts.values()}
        runs = sorted(i for _, run in parts.values() for i in run)
        total = len(tutorial_steps(pages[name].read_text(encoding="utf-8")))
        assert len(after) == 1 and after.pop() >= shared_prefix(pages[name]), name
        assert runs == list(range(min(k for k, _ in parts.values()), total)), name


#: Pages whose commands another test runs, with checks of its own.
RUN_ELSEWHERE = {"three-tank.md": "tests/test_three_tank.py::test_tutorial_recipe_*_passes_with_reduced_paths"}


def _page_params() -> list[object]:
    # Seconds measured on 2 busy cores, for the scheduler in conftest.py (longest first).
    seconds = {"paper-example.md": 25, "output-feedback.md": 35, "dc-motor.md": 17, "three-tank-risk.md": 20}
    out = []
    for p in TUTORIALS:
        if p.name in RUN_ELSEWHERE:
            continue
        parts = PARTS.get(p.name, {"": (None, None)})
        for part, (after, run) in parts.items():
            out.append(pytest.param(p, after, run, id=f"{p.stem}-{part}" if part else p.stem,
                                    marks=pytest.mark.slow(seconds.get(p.name, 10))))
    return out


@pytest.mark.parametrize(("page", "after", "run"), _page_params())
def test_tutorial_commands_run(page: Path, after: int | None, run: range | None, tmp_path: Path,
                               shared_tmp: Path) -> None:
    _, results = run_tutorial(page, tmp_path, shared_tmp, after=after, run=run)
    steps = tutorial_steps(page.read_text(encoding="utf-8"))
    assert len(results) == (len(steps) if run is None else run.stop - run.start + after)


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
