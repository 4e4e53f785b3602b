"""Verdicts over the whole rate box, proofs on the data as written, and the gamma bracket."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from fractions import Fraction
from pathlib import Path

import cli_inprocess
import numpy as np
import pytest

from box_systems import coupled_riccati_gain, interior_files, interior_loop, shifted
from process_stages import child_has_worked, wait_for_stage
from ftc_verify.analysis.analyze import analyze
from ftc_verify.analysis.closedloop import closed_loop
from ftc_verify.analysis.exact import exact_loop
from ftc_verify.analysis.lmi_analysis import hinf_gamma
from ftc_verify.analysis.lower_bound import gain_lower_bound
from ftc_verify.analysis.rigorous import precision
from ftc_verify.analysis.moments.stability import mean_square_stability, spectral_abscissa
from ftc_verify.controllers.files import load_controller
from ftc_verify.model.files import load_system

ROOT = Path(__file__).resolve().parents[1]


def _covered(result, chain, rng: np.random.Generator, samples: int = 300) -> bool:
    """Every sampled rate vector of the box lies in a region proved stable."""
    regions = [r for r in result.vertex_verdicts if r.verdict == "stable"]
    lo, hi = chain.rate_min, chain.rate_max
    for _ in range(samples):
        point = lo + rng.uniform(size=lo.shape) * (hi - lo)
        if not any(np.all(r.rate_min <= point) and np.all(point <= r.rate_max) for r in regions):
            return False
    return True


@pytest.mark.parametrize("phases", [1, 4])
def test_instability_inside_the_box_is_found_though_every_vertex_is_stable(tmp_path: Path, phases: int) -> None:
    loop = interior_loop(tmp_path, extra=f"delay_phases = {phases}")
    vertices = [spectral_abscissa(loop, v) for v in loop.chain.vertices()]
    assert max(vertices) < -0.05  # what the vertex test saw
    r = mean_square_stability(loop)
    assert r.verdict == "not stable"
    w = r.witness
    assert w is not None and np.array_equal(w.rate_min, w.rate_max)
    lo, hi = loop.chain.rate_min, loop.chain.rate_max
    inside = w.rate_min[lo < hi]
    assert np.all(inside > lo[lo < hi]) and np.all(inside < hi[lo < hi])  # an interior point
    assert w.enclosure is not None and w.enclosure[0] > 0  # the abscissa there, proved positive
    assert spectral_abscissa(loop, w.rate_min) == pytest.approx(w.estimate, rel=1e-9)
    assert r.spectral_abscissa >= w.estimate  # the estimate reports the witness


def test_cli_no_longer_calls_the_interior_instability_stable(tmp_path: Path) -> None:
    system, gains = interior_files(tmp_path)
    proc = cli_inprocess.run_cli(["analyze", str(system), "--gains", str(gains), "--no-lmi", "--json"])
    assert proc.returncode == 1, proc.stdout + proc.stderr
    mss = json.loads(proc.stdout)["mss"]
    assert mss["verdict"] == "not stable" and mss["witness"]["abscissa_enclosure"][0] > 0
    assert "every vertex" not in mss["verified_by"]


def test_stable_loop_whose_worst_rate_is_interior_is_proved_over_the_box(tmp_path: Path) -> None:
    base = interior_loop(tmp_path)
    loop = shifted(base, 0.1202)  # true worst abscissa about -0.04, inside the box in beta[1][2]
    grid = np.geomspace(0.1, 10.0, 15)
    worst = max(spectral_abscissa(loop, np.array([[0, a], [b, 0]])) for a in grid for b in grid)
    assert -0.06 < worst < 0
    r = mean_square_stability(loop)
    assert r.verdict == "stable", r.reason
    assert _covered(r, loop.chain, np.random.default_rng(3))
    assert mean_square_stability(shifted(base, 0.0902)).verdict == "not stable"  # the same, 0.02 above zero


def test_false_alarm_rates_are_part_of_the_box(tmp_path: Path) -> None:
    """The false-alarm rates are coordinates of the box: the instability is found with its
    false-alarm rate, and the stable loop (shifted by 0.2: 30 sub-boxes, 1 s of CPU; at
    0.15 the proof took 364 sub-boxes and 10 s, and at load 14 ran out of its 60 s budget)
    is proved by sub-boxes that split the false-alarm rates too."""
    extra = "false_alarm_min = [[0.0, 0.01], [0.01, 0.0]]\nfalse_alarm_max = [[0.0, 0.5], [0.5, 0.0]]"
    loop = interior_loop(tmp_path, extra=extra)
    r = mean_square_stability(loop)
    assert r.verdict == "not stable"
    w = r.witness
    assert w is not None and spectral_abscissa(loop, w.rate_min) > 0
    stable = mean_square_stability(shifted(loop, 0.2))
    assert stable.verdict == "stable" and _covered(stable, loop.chain, np.random.default_rng(4))
    lo, hi = loop.chain.rate_min[1], loop.chain.rate_max[1]  # the false-alarm coordinates
    assert any(np.any(v.rate_max[1] - v.rate_min[1] < 0.5 * (hi - lo)) for v in stable.vertex_verdicts)


def test_a_box_of_two_to_the_twenty_vertices(tmp_path: Path) -> None:
    """m = 5: 20 uncertain detection rates; the verdict covers the whole box, proved
    with one Lyapunov stack, after evaluating a few hundred vertices at most."""
    m = 5
    alpha = np.full((m, m), 0.5)
    np.fill_diagonal(alpha, -0.5 * (m - 1))
    lo, hi = np.full((m, m), 0.5), np.full((m, m), 20.0)
    np.fill_diagonal(lo, 0.0)
    np.fill_diagonal(hi, 0.0)
    modes = "".join(f"[[mode]]\nA = [[-1.0, {0.5 * k}], [0.0, -2.0]]\nB = [[1.0], [1.0]]\nC = [[1.0, 0.0]]\n"
                    "D = [[1.0], [0.0]]\n" for k in range(m))
    (tmp_path / "five.toml").write_text(f"[chain]\nalpha = {alpha.tolist()}\nbeta_min = {lo.tolist()}\n"
                                        f"beta_max = {hi.tolist()}\n{modes}")
    gains = "".join(f"[[gain]]\nK = [[{-0.1 * k}, 0.0]]\n" for k in range(m))
    (tmp_path / "k.toml").write_text(gains)
    loop = closed_loop(load_system(tmp_path / "five.toml"), load_controller(tmp_path / "k.toml"))
    assert loop.chain.vertex_count() == 2 ** 20
    t0 = time.perf_counter()
    r = mean_square_stability(loop)
    assert r.verdict == "stable" and r.time_varying and not r.exhaustive and r.vertices_evaluated < 600
    (region,) = r.vertex_verdicts
    assert np.all(region.rate_min <= loop.chain.rate_min) and np.all(region.rate_max >= loop.chain.rate_max)
    assert time.perf_counter() - t0 < 120


def test_budget_gives_undecided_with_the_open_sub_box(tmp_path: Path) -> None:
    loop = shifted(interior_loop(tmp_path), 0.1052)  # stable, 0.01 from the edge: many sub-boxes
    r = mean_square_stability(loop, budget_seconds=0.5)
    assert r.verdict == "undecided" and "budget" in r.reason
    last = r.vertex_verdicts[-1]
    assert last.verdict == "undecided"
    assert np.all(last.rate_min >= np.nextafter(loop.chain.rate_min, -np.inf))
    assert np.all(last.rate_max <= np.nextafter(loop.chain.rate_max, np.inf))


@pytest.mark.slow(3)
def test_sigterm_during_the_branch_and_bound_exits_143(tmp_path: Path) -> None:
    """SIGTERM once the analysis's child has done 0.5 s of the branch and bound (it starts
    at once there: about 9 s of sub-boxes in all; ``tests/process_stages.py``)."""
    system, gains = interior_files(tmp_path, shift=0.1052)
    proc = subprocess.Popen([sys.executable, "-m", "ftc_verify", "analyze", str(system), "--gains", str(gains),
                             "--no-lmi"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    wait_for_stage(proc, lambda: child_has_worked(proc.pid, 0.5), "0.5 s of the branch and bound")
    assert proc.poll() is None, proc.communicate()
    sent = time.monotonic()
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 143 and time.monotonic() - sent < 10.0
    assert err.strip() == "ftc-verify: terminated"


def _physical_units(path: Path) -> tuple[Path, Path]:
    """An identical-mode loop (so its gain is the LTI norm) whose plant carries a
    stabilising gain of about 9e6 that the controller file cancels: ``A + B K`` loses
    about 1e-9 per entry in float64, near a slow pole of 1e-2."""
    rng = np.random.default_rng(11)
    n = 6
    K0 = rng.uniform(-9.06e6, 9.06e6, size=(1, n))
    B = rng.normal(size=(n, 1))
    A0 = -np.diag(np.geomspace(1e-2, 3.0, n)) + 0.2 * np.triu(rng.normal(size=(n, n)), 1)
    A = A0 - B @ K0
    dK = 1e-5 * rng.normal(size=(1, n))
    mode = (f"[[mode]]\nA = {A.tolist()}\nB = {B.tolist()}\nC = {rng.normal(size=(1, n)).tolist()}\n"
            f"D = {rng.normal(size=(n, 1)).tolist()}\n")
    (path / "units.toml").write_text("[chain]\nalpha = [[-1.0, 1.0], [1.0, -1.0]]\n"
                                     "beta_min = [[0.0, 1.0], [1.0, 0.0]]\nbeta_max = [[0.0, 2.0], [2.0, 0.0]]\n"
                                     + mode + mode)
    K = (K0 + dK).tolist()
    (path / "units_k.toml").write_text(f"[[gain]]\nK = {K}\n[[gain]]\nK = {K}\n")
    return path / "units.toml", path / "units_k.toml"


def _decimal_matrix(text: str, key: str) -> list[list[Fraction]]:
    import tomllib

    doc = tomllib.loads(text, parse_float=Fraction)
    table = doc["mode"][0] if key in ("A", "B", "C", "D") else doc["gain"][0]
    return [[Fraction(v) for v in row] for row in table[key]]


def test_certificate_holds_for_the_numbers_as_written(tmp_path: Path) -> None:
    """The certified nominal gamma is at least the DC gain of the loop formed from the
    files' decimals in rational arithmetic, and the exact enclosure contains that loop."""
    system_path, gains_path = _physical_units(tmp_path)
    A, B, C, D = (_decimal_matrix(system_path.read_text(), k) for k in ("A", "B", "C", "D"))
    K = _decimal_matrix(gains_path.read_text(), "K")
    n = len(A)
    Acl = [[A[i][j] + B[i][0] * K[0][j] for j in range(n)] for i in range(n)]
    # DC gain: C (-Acl)^-1 D, by Gaussian elimination in rationals
    M = [[-Acl[i][j] for j in range(n)] + [D[i][0]] for i in range(n)]
    for col in range(n):
        piv = next(r for r in range(col, n) if M[r][col] != 0)
        M[col], M[piv] = M[piv], M[col]
        for r in range(n):
            if r != col and M[r][col] != 0:
                f = M[r][col] / M[col][col]
                M[r] = [a - f * b for a, b in zip(M[r], M[col])]
    x = [M[i][n] / M[i][i] for i in range(n)]
    dc = abs(float(sum(C[0][j] * x[j] for j in range(n))))
    loop = closed_loop(load_system(system_path), load_controller(gains_path))
    with precision():
        enclosure = exact_loop(loop).A[0].value
        for i in range(n):
            for j in range(n):
                exact = Acl[i][j]
                import flint

                assert enclosure[i, j].contains(flint.arb(flint.fmpq(exact.numerator, exact.denominator)))
    nominal = hinf_gamma(loop, robust=False)
    assert nominal.certified and nominal.gamma >= dc
    low = gain_lower_bound(loop, upper=nominal.gamma)
    assert low is not None and low.value is not None and low.value <= nominal.gamma


