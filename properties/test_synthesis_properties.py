"""Synthesis properties (hypothesis, ``ci`` profile): every reported design passes the
core's independent verification; iterative never ends above its start; the
full-information optimum bounds FDI-only designs; relabelling modes changes nothing.

Solver: Clarabel (settings in ftc_verify.analysis.solvers). Tolerances: certified gammas carry the
re-centring ladder (``GAMMA_LADDER``, first step 1e-4 relative) and Clarabel's 1e-9
tolerances, so comparisons of two certified gammas allow 1e-3 relative.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, event, given, note, settings
from hypothesis import strategies as st

from ftc_verify.analysis.closedloop import closed_loop
from ftc_verify.analysis.lmi import block_specs, check_certificate, xy_block
from ftc_verify.model.system import FTCSystem, JointChain
from ftc_verify.synthesis.state_feedback import synthesize
from ftc_verify.testing import systems
from ftc_verify.testing.profiles import capped

from .replay import replay_on_failure

RTOL = 1e-3


def relabel(system: FTCSystem, perm: list[int]) -> FTCSystem:
    """The same plant with the modes listed in the order ``perm``."""
    P = np.eye(system.m)[perm]
    ch = system.chain
    chain = JointChain(P @ ch.alpha @ P.T, P @ ch.beta_min @ P.T, P @ ch.beta_max @ P.T, ch.fault_during_delay)
    return FTCSystem(system.name, tuple(system.modes[k] for k in perm), chain)


@settings(max_examples=5)
@given(system=systems(n=2, m=2, uncertain=None),
       method=st.sampled_from(["common", "full-info", "two-step"]), k_max=st.just(20.0))
def test_reported_designs_pass_independent_verification(system: FTCSystem, method: str, k_max: float | None) -> None:
    """Feasible => certified by the core: spectral test stable, the robust certificate
    rebuilt with numpy from the returned matrices passes, the certified gamma is at most
    the synthesis-side gamma, and the gain bound holds. Gains are bounded (k_max = 20):
    unbounded designs reach norms of 1e4 and more, whose verification LMIs are badly
    conditioned and took minutes per example (measured); the README reports them."""
    res = synthesize(system, method=method, gamma=20.0 if method == "two-step" else None, k_max=k_max, solver="clarabel")
    note(res.message)
    assume(res.feasible)
    assert res.controller is not None
    with replay_on_failure(system, res.controller):
        assert res.certified, res.message
        rep = res.report
        assert rep is not None and rep.mss.stable
        robust = rep.robust
        assert robust.P is not None and robust.gamma is not None
        loop = closed_loop(system, res.controller)
        cert = check_certificate(loop, robust.condition, robust.P, robust.multipliers, robust.gamma ** 2)
        assert cert.ok, cert.reason
        assert res.gamma_certified is not None and res.synthesis_gamma is not None
        assert res.gamma_certified <= res.synthesis_gamma * (1 + RTOL)
        if k_max is not None:
            assert max(np.linalg.norm(K, 2) for K in res.gains) <= k_max * (1 + 1e-6)


@pytest.mark.slow(6)  # seconds measured on 2 busy cores: scheduled first
@settings(max_examples=4)
@given(system=systems(n=(2, 3), m=2, uncertain=False))
def test_iterative_from_common_never_ends_above(system: FTCSystem) -> None:
    """Started from ``common``, ``iterative`` ends at or below it, with a non-increasing
    history of certified gammas."""
    start = synthesize(system, method="common", k_max=20.0, solver="clarabel")
    assume(start.certified and start.gamma_certified is not None)
    res = synthesize(system, method="iterative", k_max=20.0, solver="clarabel", start=list(start.gains), max_iter=2)
    controller = res.controller or start.controller
    assert controller is not None
    with replay_on_failure(system, controller):
        assert res.certified and res.gamma_certified is not None
        assert res.gamma_certified <= start.gamma_certified * (1 + RTOL)
        assert all(b <= a for a, b in zip(res.history, res.history[1:]))


@settings(max_examples=5)
@given(system=systems(n=(1, 3), m=2, uncertain=None), method=st.sampled_from(["common", "two-step"]))
def test_full_info_relaxes_every_fdi_only_design(system: FTCSystem, method: str) -> None:
    """The full-information LMI is a relaxation of FDI-only designs, so its optimum is at
    most their certified gamma: the Lemma 4.1 certificate (P, lambda, gamma) of FDI-mode
    gains K_j maps to a point of the full-information LMI (``lmi.xy_block``) at the same
    gamma -- X = P^-1, Y = K_j X, eps = 1/lambda_1, delta = 1/lambda_2 -- which must be
    negative definite (checked with numpy, relative to each block's scale; no solver).
    (Comparing with the solver's full-information *optimum* instead fails: Clarabel
    reports 'optimal' 1.5x to 4x too high when the feasible X are badly conditioned.)"""
    res = synthesize(system, method=method, gamma=20.0 if method == "two-step" else None, k_max=20.0, solver="clarabel")
    assume(res.certified and res.report is not None)
    assert res.report is not None and res.controller is not None
    robust = res.report.robust
    assert robust.P is not None and robust.gamma is not None
    loop = closed_loop(system, res.controller)
    with replay_on_failure(system, res.controller):
        for spec in block_specs(loop):
            mode = system.modes[spec.true]
            X = [np.linalg.inv(P) for P in robust.P]
            lam = list(robust.multipliers[spec.s]) if robust.multipliers is not None else []
            k = 0
            eps = delta = None
            if mode.A1 is not None and lam:
                eps, k = 1.0 / lam[k], k + 1
            if mode.B1 is not None and lam:
                delta = 1.0 / lam[k]
            if robust.multipliers is None:  # nominal certificate (no channels): drop them
                mode = type(mode)(mode.A, mode.B, mode.C, mode.D)
            M = xy_block(mode, X, spec.s, res.gains[spec.fdi] @ X[spec.s], eps, delta, robust.gamma ** 2, spec.q_row, np.block)
            ev = np.linalg.eigvalsh(0.5 * (M + M.T))
            assert ev[-1] < 1e-9 * max(1.0, float(np.max(np.abs(ev)))), (spec.label, ev[-1])


@pytest.mark.slow(9)  # seconds measured on 2 busy cores: scheduled first
@settings(max_examples=4)
@given(system=systems(n=(1, 2), m=3, uncertain=False),
       perm=st.permutations([0, 1, 2]))
def test_relabelling_modes_keeps_two_step_feasibility(system: FTCSystem, perm: list[int]) -> None:
    """Relabelling the modes leaves step 1 of two-step (a convex problem) with the same
    optimal margin; when both labellings succeed, each design meets the requested gamma as
    far as the code guarantees it (below). Their certified gammas are compared but not
    asserted equal: step 2 at ``gamma = 5`` is a feasibility problem, whose interior point
    the solver returns from step-1 data equal between labellings only to step 1's
    tolerance, and nothing bounds how the certified gamma of that point moves with them
    (a draw of the CI profile, step-1 margin below its cap, had certified gammas more than
    1e-3 apart; its 8-digit printout gives margins 0.3638668 and 0.3638723, certified gammas
    0.496715 and 0.496922); a difference above 1e-3 is an event.

    What ``synthesize(system, method="two-step", gamma=5.0)`` guarantees about 5 (derived
    from the code): ``state_feedback.two_step`` returns gains only when every FDI mode's
    step-2 gamma ``g_j`` (eq. 18 at step 1's ``P``, minimised by the solver) satisfies
    ``g_j <= 5 (1 + 1e-6)``, an exact float comparison, and ``synthesis_gamma`` is
    ``max_j g_j``: asserted exactly. ``gamma_certified`` is not that number: it is the
    core's own result on the gains (``analysis.lmi_analysis.hinf_gamma``, robust), a
    minimum over ``P`` and the multipliers by another solve, raised by a margin until its
    certificate passes in ball arithmetic (up to ``MARGIN_GAP`` = 1e-4 above its dual bound
    on the one-solve path, up to a factor 2 on ``GAMMA_LADDER``). That minimum is at most
    ``synthesis_gamma`` only up to both solvers' feasibility tolerances (step 2's point is
    feasible for the core's program only to the solver's tolerance), so the code
    guarantees no bound ``gamma_certified <= 5 c`` for any ``c`` derived from it; asserted
    instead what it does guarantee: the certificate behind each ``gamma_certified`` (its
    ``P`` in the conditioned coordinates and the similarity, the exact certificate of
    ``analysis.lmi_analysis``), rebuilt, passes at ``gamma_certified`` (ball arithmetic). A
    certified gamma above ``5 (1 + 1e-6)`` is recorded as an event.

    Whether step 2 then succeeds is decided by a solver at the boundary of its feasible
    set; the suite found draws where it differed between labellings inside one pytest
    process but not in another (order-dependent solver numerics), so a difference there is
    recorded as an event, not asserted. Where the cap binds, step 1's maximiser is not
    unique (``xy_design._xy_objective``): its point is chosen by a penalty of weight
    ``CENTRE_WEIGHT`` = 1e-6, within the solver's tolerance, and the gains follow it. A
    draw the suite makes under ``OPENBLAS_CORETYPE=Prescott`` (margin 1 in both
    labellings): X's largest eigenvalue 220 against 403, certified gammas 0.2553 against
    0.2780 (Haswell kernels), 0.2662 against 0.2600 (Prescott); a gamma difference there
    is recorded as an event."""
    from ftc_verify.synthesis.results import SolverCalls
    from ftc_verify.synthesis.xy_design import xy_solve

    relabelled = relabel(system, perm)
    a1 = xy_solve(system, "projected", 5.0, SolverCalls("clarabel"), None)
    b1 = xy_solve(relabelled, "projected", 5.0, SolverCalls("clarabel"), None)
    assert (a1 is None) == (b1 is None)
    if a1 is not None and b1 is not None:
        assert abs(a1["margin"] - b1["margin"]) <= 1e-3 * max(1.0, a1["margin"])
    a = synthesize(system, method="two-step", gamma=5.0, solver="clarabel")
    b = synthesize(relabelled, method="two-step", gamma=5.0, solver="clarabel")
    if a.feasible != b.feasible:
        event("two-step step 2 outcome differed between labellings")
    if a.certified and b.certified:
        assert a.gamma_certified is not None and b.gamma_certified is not None
        for res, plant in ((a, system), (b, relabelled)):
            assert res.synthesis_gamma is not None and res.synthesis_gamma <= 5.0 * (1 + 1e-6)
            robust, gamma = (res.report.robust if res.report is not None else None), res.gamma_certified
            assert robust is not None and robust.P_conditioned is not None and res.controller is not None
            assert gamma is not None
            cert = check_certificate(closed_loop(plant, res.controller), robust.condition, robust.P_conditioned,
                                     robust.multipliers, gamma ** 2, similarity=robust.similarity)
            assert cert.ok, cert.reason
            if gamma > 5.0 * (1 + 1e-6):
                event("two-step certified gamma above the requested 5 (the core's margin)")
        diff = abs(a.gamma_certified - b.gamma_certified) / max(a.gamma_certified, b.gamma_certified)
        note(f"certified gammas {a.gamma_certified:.9g} and {b.gamma_certified:.9g} (relative difference {diff:.2e})")
        if diff > RTOL:
            cap = a1 is None or a1["margin"] >= 1.0 - 1e-6
            event("two-step certified gammas differed by more than 1e-3 between labellings"
                  + (" (step-1 margin at its cap)" if cap else " (step 2 at gamma 5 is a feasibility problem)"))


def textbook_lqr(system: FTCSystem) -> list[np.ndarray] | None:
    """Per-mode LQR, ``Q = 10 I``, ``R = I``, written out as a user would (scipy), not
    through the project's ``starts`` module."""
    from scipy.linalg import solve_continuous_are

    gains = []
    for md in system.modes:
        n, nu = md.B.shape
        try:
            X = solve_continuous_are(md.A, md.B, 10.0 * np.eye(n), np.eye(nu))
        except (np.linalg.LinAlgError, ValueError):
            return None
        gains.append(-md.B.T @ X)
    return gains


@pytest.mark.slow(24)  # seconds measured on 2 busy cores: scheduled first
@capped(3, 30)  # ci: 3 examples (an iterative synthesis, 8 starts, each)
@given(system=systems(n=(2, 3), m=2, uncertain=None))
def test_iterative_never_loses_to_textbook_lqr(system: FTCSystem) -> None:
    """Where the textbook per-mode LQR gains are certified by the core (spectral test and
    robust gamma), ``iterative`` (no gain bound, as the LQR has none) returns certified
    gains whose robust gamma is at most the LQR's (1e-3 relative: two certified gammas)."""
    from ftc_verify.analysis.closedloop import state_feedback_loop
    from ftc_verify.analysis.lmi_analysis import hinf_gamma
    from ftc_verify.analysis.moments.stability import mean_square_stability

    lqr = textbook_lqr(system)
    assume(lqr is not None)
    loop = state_feedback_loop(system, lqr)
    assume(mean_square_stability(loop).stable)
    base = hinf_gamma(loop, robust=True, solver="clarabel")
    assume(base.certified and base.gamma is not None)
    event("textbook LQR certified")
    res = synthesize(system, method="iterative", solver="clarabel", max_iter=2)
    note(res.message)
    assert res.certified and res.gamma_certified is not None, res.message
    assert res.gamma_certified <= base.gamma * (1 + RTOL)
    won = [r for r in res.starts if r["name"] == res.start]
    assert len(won) == 1 and res.gamma_certified <= won[0]["gamma_certified"] * (1 + RTOL)
