"""``synthesize --gamma G`` with a large G (independent check, finding 02).

Feasibility in gamma is monotone: a design LMI feasible at gamma' is feasible at every
G >= gamma', so a request for a large G must not fail where a smaller one succeeds. Posed
with ``g = G**2`` on the diagonal, Clarabel called the feasible common LMI of the paper's
example infeasible at 1e6 and panicked at 1e16 (its Rust backtrace on the terminal, the
panic read as infeasibility); 1e155 overflowed ``G**2`` (exit 4). Now a level is posed at
``D / G`` with ``g <= 1`` (:func:`~ftc_verify.synthesis.xy_design.scaled_disturbance`),
a panic's output is held off the terminal and reported as a solver failure, and a
``--gamma`` above :data:`~ftc_verify.limits.GAMMA_MAX` is refused at parse time.
"""

from __future__ import annotations

import os
from pathlib import Path

import cli_inprocess
import numpy as np
import pytest

from ftc_verify.analysis import solvers
from ftc_verify.analysis.solvers import SolveOutcome
from ftc_verify.cli.common import gamma_level
from ftc_verify.errors import ValidationError
from ftc_verify.limits import GAMMA_MAX
from ftc_verify.model.files import load_system
from ftc_verify.synthesis.results import SolverCalls
from ftc_verify.synthesis.convex_designs import convex_gains
from ftc_verify.synthesis.state_feedback import Descent, synthesize, two_step
from ftc_verify.synthesis.xy_design import scaled_disturbance, xy_solve, xy_solver

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "examples" / "paper.toml"


@pytest.mark.parametrize("kind", ["common", "full-info", "projected"])
def test_a_design_lmi_feasible_at_1e3_stays_feasible_at_every_larger_gamma(paper_system, kind):
    calls = SolverCalls("clarabel")
    assert xy_solve(paper_system, kind, 1e3, calls, None) is not None
    for gamma in (1e6, 1e16, GAMMA_MAX):
        sol = xy_solve(paper_system, kind, gamma, calls, None)
        assert sol is not None, (kind, gamma, calls.outcomes[-1])
        assert sol["gamma"] == gamma


def test_common_with_a_gain_bound_is_certified_at_a_large_gamma(paper_system):
    """The audit's ``--method common --gamma 1e6 --k-max 30`` (minimising certifies 0.36)."""
    res = synthesize(paper_system, method="common", gamma=1e6, k_max=30.0)
    assert res.feasible and res.report is not None and res.report.robust.certified
    assert res.report.robust.gamma <= 1e6


@pytest.mark.parametrize("gamma", [1e6, GAMMA_MAX])
def test_two_step_certified_at_1e3_is_certified_at_a_larger_gamma(paper_system, gamma):
    for level in (1e3, gamma):
        res = synthesize(paper_system, method="two-step", gamma=level)
        assert res.feasible, (level, res.message)
        assert res.report is not None and res.report.certified_stable and res.report.robust.certified
        assert res.report.robust.gamma <= level


def test_two_step_never_fails_at_a_larger_gamma_on_a_badly_scaled_system(paper_system):
    """The paper's example with ``D`` times 1e6 (review of fixb): step 1's capped margin
    is not invariant under the scaling of a level, and step 2 failed at 3e3 to 1e5 after
    succeeding at 1e3; a failed level is now halved, so on this grid every G above the
    first success succeeds, with gains achieving a level at most G that the message names.
    (Not every G does: only the levels ``G / 2^k`` are tried, and with ``D`` times 1e3
    two-step fails at 2.735 and succeeds at 2 and 3; the second review.)"""
    big = scaled_disturbance(paper_system, 1e-6)
    succeeded = None
    for G in (1e3, 3e3, 1e4, 3e4, 1e5, 1e6, 1e8):
        res = synthesize(big, method="two-step", gamma=G)
        if succeeded is not None:
            assert res.feasible, (G, succeeded, res.message)
        if res.feasible:
            succeeded = succeeded or G
            assert res.synthesis_gamma is not None and res.synthesis_gamma <= G * (1 + 1e-6), res.message
            used = float(res.message.split("two-step succeeded at gamma ")[1].split()[0])
            assert res.synthesis_gamma <= used * (1 + 1e-6) and used <= G
            assert (used < G) == (f"below the requested {G:.6g} " in res.message), res.message
    assert succeeded == 1e3


def _failing_after(monkeypatch, good: int) -> None:
    """Clarabel raises from its ``good + 1``-th call on (as a caught panic does)."""
    real, seen = solvers.solve_clarabel, []

    def solve(problem, settings):
        seen.append(1)
        if len(seen) > good:
            raise RuntimeError("simulated solver failure")
        return real(problem, settings)
    monkeypatch.setattr(solvers, "solve_clarabel", solve)


