"""Start-up (issue 24): a command imports what it needs when it needs it.

``ftc-verify --help`` (building the whole parser) imports neither numpy, scipy,
python-control nor fmpy: checked on the interpreter's own import log (``-X importtime``),
not by timing. The constants the parser shows are the ones the pipeline uses.
"""

from __future__ import annotations

import subprocess
import sys


def test_help_imports_no_numerical_library() -> None:
    out = subprocess.run([sys.executable, "-X", "importtime", "-m", "ftc_verify", "--help"], capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 0 and "usage: ftc-verify" in out.stdout
    imported = {line.rsplit("|", 1)[-1].strip() for line in out.stderr.splitlines() if line.startswith("import time:")}
    assert "ftc_verify.cli.plant_commands" in imported  # the log is the one of the parser's build
    for heavy in ("numpy", "scipy", "control", "fmpy", "cvxpy", "flint", "matplotlib"):
        assert heavy not in imported, heavy


def test_the_parser_shows_the_pipeline_constants() -> None:
    from ftc_verify.cli.plant_commands import LINEARIZE_ACCURACY, LINEARIZE_ROUTES
    from ftc_verify.plants.linearize import ACCURACY_FRACTION, ROUTES

    assert LINEARIZE_ROUTES == ROUTES and LINEARIZE_ACCURACY == ACCURACY_FRACTION
