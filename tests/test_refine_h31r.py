"""The ``h_max`` refinement by covers of cubic clock certificates
(:mod:`ftc_verify.analysis.moments.sampled_cubic`, :mod:`~ftc_verify.analysis.moments.sampled_cover`,
:mod:`~ftc_verify.analysis.moments.sampled_refine`; ``analyze``/``verify --h-max-work``): the
certificate proved in ball arithmetic and refused when tampered with, the period it proves
confirmed by the independent sub-box proof, the cover's splits, budget and ladder, the CLI's
refusals before any work."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from ftc_verify.analysis.moments import sampled_cover
from ftc_verify.analysis.moments.sampled import SampledLoop, SampledResult
from ftc_verify.analysis.moments.sampled_bracket import envelope_work
from ftc_verify.analysis.moments.sampled_cover import (MAP_DEPTH, cover_box, cover_h_max, cover_rungs,
                                                       cubic_work, rung_pieces)
from ftc_verify.analysis.moments.sampled_cubic import cubic_stable, prove_cubic
from ftc_verify.analysis.moments.sampled_proof import box_verdict
from ftc_verify.analysis.moments.sampled_refine import refine_result
from ftc_verify.cli.main import main
from ftc_verify.controllers.files import load_controller
from ftc_verify.model.files import load_system

ROOT = Path(__file__).resolve().parents[1]
PAPER_UNSTABLE = 0.0843  # above the paper loop's float64 crossing 0.08426 (h31c)


@pytest.fixture(autouse=True)
def _no_map_proofs(monkeypatch: pytest.MonkeyPatch) -> None:
    """The cover's one-period-map proofs refused, so that these tests count the cubic
    certificates alone (the mixed cover: ``tests/test_cover_mixed_h31t.py``)."""
    monkeypatch.setattr(sampled_cover, "subbox_stable", lambda *args, spend=None: False)


def _paper() -> SampledLoop:
    return SampledLoop.build(load_system(ROOT / "examples" / "paper.toml"),
                             load_controller(ROOT / "examples" / "paper_gains.toml"))


def test_cubic_certificate_proves_close_to_the_crossing_and_not_above() -> None:
    """Two cubic pieces prove the paper loop 5e-4 below 0.0843 (3e-5 below its crossing);
    the sub-box proof (no clock certificate) confirms that period independently; above
    the crossing no certificate is found."""
    loop = _paper()
    h = PAPER_UNSTABLE * (1 - 5e-4)
    cert = cubic_stable(loop, h, 2)
    assert cert is not None and cert.proved and cert.pieces == 2
    assert box_verdict(loop, h, max_boxes=64, max_seconds=float("inf")).verdict == "stable"
    above = cubic_stable(loop, PAPER_UNSTABLE * 1.001, 2)
    assert above is None or not above.proved


def test_tampered_certificate_is_refused() -> None:
    from ftc_verify.analysis.moments.sampled_conditioned import conditioned

    loop = conditioned(_paper())
    cert = cubic_stable(loop, 0.08, 2)
    assert cert is not None and cert.proved and prove_cubic(loop, cert)
    # a last node too small for the sample's jump condition
    nodes = cert.nodes[:-1] + (tuple(0.5 * y for y in cert.nodes[-1]),)
    assert not prove_cubic(loop, dataclasses.replace(cert, nodes=nodes))
    # a Gram part that breaks the negativity of the flow on the first piece
    grams = list(cert.grams)
    B2, C2, K = grams[0][0]
    grams[0] = ((B2 + 1e3 * np.eye(len(B2)), C2, K),) + grams[0][1:]
    assert not prove_cubic(loop, dataclasses.replace(cert, grams=tuple(grams)))
    # a sub-box certificate claims its own rates only: moved to rates outside the box, it fails
    hi = cert.hi * 4.0
    assert not prove_cubic(loop, dataclasses.replace(cert, lo=cert.hi, hi=hi))


class _Cubic:
    """A stand-in for :func:`cubic_stable` proving a sub-box when its width in every
    rate is at most ``share`` of the box's (records what it was asked)."""

    def __init__(self, share: float) -> None:
        self.share = share
        self.asked: list[tuple[float, int, Any]] = []

    def __call__(self, loop: SampledLoop, h: float, pieces: int, lo: np.ndarray, hi: np.ndarray) -> object:
        full = loop.chain.rate_max - loop.chain.rate_min
        ok = all(hi[r] - lo[r] <= self.share * full[r] * (1 + 1e-12) for r in loop.chain.rate_indices)
        self.asked.append((h, pieces, (lo.copy(), hi.copy())))
        return type("Cert", (), {"proved": ok})()


