"""With uncertainty channels Lemma 4.1's child starts once Theorem 3.2's child has its
answer (analysis.analyze._gamma_ahead and _after, issue 37 item 3): one core solves the two
programs one after the other while the other runs the spectral stage and the lower bounds;
the answers are those of the programs solved in this process, and a Theorem 3.2 child that
dies without an answer opens the gate too."""

from __future__ import annotations

import importlib
import json
import os
import time
from pathlib import Path
from typing import Any

import pytest

from ftc_verify.analysis.lmi_analysis import hinf_gamma
from ftc_verify.analysis.solvers import ForkedCall

analyze_module = importlib.import_module("ftc_verify.analysis.analyze")
pytestmark = pytest.mark.skipif(not hasattr(os, "fork"), reason="POSIX fork")


def test_lemma_4_1_starts_after_theorem_3_2_has_its_answer(paper_loop: Any, tmp_path: Path,
                                                            monkeypatch: pytest.MonkeyPatch) -> None:
    log = tmp_path / "log"

    def timed(loop: Any, **kwargs: Any) -> Any:
        start = time.perf_counter()
        result = hinf_gamma(loop, **kwargs)
        with log.open("a") as out:  # one line per call, from whichever process ran it
            out.write(json.dumps({"robust": kwargs["robust"], "pid": os.getpid(), "start": start,
                                  "end": time.perf_counter()}) + "\n")
        return result

    monkeypatch.setattr(analyze_module, "hinf_gamma", timed)
    assert paper_loop.uncertain
    rep = analyze_module.analyze(paper_loop, cross_validation=False)
    calls = {c["robust"]: c for c in map(json.loads, log.read_text().splitlines())}
    assert set(calls) == {False, True} and len({c["pid"] for c in calls.values()} | {os.getpid()}) == 3
    assert calls[True]["start"] >= calls[False]["end"]
    monkeypatch.undo()
    assert rep.robust.gamma == hinf_gamma(paper_loop, robust=True).gamma
    assert rep.nominal.gamma == hinf_gamma(paper_loop, robust=False).gamma


@pytest.mark.parametrize("lower_bounds", [True, False])
def test_gated_only_when_the_lower_bounds_run(paper_loop: Any, lower_bounds: bool,
                                             monkeypatch: pytest.MonkeyPatch) -> None:
    """Without the lower bounds (or above the size where they are computed) Lemma 4.1's
    solve is the longest chain and starts at once: no gate."""
    gates: list[bool] = []
    after = analyze_module._after

    def spy(gate: int | None, *args: Any) -> Any:
        gates.append(gate is not None)
        return after(gate, *args)

    monkeypatch.setattr(analyze_module, "_after", spy)
    rep = analyze_module.analyze(paper_loop, cross_validation=False, lower_bounds=lower_bounds)
    assert gates == [lower_bounds, False]  # Lemma 4.1's, then Theorem 3.2's (never gated)
    assert rep.robust.certified and analyze_module.within_solve_limit(paper_loop)
    assert (rep.robust_lower is not None) == lower_bounds


def test_a_killed_opener_opens_the_gate() -> None:
    gate, opener = os.pipe()
    try:
        waiting = ForkedCall(analyze_module._after(gate, opener, lambda: "ran"), "gated")
        holder = ForkedCall(analyze_module._after(None, gate, lambda: time.sleep(60), opener), "holder")
    finally:
        os.close(gate)
        os.close(opener)
    try:
        time.sleep(0.2)
        assert os.waitpid(waiting.pid, os.WNOHANG) == (0, 0)  # still at the gate
        start = time.perf_counter()
        holder.cancel()  # SIGKILL: its write end closes with it
        assert waiting.result() == "ran" and time.perf_counter() - start < 10.0
    finally:
        holder.cancel()
        waiting.cancel()
