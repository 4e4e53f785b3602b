"""The exact reference simulator of the sampled-data loop, its fast energies and the
continuous loop (``ftc_verify.simulation.reference``, ``.energies``, ``.continuous``,
``.discretise``) under static state feedback ``Controller.state_feedback(gains)``, and the
Fig. 1 plot.

Independent checks: a closed-form scalar recursion, a hand-rolled per-interval
``scipy.linalg.expm`` loop, the trapezoidal norms of the records, first-order
convergence of the sampled loop to the continuous one, a Monte Carlo second moment
against the exact second-moment equation of ``ftc_verify.analysis.moments.stability``, and the perturbed
closed loop of ``ftc_verify.analysis.closedloop`` for a constant ``Delta``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.linalg

import ftc_verify.simulation.continuous as continuous_mod
import ftc_verify.simulation.discretise as discretise_mod
import ftc_verify.simulation.vectorised as energies_mod
from ftc_verify.analysis.closedloop import state_feedback_loop
from ftc_verify.controllers import Controller
from ftc_verify.errors import ValidationError
from ftc_verify.model.system import FTCSystem
from ftc_verify.simulation.paths import DISTURBANCES, ChainPath, communication_grid, disturbance, sample_paths
from ftc_verify.verification.plots import plot_path
from ftc_verify.simulation.reference import (
    energies_reference,
    phi_gamma,
    simulate_continuous,
    simulate_reference,
    zoh_matrices,
)
from ftc_verify.simulation.records import l2_norm
from ftc_verify.analysis.moments.stability import duplication_matrix, second_moment_generator
from ftc_verify.simulation.delta import DeltaSchedule, delta_segments, delta_shapes
from ftc_verify.simulation.spec import GRID_SNAP_RTOL

sf = Controller.state_feedback  # static state feedback u = K x from a list of gains

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


# ----------------------------------------------------------------------------- helpers
def hand_rolled(system, gains, path, *, step, kind="paper", delta=None, x0=None, rng=None):
    """Per grid interval one ``scipy.linalg.expm`` of ``[[A, B, D], [0, 0, 0]] h`` with
    ``h = t[k+1] - t[k]`` (no caching, no special cases); ``u`` and ``w`` are taken at the
    first grid point of every period ``floor((t + tol) / step)`` (and at the end) and held
    across the jumps inside it; returns ``(t, x, u, w, y)``."""
    n, nu, _ny, nw = system.dims
    m = system.m
    sched = delta or DeltaSchedule("zero")
    segs = delta_segments(system, path, sched, rng)
    t, true, fdi = communication_grid(path, step)
    seg = np.searchsorted(path.times, t[:-1], side="right") - 1
    W = disturbance(kind, nw)(t)
    x = np.zeros(n) if x0 is None else np.asarray(x0, dtype=float)
    X, U, Y = [], [], []
    period = np.floor((t + GRID_SNAP_RTOL * step) / step)
    for k in range(len(t)):
        r, l = (true[k], fdi[k]) if k < len(t) - 1 else (true[-1], fdi[-1])
        md = system.modes[r]
        if k == 0 or k == len(t) - 1 or period[k] > period[k - 1]:
            K = gains[r * m + l] if len(gains) == m * m else gains[l]
            u, w = K @ x, W[k]
        X.append(x), U.append(u), Y.append(md.C @ x)
        if k == len(t) - 1:
            break
        d1, d2 = segs[seg[k]]
        A = md.A + (md.A1 @ d1 @ md.A2 if md.A1 is not None else 0.0)
        B = md.B + (md.B1 @ d2 @ md.B2 if md.B1 is not None else 0.0)
        M = np.zeros((n + nu + nw, n + nu + nw))
        M[:n, :n], M[:n, n:n + nu], M[:n, n + nu:] = A, B, md.D
        E = scipy.linalg.expm(M * (t[k + 1] - t[k]))
        x = E[:n, :n] @ x + E[:n, n:] @ np.concatenate([u, w])
    return t, np.array(X), np.array(U), W, np.array(Y)


def rel(a, b) -> float:
    return float(np.max(np.abs(np.asarray(a) - np.asarray(b))) / max(float(np.max(np.abs(b))), 1e-300))


def edge_paths(horizon: float, step: float) -> list[ChainPath]:
    """Hand-made paths with jumps exactly on, just before and just after grid points,
    two jumps in one interval and a jump close to the horizon."""
    z = np.zeros((2, 2))
    k = step
    return [
        ChainPath(np.array([0.0, 5 * k, 5 * k + 3e-13 * k, 9.5 * k, 9.7 * k, 12 * k + 2e-13 * k, 20 * k - 4e-13 * k,
                            horizon - 1e-13]),
                  np.array([0, 1, 1, 0, 1, 1, 0, 0]), np.array([0, 0, 1, 1, 1, 0, 0, 1]), z, horizon),
        ChainPath(np.array([0.0, 1e-13 * k, 0.5 * k, 3 * k, 4 * k - 1e-14 * k, 4 * k - 5e-15 * k]),
                  np.array([0, 1, 1, 0, 0, 1]), np.array([0, 0, 1, 1, 0, 0]), z, horizon),
        ChainPath(np.array([0.0]), np.array([1]), np.array([0]), z, horizon),
    ]


@pytest.fixture(scope="module")
def scalar_two_mode():
    system = FTCSystem.from_arrays(
        name="scalar",
        modes=[{"A": [[1.0]], "B": [[1.0]], "C": [[1.0]], "D": [[1.0]], "A1": [[0.3]], "A2": [[1.0]]},
               {"A": [[0.5]], "B": [[0.3]], "C": [[2.0]], "D": [[0.5]], "A1": [[0.2]], "A2": [[1.0]]}],
        alpha=[[-1.0, 1.0], [1.0, -1.0]], beta_min=[[0, 2.0], [2.0, 0]], beta_max=[[0, 3.0], [3.0, 0]])
    return system, [np.array([[-3.0]]), np.array([[-6.0]])]


def constant_delta(system, scale=0.8):
    s1, s2 = delta_shapes(system)
    g = np.random.default_rng(3)

    def unit(shape):
        if shape is None:
            return None
        M = g.standard_normal(shape)
        return scale * M / np.linalg.norm(M, 2)

    return unit(s1), unit(s2)


# ----------------------------------------------------------------------------- sampled loop
def test_scalar_no_jump_matches_the_closed_form_recursion() -> None:
    """x' = a x + b u + d w, u = k x(t_k), w held: x_{k+1} = e^{ah} x_k + (e^{ah}-1)/a (b k x_k + d w_k)."""
    a, b, c, d, k = 0.7, 1.3, 2.0, 0.5, -2.1
    system = FTCSystem.from_arrays(name="s", modes=[{"A": [[a]], "B": [[b]], "C": [[c]], "D": [[d]]}] * 2,
                                   alpha=[[-1, 1], [1, -1]], beta_min=[[0, 1], [1, 0]], beta_max=[[0, 1], [1, 0]])
    path = ChainPath(np.array([0.0]), np.array([0]), np.array([0]), np.zeros((2, 2)), 1.3)
    h = 0.05
    res = simulate_reference(system, sf([np.array([[k]]), np.array([[9.0]])]), [path], step=h, x0=[0.8], seed=4)
    rec = res.records[0]
    t = np.arange(27) * h
    t[-1] = 1.3
    assert np.array_equal(rec.t, t)
    w = np.exp(-0.1 * t) * np.sin(t)
    x = [0.8]
    for j in range(26):
        hj = t[j + 1] - t[j]
        e = math.exp(a * hj)
        x.append(e * x[-1] + (e - 1) / a * (b * k * x[-1] + d * w[j]))
    x = np.array(x)
    assert rel(rec.x[:, 0], x) < 1e-13
    assert rel(rec.u[:, 0], k * x) < 1e-13
    assert rel(rec.y[:, 0], c * x) < 1e-13
    assert np.array_equal(rec.w[:, 0], w)
    assert rec.xc.shape == (27, 0) and np.array_equal(rec.ym, rec.x)  # static: no x_c, v = x
    assert (res.backend, res.seed, res.step, res.horizon, res.disturbance) == ("reference", 4, h, 1.3, "paper")
    assert res.options["delta"] == "zero" and res.options["gains"] == "fdi"


