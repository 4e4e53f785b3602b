"""The ``h_max`` cover's map proofs with third-order forms in other units
(:mod:`ftc_verify.analysis.moments.sampled_cover`, :mod:`ftc_verify.analysis.moments.cubic_balls`).

The random ``n = 2, m = 2`` loop of ``tests/test_cover_reach_r16.py`` (two free rates, where
the cover pays for third-order forms) moved to other units (``tests/moved_loops.py``:
states :math:`x' = S x`, inputs :math:`u = a u'`, time :math:`t \\to s t`). A state
similarity and an input scaling leave the one-period spectrum unchanged and the time
scaling maps period ``h`` to ``h / s``, so the moved loop's crossing is ``h_u / s``
exactly. Asserted per frame, as in good units: 1 % below it the cover by map proofs
alone is exactly the box, third-order forms among its proofs and about as many
sub-boxes as in good units; 1 % above it no cover is claimed."""

from __future__ import annotations

import numpy as np
import pytest

from moved_loops import Units, moved

from ftc_verify.analysis.moments import cubic_balls
from ftc_verify.analysis.moments.sampled import SampledLoop, crossing
from ftc_verify.analysis.moments.sampled_conditioned import conditioned
from ftc_verify.analysis.moments.sampled_cover import cover_box
from ftc_verify.controllers.controller import Controller
from ftc_verify.model.system import FTCSystem
from ftc_verify.testing.illconditioned import similarity
from ftc_verify.testing.sampled_cases import lqr_case

from test_cover_mixed_h31t import _assert_exact_cover, _box
from test_cover_reach_r16 import _Count

SPLIT = np.diag([1e-6, 1e6])

FRAMES = [
    Units("good units"),
    Units("states 1e-6 and 1e6, time 1e3", S=SPLIT, s=1e3),
    Units("states 1e-6 and 1e6, time 1e-3, inputs 1e6", S=SPLIT, s=1e-3, a=1e6),
    Units("similarity of condition 1e4 in units of condition 1e8", S=similarity(np.random.default_rng(31), 2, 1e8, 1e4)),
]


def _case() -> tuple[FTCSystem, Controller]:
    return lqr_case(2, 2, np.random.default_rng(11))


@pytest.fixture(scope="module")
def h_u() -> float:
    """The crossing in good units (float64 bisection of the worst rate point, 1e-10)."""
    return crossing(SampledLoop.build(*_case()), 1e-3, 10.0, True, 1e-10)


@pytest.fixture(scope="module")
def good_leaves(h_u: float) -> int:
    loop = conditioned(SampledLoop.build(*_case()))
    leaves = cover_box(loop, h_u * (1 - 1e-2), None, _box(loop), 1e12)[0]
    assert leaves is not None
    return len(leaves)


@pytest.mark.parametrize("u", FRAMES, ids=[u.name for u in FRAMES])
def test_cover_with_third_order_forms_in_every_frame(monkeypatch: pytest.MonkeyPatch, h_u: float, good_leaves: int,
                                                     u: Units) -> None:
    cubic = _Count(cubic_balls.cubic_map)
    monkeypatch.setattr(cubic_balls, "cubic_map", cubic)
    loop = conditioned(SampledLoop.build(*moved(*_case(), u)))
    leaves, _, attempts, _ = cover_box(loop, h_u * (1 - 1e-2) / u.s, None, _box(loop), 1e12)
    assert leaves is not None and attempts == 0, u.name
    _assert_exact_cover(loop, leaves)
    assert cubic.calls > 0, u.name
    assert good_leaves / 2 <= len(leaves) <= 2 * good_leaves, (u.name, len(leaves), good_leaves)
    above = cover_box(loop, h_u * (1 + 1e-2) / u.s, None, _box(loop), 1e12)[0]
    assert above is None, u.name
