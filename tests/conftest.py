"""Shared fixtures: example paths, the paper's system/gains/closed loop, and small
reference implementations written from READING-NOTES (independent of ftc_verify)."""

from __future__ import annotations

import fcntl
import json
import os
import signal
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from paper_run import PAPER_VERIFY_OPTIONS

from ftc_verify.analysis.closedloop import state_feedback_loop
from ftc_verify.model.system import FTCSystem
from ftc_verify.model.files import load_system
from ftc_verify.controllers.files import load_gains

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


# --------------------------------------------------------------------------- reference code
def ref_joint_generator(alpha, beta, fault_during_delay: bool = False) -> np.ndarray:
    """Joint (true, FDI) generator written directly from READING-NOTES.

    (i, i) -> (k, i) at alpha[i][k]; (i, j) -> (i, i) at beta[j][i]; in the named
    variant also (i, j) -> (k, j) at alpha[i][k] for i != j. Joint index s = i*m + j.
    """
    alpha = np.asarray(alpha, dtype=float)
    beta = np.asarray(beta, dtype=float)
    m = alpha.shape[0]
    idx = {(i, j): i * m + j for i in range(m) for j in range(m)}
    Q = np.zeros((m * m, m * m))
    for (i, j), s in idx.items():
        if i == j:
            for k in range(m):
                if k != i:
                    Q[s, idx[(k, i)]] += alpha[i][k]
        else:
            Q[s, idx[(i, i)]] += beta[j][i]
            if fault_during_delay:
                for k in range(m):
                    if k != i:
                        Q[s, idx[(k, j)]] += alpha[i][k]
    for s in range(m * m):
        Q[s, s] = -(Q[s].sum() - Q[s, s])
    return Q


def ref_second_moment_full(A_list, Q) -> np.ndarray:
    """Full (vec, not vech) second-moment generator: dX_s = A_s X_s + X_s A_s' + sum_t Q[t, s] X_t."""
    n = np.asarray(A_list[0]).shape[0]
    N = len(A_list)
    eye = np.eye(n)
    big = np.zeros((N * n * n, N * n * n))
    for s, A in enumerate(A_list):
        A = np.asarray(A, dtype=float)
        big[s * n * n:(s + 1) * n * n, s * n * n:(s + 1) * n * n] += np.kron(eye, A) + np.kron(A, eye)
        for t in range(N):
            big[s * n * n:(s + 1) * n * n, t * n * n:(t + 1) * n * n] += Q[t, s] * np.eye(n * n)
    return big


def ref_abscissa(M) -> float:
    return float(np.max(np.linalg.eigvals(M).real))


def ref_box_vertices(beta_min, beta_max):
    """Every vertex of the beta box (off-diagonal entries at min or max), possibly repeated."""
    beta_min = np.asarray(beta_min, dtype=float)
    beta_max = np.asarray(beta_max, dtype=float)
    m = beta_min.shape[0]
    pairs = [(j, i) for j in range(m) for i in range(m) if i != j]
    out = []
    for bits in range(2 ** len(pairs)):
        b = np.zeros((m, m))
        for k, (j, i) in enumerate(pairs):
            b[j, i] = beta_max[j, i] if (bits >> k) & 1 else beta_min[j, i]
        out.append(b)
    return out


@pytest.fixture(scope="session")
def ref():
    """Reference implementations (independent of the package)."""
    return SimpleNamespace(
        joint_generator=ref_joint_generator,
        second_moment_full=ref_second_moment_full,
        abscissa=ref_abscissa,
        box_vertices=ref_box_vertices,
    )


# --------------------------------------------------------------------------- examples
@pytest.fixture(scope="session")
def paper_path() -> Path:
    return EXAMPLES / "paper.toml"


@pytest.fixture(scope="session")
def paper_gains_path() -> Path:
    return EXAMPLES / "paper_gains.toml"


@pytest.fixture(scope="session")
def paper_system(paper_path) -> FTCSystem:
    return load_system(paper_path)


@pytest.fixture(scope="session")
def paper_gains(paper_gains_path):
    return load_gains(paper_gains_path)


@pytest.fixture(scope="session")
def paper_loop(paper_system, paper_gains):
    return state_feedback_loop(paper_system, paper_gains)