@pytest.mark.parametrize("kind", ["zero", "constant", "sign", "random"])
def test_paths_with_jumps_match_a_hand_rolled_expm_loop(paper_system, paper_gains, kind) -> None:
    d1, d2 = constant_delta(paper_system)
    sched = DeltaSchedule(kind, d1, d2) if kind in ("constant", "sign") else DeltaSchedule(kind)
    paths = sample_paths(paper_system.chain, 1.0, 2, 8) + edge_paths(1.0, 0.04)[:2]
    assert sum(p.times.size - 1 for p in paths) >= 10
    x0 = np.array([0.6, -0.4])
    res = simulate_reference(paper_system, sf(paper_gains), paths, step=0.04, delta=sched, x0=x0, seed=21)
    rng = np.random.default_rng(21)
    for rec, p in zip(res.records, paths):
        t, X, U, W, Y = hand_rolled(paper_system, paper_gains, p, step=0.04, delta=sched, x0=x0, rng=rng)
        assert np.array_equal(rec.t, t) and np.array_equal(rec.w, W)
        for got, want in ((rec.x, X), (rec.u, U), (rec.y, Y)):
            assert rel(got, want) < 1e-12
    assert res.options["delta"] == kind


def test_full_information_gains(paper_system, paper_gains) -> None:
    gains = [paper_gains[0], paper_gains[1], 0.5 * paper_gains[0], 0.5 * paper_gains[1]]
    paths = sample_paths(paper_system.chain, 1.5, 2, 1)
    res = simulate_reference(paper_system, sf(gains), paths, step=0.03, x0=[1.0, 0.0])
    for rec, p in zip(res.records, paths):
        _t, X, U, _W, _Y = hand_rolled(paper_system, gains, p, step=0.03, x0=[1.0, 0.0])
        assert rel(rec.x, X) < 1e-12 and rel(rec.u, U) < 1e-12
    assert res.options["gains"] == "full-information"


