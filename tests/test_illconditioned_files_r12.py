"""Accepted files of ill-conditioned identical-mode loops (found by an independent
check, round 12): ``analyze`` exited 4 ("internal error: LinAlgError") in the per-mode
python-control cross-check, where ``j omega I - A`` of a mode was singular in float64 at
``omega = 0``. The verdicts are checked against the closed loop formed from the decimals
as written, in rational arithmetic (every mode and gain of these files is the same, so
the loop is mean-square stable iff ``A + B K`` is Hurwitz)."""

from __future__ import annotations

import json
import tomllib
from fractions import Fraction
from pathlib import Path

import cli_inprocess
import numpy as np
import pytest

from ftc_verify.analysis.crossval import linf_norm

DATA = Path(__file__).resolve().parent / "data"


def _written_abscissa(system: Path, gains: Path, parse_float: type = Fraction) -> float:
    """The largest real part of the eigenvalues of ``A + B K`` from the files' decimals:
    the product and sum in fractions, the eigenvalues by python-flint at 600 bits
    (``parse_float=float``: from the floats nearest to the decimals instead, exactly)."""
    import flint

    def parse(path: Path) -> dict:
        return tomllib.loads(path.read_text(), parse_float=lambda text: Fraction(parse_float(text)))

    mode, gain = parse(system)["mode"][0], parse(gains)["gain"][0]["K"]
    A, B = mode["A"], mode["B"]
    n, m = len(A), len(gain)
    Acl = [[Fraction(A[i][j]) + sum(Fraction(B[i][k]) * Fraction(gain[k][j]) for k in range(m)) for j in range(n)]
           for i in range(n)]
    old = flint.ctx.prec
    flint.ctx.prec = 600
    try:
        M = flint.acb_mat([[flint.acb(flint.arb(flint.fmpq(x.numerator, x.denominator))) for x in row] for row in Acl])
        eigenvalues = M.eig()
        assert not any(e.real.contains(0) for e in eigenvalues)  # every sign decided at 600 bits
        return max(float(e.real.mid()) for e in eigenvalues)
    finally:
        flint.ctx.prec = old


@pytest.mark.parametrize("case", ["marg1323", "ident1210", "marg1302"])
def test_ill_conditioned_files_get_the_written_loops_verdict(case: str) -> None:
    system, gains = DATA / f"illcond_{case}.toml", DATA / f"illcond_{case}_K.toml"
    proc = cli_inprocess.run_cli(["analyze", str(system), "--gains", str(gains), "--no-lmi", "--json"])
    assert "internal error" not in proc.stderr and "Traceback" not in proc.stderr
    truth = _written_abscissa(system, gains)
    expected = "stable" if truth < 0 else "not stable"
    assert proc.returncode == (0 if expected == "stable" else 1), proc.stderr
    assert json.loads(proc.stdout)["mss"]["verdict"] == expected


@pytest.mark.parametrize("case", ["hg115", "hgr359"])
def test_the_verdict_is_the_decimals_not_their_nearest_floats(case: str) -> None:
    """High-gain loops (gains 1e7-1e8, no similarity; an independent check's hunt) whose
    abscissa, about 1e-9, has one sign for the decimals as written and the other for the
    nearest floats: the verdict is the decimals'."""
    system, gains = DATA / f"written_{case}.toml", DATA / f"written_{case}_K.toml"
    truth, rounded = _written_abscissa(system, gains), _written_abscissa(system, gains, float)
    assert (truth < 0) != (rounded < 0)  # the case discriminates
    proc = cli_inprocess.run_cli(["analyze", str(system), "--gains", str(gains), "--no-lmi", "--json"])
    assert json.loads(proc.stdout)["mss"]["verdict"] == ("stable" if truth < 0 else "not stable")
    assert proc.returncode == (0 if truth < 0 else 1)


def test_a_contradicted_float_estimate_is_labelled(monkeypatch: pytest.MonkeyPatch) -> None:
    """marg1302 (similarity of condition 2e11): proved stable; its float64 estimate of the
    abscissa was positive on one machine's LAPACK (+510.9) and negative on another
    (-1.88), so it is forced positive here: the line says it is contradicted."""
    from test_contradicted_estimate_lo13 import forced_estimate

    forced_estimate(monkeypatch, 510.9)
    proc = cli_inprocess.run_cli(["analyze", str(DATA / "illcond_marg1302.toml"), "--gains",
                                  str(DATA / "illcond_marg1302_K.toml"), "--no-lmi"])
    line = next(x for x in proc.stdout.splitlines() if "mean-square stability" in x)
    assert line.endswith(": stable") and "contradicted by the proof" in line


def test_linf_norm_of_a_matrix_singular_at_zero_frequency_is_infinite() -> None:
    """The float64 closed loop of ident1210 (similarity of condition 1e12): ``-A`` is
    singular to ``numpy.linalg.solve`` while no eigenvalue computed is within the axis
    threshold; the float norm is infinite, not a ``LinAlgError`` (the CLI test above
    exits 0 on this file either way)."""
    from ftc_verify.analysis.closedloop import closed_loop
    from ftc_verify.controllers.files import load_controller
    from ftc_verify.model.files import load_system

    loop = closed_loop(load_system(DATA / "illcond_ident1210.toml"), load_controller(DATA / "illcond_ident1210_K.toml"))
    A, B, C = loop.A[0], loop.Bw[0], loop.Cz[0]
    poles = np.linalg.eigvals(A)
    assert not np.any(np.abs(poles.real) <= 1e-12 * np.maximum(1.0, np.abs(poles)))
    try:  # singular to this LAPACK build (it was to OpenBLAS 0.3 here); another may factor it
        np.linalg.solve(-A, B)
    except np.linalg.LinAlgError:
        assert linf_norm(A, B, C) == np.inf
    else:
        assert linf_norm(A, B, C) > 0
