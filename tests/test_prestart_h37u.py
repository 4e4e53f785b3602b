"""numpy's test helpers and Fortran wrapper generator imported only when used
(ftc_verify.prestart.defer_numpy_tools, analyze's start-up, issue 37 item 3)."""

from __future__ import annotations

import subprocess
import sys

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
    out = subprocess.run([sys.executable, "-c", CHILD], capture_output=True, text=True, check=True).stdout.split("\n")
    assert out[0] == "deferred True"  # scipy.linalg and the analysis imported: neither was loaded
    assert out[1] == "testing real module True"  # a from-import of a name: the real package, bound in numpy
    assert out[2] == "submodule numpy.testing.overrides"
    assert out[3] == "f2py True module"


def test_already_imported_tools_are_left_alone() -> None:
    import numpy.testing

    from ftc_verify.prestart import DeferredModule

    code = ("import sys, numpy.testing; from ftc_verify.prestart import defer_numpy_tools; defer_numpy_tools(); "
            "print(type(sys.modules['numpy.testing']).__name__, numpy.testing.assert_allclose.__module__)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert out == ["module", "numpy.testing._private.utils"]
    assert not isinstance(numpy.testing, DeferredModule)