def _assert_exact_cover(loop: SampledLoop, leaves: list[Any]) -> None:
    """The leaves' union is the box, exactly in the floats: every leaf inside it, no two
    overlapping (in some rate one ends where the other starts, at the same float), and
    their volumes summing to the box's in exact rationals (closed boxes with disjoint
    interiors inside the box and the box's volume: their union is the box)."""
    from fractions import Fraction

    lo0, hi0 = loop.chain.rate_min, loop.chain.rate_max
    idx = loop.chain.rate_indices
    for lo, hi, _ in leaves:
        assert all(lo0[r] <= lo[r] < hi[r] <= hi0[r] for r in idx)
    for a, (la, ha, _) in enumerate(leaves):
        for lb, hb, _ in leaves[a + 1:]:
            assert any(ha[r] <= lb[r] or hb[r] <= la[r] for r in idx)
    # the shared faces: every split value is the end of one leaf and the start of another
    for r in idx:
        ends = {float(hi[r]) for _, hi, _ in leaves} - {float(hi0[r])}
        assert ends == {float(lo[r]) for lo, _, _ in leaves} - {float(lo0[r])}

    def volume(lo: Any, hi: Any) -> Fraction:
        out = Fraction(1)
        for r in idx:
            out *= Fraction(float(hi[r])) - Fraction(float(lo[r]))
        return out

    assert sum((volume(lo, hi) for lo, hi, _ in leaves), Fraction(0)) == volume(lo0, hi0)


def _halvings(loop: SampledLoop, lo: np.ndarray, hi: np.ndarray) -> int:
    """How many halvings of the box give the sub-box ``[lo, hi]``."""
    full = loop.chain.rate_max - loop.chain.rate_min
    return round(float(sum(np.log2(full[r] / (hi[r] - lo[r])) for r in loop.chain.rate_indices)))


def test_cover_splits_until_proved_and_covers_the_box(monkeypatch: pytest.MonkeyPatch) -> None:
    loop = _paper()
    fake = _Cubic(0.5)
    monkeypatch.setattr(sampled_cover, "cubic_stable", fake)
    start = [(loop.chain.rate_min.copy(), loop.chain.rate_max.copy(), 0)]
    leaves, spent, attempts, maps = cover_box(loop, 0.08, 4, start, 1e12)
    assert leaves is not None
    # two rates, each halved once: 4 leaves, exactly the box. The box fails: its probe (10
    # halvings down), the top of the path to it (1: not proved), the bisection (5, 3, 2:
    # proved), the other half at 2; the other half at 1 fails: its probe, the top of its
    # path (2: proved), the other half at 2. Map proofs on the sub-boxes popped only
    assert len(leaves) == 4 and maps == 4 and attempts == 11
    assert spent == pytest.approx(11 * cubic_work(loop, 4) + 4 * envelope_work(loop))  # the envelope proves each
    assert [_halvings(loop, lo, hi) for _, _, (lo, hi) in fake.asked] == [0, 10, 1, 5, 3, 2, 2, 1, 10, 2, 2]
    _assert_exact_cover(loop, leaves)
    # the budget is charged before each solve: none is started that it cannot pay
    fake.asked.clear()
    leaves, spent, attempts, _ = cover_box(loop, 0.08, 4, start, 2.5 * cubic_work(loop, 4))
    assert leaves is None and attempts == 2 and len(fake.asked) == 2 and spent <= 2.5 * cubic_work(loop, 4)
    # a sub-box never proved: three programs (the box, then its hardest sub-boxes at
    # COVER_DEPTH and PROBE_DEPTH, not one at every depth), then map proofs alone, to the
    # depth limit
    monkeypatch.setattr(sampled_cover, "cubic_stable", _Cubic(0.0))
    leaves, _, attempts, maps = cover_box(loop, 0.08, 4, start, 1e12)
    assert leaves is None and attempts == 3 and maps == MAP_DEPTH + 1
    leaves, _, attempts, maps = cover_box(loop, 0.08, None, start, 1e12)
    assert leaves is None and attempts == 0 and maps == MAP_DEPTH + 1


