"""The cross-check child imports python-control without ``scipy.signal``, ``scipy.stats``,
matplotlib, ``control.grid`` (and the rest of CROSS_CHECK_DEFERRED) until something of
them is used (ftc_verify.prestart.defer_modules, issue 37 item 3): the stand-in's semantics (a listed ``from`` import does not load the
package, anything else does and is the real package, submodule imports work, a deferred
package's deferred submodule is imported for real with it) and the cross-check's numbers,
those of a normal import.

Each case runs in a fresh interpreter: the stand-in changes ``sys.modules``."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path


from ftc_verify import prestart
from cross_check_compare import assert_checks_equal

ROOT = Path(__file__).resolve().parents[1]


def _run(code: str, *args: str) -> dict:
    done = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, check=True,
                          timeout=120)
    return json.loads(done.stdout.strip().splitlines()[-1])


_SEMANTICS = """
import json, sys
from ftc_verify.prestart import DeferredModule, defer_modules
defer_modules({"scipy.stats": ("scoreatpercentile",)})
out = {}
from scipy.stats import scoreatpercentile
out["after_from_import"] = type(sys.modules["scipy.stats"]).__name__
out["value"] = float(scoreatpercentile([1.0, 2.0, 3.0, 4.0], 50))
out["after_call"] = type(sys.modules["scipy.stats"]).__name__
import scipy.stats
out["same_module"] = scipy.stats is sys.modules["scipy.stats"]
out["norm"] = float(scipy.stats.norm.cdf(1.0))
print(json.dumps(out))
"""

_OTHER_NAME = """
import json, sys
from ftc_verify.prestart import defer_modules
defer_modules({"scipy.stats": ("scoreatpercentile",)})
from scipy.stats import norm
print(json.dumps({"kind": type(sys.modules["scipy.stats"]).__name__, "norm": float(norm.cdf(1.0))}))
"""

_SUBMODULE = """
import json, sys
from ftc_verify.prestart import defer_modules
defer_modules({"scipy.stats": ("scoreatpercentile",)})
import scipy.stats.qmc as qmc
import scipy.stats
print(json.dumps({"kind": type(sys.modules["scipy.stats"]).__name__, "same": scipy.stats.qmc is qmc,
                  "engine": type(qmc.Sobol(2, seed=1)).__name__}))
"""


def test_a_listed_from_import_defers_the_package_and_its_call_is_the_real_function() -> None:
    import scipy.stats

    out = _run(_SEMANTICS)
    assert out["after_from_import"] == "DeferredModule"  # ``from ... import`` alone loaded nothing
    assert out["value"] == float(scipy.stats.scoreatpercentile([1.0, 2.0, 3.0, 4.0], 50))
    assert out["after_call"] == "module"  # the call imported the real package
    assert out["same_module"] and out["norm"] == float(scipy.stats.norm.cdf(1.0))


_CLASS = """
import json, sys
from ftc_verify.prestart import CROSS_CHECK_DEFERRED, defer_modules
defer_modules(CROSS_CHECK_DEFERRED)
from scipy.signal import StateSpace
before = type(sys.modules["scipy.signal"]).__name__
made = StateSpace([[-1.0]], [[1.0]], [[2.0]], [[0.0]])
import scipy.signal
print(json.dumps({"before": before, "real": isinstance(made, scipy.signal.StateSpace),
                  "after": type(sys.modules["scipy.signal"]).__name__, "C": made.C.tolist()}))
"""


def test_a_listed_class_called_through_the_stand_in_makes_the_real_class() -> None:
    assert _run(_CLASS) == {"before": "DeferredModule", "real": True, "after": "module", "C": [[2.0]]}


def test_any_other_name_or_a_submodule_imports_the_real_package() -> None:
    import scipy.stats

    other = _run(_OTHER_NAME)
    assert other == {"kind": "module", "norm": float(scipy.stats.norm.cdf(1.0))}
    sub = _run(_SUBMODULE)
    assert sub == {"kind": "module", "same": True, "engine": "Sobol"}


_MATPLOTLIB = """
import json, sys
from ftc_verify.prestart import CROSS_CHECK_DEFERRED, DeferredModule, defer_modules
defer_modules(CROSS_CHECK_DEFERRED)
import matplotlib as mpl
import matplotlib.pyplot as plt
before = [type(sys.modules[k]).__name__ for k in ("matplotlib", "matplotlib.pyplot")]
mpl.use("Agg")
fig = plt.figure()
fig.gca().plot([0.0, 1.0], [1.0, 2.0])
from matplotlib.transforms import Affine2D
print(json.dumps({"before": before, "after": type(sys.modules["matplotlib.pyplot"]).__name__,
                  "same": plt.figure is sys.modules["matplotlib.pyplot"].figure,
                  "lines": len(fig.gca().lines), "scale": Affine2D().scale(2.0).get_matrix()[0][0]}))