# ----------------------------------------------------------------------------- fast energies
def _energy_case(system, gains, paths, step, sched, x0, dist="paper"):
    res = simulate_reference(system, sf(gains), paths, step=step, delta=sched, x0=x0, seed=17, disturbance=dist)
    ey, ew = energies_reference(system, sf(gains), paths, step=step, delta=sched, x0=x0,
                                rng=np.random.default_rng(17), disturbance=dist)
    ry = np.array([r.y_norm ** 2 for r in res.records])
    rw = np.array([r.w_norm ** 2 for r in res.records])
    assert ey.shape == ew.shape == (len(paths),)
    np.testing.assert_allclose(ey, ry, rtol=1e-12, atol=0)
    np.testing.assert_allclose(ew, rw, rtol=1e-12, atol=1e-300)
    return ey, ew


@pytest.mark.parametrize("kind", ["zero", "sign", "random"])
def test_energies_equal_the_records_norms(paper_system, paper_gains, kind, monkeypatch) -> None:
    d1, d2 = constant_delta(paper_system)
    sched = DeltaSchedule(kind, d1, d2) if kind == "sign" else DeltaSchedule(kind)
    paths = sample_paths(paper_system.chain, 1.5, 4, 2) + edge_paths(1.5, 0.01)
    x0 = [1.0, -1.0]
    _energy_case(paper_system, paper_gains, paths, 0.01, sched, x0)
    # one regular step per chunk, and the gathered kernel instead of "all ids, then select"
    monkeypatch.setattr(energies_mod, "_CHUNK_DOUBLES", 1)
    monkeypatch.setattr(energies_mod, "_SELECT_LIMIT", 0)
    _energy_case(paper_system, paper_gains, paths, 0.01, sched, x0)