def test_bracket_against_an_independent_coupled_riccati_gain() -> None:
    loop = closed_loop(load_system(ROOT / "examples/paper.toml"), load_controller(ROOT / "examples/paper_gains.toml"))
    rep = analyze(loop, cross_validation=False)
    low, gamma = rep.nominal_lower, rep.nominal.gamma
    assert low is not None and low.value is not None and gamma is not None
    truth = coupled_riccati_gain(loop.nominal(), low.rates)
    assert low.value <= truth * (1 + 1e-9)  # a lower bound of the gain at its own rates
    assert truth <= gamma * (1 + 1e-9)  # which the box certificate covers
    assert gamma / low.value < 1.002  # the bracket within 0.2 %
    robust = rep.to_dict()["hinf"]["robust_lower_bound"]
    assert robust["proved"] and robust["value"] <= rep.robust.gamma and robust["ratio"] < 1.05


def test_dynamic_controller_loop_is_formed_in_balls_from_its_files() -> None:
    """The observer-based controller's augmented loop: every block formed from the files'
    decimals (enclosures about the float loop, of the reading's width, not exact floats)."""
    from ftc_verify.analysis.rigorous import midpoint

    system = load_system(ROOT / "examples/paper.toml")
    controller = load_controller(ROOT / "examples/paper_observer.toml")
    loop = closed_loop(system, controller)
    assert loop.source is not None and controller.literals
    with precision():
        exact = exact_loop(loop)
        for A_ball, A in zip(exact.A, loop.A):
            mid = midpoint(A_ball)
            assert mid.shape == A.shape == (loop.n, loop.n) and loop.n > system.dims[0]
            assert np.abs(mid - A).max() <= 1e-12 * np.abs(A).max()
        radii = [float(e.rad()) for e in exact.A[0].value.entries()]
        assert max(radii) > 0  # the decimal 0.1 etc. are not floats: enclosed, not taken as exact
    moved = loop.transformed(2.0 * np.eye(loop.n), 0.5 * np.eye(loop.n))
    assert moved.source is None  # a loop in other coordinates is its own data
