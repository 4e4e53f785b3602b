"""The order and budget of the stability proofs below the float64 crossing of ``h_max``."""

from __future__ import annotations

import math
from pathlib import Path

from ftc_verify.analysis.moments.sampled import SampledLoop
from ftc_verify.analysis.moments.sampled_bracket import TIGHT, prove_below
from ftc_verify.analysis.moments.sampled_proof import box_verdict
from ftc_verify.controllers.files import load_controller
from ftc_verify.model.files import load_system

ROOT = Path(__file__).resolve().parents[1]


def _paper() -> SampledLoop:
    return SampledLoop.build(load_system(ROOT / "examples" / "paper.toml"),
                             load_controller(ROOT / "examples" / "paper_gains.toml"))


def test_tight_proof_first() -> None:
    """On the paper's loop (float64 crossing near 0.08424) the tight attempt succeeds:
    the period is within ``rtol / 4`` of the crossing and is proved stable."""
    loop = _paper()
    a, rtol = 0.0842, 1e-3
    h = prove_below(loop, a, rtol, 16, 10.0, math.inf)
    assert h is not None and math.isclose(h, a * (1 - TIGHT[0][0] * rtol)) and TIGHT[0][0] == 0.25
    assert box_verdict(loop, h, max_boxes=16, max_seconds=10.0).verdict == "stable"


def test_no_budget_no_claim() -> None:
    """Without budget (or after the deadline) nothing is proved."""
    loop = _paper()
    assert prove_below(loop, 0.0842, 1e-3, 0, 10.0, math.inf) is None
    assert prove_below(loop, 0.0842, 1e-3, 16, 10.0, -1.0) is None


def test_easy_first_above_the_crossing() -> None:
    """Above the crossing (a = 0.2, unstable there and down to ~0.0843) the tight and
    1 % attempts fail and the 10 % one is not proved either (0.18 is unstable)."""
    loop = _paper()
    assert prove_below(loop, 0.2, 1e-3, 4, 2.0, math.inf) is None
