"""Verification properties (hypothesis, ``ci`` profile): the certified gamma bounds the
exact expected energy and every disturbance the worst-case search finds; the simulated
attenuation at the simulation step stays below the sampled loop's certificate at that
step; Monte Carlo agrees with the exact moments; python-control agrees on every frozen mode.

Solver: Clarabel. Statistical property: the Monte Carlo check uses a two-sided Student-t
interval at alpha = 1e-6 per side, so each example fails falsely with probability about
2e-6 (CLT approximation); the ``ci`` profile is derandomized, so CI runs are repeatable.
"""

from __future__ import annotations

import numpy as np
from hypothesis import assume, event, given, note, settings
from hypothesis import strategies as st

from ftc_verify.analysis.crossval import cross_validate
from ftc_verify.analysis.lmi_analysis import hinf_gamma
from ftc_verify.verification.montecarlo import estimate
from ftc_verify.analysis.moments.energy import exact_energy, worst_case_disturbance
from ftc_verify.analysis.moments.sampled_gamma import sampled_gamma
from ftc_verify.simulation.paths import sample_paths
from ftc_verify.simulation.reference import energies_reference
from ftc_verify.simulation.delta import constant_delta_loops

from ftc_verify.testing import DrawnLoop, stable_loops

from .replay import replay_on_failure

SLACK = 1e-6  # relative: the certified gamma is strictly feasible, the energies exact to rounding


@settings(max_examples=8)
@given(drawn=stable_loops(n=(1, 2), m=2, nw=1, uncertain=None))
def test_exact_energy_below_certified_gamma(drawn: DrawnLoop) -> None:
    """E||z||^2 <= gamma^2 ||w||^2 from zero initial state, at every beta vertex, for the
    paper's disturbance on [0, inf): nominal gamma for Delta = 0, robust gamma for a
    constant Delta = +-E (the certificate covers every ||Delta|| <= 1)."""
    loop = drawn.loop
    nominal = hinf_gamma(loop, robust=False)
    assume(nominal.certified and nominal.gamma is not None)
    cases = [(loop.nominal(), nominal.gamma)]
    if loop.uncertain:
        robust = hinf_gamma(loop, robust=True)
        assume(robust.certified and robust.gamma is not None)
        cases += [(dl, robust.gamma) for _, dl in constant_delta_loops(drawn.system, loop)[1:]]
    with replay_on_failure(drawn.system, drawn.controller):
        for case, gamma in cases:
            for beta in drawn.system.chain.vertices():
                e = exact_energy(case, beta=beta)
                note(f"ratio {e.ratio:.6g} vs gamma^2 {gamma ** 2:.6g}")
                assert e.ratio <= gamma ** 2 * (1 + SLACK)


@settings(max_examples=6)
@given(drawn=stable_loops(n=(1, 2), m=2, nw=1, uncertain=False))
def test_worst_case_never_exceeds_certified_gamma(drawn: DrawnLoop) -> None:
    """The worst disturbance found (a lower bound of the stochastic gain) stays below the
    certified nominal gamma at every beta vertex."""
    nominal = hinf_gamma(drawn.loop, robust=False)
    assume(nominal.certified and nominal.gamma is not None)
    with replay_on_failure(drawn.system, drawn.controller):
        for beta in drawn.system.chain.vertices():
            wc = worst_case_disturbance(drawn.loop, beta=beta, horizon=10.0, pieces=20)
            assert wc.gain <= nominal.gamma * (1 + SLACK)


@settings(max_examples=4)
@given(drawn=stable_loops(n=(1, 2), m=2, nw=1, uncertain=False),
       seed=st.integers(0, 2**32 - 1))
