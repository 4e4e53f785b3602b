"""The convex designs of ftc_verify.synthesis.convex_designs and the ``best`` method.

The dilated block projects exactly onto xy_block (Finsler: ``R' D R = xy_block`` for any
slack, scalar and gain), the dilated and common-fdi designs respect the gain bound and are
certified on the paper's plant, ``best`` is never above any of its routes nor above
``iterative`` run alone, the true-mode reference matches the closed-form H-infinity norm
of an uncontrolled scalar plant, and the CLI runs ``best`` without ``--method``.
Solver: Clarabel. No randomness except the fixed seeds of the drawn matrices.
"""

from __future__ import annotations

import json
from pathlib import Path

import cli_inprocess
import numpy as np
import pytest
from session_cache import computed_once

from ftc_verify.analysis.closedloop import gain_loop
from ftc_verify.analysis.lmi import block_specs, dilated_block, xy_block
from ftc_verify.model.files import load_system
from ftc_verify.model.system import FTCSystem
from ftc_verify.synthesis.convex_designs import true_mode_reference
from ftc_verify.synthesis.results import SolverCalls
from ftc_verify.synthesis.state_feedback import synthesize

RTOL = 1e-3  # two certified gammas (Clarabel 1e-9, re-centring ladder 1e-4)


def _spd(rng: np.random.Generator, n: int) -> np.ndarray:
    M = rng.normal(size=(n, n))
    return M @ M.T + n * np.eye(n)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_dilated_block_projects_onto_xy_block(paper_system: FTCSystem, seed: int) -> None:
    """``R' D(X, G, Y = K G, tau) R = xy_block(X, Y = K X_s)`` with ``R = [[I, 0], [A_cl', H_K'], [0, I]]``
    for every block of the paper's plant and random ``X, G, K, tau`` (the He-term vanishes on range R)."""
    rng = np.random.default_rng(seed)
    sysm = paper_system
    n, nu = sysm.dims[0], sysm.dims[1]
    X = [_spd(rng, n) for _ in range(sysm.chain.n_states)]
    G = [rng.normal(size=(n, n)) for _ in range(sysm.m)]
    K = [rng.normal(size=(nu, n)) for _ in range(sysm.m)]
    tau, eps, dlt, g = float(rng.uniform(0.1, 2.0)), 0.7, 1.3, 2.0
    probe = gain_loop(sysm, [np.zeros((nu, n))] * sysm.m, "probe")
    for spec in block_specs(probe):
        md, j = sysm.modes[spec.true], spec.fdi
        D = dilated_block(md, X, G[j], spec.s, K[j] @ G[j], eps, dlt, g, spec.q_row, tau, np.block)
        L = xy_block(md, X, spec.s, K[j] @ X[spec.s], eps, dlt, g, spec.q_row, np.block)
        p = L.shape[0] - n
        R = np.zeros((2 * n + p, n + p))
        R[:n, :n] = np.eye(n)
        R[n:2 * n, :n] = (md.A + md.B @ K[j]).T
        b2 = md.A2.shape[0] + md.C.shape[0]  # rows x | A2 | C | B2 of xy_block
        R[n:2 * n, n + b2:n + b2 + md.B2.shape[0]] = (md.B2 @ K[j]).T
        R[2 * n:, n:] = np.eye(p)
        np.testing.assert_allclose(R.T @ D @ R, L, rtol=1e-12, atol=1e-9 * np.abs(L).max())


def test_dilated_and_common_fdi_certified_within_the_bound(paper_system: FTCSystem) -> None:
    """Both designs give FDI-mode gains within ``--k-max`` that the core certifies; at the
    tight bound 5 the common-X designs are infeasible and the dilated one is not."""
    for method, k_max in (("dilated", 5.0), ("common-fdi", 10.0), ("dilated", 10.0)):
        res = synthesize(paper_system, method=method, k_max=k_max, solver="clarabel")
        assert res.certified, res.message
        assert len(res.gains) == paper_system.m
        assert max(np.linalg.norm(K, 2) for K in res.gains) <= k_max * (1 + 1e-6)
    assert not synthesize(paper_system, method="common-fdi", k_max=5.0, solver="clarabel").feasible


@pytest.fixture(scope="module")
def paper_system_module() -> FTCSystem:
    return load_system(Path(__file__).resolve().parents[1] / "examples" / "paper.toml")


