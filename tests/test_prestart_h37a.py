"""python-control imported without scipy's and matplotlib's generated docstrings
(ftc_verify.prestart.skip_docstring_generation, the cross-check child's import, issue 37):
the switch takes effect, and the cross-check's numbers are those of a normal import."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from cross_check_compare import assert_checks_equal

ROOT = Path(__file__).resolve().parents[1]

_CHILD = """
import json, sys
from ftc_verify.prestart import skip_docstring_generation
skip_docstring_generation()
import control, matplotlib.lines, scipy.signal
from ftc_verify.analysis.closedloop import closed_loop
from ftc_verify.analysis.crossval import cross_validate
from ftc_verify.cli.common import load
system, gains = load(sys.argv[1], sys.argv[2])
checks = cross_validate(closed_loop(system, gains))
print(json.dumps({
    "set_doc": matplotlib.lines.Line2D.set.__doc__ or "",
    "lfilter_doc": scipy.signal.lfilter.__doc__ or "",
    "checks": [[m.true_mode, m.fdi_mode, m.poles.real.tolist(), m.poles.imag.tolist(), m.linf_norm,
                m.control_poles.real.tolist(), m.control_poles.imag.tolist(), m.control_linf_norm, m.agree]
               for m in checks],
}))
"""


def test_the_cross_check_without_generated_docstrings_gives_the_same_numbers() -> None:
    """A fresh interpreter (nothing imported before the switch) against this process."""
    import matplotlib.lines
    import scipy.signal

    paper, gains_file = str(ROOT / "examples" / "paper.toml"), str(ROOT / "examples" / "paper_gains.toml")
    done = subprocess.run([sys.executable, "-c", _CHILD, paper, gains_file], capture_output=True, text=True,
                          check=True, timeout=120)
    child = json.loads(done.stdout)
    # the switch took effect there (an empty property table), not here
    assert "Properties:" not in child["set_doc"]
    assert "Properties:" in (matplotlib.lines.Line2D.set.__doc__ or "")
    assert "Parameters" not in child["lfilter_doc"] and "Parameters" in (scipy.signal.lfilter.__doc__ or "")
    assert len(child["checks"]) == 4
    assert_checks_equal(child["checks"], paper, gains_file)


def test_a_missing_private_name_is_left_alone(monkeypatch: pytest.MonkeyPatch) -> None:
    """Another scipy/matplotlib version without the patched names: no error, nothing set
    (in this process; monkeypatch puts the real names back)."""
    import matplotlib.artist as artist
    import scipy._lib._array_api as array_api
    import scipy._lib._docscrape as docscrape

    from ftc_verify import prestart

    monkeypatch.delattr(docscrape.NumpyDocString, "_parse")
    monkeypatch.delattr(array_api, "FunctionDoc")
    monkeypatch.delattr(artist, "kwdoc")
    prestart.skip_docstring_generation()
    assert not hasattr(docscrape.NumpyDocString, "_parse")
    assert not hasattr(array_api, "FunctionDoc") and not hasattr(artist, "kwdoc")
    assert "skip_docstring_generation" in prestart.__all__
