"""The README's test command is CI's, and the documentation's code blocks that claim to be
files are those files, verbatim."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def python_blocks(text: str) -> list[str]:
    """The bodies of a markdown page's ```python fenced blocks."""
    return re.findall(r"```python\n(.*?)```", text, flags=re.S)


def test_user_property_example_is_shown_verbatim() -> None:
    page = (ROOT / "docs" / "user-guide" / "property-testing.md").read_text(encoding="utf-8")
    example = (ROOT / "examples" / "user_property_test.py").read_text(encoding="utf-8")
    assert "examples/user_property_test.py" in page
    assert example in python_blocks(page), "the docs' block differs from examples/user_property_test.py"


def test_readme_test_command_is_the_ci_command() -> None:
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    command = "python -m pytest -n 2 --hypothesis-profile=ci -p no:cacheprovider"
    assert command in readme and command in ci
    assert 'pip install -e ".[test]"' in readme and 'pip install -e ".[test]"' in ci