def test_ladder_reuses_the_previous_cover(monkeypatch: pytest.MonkeyPatch) -> None:
    loop = _paper()
    assert cover_rungs(0.02, 1e-3) == pytest.approx((0.005, 0.00125, 0.0009))
    assert cover_rungs(0.0009, 1e-3) == ()
    fake = _Cubic(0.5)
    monkeypatch.setattr(sampled_cover, "cubic_stable", fake)
    hu = PAPER_UNSTABLE
    got = cover_h_max(loop, hu * (1 - 0.02), hu, 1e12, 1e-3)
    assert got.h_max == pytest.approx(hu * (1 - 0.0009)) and got.boxes == 4
    assert [ok for _, ok in got.rungs] == [True, True, True]
    # each rung: its probe (1 attempt), then the first splits the box (10 attempts: the
    # cover above, its probe already proved); the next two start from its 4 leaves, with
    # 4 pieces (below FINE_FROM), their probe below the leaf holding the worst vertex, then
    # the 4 leaves
    assert got.attempts == (1 + 10) + (1 + 4) + (1 + 4) and got.pieces == 4
    assert [p for _, p, _ in fake.asked] == [2] * 11 + [4] * 10


class _Pieces(_Cubic):
    """Proves a sub-box of width ``share`` only with at least ``least`` pieces."""

    def __init__(self, share: float, least: int) -> None:
        super().__init__(share)
        self.least = least

    def __call__(self, loop: SampledLoop, h: float, pieces: int, lo: np.ndarray, hi: np.ndarray) -> object:
        cert = super().__call__(loop, h, pieces, lo, hi)
        if pieces < self.least:
            return type("Cert", (), {"proved": False})()
        return cert


def test_rung_pieces_from_the_probe(monkeypatch: pytest.MonkeyPatch) -> None:
    loop = _paper()
    lo, hi = loop.chain.rate_min.copy(), loop.chain.rate_max.copy()
    monkeypatch.setattr(sampled_cover, "cubic_stable", _Pieces(1.0, 4))
    assert rung_pieces(loop, 0.08, lo, hi, 2, 1e12) == (4, pytest.approx(cubic_work(loop, 2) + cubic_work(loop, 4)), 2)
    assert rung_pieces(loop, 0.08, lo, hi, 4, 1e12)[0] == 4  # never fewer than the last rung's
    assert rung_pieces(loop, 0.08, lo, hi, 2, 1.5 * cubic_work(loop, 2))[0] is None  # the budget first
    monkeypatch.setattr(sampled_cover, "cubic_stable", _Pieces(1.0, 16))
    got = cover_h_max(loop, 0.0843 * 0.98, 0.0843, 1e12, 1e-3)
    # 5e-3 fails, then the geometric means of 2e-2 and the closest failed distance while
    # more than BISECT apart: 1e-2, 1.41e-2, 1.68e-2
    assert got.h_max is None
    assert [h for h, _ in got.rungs] == pytest.approx([0.0843 * (1 - f) for f in (5e-3, 1e-2, 2 ** 0.5 * 1e-2,
                                                                                 2 ** 0.75 * 1e-2)])
    assert not any(ok for _, ok in got.rungs)


def test_refine_result_only_when_wider_than_rtol(monkeypatch: pytest.MonkeyPatch) -> None:
    system = load_system(ROOT / "examples" / "paper.toml")
    controller = load_controller(ROOT / "examples" / "paper_gains.toml")
    fake = _Cubic(1.0)
    monkeypatch.setattr(sampled_cover, "cubic_stable", fake)
    base = SampledResult(0.05, "stable", 0.5, [[0.0]], "", 0, PAPER_UNSTABLE * 0.9995, PAPER_UNSTABLE, "narrow",
                         (), (0.01, 1.0), 0.0)
    assert refine_result(system, controller, base, 1e9) is base and fake.asked == []
    wide = dataclasses.replace(base, h_max=PAPER_UNSTABLE * 0.96, h_max_note="wide")
    got = refine_result(system, controller, wide, 1e9)
    assert got.h_max == pytest.approx(PAPER_UNSTABLE * 0.9991) and "refinement (--h-max-work" in got.h_max_note
    assert "by 1 sub-box(es), each by its one-period map or a cubic clock certificate" in got.h_max_note
    none = dataclasses.replace(base, h_max=None, h_max_note="not proved")
    # the probe, then the box, with half the budget left (RUNG_SHARE)
    got = refine_result(system, controller, none, cubic_work(_paper(), 2) * 3.5)
    assert got.h_max == pytest.approx(PAPER_UNSTABLE * (1 - 0.125))  # from a 50 % bracket: g / 4
    monkeypatch.setattr(sampled_cover, "cubic_stable", _Cubic(0.0))
    assert refine_result(system, controller, wide, 1e5).h_max == wide.h_max  # nothing proved: unchanged


