"""``mss.spectral_abscissa_contradicted``: the JSON says what the summary's "contradicted by
the proof" says -- the float64 estimate of the spectral abscissa has the sign the proved
verdict rules out (:attr:`ftc_verify.analysis.moments.stability.MSSResult.spectral_abscissa_contradicted`).

On round 12's ill-conditioned files (``tests/test_illconditioned_files_r12.py``, whose
verdicts that file checks against the loops as written) the flag follows the estimate,
whose sign there depends on the machine's LAPACK; with the estimate forced positive,
``illcond_marg1302`` is proved stable and flagged. On the paper's example it is false in
``analyze --json`` and in ``verify``'s ``report.json``.
"""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import cli_inprocess
import numpy as np
import pytest

from ftc_verify.analysis.moments.stability import MSSResult

DATA = Path(__file__).resolve().parent / "data"
EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


@pytest.mark.parametrize(("verdict", "estimate", "contradicted"), [
    ("stable", -1.0, False), ("stable", 0.0, True), ("stable", 510.9, True),
    ("not stable", 1e-10, False), ("not stable", 0.0, False), ("not stable", -1e-10, True),
    ("undecided", -1.0, False), ("undecided", 1.0, False), ("stable", float("nan"), False),
])
def test_the_flag_is_the_estimates_sign_against_the_verdict(verdict: str, estimate: float,
                                                            contradicted: bool) -> None:
    """Mean-square stable means an abscissa below 0, not stable one at or above 0; an
    undecided verdict contradicts nothing, nor does a NaN estimate."""
    mss = MSSResult(estimate, np.zeros((2, 2)), 4, True, verdict=verdict)
    assert mss.spectral_abscissa_contradicted is contradicted
    assert mss.to_dict()["spectral_abscissa_contradicted"] is contradicted


@pytest.mark.parametrize("case", ["illcond_marg1302", "illcond_marg1323", "illcond_ident1210"])
def test_analyze_json_flags_the_contradicted_estimate_as_the_text_does(case: str) -> None:
    """``analyze --json`` and the text output of the same file say the same, and the flag
    is the estimate's sign against the verdict. Whether float64's estimate is contradicted
    on these files depends on the machine's LAPACK (``illcond_marg1302``: +510.9 on one,
    -1.88 on another; proved stable either way): the case below forces it."""
    args = ["analyze", str(DATA / f"{case}.toml"), "--gains", str(DATA / f"{case}_K.toml"), "--no-lmi"]
    mss = json.loads(cli_inprocess.run_cli([*args, "--json"]).stdout)["mss"]
    estimate, verdict = mss["spectral_abscissa"], mss["verdict"]
    assert mss["spectral_abscissa_contradicted"] is ((verdict == "stable" and estimate >= 0)
                                                     or (verdict == "not stable" and estimate < 0))
    line = next(x for x in cli_inprocess.run_cli(args).stdout.splitlines() if "mean-square stability" in x)
    assert ("contradicted by the proof" in line) is mss["spectral_abscissa_contradicted"]


def forced_estimate(monkeypatch: pytest.MonkeyPatch, value: float) -> None:
    """Every float64 abscissa of the vertex search (and of a point proof's estimate) is
    ``value``: the dense eigenvalues return it, the shift test and the near search decline."""
    from ftc_verify.analysis.moments import stability

    monkeypatch.setattr(stability, "spectral_abscissa", lambda *args, **kwargs: value)
    monkeypatch.setattr(stability, "abscissa_near", lambda *args, **kwargs: None)
    monkeypatch.setattr(stability, "abscissa_below", lambda *args, **kwargs: False)


def test_a_forced_contradiction_is_flagged_in_json_and_text(monkeypatch: pytest.MonkeyPatch) -> None:
    """``illcond_marg1302`` (written abscissa -0.457, proved stable) with every float64
    estimate +510.9: still proved stable, the JSON flag true and the text labelled."""
    forced_estimate(monkeypatch, 510.9)
    args = ["analyze", str(DATA / "illcond_marg1302.toml"), "--gains", str(DATA / "illcond_marg1302_K.toml"), "--no-lmi"]
    mss = json.loads(cli_inprocess.run_cli([*args, "--json"]).stdout)["mss"]
    assert mss["verdict"] == "stable" and mss["spectral_abscissa"] == 510.9 and mss["spectral_abscissa_contradicted"]
    line = next(x for x in cli_inprocess.run_cli(args).stdout.splitlines() if "mean-square stability" in x)
    assert line.endswith(": stable") and "contradicted by the proof" in line


def test_the_paper_example_is_not_contradicted(paper_verify_run: SimpleNamespace) -> None:
    """The paper's gains: false in ``analyze --json`` (LMIs included) and in ``report.json``."""
    proc = cli_inprocess.run_cli(["analyze", str(EXAMPLES / "paper.toml"), "--gains",
                                  str(EXAMPLES / "paper_gains.toml"), "--json"])
    mss = json.loads(proc.stdout)["mss"]
    assert mss["verdict"] == "stable" and mss["spectral_abscissa_contradicted"] is False
    report = json.loads((paper_verify_run.out / "report.json").read_text())
    assert report["analysis"]["mss"]["spectral_abscissa_contradicted"] is False