@pytest.fixture(scope="module")
def best_paper(shared_tmp: Path, paper_path: Path) -> tuple[int, dict, Path]:
    """``synthesize examples/paper.toml --k-max 30 -o K.toml --json`` (no ``--method``: the
    ``best`` route) run once per session, in a test process (``tests/cli_inprocess.py``;
    ``tests/session_cache.py``), for the tests of the CLI default and of ``best``'s rows
    (its JSON is ``SynthesisResult.to_dict``): exit code, JSON, the gains file."""
    def run(folder: Path) -> tuple[int, dict, Path]:
        proc = cli_inprocess.run_cli(["synthesize", str(paper_path), "--k-max", "30", "-o", "K.toml", "--json"],
                                     folder)
        assert proc.returncode == 0, proc.stderr
        return proc.returncode, json.loads(proc.stdout), folder / "K.toml"

    return computed_once(shared_tmp, "convex-best-paper", run)


@pytest.mark.slow(7)  # seconds on 2 busy cores (--durations at load 9, / 4): scheduled first
def test_best_is_never_above_its_routes(best_paper, paper_system_module: FTCSystem) -> None:  # type: ignore[no-untyped-def]
    """``best``: certified, every route a row with seconds, the result the smallest certified
    row, at most the ``iterative`` method run alone, and the reference line present."""
    _, res, _ = best_paper
    assert res["method"] == "best" and res["certified"]
    names = [r["name"] for r in res["starts"]]
    for route in ("two-step", "common", "common-fdi", "dilated", "descent from common"):
        assert route in names
    certified = [r["gamma_certified"] for r in res["starts"] if r["gamma_certified"] is not None]
    assert all(r["seconds"] is not None and r["seconds"] >= 0 for r in res["starts"])
    assert res["gamma_certified"] <= min(certified) * (1 + RTOL)
    alone = synthesize(paper_system_module, method="iterative", k_max=30.0, solver="clarabel")
    assert res["gamma_certified"] <= alone.gamma_certified * (1 + RTOL)
    assert max(np.linalg.norm(np.array(K), 2) for K in res["gains"]) <= 30.0 * (1 + 1e-6)
    ref = res["reference"]
    assert ref["name"].startswith("true-mode") and ref["lmi_gamma"] is not None


def test_true_mode_reference_closed_form() -> None:
    """Without actuation (B = 0) and identical scalar modes, the true-mode design's gamma is
    the H-infinity norm |c d| / |a| of the plant (the LMI is exact there)."""
    a, c, d = -2.0, 3.0, 0.5
    mode = dict(A=[[a]], B=[[0.0]], C=[[c]], D=[[d]])
    sysm = FTCSystem.from_arrays(name="scalar", modes=[mode, mode], alpha=[[-1.0, 1.0], [2.0, -2.0]],
                                 beta_min=[[0.0, 1.0], [1.0, 0.0]], beta_max=[[0.0, 2.0], [2.0, 0.0]])
    ref = true_mode_reference(sysm, SolverCalls("clarabel"))
    assert ref is not None
    assert ref["gamma"] == pytest.approx(abs(c * d / a), rel=1e-4)


def test_cli_default_is_best(best_paper) -> None:  # type: ignore[no-untyped-def]
    """``synthesize SYSTEM -o K.toml`` without ``--method``: the best route, exit 0, file
    written (the run of the ``best_paper`` fixture, whose rows the test above checks)."""
    code, d, out = best_paper
    assert code == 0
    assert d["method"] == "best" and d["certified"] and out.exists()
    assert d["reference"]["gamma_certified"] is None or d["reference"]["gamma_certified"] > 0


def test_best_on_an_unstabilisable_plant_is_diagnosed() -> None:
    """No route can certify (mode 1's unstable eigenvalue 1 is uncontrollable in both
    modes): not certified, every route a row, the diagnosis names the PBH failure."""
    chain = dict(alpha=[[-0.5, 0.5], [1.0, -1.0]], beta_min=[[0.0, 2.0], [2.5, 0.0]],
                 beta_max=[[0.0, 3.0], [3.5, 0.0]])
    modes = [dict(A=[[1.0, 0.0], [0.0, -1.0]], B=[[0.0], [k]], C=[[1.0, 1.0]], D=[[1.0], [0.0]]) for k in (1.0, 0.5)]
    res = synthesize(FTCSystem.from_arrays(name="unstab", modes=modes, **chain), solver="clarabel")
    assert not res.certified and res.diagnosis is not None
    assert res.diagnosis["reason"] == "not stabilisable"
    assert {"common-fdi", "dilated", "two-step"} <= {r["name"] for r in res.starts}
    assert all(r["gamma_certified"] is None for r in res.starts)
