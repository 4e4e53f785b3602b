"""numpy's test helpers and Fortran wrapper generator imported only when used
(ftc_verify.prestart.defer_numpy_tools, analyze's start-up, issue 37 item 3)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

CHILD = r"""
import sys
from ftc_verify.prestart import DeferredModule, defer_numpy_tools
defer_numpy_tools()
import numpy
import scipy.linalg, scipy.sparse.linalg
import ftc_verify.analysis.analyze
print("deferred", all(isinstance(sys.modules[f"numpy.{n}"], DeferredModule) for n in ("f2py", "testing")))
from numpy.testing import assert_allclose
assert_allclose(scipy.linalg.solve(numpy.eye(2), numpy.ones(2)), numpy.ones(2))
print("testing real", type(sys.modules["numpy.testing"]).__name__, numpy.testing is sys.modules["numpy.testing"])
import numpy.testing.overrides
print("submodule", numpy.testing.overrides.__name__)
print("f2py", callable(numpy.f2py.get_include), type(sys.modules["numpy.f2py"]).__name__)
"""


def test_numpy_tools_are_stand_ins_until_used_then_real() -> None:
    out = subprocess.run([sys.executable, "-c", CHILD], capture_output=True, text=True, check=True,
                         timeout=120).stdout.split("\n")
    assert out[0] == "deferred True"  # scipy.linalg and the analysis imported: neither was loaded
    assert out[1] == "testing real module True"  # a from-import of a name: the real package, bound in numpy
    assert out[2] == "submodule numpy.testing.overrides"
    assert out[3] == "f2py True module"


def test_already_imported_tools_are_left_alone() -> None:
    code = ("import sys, numpy.testing; from ftc_verify.prestart import defer_numpy_tools; defer_numpy_tools(); "
            "print(type(sys.modules['numpy.testing']).__name__, numpy.testing.assert_allclose.__module__)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         timeout=120).stdout.split()
    assert out == ["module", "numpy.testing._private.utils"]


STATE = r"""
import sys
from ftc_verify import prestart
from ftc_verify.cli import main
def state():
    return [type(sys.modules.get(f"numpy.{n}")).__name__ for n in prestart.NUMPY_TOOLS] + [
        any(isinstance(f, prestart._DeferredFinder) for f in sys.meta_path), prestart._deferring()]
code = main(["analyze", sys.argv[1], "--gains", sys.argv[2], "--no-lmi"])
print(code, *state())
prestart.defer_numpy_tools()
print(*state())
prestart.defer_modules({"colorsys": ("rgb_to_hls",)})
print(*state())
"""


def test_in_process_analyze_leaves_the_interpreter_alone_and_tools_alone_never_rerun(tmp_path: Path) -> None:
    """``main([...])`` from a caller's interpreter installs no stand-in, no finder (only the
    process's own command line does); stand-ins without listed names do not make a failed
    child job run again (``_deferring``), listed ones do."""
    examples = Path(__file__).resolve().parents[1] / "examples"
    out = subprocess.run([sys.executable, "-c", STATE, str(examples / "paper.toml"), str(examples / "paper_gains.toml")],
                         capture_output=True, text=True, check=True, timeout=120, cwd=tmp_path).stdout.splitlines()
    head = out[-3].split()
    assert head[0] == "0" and head[3:] == ["False", "False"]  # exit 0, no finder, no rerun
    assert "DeferredModule" not in head[1:3]
    assert out[-2].split()[2:] == ["True", "False"]  # the finder, and no rerun for the numpy tools
    assert out[-1].split()[2:] == ["True", "True"]  # a listed name: a failed job runs again
