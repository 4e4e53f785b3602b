"""Starts of the iterative method (ftc_verify.synthesis.starts) and the diagnosis when
nothing is certified: the LQR gain equals python-control's, the stationary distribution
is exact, the iterative method beats the textbook LQR on a plant with nearly parallel
input columns where two-step fails, never ends above its start, respects the gain bound,
and an unstabilisable plant is diagnosed as such (exit 1). Solver: Clarabel."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import cli_inprocess
import numpy as np
import pytest

from ftc_verify.analysis.closedloop import state_feedback_loop
from ftc_verify.analysis.lmi_analysis import hinf_gamma
from ftc_verify.model.files import load_system, save_system
from ftc_verify.model.system import FTCSystem
from ftc_verify.synthesis.starts import candidates, lqr_gain, stabilisability, stationary
from ftc_verify.synthesis.state_feedback import synthesize

ROOT = Path(__file__).resolve().parents[1]
CHAIN = dict(alpha=[[-0.5, 0.5], [1.0, -1.0]], beta_min=[[0.0, 2.0], [2.5, 0.0]], beta_max=[[0.0, 3.0], [3.5, 0.0]])
RTOL = 1e-3  # two certified gammas (Clarabel 1e-9, re-centring ladder 1e-4)


def nearly_parallel(seed: int = 1) -> FTCSystem:
    """A random 3-state, 2-mode plant whose two input columns are nearly parallel (1 %),
    mode 2 with 30 % actuator effectiveness: the case in which two-step found nothing."""
    rng = np.random.default_rng(seed)
    b = rng.normal(size=(3, 1))
    modes = []
    for i in range(2):
        B = np.hstack([b, b + 0.01 * rng.normal(size=(3, 1))]) * (1.0 if i == 0 else 0.3)
        modes.append(dict(A=rng.normal(size=(3, 3)), B=B, C=rng.normal(size=(1, 3)), D=rng.normal(size=(3, 1))))
    return FTCSystem.from_arrays(name=f"nearly-parallel-{seed}", modes=modes, **CHAIN)


def textbook(system: FTCSystem) -> list[np.ndarray]:
    from scipy.linalg import solve_continuous_are

    return [-md.B.T @ solve_continuous_are(md.A, md.B, 10 * np.eye(md.A.shape[0]), np.eye(md.B.shape[1]))
            for md in system.modes]


def test_lqr_gain_equals_python_control() -> None:
    import control

    A = np.array([[0.0, 1.0], [2.0, -1.0]])
    B = np.array([[0.0], [1.0]])
    K = lqr_gain(A, B, np.diag([3.0, 1.0]), np.array([[0.5]]))
    Kc, _, _ = control.lqr(A, B, np.diag([3.0, 1.0]), np.array([[0.5]]))
    assert K is not None
    np.testing.assert_allclose(K, -Kc, rtol=1e-10)
    assert lqr_gain(np.eye(2), np.zeros((2, 1)), np.eye(2), np.eye(1)) is None  # not stabilisable


def test_stationary_distribution() -> None:
    p = stationary(np.array([[-1.0, 1.0], [0.5, -0.5]]))
    np.testing.assert_allclose(p, [1 / 3, 2 / 3], rtol=1e-12)


def test_pbh_finds_the_uncontrollable_unstable_eigenvalue() -> None:
    modes = [dict(A=[[1.0, 0.0], [0.0, -1.0]], B=[[0.0], [k]], C=[[1.0, 1.0]], D=[[1.0], [0.0]]) for k in (1.0, 0.5)]
    rows = stabilisability(FTCSystem.from_arrays(name="u", modes=modes, **CHAIN))
    assert [r["stabilisable"] for r in rows] == [False, False]
    assert rows[0]["uncontrollable"] == [[1.0, 0.0]]
    paper = stabilisability(load_system(ROOT / "examples" / "paper.toml"))
    assert all(r["stabilisable"] for r in paper)


@pytest.mark.slow(5)  # seconds measured on 2 busy cores: scheduled first
def test_iterative_beats_the_textbook_lqr_where_two_step_fails() -> None:
    system = nearly_parallel()
    base = hinf_gamma(state_feedback_loop(system, textbook(system)), robust=True, solver="clarabel")
    assert base.certified and base.gamma is not None
    res = synthesize(system, method="iterative", solver="clarabel", max_iter=3)
    rows = {r["name"]: r for r in res.starts}
    assert rows["two-step"]["gamma_certified"] is None and rows["two-step"]["reason"]
    assert rows["lqr"]["gamma_certified"] == pytest.approx(base.gamma, rel=RTOL)
    assert res.certified and res.gamma_certified is not None
    assert res.gamma_certified <= base.gamma * (1 + RTOL)
    won = rows[res.start]
    assert res.gamma_certified <= won["gamma_certified"] * (1 + RTOL)  # never above its start
    assert res.history[0] == pytest.approx(won["gamma_certified"], rel=1e-12)
    assert all(b <= a for a, b in zip(res.history, res.history[1:]))
    d = res.to_dict()
    assert d["start"] == res.start and d["iterations"] == len(res.history) - 1 and len(d["starts"]) == 8


def test_starts_respect_the_gain_bound() -> None:
    system = nearly_parallel()
    k_max = 5.0
    for c in candidates(system, k_max, None):
        if c.gains is not None:
            assert max(np.linalg.norm(K, 2) for K in c.gains) <= k_max * (1 + 1e-12)
    scaled = [c.name for c in candidates(system, k_max, None) if c.note == "scaled to the gain bound"]
    assert "lqr" in scaled  # the textbook gains have norms of about 5 to 50
    res = synthesize(system, method="iterative", k_max=k_max, solver="clarabel", max_iter=2)
    assert res.certified and max(np.linalg.norm(K, 2) for K in res.gains) <= k_max * (1 + 1e-6)


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    """``ftc-verify ARGS`` in this process (``tests/cli_inprocess.py``: exit code, stdout and
    stderr as a subprocess gives them)."""
    return cli_inprocess.run_cli(args)


def test_unstabilisable_plant_is_diagnosed_exit_1(tmp_path: Path) -> None:
    modes = [dict(A=[[1.0, 0.0], [0.0, -1.0]], B=[[0.0], [k]], C=[[1.0, 1.0]], D=[[1.0], [0.0]]) for k in (1.0, 0.5)]
    path = tmp_path / "unstab.toml"
    save_system(FTCSystem.from_arrays(name="unstab", modes=modes, **CHAIN), path)
    out = _cli("synthesize", str(path), "--method", "iterative", "-o", str(tmp_path / "K.toml"), "--json")
    assert out.returncode == 1 and "Traceback" not in out.stderr, out.stderr
    d = json.loads(out.stdout)
    assert d["verdict"] == "NOT certified" and d["diagnosis"]["reason"] == "not stabilisable"
    assert [m["stabilisable"] for m in d["diagnosis"]["modes"]] == [False, False]
    assert not (tmp_path / "K.toml").exists()
    text = _cli("synthesize", str(path), "--method", "iterative", "-o", str(tmp_path / "K.toml"))
    assert text.returncode == 1 and "diagnosis: not stabilisable" in text.stdout and "PBH" in text.stdout


def test_gain_bound_too_small_is_diagnosed() -> None:
    """The paper's plant is open-loop unstable; with gains of norm 1e-3 nothing stabilises
    it: the diagnosis says so and gives the best spectral abscissa (positive)."""
    res = synthesize(load_system(ROOT / "examples" / "paper.toml"), method="iterative", k_max=1e-3, solver="clarabel")
    assert not res.certified and res.diagnosis is not None
    assert res.diagnosis["reason"] == "no certified controller"
    assert res.diagnosis["best_spectral_abscissa"] > 0 and "gain bound 0.001" in res.message
