"""The hinf route of output feedback (ftc_verify.synthesis.hinf_descent).

The dual-based gradient of the bounded-real level agrees with central differences, the
level equals the core's certified nominal gamma for the same controller, and the route
started at a planted certified controller returns a certified controller whose gamma is
at most the planted one, within the gain bound. Solver: Clarabel; matrices from fixed
seeds (no statistical test).
"""

from __future__ import annotations

import numpy as np
import pytest

from ftc_verify.controllers.controller import Controller
from ftc_verify.model.system import FTCSystem
from ftc_verify.synthesis.descent import accepted_gamma
from ftc_verify.synthesis.hinf_descent import NominalGamma, hinf_route
from ftc_verify.synthesis.of_blocks import controller_blocks
from ftc_verify.synthesis.results import SolverCalls, verify_controller

CHAIN = dict(alpha=[[-0.5, 0.5], [1.0, -1.0]], beta_min=[[0.0, 2.0], [2.5, 0.0]], beta_max=[[0.0, 3.0], [3.5, 0.0]])


def planted(seed: int) -> tuple[FTCSystem, Controller]:
    """A 2-state, 2-mode plant with one measured output and a first-order controller,
    both shifted by ``-(mu + 0.3) I`` so that every pair's loop is stable with margin."""
    from ftc_verify.analysis.closedloop import closed_loop

    rng = np.random.default_rng(seed)
    A, B, Cy = rng.normal(size=(2, 2)), rng.normal(size=(2, 1)), rng.normal(size=(1, 2))
    C, D = rng.normal(size=(1, 2)), rng.normal(size=(2, 1))
    modes = [dict(A=A, B=B, C=C, D=D, Cy=Cy), dict(A=A + 0.2 * rng.normal(size=(2, 2)), B=0.5 * B, C=C, D=D, Cy=Cy)]
    blocks = [[rng.normal(size=(1, 1)), rng.normal(size=(1, 1)), 0.5 * rng.normal(size=(1, 1)),
               0.5 * rng.normal(size=(1, 1))] for _ in range(2)]
    probe = FTCSystem.from_arrays(name="probe", modes=modes, **CHAIN)
    ctrl = Controller.dynamic(*[[b[q] for b in blocks] for q in range(4)], name="planted")
    c = max(float(np.max(np.linalg.eigvals(M).real)) for M in closed_loop(probe, ctrl).A) + 0.3
    for md in modes:
        md["A"] = md["A"] - c * np.eye(2)
    ctrl = Controller.dynamic([b[0] - c * np.eye(1) for b in blocks], *[[b[q] for b in blocks] for q in (1, 2, 3)],
                              name="planted")
    return FTCSystem.from_arrays(name=f"planted-{seed}", modes=modes, **CHAIN), ctrl


@pytest.mark.parametrize("seed", [0, 1])
def test_gradient_matches_central_differences(seed: int) -> None:
    """Directional derivative of the level against central differences (step 1e-4; the
    level is solved to about 1e-8, so the difference is accurate to about 1e-4 relative
    of the level; 2 % of the slope, or 1e-3 absolute, allowed)."""
    system, ctrl = planted(seed)
    fun = NominalGamma(system, 1, SolverCalls("clarabel"))
    theta = fun.par.theta(controller_blocks(ctrl))
    f, g = fun(theta)
    assert np.isfinite(f)
    rng = np.random.default_rng(10 + seed)
    for _ in range(3):
        d = rng.standard_normal(theta.size)
        d /= np.linalg.norm(d)
        h = 1e-4
        fd = (fun(theta + h * d)[0] - fun(theta - h * d)[0]) / (2 * h)
        assert fd == pytest.approx(float(g @ d), rel=2e-2, abs=1e-3)


def test_level_is_the_certified_nominal_gamma() -> None:
    """The program's level for a controller equals the core's certified nominal gamma
    (the same blocks; the core's ladder lands within its 1e-3 relative steps above)."""
    system, ctrl = planted(0)
    fun = NominalGamma(system, 1, SolverCalls("clarabel"))
    f, _ = fun(fun.par.theta(controller_blocks(ctrl)))
    report = verify_controller(system, ctrl, "clarabel")
    assert report.nominal.certified
    assert f <= report.nominal.gamma * (1 + 1e-6)
    assert report.nominal.gamma <= f * (1 + 2e-2)


def test_route_beats_the_planted_controller() -> None:
    """From the planted controller: certified, gamma at most the planted one, within the bound.

    Budget 2 s (the route's default is 40 s): BFGS only accepts points below the start's
    level, so the claim holds at any length of the descent; measured, 2 s reach a
    certified 0.246 from the planted 0.371 (10 s: 0.240)."""
    system, ctrl = planted(1)
    planted_gamma = accepted_gamma(verify_controller(system, ctrl, "clarabel"), True)
    assert planted_gamma is not None
    bound = 2.0 * max(float(np.linalg.norm(K, 2)) for K in controller_blocks(ctrl))
    found, report, history, msg, rows = hinf_route(system, 1, [("planted", ctrl)], SolverCalls("clarabel"),
                                                   "clarabel", k_max=bound, seed=0, budget_seconds=2.0)
    assert found is not None, msg
    gamma = accepted_gamma(report, True)
    assert gamma is not None and gamma <= planted_gamma * (1 + 1e-3)
    assert history[-1] == gamma and rows[0]["gamma_certified"] == gamma
    assert max(float(np.linalg.norm(K, 2)) for K in controller_blocks(found)) <= bound * (1 + 1e-9)


def test_tangent_removes_the_outward_part_on_the_bound() -> None:
    """On the bound, a gradient whose negative points outward loses its part along the
    normal ``u1 v1'``; one pointing inward, and any gradient off the bound, is unchanged."""
    from ftc_verify.synthesis.hinf_descent import _tangent

    system, _ = planted(0)
    par = NominalGamma(system, 1, SolverCalls("clarabel")).par
    rng = np.random.default_rng(3)
    blocks = [rng.normal(size=par.shape) for _ in range(system.m)]
    k_max = float(np.linalg.norm(blocks[0], 2))  # block 1 on the bound, block 2 scaled inside
    blocks[1] *= 0.5 * k_max / float(np.linalg.norm(blocks[1], 2))
    U, _, Vt = np.linalg.svd(blocks[0])
    normal = np.outer(U[:, 0], Vt[0])
    for sign in (-1.0, 1.0):
        grads = [sign * normal + 0.1 * rng.normal(size=par.shape), rng.normal(size=par.shape)]
        _, out = _tangent(par, par.theta(blocks), (1.0, par.theta(grads)), k_max)
        got = par.blocks(out)
        if float(np.sum(grads[0] * normal)) < 0:
            assert float(np.sum(got[0] * normal)) == pytest.approx(0.0, abs=1e-12)
        else:
            np.testing.assert_array_equal(got[0], grads[0])
        np.testing.assert_array_equal(got[1], grads[1])
