"""The second-order form of a sub-box's one-period map, for the tests of the sampled
sub-box proofs (``test_bracket_h31x.py``, ``test_second_order_h31w.py``):
:func:`~ftc_verify.analysis.moments.quad_balls.quad_map` on the float parts of
:class:`~ftc_verify.analysis.moments.sampled_proof.MapParts` at 64 bits."""

from __future__ import annotations

import numpy as np

from ftc_verify.analysis.moments.quad_balls import quad_map
from ftc_verify.analysis.moments.sampled import SampledLoop
from ftc_verify.analysis.moments.sampled_proof import MapParts
from ftc_verify.analysis.moments.sampled_taylor import _rates_affine
from ftc_verify.analysis.rigorous import precision


def second_order_form(loop: SampledLoop, h: float, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, ...]:
    """``T(delta)`` on ``[lo, hi]`` at period ``h`` as ``(T_c, T_a, T_ab, radius)``."""
    with precision(64):
        res, modes, lift, hb = MapParts.build(loop, h).floats
        found = _rates_affine(loop, lo, hi)
        assert found is not None
        out = quad_map(res, modes, found[0], found[1], hb, lift)
    assert out is not None
    return out
