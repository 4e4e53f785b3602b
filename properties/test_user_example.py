"""The user example ``examples/user_property_test.py`` (the README's property-testing
section shows it verbatim) runs and passes, on its own.

The example is imported by path, as a user's file would be, and each of its ``test_*``
functions is called (each is a hypothesis property carrying its own ``profile("ci", ...)``
settings). The README text is not read here: while the example runs, opening any file
whose name contains ``readme`` raises, so the example cannot depend on it.
"""

from __future__ import annotations

import builtins
import importlib.util
import inspect
from pathlib import Path
from types import ModuleType
from typing import Any
from collections.abc import Callable

import pytest

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "user_property_test.py"
#: The README calls it a ten-line property test: the test function, not counting imports.
MAX_TEST_LINES = 10


def load_example() -> ModuleType:
    """Import the example file by path under a private module name."""
    spec = importlib.util.spec_from_file_location("_ftc_user_property_test", EXAMPLE)
    assert spec is not None and spec.loader is not None, EXAMPLE
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def example_tests(module: ModuleType) -> list[Callable[[], None]]:
    """The module's ``test_*`` functions, in definition order."""
    return [f for name, f in vars(module).items() if name.startswith("test_") and callable(f)]


@pytest.mark.slow(5)  # seconds measured on 2 busy cores: scheduled first
def test_user_example_runs_without_the_readme(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every property of the example passes; no README file is opened meanwhile."""
    real_open = builtins.open

    def guarded_open(file: Any, *args: Any, **kwargs: Any) -> Any:
        if "readme" in str(file).lower():
            raise AssertionError(f"the user example opened {file!r} at test time")
        return real_open(file, *args, **kwargs)

    monkeypatch.setattr(builtins, "open", guarded_open)
    tests = example_tests(load_example())
    assert tests, f"{EXAMPLE} defines no test_* function"
    for test in tests:
        test()


def test_user_example_is_short() -> None:
    """The example's test functions fit in ten lines (decorators, signature and body)."""
    for test in example_tests(load_example()):
        source = inspect.getsource(test)
        lines = [ln for ln in source.splitlines() if ln.strip()]
        assert len(lines) <= MAX_TEST_LINES, f"{test.__name__}: {len(lines)} lines"