def test_monte_carlo_agrees_with_exact_moments(drawn: DrawnLoop, seed: int) -> None:
    """3000 reference-simulator paths (beta at the box centre, horizon 6, Richardson on
    h = 0.01 / 0.005 to cancel the sample-and-hold bias): the exact expected energy lies
    in the Monte Carlo interval (alpha = 1e-6 per side)."""
    system, controller = drawn.system, drawn.controller
    beta, T = system.chain.midpoint(), 6.0
    exact = exact_energy(drawn.loop.nominal(), beta=beta, horizon=T)
    assume(exact.y_energy > 1e-8)
    paths = sample_paths(system.chain, T, 3000, seed, beta=beta)
    y1, w = energies_reference(system, controller, paths, step=0.01)
    y2, _ = energies_reference(system, controller, paths, step=0.005)
    est = estimate(2.0 * y2 - y1, w, alpha=1e-6, seed=seed)
    lo, hi = est.lower_bound * est.w_energy, est.upper_bound * est.w_energy
    note(f"exact {exact.y_energy:.6g}, interval [{lo:.6g}, {hi:.6g}]")
    with replay_on_failure(system, controller):
        # O(h^2) left after Richardson: allow 0.5 % of the value on top of the interval
        assert lo - 5e-3 * exact.y_energy <= exact.y_energy <= hi + 5e-3 * exact.y_energy


@settings(max_examples=4)
@given(drawn=stable_loops(n=(1, 2), m=2, nw=1, uncertain=False, period=(5e-3, 0.05)),
       seed=st.integers(0, 2**32 - 1))
def test_simulated_attenuation_below_the_sampled_certificate(drawn: DrawnLoop, seed: int) -> None:
    """The attenuation the simulator measures at its step ``h`` (the drawn controller
    period: the controller sampled every ``h``, its output held) stays below the sampled
    loop's proved gain at ``h`` (:mod:`ftc_verify.analysis.moments.sampled_gamma`, which
    includes the behaviour between samples): 1000 paths at the box centre, horizon 6, the
    Monte Carlo's lower bound of E||y||^2 / E||w||^2 (one-sided, alpha = 1e-6: false
    failure about 1e-6 per example) at most gamma^2, plus 1 % for the grid's quadrature."""
    system, controller = drawn.system, drawn.controller
    h = controller.period
    assert h is not None
    cert = sampled_gamma(system, controller, h, robust=False)
    assume(cert.gamma is not None)
    assert cert.gamma is not None
    paths = sample_paths(system.chain, 6.0, 1000, seed, beta=system.chain.midpoint())
    y, w = energies_reference(system, controller, paths, step=h)
    est = estimate(y, w, alpha=1e-6, seed=seed)
    note(f"h {h:.4g}: Monte Carlo ratio >= {est.lower_bound:.6g} vs gamma^2 {cert.gamma ** 2:.6g}")
    with replay_on_failure(system, controller):
        assert est.lower_bound <= cert.gamma ** 2 * 1.01


@settings(max_examples=8)
@given(drawn=stable_loops(n=(1, 3), m=(2, 3), uncertain=None))
def test_python_control_agrees_per_mode(drawn: DrawnLoop) -> None:
    """python-control's poles match ours on every frozen joint mode, and so do its
    L-infinity norms whenever it returns one. (This property found python-control 0.10.2's
    ``norm(sys, 'inf', method='scipy')`` raising ``LinAlgError: Singular matrix`` on a
    stable first-order mode; ``cross_validate`` reports such a case as a disagreement,
    and here it is recorded as an event.)"""
    checks = cross_validate(drawn.loop)
    with replay_on_failure(drawn.system, drawn.controller):
        assert len(checks) == drawn.system.m ** 2
        for c in checks:
            assert c.poles.shape == c.control_poles.shape
            assert np.allclose(np.sort_complex(c.poles), np.sort_complex(c.control_poles), rtol=1e-8, atol=1e-10)
            if "control.norm raised" in c.detail:
                event("python-control's norm raised")
                assert not c.agree  # reported, never hidden
                continue
            assert c.agree, c.detail