# --------------------------------------------------------------------------- small builders
def scalar_system(a, b, c=(1.0, 1.0), d=(1.0, 1.0), *, alpha, beta_min, beta_max, unc=None,
                  fault_during_delay=False) -> FTCSystem:
    """Two-or-more-mode scalar plant x' = a_i x + b_i u + d_i w, y = c_i x."""
    modes = []
    for k in range(len(a)):
        md = {"A": [[a[k]]], "B": [[b[k]]], "C": [[c[k]]], "D": [[d[k]]]}
        if unc is not None:
            md["A1"], md["A2"] = [[unc[0]]], [[unc[1]]]
        modes.append(md)
    return FTCSystem.from_arrays(name="scalar", modes=modes, alpha=alpha, beta_min=beta_min,
                                 beta_max=beta_max, fault_during_delay=fault_during_delay)


@pytest.fixture(scope="session")
def make_scalar_system():
    return scalar_system


# --------------------------------------------------------------------------- shared between workers
@pytest.fixture(scope="session")
def shared_tmp(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder every test process of this session sees (under pytest-xdist the parent of
    the workers' own temporary folders): for results computed once per session and shared
    under a lock (``tests/tutorials.py``)."""
    base = tmp_path_factory.getbasetemp()
    folder = (base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base) / "shared"
    folder.mkdir(exist_ok=True)
    return folder




@pytest.fixture(autouse=True, scope="session")
def _cross_check_modules_imported() -> None:
    """python-control (and the cross-check module) imported once per test process: every
    ``analyze`` and ``verify`` run in a test process (``main(argv)``, ``run_verify``) forks
    a cross-check child (:func:`ftc_verify.prestart.cross_check`) that imports them unless
    its parent has; imported here, each child finds them (about 1 s of CPU saved per run;
    the child still computes the cross-check). Subprocess runs of the CLI are unaffected."""
    import importlib

    from ftc_verify.prestart import CROSS_CHECK_MODULES

    for name in CROSS_CHECK_MODULES:
        importlib.import_module(name)


@pytest.fixture(autouse=True, scope="session")
def _sigint_as_at_a_terminal() -> None:
    """Python's SIGINT handler in every test process: a run started in the background by a
    non-interactive shell (``pytest ... &``) inherits SIGINT ignored, and so would every CLI
    the tests start, so the Ctrl-C tests (a SIGINT to the process group) would see it
    ignored -- as the command would be, correctly, in that shell."""
    if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)


@pytest.fixture(scope="session")
def paper_verify_run(shared_tmp: Path) -> SimpleNamespace:
    """``ftc-verify verify examples/paper.toml --gains examples/paper_gains.toml --paths 30
    --horizon 15 --step 0.01 --seed 3 --out report`` run once per session as a user runs it
    (a subprocess; under pytest-xdist once for all workers, under a lock), for the tests
    that check its report (``tests/test_cli_verify.py``, ``tests/test_sampled_gamma.py``),
    start from a passing run's folder (``tests/test_cli_contract.py``) or compare other runs
    with it (``tests/test_cluster.py``).
    ``returncode``, ``stdout``, ``stderr``; ``out`` the report folder (read or copy it, never
    write into it); ``folder`` the run's working folder (its ``TMPDIR`` is ``folder/.tmp``);
    ``cache`` its FMU cache (``FTC_VERIFY_CACHE``; the FMU's path there is in the report)."""
    folder = shared_tmp / "paper-verify"
    with open(shared_tmp / "paper-verify.lock", "a") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            if not (folder / "run.json").is_file():
                (folder / ".tmp").mkdir(parents=True, exist_ok=True)
                env = os.environ | {"TMPDIR": str(folder / ".tmp"), "FTC_VERIFY_CACHE": str(folder / "cache")}
                run = subprocess.run([sys.executable, "-m", "ftc_verify", "verify", str(EXAMPLES / "paper.toml"),
                                      "--gains", str(EXAMPLES / "paper_gains.toml"), *PAPER_VERIFY_OPTIONS,
                                      "--out", "report"], capture_output=True, text=True, timeout=600, cwd=folder,
                                     env=env)
                (folder / "run.json").write_text(json.dumps([run.returncode, run.stdout, run.stderr]))
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)
    code, stdout, stderr = json.loads((folder / "run.json").read_text())
    return SimpleNamespace(returncode=code, stdout=stdout, stderr=stderr, out=folder / "report", folder=folder,
                           cache=folder / "cache")