def test_energies_other_cases(paper_system, paper_gains, scalar_two_mode, monkeypatch) -> None:
    # constant Delta, full-information gains, a horizon that is no multiple of the step,
    # several horizons in one call, a discontinuous disturbance
    d1, d2 = constant_delta(paper_system)
    gains = list(paper_gains) + [0.5 * paper_gains[0], 0.7 * paper_gains[1]]
    paths = sample_paths(paper_system.chain, 1.234, 3, 4) \
        + sample_paths(paper_system.chain, 0.9, 2, 5)
    _energy_case(paper_system, gains, paths, 0.025, DeltaSchedule("constant", d1, d2), [0.3, 0.2], dist="pulse")
    # a stiff plant (||A h|| > 1/2: scaling and squaring), few and many matrices
    system, K = scalar_two_mode
    stiff = FTCSystem.from_arrays(
        name="stiff", modes=[{"A": [[-40.0]], "B": [[1.0]], "C": [[1.0]], "D": [[1.0]], "A1": [[5.0]], "A2": [[1.0]]},
                             {"A": [[-100.0]], "B": [[0.3]], "C": [[2.0]], "D": [[0.5]], "A1": [[9.0]], "A2": [[1.0]]}],
        alpha=[[-1.0, 1.0], [1.0, -1.0]], beta_min=[[0, 2.0], [2.0, 0]], beta_max=[[0, 3.0], [3.0, 0]])
    paths = sample_paths(system.chain, 2.0, 4, 6) + edge_paths(2.0, 0.04)
    _energy_case(stiff, K, paths, 0.04, DeltaSchedule("sign", np.array([[0.9]])), [1.0], dist="sine")
    monkeypatch.setattr(discretise_mod, "_GROUP_LIMIT", 0)
    _energy_case(stiff, K, paths, 0.04, DeltaSchedule("random"), [1.0], dist="step")
    # a single path, given bare
    ey, ew = energies_reference(system, sf(K), paths[0], step=0.04, disturbance="zero", x0=[1.0])
    assert ew.tolist() == [0.0] and ey[0] > 0


@pytest.mark.parametrize("horizon", [2.0, 1.234])
def test_energies_of_paths_without_any_jump(paper_system, paper_gains, horizon) -> None:
    """No jump on any path, the horizon a multiple of the step or not (2.0 once failed:
    no interval was special)."""
    z = np.zeros((2, 2))
    paths = [ChainPath(np.array([0.0]), np.array([k]), np.array([k]), z, horizon) for k in (0, 1)]
    ey, ew = _energy_case(paper_system, paper_gains, paths, 0.04, DeltaSchedule("zero"), [1.0, 0.5])
    assert np.all(ey > 0) and np.all(ew > 0)


def random_system(seed: int, *, n=3, nu=2, ny=2, nw=2, m=3, fault_during_delay=True) -> FTCSystem:
    g = np.random.default_rng(seed)
    modes = []
    for _ in range(m):
        modes.append({"A": g.standard_normal((n, n)) - 1.0 * np.eye(n), "B": g.standard_normal((n, nu)),
                      "C": g.standard_normal((ny, n)), "D": g.standard_normal((n, nw)),
                      "A1": 0.3 * g.standard_normal((n, 2)), "A2": 0.3 * g.standard_normal((3, n)),
                      "B1": 0.3 * g.standard_normal((n, 1)), "B2": 0.3 * g.standard_normal((2, nu))})
    alpha = g.uniform(0.5, 2.0, (m, m))
    np.fill_diagonal(alpha, 0.0)
    np.fill_diagonal(alpha, -alpha.sum(axis=1))
    bmin = g.uniform(1.0, 3.0, (m, m))
    np.fill_diagonal(bmin, 0.0)
    return FTCSystem.from_arrays(name=f"random-{seed}", modes=modes, alpha=alpha, beta_min=bmin,
                                 beta_max=bmin + 1.0, fault_during_delay=fault_during_delay)


@pytest.mark.parametrize("kind", ["constant", "sign", "random"])
def test_energies_on_a_random_three_mode_system(kind) -> None:
    """m = 3 (fault_during_delay), several outputs and disturbance channels; ``sign``
    has 18 dynamics ids (gathered kernel), ``constant`` 9 (select kernel)."""
    system = random_system(5)
    g = np.random.default_rng(6)
    gains = [0.5 * g.standard_normal((2, 3)) for _ in range(3)]
    d1, d2 = constant_delta(system)
    sched = DeltaSchedule(kind, d1, d2) if kind != "random" else DeltaSchedule("random")
    paths = sample_paths(system.chain, 1.2, 5, 7)
    _energy_case(system, gains, paths, 0.03, sched, [0.5, -0.5, 1.0], dist="sine")


