"""The cross-check children's answers against this process's (``test_prestart_h37a.py``,
``test_prestart_h37p.py``): a child prints its per-mode checks as JSON lists, and they
must equal :func:`ftc_verify.analysis.crossval.cross_validate` here, bit for bit."""

from __future__ import annotations

import math
from typing import Any

import numpy as np


def assert_checks_equal(theirs: list[Any], system_file: str, gains_file: str) -> None:
    """``theirs``: one ``[true mode, FDI mode, pole real parts, pole imaginary parts, L-inf
    norm, python-control's pole real and imaginary parts, its L-inf norm, agree]`` per joint
    mode, for the loop of ``system_file`` and ``gains_file``; every number equal to this
    process's, python-control's norm finite, every mode in agreement."""
    from ftc_verify.analysis.closedloop import closed_loop
    from ftc_verify.analysis.crossval import cross_validate
    from ftc_verify.cli.common import load

    ours = cross_validate(closed_loop(*load(system_file, gains_file)))
    assert len(theirs) == len(ours) > 0
    for row, m in zip(theirs, ours, strict=True):
        true_mode, fdi_mode, re, im, linf, cre, cim, clinf, agree = row
        assert (true_mode, fdi_mode) == (m.true_mode, m.fdi_mode) and agree and m.agree
        np.testing.assert_array_equal(np.array(re) + 1j * np.array(im), m.poles)
        np.testing.assert_array_equal(np.array(cre) + 1j * np.array(cim), m.control_poles)
        assert linf == m.linf_norm and math.isfinite(clinf) and clinf == m.control_linf_norm