"""


def test_a_deferred_package_and_its_deferred_submodules_work_when_used() -> None:
    """``import matplotlib.pyplot as plt`` gives the stand-in; using it imports the real
    package and submodules (nothing half-imported)."""
    out = _run(_MATPLOTLIB)
    assert out["before"] == ["DeferredModule", "DeferredModule"]
    assert out == {"before": out["before"], "after": "module", "same": True, "lines": 1, "scale": 2.0}


def test_defer_modules_leaves_an_imported_package_alone() -> None:
    import scipy.stats

    before = sys.modules["scipy.stats"]
    prestart.defer_modules({"scipy.stats": ("scoreatpercentile",)})
    assert sys.modules["scipy.stats"] is before is scipy.stats
    assert {"defer_modules", "DeferredModule", "CROSS_CHECK_DEFERRED"} <= set(prestart.__all__)


_CHILD = """
import json, sys
import numpy, scipy.linalg
import ftc_verify.analysis.analyze
from ftc_verify.prestart import cross_check
from ftc_verify.analysis.closedloop import closed_loop
from ftc_verify.analysis.crossval import cross_validate
from ftc_verify.cli.common import load
system, gains = load(sys.argv[1], sys.argv[2])
check = cross_check()
check.submit(cross_validate, closed_loop(system, gains))
checks = check.result()
check.cancel()
print(json.dumps({
    "child_answered": "import" in check.seconds,  # computed in the child, not here after it failed
    "stats_here": "scipy.stats" in sys.modules,
    "checks": [[m.true_mode, m.fdi_mode, m.poles.real.tolist(), m.poles.imag.tolist(), m.linf_norm,
                m.control_poles.real.tolist(), m.control_poles.imag.tolist(), m.control_linf_norm, m.agree]
               for m in checks],
}))
"""

_STAND_IN = """
import json, sys
import numpy, scipy.linalg
import ftc_verify.analysis.analyze
from ftc_verify.prestart import CROSS_CHECK_DEFERRED, CROSS_CHECK_MODULES, _cross_check_prepare
import importlib
_cross_check_prepare()
for name in CROSS_CHECK_MODULES:
    importlib.import_module(name)
from ftc_verify.analysis.closedloop import closed_loop
from ftc_verify.analysis.crossval import cross_validate
from ftc_verify.cli.common import load
cross_validate(closed_loop(*load(sys.argv[1], sys.argv[2])))
PREFIXES = ("matplotlib", "mpl_toolkits", "scipy.stats", "scipy.signal", "scipy.interpolate", "scipy.integrate")
print(json.dumps({"kinds": sorted({type(sys.modules[k]).__name__ for k in CROSS_CHECK_DEFERRED}),
                  "real": sorted(k for k, v in sys.modules.items() if k.startswith(PREFIXES)
                                 and type(v).__name__ != "DeferredModule")}))
"""


def test_the_cross_check_child_gives_the_numbers_of_a_normal_import() -> None:
    """The child (python-control imported with the stand-in) against this process."""
    paper, gains_file = str(ROOT / "examples" / "paper.toml"), str(ROOT / "examples" / "paper_gains.toml")
    # python-control's import and the check itself left every deferred package unimported
    assert _run(_STAND_IN, paper, gains_file) == {"kinds": ["DeferredModule"], "real": []}
    child = _run(_CHILD, paper, gains_file)
    assert child["child_answered"] and not child["stats_here"]  # the parent never imported it either
    assert len(child["checks"]) == 4
    assert_checks_equal(child["checks"], paper, gains_file)


_FAILS_ON_A_STAND_IN = """
import json
from ftc_verify.prestart import cross_check
def job(_):
    import scipy.signal
    return isinstance(1, scipy.signal.StateSpace)  # a listed class used as a class
check = cross_check()
check.submit(job, None)
value = check.result()
check.cancel()
print(json.dumps({"value": value, "computed_here": "import" not in check.seconds}))
"""


def test_a_job_that_fails_on_a_stand_in_is_run_again_with_the_real_modules() -> None:
    """A job that trips over a stand-in in the cross-check child (there ``isinstance`` with
    the listed ``scipy.signal.StateSpace`` raises TypeError: it is a deferred function
    until the package loads) is not raised in the parent: the child answers "error" and
    the parent computes it with the real modules (``isinstance`` is False there)."""
    assert _run(_FAILS_ON_A_STAND_IN) == {"value": False, "computed_here": True}
