"""The sampled gain certificate's piece schedule depends on the problem only
(:data:`~ftc_verify.analysis.moments.sampled_gamma.MAX_ROWS`,
:func:`~ftc_verify.analysis.moments.sampled_quadratic.program_rows`): the same input gives
the same gamma, pieces and degree however slow the machine is."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from ftc_verify.analysis.conic import Rows
from ftc_verify.analysis.moments import sampled_gamma as sg
from ftc_verify.analysis.moments.sampled import SampledLoop
from ftc_verify.analysis.moments.sampled_quadratic import QuadraticLayout, instance_sizes, program_rows, quadratic_rows
from ftc_verify.controllers.controller import Controller
from ftc_verify.controllers.files import load_controller
from ftc_verify.model.files import load_system
from ftc_verify.model.system import FTCSystem

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def paper() -> tuple[FTCSystem, Controller]:
    return load_system(ROOT / "examples" / "paper.toml"), load_controller(ROOT / "examples" / "paper_gains.toml")


def _built_rows(aug: object, jumps: list[np.ndarray], piece: tuple[int, int], h: float, robust: bool) -> int:
    """Rows of the program as the certificate builds it."""
    degree, N = piece
    chans = tuple(len(c) if robust else 0 for c in aug.channels)  # type: ignore[attr-defined]
    if degree == 1:
        lay = sg._Layout(aug.n, len(aug.A), N + 1, chans)  # type: ignore[attr-defined]
        rows: Rows = sg._rows(aug, jumps, lay, h, robust)  # type: ignore[arg-type]
    else:
        qlay = QuadraticLayout(aug.n, len(aug.A), N, chans, instance_sizes(aug, robust))  # type: ignore[attr-defined, arg-type]
        rows = quadratic_rows(aug, jumps, qlay, h, robust)  # type: ignore[arg-type]
    return int(rows.problem(np.zeros(rows.K)).A.shape[0])


@pytest.mark.parametrize("robust", [False, True])
def test_program_rows_counts_the_built_program(paper: tuple[FTCSystem, Controller], robust: bool) -> None:
    """The rows predicted from the dimensions equal those of the program built, for the
    affine and the quadratic storage (paper loop; nominal and robust)."""
    system, controller = paper
    loop = SampledLoop.build(system, controller)
    aug = sg.augmented_loop(loop, system)
    aug = aug if robust else aug.nominal()
    jumps = sg.sample_jumps(loop, 0.05)
    for piece in ((1, 2), (1, 4), (2, 1), (2, 2), (2, 4)):
        assert program_rows(aug, piece, robust) == _built_rows(aug, jumps, piece, 0.05, robust), piece
    assert program_rows(aug, (2, 8), True) <= sg.MAX_ROWS  # the paper's whole schedule is admitted


def test_schedule_ignores_the_clock(paper: tuple[FTCSystem, Controller], monkeypatch: pytest.MonkeyPatch) -> None:
    """h = 0.08 (0.95 h_max), nominal, storage affine on 4 then quadratic on 2, 4 pieces,
    at most the quadratic N = 2's rows: the affine storage fails, N = 2 is proved, N = 4
    is not tried and the note gives its rows. With a clock that advances 1000 s at every
    reading (a very slow machine) the result is the same gamma, pieces and degree."""
    system, controller = paper
    loop = SampledLoop.build(system, controller)
    aug = sg.augmented_loop(loop, system).nominal()
    cap = program_rows(aug, (2, 2), False)
    schedule = ((1, 4), (2, 2), (2, 4))
    fast = sg.sampled_gamma(system, controller, 0.08, robust=False, pieces=schedule, loop=loop, max_rows=cap)
    assert fast.gamma is not None and (fast.degree, fast.pieces) == (2, 2) and fast.rows == cap, fast.note
    ticks = iter(range(0, 10**9, 1000))
    monkeypatch.setattr(time, "process_time", lambda: float(next(ticks)))
    slow = sg.sampled_gamma(system, controller, 0.08, robust=False, pieces=schedule, loop=loop, max_rows=cap)
    assert (slow.gamma, slow.pieces, slow.degree, slow.rows) == (fast.gamma, fast.pieces, fast.degree, fast.rows)
    assert slow.seconds >= 1000.0  # the clock was read, and ignored


def test_rows_limit_names_the_entry_not_tried(paper: tuple[FTCSystem, Controller]) -> None:
    """A limit below the quadratic N = 2's rows: the affine N = 4 (not proved at h = 0.08)
    is the only one tried, and the note says which was not and why (its rows)."""
    system, controller = paper
    loop = SampledLoop.build(system, controller)
    aug = sg.augmented_loop(loop, system).nominal()
    rows = program_rows(aug, (2, 2), False)
    cert = sg.sampled_gamma(system, controller, 0.08, robust=False, pieces=((1, 4), (2, 2)), loop=loop,
                            max_rows=rows - 1)
    assert cert.gamma is None
    assert f"N = 2 not tried (its program would have {rows} rows, above {rows - 1})" in cert.note


def test_json_records_the_schedule(paper: tuple[FTCSystem, Controller]) -> None:
    """``sampled.*`` carries, for both certificates, the pieces, the storage degree, the
    program's rows, and the rows limit (h = 0.05: affine on 4 pieces)."""
    from ftc_verify.analysis.moments.sampled_gamma import sampled_performance

    system, controller = paper
    out = sampled_performance(system, controller, 0.05).to_dict()
    assert out["gamma_max_program_rows"] == sg.MAX_ROWS
    for kind in ("nominal", "robust"):
        assert out[f"{kind}_gamma"] is not None
        assert out[f"{kind}_gamma_pieces"] == 4 and out[f"{kind}_gamma_storage_degree"] == 1
        assert 0 < out[f"{kind}_gamma_program_rows"] <= sg.MAX_ROWS
    assert out["robust_gamma_program_rows"] > out["nominal_gamma_program_rows"]  # the channels' rows
