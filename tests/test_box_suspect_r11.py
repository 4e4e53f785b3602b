"""A loop unstable at a vertex of a wide rate box is proved not stable there, at once.

The loop of ``tests/data/unstable_vertex_wide_box.toml`` (n = 2, m = 3, false alarms: 12
uncertain rates, 4096 vertices; found by an independent check) has a float64 abscissa of
+0.1147 at the worst vertex of the vertex ascent, while the centres of its sub-boxes are
stable: the branch and bound alone spent its whole budget proving sub-boxes stable and
answered "undecided" (exit 5). The instability proof at the ascent's worst vertex comes
first now (``box_stability(suspect=...)``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ftc_verify.analysis.closedloop import closed_loop
from ftc_verify.analysis.moments.stability import mean_square_stability, spectral_abscissa
from ftc_verify.controllers.files import load_controller
from ftc_verify.model.files import load_system

DATA = Path(__file__).resolve().parent / "data"


def test_unstable_vertex_of_a_wide_box_is_proved_not_stable() -> None:
    """Within a budget of 10 s (the branch and bound alone took 60 s and gave up), the
    verdict is "not stable" with its witness at a vertex of the box whose abscissa
    enclosure is above 0 and contains the float64 value there."""
    loop = closed_loop(load_system(DATA / "unstable_vertex_wide_box.toml"),
                       load_controller(DATA / "unstable_vertex_wide_box_K.toml"))
    result = mean_square_stability(loop, budget_seconds=10.0)
    assert result.verdict == "not stable"
    witness = result.vertex_verdicts[-1]
    chain = loop.chain
    point = witness.rate_min
    assert np.array_equal(point, witness.rate_max)
    assert all(point[r] in (chain.rate_min[r], chain.rate_max[r]) for r in chain.rate_indices)
    assert witness.enclosure is not None and witness.enclosure[0] > 0.0
    mu = spectral_abscissa(loop.nominal(), point)
    assert witness.enclosure[0] - 1e-9 <= mu <= witness.enclosure[1] + 1e-9
    assert result.spectral_abscissa >= mu - 1e-12
