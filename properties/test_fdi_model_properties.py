r"""Property tests of the analysis core on the FDI models of :mod:`ftc_verify.model.chain`
(Erlang-``k`` detection delays, false alarms, missed detection ``beta_min = 0``), drawn
by :func:`ftc_verify.testing.chains` (issue 32: the strategies had no options for them).

* For fixed rates (a box of one point) Theorem 3.1 is the exact Markov-jump Lyapunov
  test: certified iff the second-moment generator's spectral abscissa is negative
  (loops drawn at least ``MARGIN`` away from the boundary).
* The box verdict is sound: a loop proved stable over the rate box has a negative
  spectral abscissa at every vertex and at drawn interior rate vectors (the abscissa
  is not convex in the rates, so the interior points test the branch and bound); a
  loop proved unstable has a point of the box with a non-negative abscissa.
"""

from __future__ import annotations

import numpy as np
from hypothesis import event, given, settings
from hypothesis import strategies as st

from ftc_verify.analysis.lmi_analysis import mes_lmi
from ftc_verify.analysis.moments.stability import mean_square_stability, spectral_abscissa
from ftc_verify.testing import DrawnLoop, closed_loops, stable_loops, unstable_loops

MARGIN = 0.05
#: The FDI models, each drawn or not; 1 to 3 Erlang phases.
MODELS = {"delay_phases": (1, 3), "false_alarms": None, "missed_detection": None}
EXACT = {"beta_width": 0.0, "false_alarm_width": 0.0}


def small(**options: object) -> dict[str, object]:
    return {"n": (1, 2), "m": 2, "uncertain": False, **options}


@settings(max_examples=12, deadline=None)
@given(drawn=st.one_of(stable_loops(margin=MARGIN, **small(), chains={**MODELS, **EXACT}),
                       unstable_loops(margin=MARGIN, **small(), chains={**MODELS, **EXACT})))
def test_theorem_3_1_iff_spectral_for_fixed_rates(drawn: DrawnLoop) -> None:
    chain = drawn.system.chain
    event(f"phases {chain.delay_phases}, false alarms {chain.has_false_alarms}, "
          f"missed detection {bool(np.any(chain.beta_min[~np.eye(chain.m, dtype=bool)] == 0))}")
    res = mes_lmi(drawn.loop)
    assert res.certified == drawn.mss.stable, (
        f"spectral abscissa {drawn.mss.spectral_abscissa!r} but Theorem 3.1 {res.outcome}: {res.message}")


@settings(max_examples=12, deadline=None)
@given(drawn=closed_loops(**small(), chains=MODELS, gain_scale=st.sampled_from([1.0, 0.5, 0.2])),
       fractions=st.lists(st.floats(0.0, 1.0), min_size=3, max_size=3))
def test_box_verdict_holds_at_vertices_and_inside(drawn: DrawnLoop, fractions: list[float]) -> None:
    chain = drawn.system.chain
    mss = mean_square_stability(drawn.loop)
    event(f"box verdict {'stable' if mss.stable else 'unstable' if mss.unstable else 'undecided'}")
    lo, hi = chain.rate_min, chain.rate_max
    points = list(chain.vertices()) + [lo + f * (hi - lo) for f in fractions]
    abscissae = [spectral_abscissa(drawn.loop, p) for p in points]
    if mss.stable:
        assert max(abscissae) < 1e-9 * (1 + max(abs(a) for a in abscissae)), (mss.reason, abscissae)
    if mss.unstable:
        assert mss.witness is not None