# ----------------------------------------------------------------------------- exponentials
@pytest.mark.parametrize("per_item", [False, True])
def test_phi_gamma_matches_scipy_expm(per_item, monkeypatch) -> None:
    if per_item:
        monkeypatch.setattr(discretise_mod, "_GROUP_LIMIT", 0)
    g = np.random.default_rng(0)
    mats = [g.standard_normal((3, 3)), np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, 0.0]]),
            np.zeros((3, 3)), 25.0 * g.standard_normal((3, 3)) - 40 * np.eye(3), np.diag([-300.0, 0.5, 2.0])]
    hs = np.array([0.0, 1e-9, 1e-3, 0.01, 0.3, 1.0, 2.0])
    A = np.stack(mats)
    groups = np.repeat(np.arange(len(mats)), hs.size)
    h = np.tile(hs, len(mats))
    Phi, Gam = phi_gamma(A, h, groups)
    for k in range(h.size):
        M = np.zeros((6, 6))
        M[:3, :3], M[:3, 3:] = A[groups[k]], np.eye(3)
        E = scipy.linalg.expm(M * h[k])
        scale = max(1.0, float(np.max(np.abs(E))))
        assert np.max(np.abs(Phi[k] - E[:3, :3])) <= 1e-12 * scale, (groups[k], h[k])
        assert np.max(np.abs(Gam[k] - E[:3, 3:])) <= 1e-12 * max(scale * h[k], 1e-300) + 1e-300, (groups[k], h[k])


def test_zoh_matrices_are_the_blocks_of_the_augmented_exponential() -> None:
    A, B, D = np.array([[0.0, 1.0], [-2.0, -0.3]]), np.array([[0.0], [1.0]]), np.array([[1.0], [0.5]])
    Phi, GB, GD = zoh_matrices(A, B, D, 0.1)
    Ph, Gm = phi_gamma(A[None], [0.1])
    assert np.allclose(Phi, Ph[0], rtol=1e-13, atol=1e-15) and np.allclose(GB, Gm[0] @ B, atol=1e-15)
    assert np.allclose(GD, Gm[0] @ D, atol=1e-15)


# ----------------------------------------------------------------------------- continuous loop
def common_points(fine_t, coarse_t):
    idx = np.minimum(np.searchsorted(fine_t, coarse_t), fine_t.size - 1)
    ok = np.abs(fine_t[idx] - coarse_t) < 1e-9
    return idx[ok], np.flatnonzero(ok)


def test_sampled_loop_converges_to_the_continuous_loop_at_first_order(scalar_two_mode) -> None:
    system, K = scalar_two_mode
    path = ChainPath(np.array([0.0, 0.37, 0.81, 1.53]), np.array([0, 1, 1, 0]), np.array([0, 0, 1, 1]),
                     np.zeros((2, 2)), 2.0)
    cont = simulate_continuous(system, sf(K), path, x0=[1.0], points_per_unit=200)
    steps = np.array([0.04, 0.02, 0.01, 0.005])
    errs = []
    for h in steps:
        rec = simulate_reference(system, sf(K), [path], step=float(h), x0=[1.0]).records[0]
        i_fine, i_coarse = common_points(cont.t, rec.t)
        assert i_coarse.size >= 2.0 / h  # every multiple of the step is compared
        errs.append(np.max(np.abs(cont.x[i_fine] - rec.x[i_coarse])))
    slope = np.polyfit(np.log(steps), np.log(errs), 1)[0]
    assert 0.8 <= slope <= 1.3, (slope, errs)


def test_continuous_loop_conventions_and_the_solve_ivp_fallback(paper_system, paper_gains, monkeypatch) -> None:
    d1, d2 = constant_delta(paper_system)
    path = sample_paths(paper_system.chain, 2.5, 1, 12)[0]
    sched = DeltaSchedule("sign", d1, d2)
    rec = simulate_continuous(paper_system, sf(paper_gains), path, delta=sched, x0=[0.5, 0.5], points_per_unit=40)
    t, true, fdi = communication_grid(path, 1 / 40)
    assert np.array_equal(rec.t, t) and np.array_equal(rec.true, true) and np.array_equal(rec.fdi, fdi)
    assert np.array_equal(rec.w, disturbance("paper", 1)(t))
    last = (true[-1], fdi[-1])
    assert np.allclose(rec.u[-1], paper_gains[last[1]] @ rec.x[-1])
    assert np.allclose(rec.y[-1], paper_system.modes[last[0]].C @ rec.x[-1])
    for k in range(len(t) - 1):
        assert np.allclose(rec.y[k], paper_system.modes[true[k]].C @ rec.x[k])
    # a shape without an exosystem goes through solve_ivp (rtol 1e-10)
    monkeypatch.setitem(DISTURBANCES, "paper-copy", DISTURBANCES["paper"])
    ivp = simulate_continuous(paper_system, sf(paper_gains), path, delta=sched, x0=[0.5, 0.5], points_per_unit=40,
                              disturbance="paper-copy")
    assert rel(ivp.x, rec.x) < 1e-7