def test_a_solver_failure_is_never_reported_as_infeasible(paper_system, monkeypatch):
    """Review of fixb: step 2 printed ``solver status error`` for a panic, and ``dilated``
    said "infeasible for every tau" whatever the statuses."""
    calls = SolverCalls("clarabel")
    step1_at = xy_solver(paper_system, "projected", calls, None)
    _failing_after(monkeypatch, 1)  # step 1 solves, every later call fails
    gains, _, msg = two_step(paper_system, 1e3, calls, None, step1_at)
    assert gains is None and "infeasible" not in msg, msg
    assert msg.startswith("step 2 (eq. 18) failed for FDI mode 1 at gamma 1000 (not solved (solver failure: ")
    assert "step 1 (eq. 17) not solved (solver failure" in msg  # the halved level: not a proof of infeasibility
    _failing_after(monkeypatch, 0)
    gains, _, msg = convex_gains(paper_system, "dilated", SolverCalls("clarabel"), None)
    assert gains is None and "infeasible for every" not in msg and "solver failure" in msg, msg
    assert "not solved for any tau" in msg and "(0 of " in msg


def test_descent_results_compare_without_raising(paper_system):
    one, two = (Descent([np.eye(2), np.eye(2)], [1.0], "", None) for _ in range(2))  # type: ignore[arg-type]
    assert one == one and one != two


def test_a_gamma_whose_square_overflows_is_refused_at_parse_time(tmp_path):
    assert gamma_level("1e150") == GAMMA_MAX
    out = tmp_path / "K.toml"
    for args in (["synthesize", str(PAPER), "--gamma", "1e155", "-o", str(out)],
                 ["synthesize", str(PAPER), "--method", "common", "--gamma", "1e155", "-o", str(out)],
                 ["verify", str(PAPER), "--gamma", "1e300"]):
        proc = cli_inprocess.run_cli(args)
        assert proc.returncode == 2, (args, proc.stderr)
        assert "--gamma" in proc.stderr and args[args.index("--gamma") + 1] in proc.stderr
        assert "1e+150" in proc.stderr and "Traceback" not in proc.stderr and proc.stderr.count("\n") == 1
    assert not out.exists()
    with pytest.raises(ValidationError, match="gamma"):
        synthesize(load_system(PAPER), method="common", gamma=1e155)


def test_no_rust_panic_reaches_the_terminal_at_gamma_1e16(tmp_path):
    proc = cli_inprocess.run_cli(["synthesize", str(PAPER), "--method", "common", "--gamma", "1e16",
                                  "-o", str(tmp_path / "K.toml")])
    assert proc.returncode in (0, 1), proc.stderr
    assert "panicked" not in proc.stderr and "backtrace" not in proc.stderr
    assert "common LMI solved at gamma 1e+16" in proc.stdout


class PanicException(BaseException):
    """Named like pyo3's panic, which is a ``BaseException``."""


def test_a_panic_is_held_off_stderr_and_reported_as_a_solver_failure(paper_system, monkeypatch, capfd):
    """Rust prints a panic on file descriptor 2 before pyo3 raises it; other output passes."""
    def panic(*_):
        os.write(2, b"thread '<unnamed>' panicked at src/algebra/sparsevector/mod.rs:73:14:\n")
        raise PanicException("index out of bounds: the len is 77 but the index is 18446744073709551615")

    monkeypatch.setattr(solvers, "solve_clarabel", panic)
    res = synthesize(paper_system, method="common", gamma=1e6)
    assert not res.feasible
    assert "solver failure: clarabel raised PanicException: index out of bounds" in res.message
    assert "infeasible" not in res.message
    assert "panicked" not in capfd.readouterr().err

    def talk(*_):
        os.write(2, b"a solver's note\n")
        raise RuntimeError("no point")

    monkeypatch.setattr(solvers, "solve_clarabel", talk)
    res = synthesize(paper_system, method="two-step", gamma=1e6)
    assert "solver failure: clarabel raised RuntimeError: no point" in res.message
    assert "a solver's note" in capfd.readouterr().err


def test_unsolved_says_infeasible_only_when_the_solver_did():
    calls = SolverCalls("clarabel")
    for status, expected in (("infeasible", "infeasible"), ("optimal", "without a strictly feasible point"),
                             ("error", "not solved (solver failure: clarabel status NumericalError)")):
        calls.outcomes.append(SolveOutcome("clarabel", status, 0.0,
                                           "clarabel status NumericalError" if status == "error" else ""))
        assert calls.unsolved() == expected
    calls.outcomes.append(SolveOutcome("scs", "unbounded", 0.0))
    assert calls.unsolved() == "not solved (solver failure: scs status unbounded)"
