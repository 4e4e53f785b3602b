"""The proved lower bound of the nominal gain on a loop above 120 moment rows.

``tests/data/lower_bound_135_rows.toml`` (n = 5, m = 3 with false alarms: 135 rows; a
held-out loop of an independent check): with the worst-case feedback refined only up to
120 rows, its feedback stayed the one taken at the certified gamma, the bound proved was
1.88 where the float gain at its own rates is 3.16, and ``float_gain`` reported the
certified gamma (3.86) instead of that gain."""

from __future__ import annotations

from pathlib import Path

from ftc_verify.analysis.closedloop import closed_loop
from ftc_verify.analysis.lmi_analysis import hinf_gamma
from ftc_verify.analysis.lower_bound import float_gain, gain_lower_bound
from ftc_verify.controllers.files import load_controller
from ftc_verify.model.files import load_system

DATA = Path(__file__).resolve().parent / "data"


def test_lower_bound_reaches_the_float_gain_at_its_rates_above_120_rows() -> None:
    """The proved bound is within 1e-3 of the float gain at its rates, computed again by an
    independent bisection from below (``float_gain`` without ``upper``, relative width
    ``BISECTION_RTOL`` = 1e-5), and never above it; ``float_gain`` is that gain, not the
    certified gamma."""
    loop = closed_loop(load_system(DATA / "lower_bound_135_rows.toml"),
                       load_controller(DATA / "lower_bound_135_rows_K.toml"))
    assert len(loop.A) * loop.n * (loop.n + 1) // 2 > 120
    nominal = hinf_gamma(loop, robust=False)
    assert nominal.certified and nominal.gamma is not None
    low = gain_lower_bound(loop, upper=nominal.gamma)
    assert low is not None and low.value is not None
    again = float_gain(loop.nominal().A, loop.Bw, loop.Cz, loop.chain.generator(low.rates))
    assert again is not None
    gain = again[0]  # the gain lies in [gain (1 - 1e-5), gain]
    assert low.value <= gain
    assert low.value >= (1.0 - 1e-3) * gain
    assert abs(low.float_gain - gain) <= 1e-4 * gain
    assert low.float_gain < 0.99 * nominal.gamma
