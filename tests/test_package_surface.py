"""``import ftc_verify`` gives the names most programs need, without importing the stages."""

from __future__ import annotations

import subprocess
import sys

import pytest

import ftc_verify


def test_every_exported_name_resolves_to_its_stage_object() -> None:
    from ftc_verify.analysis import analyze
    from ftc_verify.model import FTCSystem

    for name in ftc_verify.__all__:
        assert getattr(ftc_verify, name) is not None, name
    assert ftc_verify.analyze is analyze and ftc_verify.FTCSystem is FTCSystem
    assert set(ftc_verify.__all__) <= set(dir(ftc_verify))


def test_an_unknown_name_is_an_attribute_error() -> None:
    with pytest.raises(AttributeError, match="no_such_name"):
        ftc_verify.no_such_name  # noqa: B018


def test_import_loads_no_stage() -> None:
    code = "import sys, ftc_verify; print(sorted(m for m in sys.modules if m.startswith(('ftc_verify.', 'numpy'))))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True)
    assert out.stdout.strip() == "[]"


def test_every_subpackage_is_installed_by_pip_install_dot() -> None:
    """``pip install .`` (the README's main job) installs the packages ``pyproject.toml``
    lists, not the tree: each package under ``ftc_verify/`` must be listed (the sampled-loop
    stages in ``analysis.moments`` and ``risk`` were missing, found by a fresh install)."""
    import tomllib
    from pathlib import Path

    root = Path(ftc_verify.__file__).resolve().parent
    listed = set(tomllib.loads((root.parent / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = {".".join(p.parent.relative_to(root.parent).parts) for p in root.rglob("__init__.py")}
    assert found - listed == set()