@pytest.mark.parametrize("kind", sorted(DISTURBANCES))
def test_exosystems_reproduce_the_disturbances(kind) -> None:
    exo = continuous_mod._exosystem(kind, 2)
    assert exo is not None  # every named shape has one (else simulate_continuous falls back)
    ts = np.linspace(0.0, 6.0, 61)
    want = disturbance(kind, 2)(ts)
    for t, w in zip(ts, want):
        z, t0 = exo.z0, 0.0
        for tb, reset in exo.breaks:
            if tb <= t:
                z, t0 = reset, tb
        got = exo.E @ (scipy.linalg.expm(exo.S * (t - t0)) @ z) if z.size else np.zeros(2)
        assert np.allclose(got, w, rtol=1e-12, atol=1e-12)


def test_monte_carlo_second_moment_matches_the_second_moment_equation(paper_system, paper_gains) -> None:
    """E|x(T)|^2 for w = 0, x0 != 0, fixed beta: vech X_s(T) = expm(L T) vech X_s(0) with
    X_(1,1)(0) = x0 x0' (``stability.second_moment_generator``), summed traces. Monte Carlo
    over 2000 continuous-loop paths, z-score |z| < 5: false-failure probability about
    6e-7 under the normal approximation (seed fixed, so the outcome is deterministic)."""
    system = paper_system.nominal()
    beta = system.chain.midpoint()
    loop = state_feedback_loop(system, paper_gains)
    x0 = np.array([1.0, -0.5])
    T = 0.5
    n = 2
    D, L = duplication_matrix(n)
    q = L.shape[0]
    Lg = second_moment_generator(loop, beta)
    v0 = np.zeros(Lg.shape[0])
    v0[:q] = L @ np.outer(x0, x0).reshape(-1, order="F")
    v = scipy.linalg.expm(Lg * T) @ v0
    exact = sum(np.trace((D @ v[s * q:(s + 1) * q]).reshape(n, n, order="F")) for s in range(system.m ** 2))
    N = 2000
    paths = sample_paths(system.chain, T, N, 2024, beta=beta)
    vals = np.array([np.sum(simulate_continuous(system, sf(paper_gains), p, disturbance="zero", x0=x0,
                                                points_per_unit=2).x[-1] ** 2) for p in paths])
    z = (vals.mean() - exact) / (vals.std(ddof=1) / math.sqrt(N))
    assert abs(z) < 5, (vals.mean(), exact, z)


# ----------------------------------------------------------------------------- uncertainty
def test_delta_kinds_have_norm_at_most_one(paper_system) -> None:
    d1, d2 = constant_delta(paper_system, scale=1.0)
    paths = sample_paths(paper_system.chain, 20.0, 20, 9)
    rng = np.random.default_rng(10)
    seen = 0
    for kind in ("zero", "constant", "sign", "random"):
        sched = DeltaSchedule(kind, d1, d2) if kind in ("constant", "sign") else DeltaSchedule(kind)
        for p in paths:
            for a, b in delta_segments(paper_system, p, sched, rng):
                for M in (a, b):
                    assert np.linalg.norm(M, 2) <= 1.0 + 1e-12
                    seen += 1
    assert seen > 400