@pytest.mark.parametrize(("command", "argv", "needle"), [
    ("analyze", ["--h-max-work", "5000"], "--h-max-work 5000: refines the sampled loop's h_max bracket; give --period"),
    ("analyze", ["--period", "0.05", "--h-max-work", "-3"], "--h-max-work"),
    ("verify", ["--h-max-work", "0"], "--h-max-work"),
])
def test_cli_refuses_before_any_work(capsys: pytest.CaptureFixture[str], command: str, argv: list[str],
                                     needle: str) -> None:
    try:
        code = main([command, str(ROOT / "examples" / "paper.toml"), "--gains",
                     str(ROOT / "examples" / "paper_gains.toml"), *argv])
    except SystemExit as stop:  # argparse's own refusal of a bad number
        code = stop.code
    err = capsys.readouterr()
    assert code == 2 and needle in err.err and err.out == "" and "Traceback" not in err.err


@pytest.mark.parametrize("command", ["analyze", "verify"])
def test_memory_limit_refused_before_any_work(capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch,
                                              tmp_path: Path, command: str) -> None:
    monkeypatch.setenv("FTC_VERIFY_MEMORY_LIMIT", "100M")  # below the program's estimate (0.2 GB)
    out = tmp_path / "report"
    extra = ["--out", str(out)] if command == "verify" else []
    code = main([command, str(ROOT / "examples" / "paper.toml"), "--gains", str(ROOT / "examples" / "paper_gains.toml"),
                 "--period", "0.05", "--h-max-work", "1000", *extra])
    err = capsys.readouterr()
    assert code == 2 and "--h-max-work 1000: the refinement's clock program needs about" in err.err
    assert err.out == "" and not out.exists()


def test_text_output_names_the_refinement(capsys: pytest.CaptureFixture[str]) -> None:
    from ftc_verify.cli.sampled_lines import print_sampled

    res = SampledResult(0.05, "stable", 0.5, [[0.0]], "by test", 0, 0.08, 0.0843,
                        "wide; refinement (--h-max-work 5000): 2 cubic clock certificate(s), 4000 units, proved",
                        (), (0.01, 1.0), 0.0)
    print_sampled(res)
    assert "      refinement (--h-max-work 5000): 2 cubic clock certificate(s)" in capsys.readouterr().out
    print_sampled(dataclasses.replace(res, h_max_note="narrow"))
    assert "refinement" not in capsys.readouterr().out


def test_verify_stage_refines_with_the_loop_built_once(monkeypatch: pytest.MonkeyPatch) -> None:
    """``verify --h-max-work``: the sampled stage hands the budget to the same refinement
    as ``analyze``, with the loop it built (once) for its size check and the analysis."""
    from ftc_verify.analysis.moments import sampled_refine
    from ftc_verify.verification.sampled_stage import sampled_stage

    system = load_system(ROOT / "examples" / "paper.toml")
    controller = load_controller(ROOT / "examples" / "paper_gains.toml")
    builds: list[SampledLoop] = []
    build = SampledLoop.build

    def counted(system: Any, controller: Any) -> SampledLoop:
        builds.append(build(system, controller))
        return builds[-1]

    calls: list[tuple[float, Any]] = []

    def refine(system: Any, controller: Any, result: SampledResult, work: float, *, loop: Any = None) -> SampledResult:
        calls.append((work, loop))
        return dataclasses.replace(result, h_max_note=result.h_max_note + "; refined by test")

    monkeypatch.setattr(SampledLoop, "build", staticmethod(counted))
    monkeypatch.setattr(sampled_refine, "refine_result", refine)
    res, check = sampled_stage(system, controller, 0.05, here=True, h_max_work=1234.0)
    assert res is not None and res.h_max_note.endswith("; refined by test") and check.ok
    assert len(builds) == 1 and calls == [(1234.0, builds[0])]
    calls.clear()
    res, _ = sampled_stage(system, controller, 0.05, here=True)
    assert res is not None and calls == []
