"""box_stability tries the sub-box LMI before the 256/512-bit ball solves when the centre's
float candidate is positive definite but misses a vertex (issue 37: 20 s -> under 1 s)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from ftc_verify.analysis import box
from ftc_verify.analysis.closedloop import state_feedback_loop
from ftc_verify.analysis.conditioning import conditioning_transform
from ftc_verify.analysis.exact import written_box

ROOT = Path(__file__).resolve().parent.parent


def _random_loop(n: int, m: int, seed: int):
    spec = importlib.util.spec_from_file_location("bench_analysis", ROOT / "benchmarks" / "analysis.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    system, gains, _ = module.make_case(n, m, seed, False)
    return state_feedback_loop(system, gains)


def test_a_wide_box_is_proved_by_its_lmi_without_the_ball_solves(monkeypatch: pytest.MonkeyPatch) -> None:
    loop = _random_loop(8, 3, 3791)  # benchmarks/scaling.py's 8x3 case with --seed 3790
    sim = conditioning_transform(loop.nominal())
    chain = loop.chain
    lo, hi = written_box(chain.rate_min, chain.rate_max)
    uncertain = tuple(r for r in chain.rate_indices if lo[r] != hi[r])
    status, _ = box._Checker.build(loop, sim, uncertain).check(lo, hi)
    assert status == "failed"  # the centre's candidate is positive definite, but misses a vertex

    def refuse(*args: object, **kwargs: object) -> None:
        raise AssertionError("the 256/512-bit ball solves ran before the sub-box LMI")

    monkeypatch.setattr(box._Checker, "check_precise", refuse)
    verdict = box.box_stability(loop, sim)
    assert verdict.verdict == "stable" and verdict.time_varying
    assert verdict.regions[0].method.startswith("P from the Theorem 3.1 LMI")
    assert np.array_equal(verdict.regions[0].rate_min, lo)