def test_constant_delta_reproduces_the_perturbed_closed_loop(paper_system, paper_gains) -> None:
    """w = 0: x at the grid points equals the product of expm(perturbed A_s dt) over the
    intervals, with A_s from ``ClosedLoop.perturbed`` (independent of the simulator)."""
    d1, d2 = constant_delta(paper_system)
    loop = state_feedback_loop(paper_system, paper_gains)
    Ap = loop.perturbed({"Delta1 (A)": d1, "Delta2 (B)": d2})
    path = ChainPath(np.array([0.0, 0.4, 0.93, 1.7]), np.array([0, 1, 1, 0]), np.array([0, 0, 1, 1]),
                     np.zeros((2, 2)), 3.0)
    x0 = np.array([0.7, -0.2])
    rec = simulate_continuous(paper_system, sf(paper_gains), path, delta=DeltaSchedule("constant", d1, d2),
                              disturbance="zero", x0=x0, points_per_unit=20)
    x = x0.copy()
    for k in range(len(rec.t) - 1):
        assert rel(rec.x[k], x) < 1e-11
        x = scipy.linalg.expm(Ap[rec.true[k] * 2 + rec.fdi[k]] * (rec.t[k + 1] - rec.t[k])) @ x
    assert rel(rec.x[-1], x) < 1e-11
    nominal = simulate_continuous(paper_system, sf(paper_gains), path, disturbance="zero", x0=x0, points_per_unit=20)
    assert not np.allclose(nominal.x, rec.x, rtol=1e-6)


# ----------------------------------------------------------------------------- validation
def test_errors_name_the_field(paper_system, paper_gains) -> None:
    path = sample_paths(paper_system.chain, 1.0, 1, 0)[0]
    bad_mode = ChainPath(np.array([0.0]), np.array([2]), np.array([0]), np.zeros((2, 2)), 1.0)
    bad_times = ChainPath(np.array([0.0, 0.5, 0.4]), np.array([0, 1, 1]), np.array([0, 0, 1]), np.zeros((2, 2)), 1.0)
    cases = [
        (dict(step=0.0), "step"),
        (dict(step=0.1, x0=[1.0]), "x0"),
        (dict(step=0.1, delta=3), "delta"),
        (dict(step=0.1, delta="wobbly"), "delta"),
        (dict(step=0.1, disturbance="noise"), "disturbance"),
    ]
    for fn in (simulate_reference, energies_reference):
        for kw, field in cases:
            with pytest.raises(ValidationError, match=field):
                fn(paper_system, sf(paper_gains), [path], **kw)
        with pytest.raises(ValidationError, match="controller: 1 entries given"):
            fn(paper_system, sf(paper_gains[:1]), [path], step=0.1)
        with pytest.raises(ValidationError, match=r"controller: expected a ftc_verify\.controllers\.Controller"):
            fn(paper_system, list(paper_gains), [path], step=0.1)  # a bare gain list is refused
        with pytest.raises(ValidationError, match=r"paths\[1\]"):
            fn(paper_system, sf(paper_gains), [path, "not a path"], step=0.1)
        with pytest.raises(ValidationError, match=r"paths\[1\]\.true"):
            fn(paper_system, sf(paper_gains), [path, bad_mode], step=0.1)
        with pytest.raises(ValidationError, match=r"paths\[0\]\.times"):
            fn(paper_system, sf(paper_gains), [bad_times], step=0.1)
        with pytest.raises(ValidationError, match="paths"):
            fn(paper_system, sf(paper_gains), [], step=0.1)
    with pytest.raises(ValidationError, match="points_per_unit"):
        simulate_continuous(paper_system, sf(paper_gains), path, points_per_unit=0)
    with pytest.raises(ValidationError, match="phi_gamma"):
        phi_gamma(np.eye(2)[None], [-1.0])


# ----------------------------------------------------------------------------- plots
def test_plot_path_writes_a_png_atomically(paper_system, paper_gains, tmp_path) -> None:
    path = sample_paths(paper_system.chain, 10.0, 1, 7)[0]
    rec = simulate_reference(paper_system, sf(paper_gains), [path], step=0.01).records[0]
    out = tmp_path / "fig1.png"
    plot_path(rec, out, title="paper example, one path")
    assert out.read_bytes()[:8] == PNG_SIGNATURE
    assert [p.name for p in tmp_path.iterdir()] == ["fig1.png"]  # no temporary file left
    assert math.isclose(rec.w_norm, l2_norm(rec.t, rec.w))
    with pytest.raises(ValidationError, match="path"):
        plot_path(rec, tmp_path / "missing-folder" / "x.png")
    with pytest.raises(ValidationError, match="record"):
        plot_path("not a record", out)  # type: ignore[arg-type]
