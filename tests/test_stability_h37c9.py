"""The spectral stage and the exact energy with less work, the same answers:
``abscissa_near`` on a reducible chain (a permanent fault), where the power iteration's
bracket cannot close, gives up after one round instead of 80 steps; the dense abscissa by
communicating classes; the infinite-horizon energy's Hurwitz condition by the shift test."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse.linalg
from box_systems import shifted

from ftc_verify.analysis.closedloop import ClosedLoop, state_feedback_loop
from ftc_verify.analysis.moments.stability import (CLASS_SPLIT_ROWS, abscissa_near, communicating_classes,
                                                   generator_size,
                                                   mean_square_stability, second_moment_generator,
                                                   spectral_abscissa)
from ftc_verify.analysis.moments.energy import exact_energy
from ftc_verify.errors import ValidationError
from ftc_verify.model.system import FTCSystem


def permanent_fault_loop(n: int, decay: tuple[float, float] = (3.0, 1.0)) -> ClosedLoop:
    """Two modes, the fault permanent (mode 1 absorbing) and the faulty dynamics the slower
    ones (``decay``: the shifts of the nominal and the faulty state matrices): the
    eigenvector of the second-moment generator's abscissa is zero on the nominal
    (transient) joint states, so the lower Collatz-Wielandt bound of ``abscissa_near``
    stays at their own decay rate."""
    rng = np.random.default_rng(3)
    modes = [{"A": rng.normal(size=(n, n)) / (2 * np.sqrt(n)) - s * np.eye(n), "B": rng.normal(size=(n, 1)),
              "C": rng.normal(size=(1, n)), "D": rng.normal(size=(n, 1))} for s in decay]
    alpha = np.array([[-0.5, 0.5], [0.0, 0.0]])
    bmin = np.array([[0.0, 1.0], [0.0, 0.0]])
    system = FTCSystem.from_arrays(name="permanent-fault", modes=modes, alpha=alpha, beta_min=bmin,
                                   beta_max=bmin + 2.0)
    return state_feedback_loop(system, [np.zeros((1, n))] * 2).nominal()


def test_a_stalled_bracket_ends_after_one_round(monkeypatch: pytest.MonkeyPatch) -> None:
    """One LU factorisation (one round of six steps), then ``None`` (the caller's dense
    eigenvalues); before, 11-14 rounds (80 steps) ended the same way."""
    loop = permanent_fault_loop(4)
    factored = []
    splu = scipy.sparse.linalg.splu
    monkeypatch.setattr(scipy.sparse.linalg, "splu", lambda *a, **k: factored.append(1) or splu(*a, **k))
    for beta in loop.chain.vertices():
        mu = spectral_abscissa(loop, beta)
        factored.clear()
        assert abscissa_near(loop, beta, mu + 0.05 * (1 + abs(mu))) is None
        assert len(factored) == 1


def test_the_vertex_search_on_a_reducible_chain_is_the_dense_one() -> None:
    """A generator of 112 rows (the pruned search): its estimate is the largest dense
    abscissa over the vertices, and it is proved stable."""
    loop = permanent_fault_loop(7)
    assert generator_size(loop) >= 100
    mss = mean_square_stability(loop)
    dense = max(spectral_abscissa(loop, b) for b in loop.chain.vertices())
    assert mss.spectral_abscissa == pytest.approx(dense, rel=1e-12) and dense < 0
    assert mss.stable


def test_the_abscissa_by_communicating_classes_is_the_whole_generators() -> None:
    """The permanent-fault loop's chain has two classes at every rate vertex (the nominal
    joint states, transient, and the faulty ones): the classes partition the joint states,
    and the largest real part over their blocks is the dense one of the whole generator
    (the block of a class keeps the rates that leave it on its diagonal: blocks built
    from the classes' own generators, the leaving rates dropped, are 0.5 higher at two of the four vertices). The
    nominal dynamics the slower ones, so that the transient class decides."""
    loop = permanent_fault_loop(7, decay=(1.0, 3.0))
    assert generator_size(loop) >= CLASS_SPLIT_ROWS
    for beta in loop.chain.vertices():
        Q = loop.chain.generator(beta)
        classes = communicating_classes(Q)
        assert len(classes) > 1
        assert sorted(np.concatenate(classes).tolist()) == list(range(len(loop.A)))
        whole = float(np.max(np.linalg.eigvals(second_moment_generator(loop, beta)).real))
        assert spectral_abscissa(loop, beta) == pytest.approx(whole, rel=1e-12, abs=1e-14)


def test_infinite_horizon_energy_proved_without_eigenvalues(paper_loop: ClosedLoop,
                                                            monkeypatch: pytest.MonkeyPatch) -> None:
    """The paper loop's infinite-horizon energy needs no eigenvalue problem (the shift test
    proves the augmented generator Hurwitz) and is the finite-horizon energy's limit; a
    non-decaying disturbance and an unstable loop are still refused (the shift test does
    not show them, the eigenvalues decide)."""
    beta = next(iter(paper_loop.chain.vertices()))
    finite = exact_energy(paper_loop, beta=beta, horizon=400.0)
    monkeypatch.setattr(np.linalg, "eigvals", lambda *a, **k: pytest.fail("eigenvalues computed"))
    infinite = exact_energy(paper_loop, beta=beta)
    assert infinite.y_energy == pytest.approx(finite.y_energy, rel=1e-9)
    monkeypatch.undo()
    for loop, disturbance in ((paper_loop, "sine"), (paper_loop, "step"), (shifted(paper_loop, -50.0), "paper")):
        with pytest.raises(ValidationError, match="infinite horizon needs"):
            exact_energy(loop, beta=beta, disturbance=disturbance)
