"""``synthesize``'s short-``h_max`` screen
(:func:`ftc_verify.analysis.moments.sampled_scan.octave_verdicts`) on a rate box with more
vertices than :func:`~ftc_verify.analysis.moments.sampled.rate_points` lists (its corners
and midpoint above 16): it sees an unstable inner vertex (issue 31 item 5; round 10 found
the same gap in the verdict at a period).

The loop (``tests/data/sampled_64_vertices_fast.toml``): round 10's 64-vertex loop
(``sampled_64_vertices.toml``, ``n = 2``, ``m = 3``, six detection-rate intervals) with
its generator, inputs, disturbances and rates times ``c = 3.04170919``, so its period
``h`` is the old loop's ``c h``. The old loop's radius at the inner vertex worst at its
crossing reaches 1 at ``0.30417090`` and at the next worst vertex at ``0.30417093``;
``0.1 c`` lies between them: at the octave 0.1 exactly one vertex is unstable (radius
``1 + 1.1e-7``; the next ``1 - 1.1e-7``, far above the float64 error of a radius of this
45-row map), and no rate point is (largest ``1 - 9.6e-4``). All of that is asserted below
over all 64 vertices, not assumed."""

from __future__ import annotations

from pathlib import Path

import pytest

from ftc_verify.analysis.moments.sampled import SampledLoop, rate_points, spectral_radius
from ftc_verify.analysis.moments.sampled_scan import octave_verdicts
from ftc_verify.cli.sampled_lines import warn_short_h_max
from ftc_verify.controllers.files import load_controller
from ftc_verify.model.files import load_system

DATA = Path(__file__).resolve().parent / "data"


@pytest.fixture(scope="module")
def case() -> tuple:
    return load_system(DATA / "sampled_64_vertices_fast.toml"), load_controller(DATA / "sampled_64_vertices_K.toml")


def test_only_an_inner_vertex_is_unstable_at_the_top_octave(case: tuple) -> None:
    """The case as described: 64 vertices; at 0.1 one vertex above 1, neither corner;
    every rate point below 1; at the smaller octaves every vertex below 1."""
    loop = SampledLoop.build(*case)
    chain = loop.chain
    vertices = list(chain.vertices())
    assert len(vertices) == 64 and len(rate_points(chain)) == 3
    radii = [spectral_radius(loop, 0.1, v) for v in vertices]
    unstable = [v for v, r in zip(vertices, radii) if r >= 1.0]
    assert len(unstable) == 1
    assert not any((unstable[0] == c).all() for c in (chain.rate_min, chain.rate_max))
    assert max(spectral_radius(loop, 0.1, p) for p in rate_points(chain)) < 1.0
    for k in range(1, 8):
        assert max(spectral_radius(loop, 0.1 / 2 ** k, v) for v in vertices) < 1.0


def test_screen_sees_the_inner_vertex(case: tuple) -> None:
    """The octaves of 0.1: not stable at 0.1 only (on main every octave passed: the
    corners and midpoint alone are stable); with the top octave a millionth lower, where
    that vertex's radius is below 1 too, every octave passes (no spurious warning)."""
    loop = SampledLoop.build(*case)
    assert [ok for _, ok in octave_verdicts(loop, 0.1, 7)] == [True] * 7 + [False]
    assert all(ok for _, ok in octave_verdicts(loop, 0.1 * (1 - 1e-6), 7))


def test_synthesize_warning_names_the_period_and_a_radius_above_one(case: tuple,
                                                                       capsys: pytest.CaptureFixture[str]) -> None:
    """The warning of ``synthesize`` without ``--period`` is printed, at period 0.1, with
    the inner vertex's radius (at least 1), not the corners' (below 1)."""
    warn_short_h_max(*case)
    err = capsys.readouterr().err
    assert "warning: the sampled loop of this controller is not mean-square stable at period 0.1 " in err
    rho = float(err.split("float64 spectral radius ")[1].split(")")[0])
    assert rho > 1.0  # printed to 9 digits: 1 + 1.1e-7 is not shown as 1


def test_no_ascent_above_the_row_limit(case: tuple, monkeypatch: pytest.MonkeyPatch) -> None:
    """On maps above ``SCREEN_ASCENT_ROWS`` rows the screen is the rate points' alone (the
    ascent costs more than a design there): with the limit set below this loop's map,
    the inner vertex is not seen and ``period_worst`` is never called."""
    from ftc_verify.analysis.moments import sampled_scan

    def no_ascent(*args: object) -> None:
        raise AssertionError("the vertex ascent ran above the row limit")

    monkeypatch.setattr(sampled_scan, "SCREEN_ASCENT_ROWS", 0)
    monkeypatch.setattr(sampled_scan, "period_worst", no_ascent)
    loop = SampledLoop.build(*case)
    assert all(ok for _, ok in octave_verdicts(loop, 0.1, 7))
