"""The numpy simulators under dynamic controllers (``ftc_verify.simulation.reference``,
``.energies``, ``.continuous``).

Independent checks: (a) a dynamic controller whose state never enters the control
(``Ac = -I, Bc = 0, Cc = 0, Dc = K_l``, on ``y_m = I x``) reproduces the static gains on
every simulator; (b) an observer-based controller on the paper's example with the single
measured output ``y_m = x1 + 2 x2``, checked against a plain per-interval
``scipy.linalg.expm`` loop written here, the fast energies against the records, and the
continuous loop against the exponential of a hand-built augmented matrix; (c) controller
shape errors surface as ``ValidationError``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.linalg
import scipy.signal

import ftc_verify.simulation.vectorised as energies_mod
from ftc_verify.controllers import Controller, load_controller
from ftc_verify.errors import ValidationError
from ftc_verify.model.files import load_system
from ftc_verify.model.system import FTCSystem
from ftc_verify.simulation.continuous import simulate_continuous
from ftc_verify.simulation.delta import DeltaSchedule, delta_segments, delta_shapes
from ftc_verify.simulation.vectorised import energies_reference
from ftc_verify.simulation.paths import ChainPath, communication_grid, disturbance, sample_paths
from ftc_verify.simulation.reference import simulate_reference
from ftc_verify.simulation.records import DIVERGENCE_BOUND
from ftc_verify.simulation.spec import GRID_SNAP_RTOL

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"

CY = np.array([[1.0, 2.0]])  # y_m = x1 + 2 x2


# ----------------------------------------------------------------------------- helpers
def rel(a, b) -> float:
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return float(np.max(np.abs(a - b)) / max(float(np.max(np.abs(b))), 1e-300))


def rel_running(a, b) -> float:
    """Largest error at each point relative to the largest reference value so far (the
    early, small values are checked as tightly as the late, large ones)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    err = np.max(np.abs(a - b).reshape(len(b), -1), axis=1, initial=0.0)
    scale = np.maximum.accumulate(np.max(np.abs(b).reshape(len(b), -1), axis=1, initial=0.0))
    return float(np.max(err / np.maximum(scale, 1e-300)))


def random_system(seed: int, *, n=3, nu=2, ny=2, nw=2, m=3) -> FTCSystem:
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
                                 beta_max=bmin + 1.0, fault_during_delay=seed % 2 == 0)


def sign_delta(system: FTCSystem, seed: int) -> DeltaSchedule:
    g = np.random.default_rng(seed)
    out = []
    for shape in delta_shapes(system):
        M = None if shape is None else g.standard_normal(shape)
        out.append(None if M is None else 0.8 * M / np.linalg.norm(M, 2))
    return DeltaSchedule("sign", *out)


def edge_paths(m: int, horizon: float, step: float) -> list[ChainPath]:
    """Jumps on, just before and just after grid points, two in one interval."""
    z = np.zeros((m, m))
    k = step
    return [
        ChainPath(np.array([0.0, 5 * k, 5 * k + 3e-13 * k, 9.5 * k, 9.7 * k, 12 * k + 2e-13 * k]),
                  np.array([0, 1, 1, 0, 1, 1]), np.array([0, 0, 1, 1, 1, 0]), z, horizon),
        ChainPath(np.array([0.0, 1e-13 * k, 0.5 * k, 3 * k]), np.array([0, 1, 1, 0]), np.array([0, 0, 1, 1]),
                  z, horizon),
    ]


@pytest.fixture(scope="module")
def paper():
    system = load_system(EXAMPLES / "paper.toml")
    controller = load_controller(EXAMPLES / "paper_gains.toml")
    assert controller.is_state_feedback and controller.entries == system.m
    return system, controller


def random_case(seed: int):
    system = random_system(seed)
    g = np.random.default_rng(seed + 100)
    gains = [0.5 * g.standard_normal((2, 3)) for _ in range(system.m)]
    return system, Controller.state_feedback(gains)


def inert_dynamic(system: FTCSystem, static: Controller, n_c: int = 2) -> tuple[FTCSystem, Controller]:
    """``Cy = I`` and the dynamic controller ``Ac = -I, Bc = 0, Cc = 0, Dc = K_l``."""
    n, nu, _, _ = system.dims
    K = static.gains
    dyn = Controller.dynamic([-np.eye(n_c)] * len(K), [np.zeros((n_c, n))] * len(K),
                             [np.zeros((nu, n_c))] * len(K), list(K))
    return system.with_measured_output(np.eye(n)), dyn


# ----------------------------------------------------------------------------- (a) equivalence
@pytest.mark.parametrize("n_c", [2, 0])
@pytest.mark.parametrize("case", ["paper", 11, 12, 13])
def test_inert_dynamic_controller_reproduces_the_static_gains(case, n_c, paper) -> None:
    """n_c = 2: the dynamic controller of the brief; n_c = 0: static output feedback
    u = K_l y_m with y_m = I x (the measured-output path of the simulators)."""
    system, static = paper if case == "paper" else random_case(case)
    sys_y, dyn = inert_dynamic(system, static, n_c)
    assert dyn.n_c == n_c and dyn.measures == "output" and dyn.static == (n_c == 0)
    n = system.dims[0]
    x0 = np.linspace(1.0, -0.5, n)
    paths = sample_paths(system.chain, 1.2, 3, case if case != "paper" else 1)
    if system.m == 2:
        paths += edge_paths(2, 1.2, 0.02)
    assert sum(p.times.size - 1 for p in paths) >= 3
    for sched in (DeltaSchedule("zero"), sign_delta(system, 4), DeltaSchedule("random")):
        a = simulate_reference(system, static, paths, step=0.02, delta=sched, x0=x0, seed=9, disturbance="sine")
        b = simulate_reference(sys_y, dyn, paths, step=0.02, delta=sched, x0=x0, seed=9, disturbance="sine")
        for ra, rb in zip(a.records, b.records):
            assert np.array_equal(ra.t, rb.t) and np.array_equal(ra.w, rb.w)
            for got, want in ((rb.x, ra.x), (rb.u, ra.u), (rb.y, ra.y), (rb.ym, ra.x)):
                assert rel(got, want) < 1e-9
            assert rb.xc.shape == (ra.t.size, n_c) and np.all(rb.xc == 0.0)  # Bc = 0, xc(0) = 0
            assert ra.xc.shape == (ra.t.size, 0)
        ea = energies_reference(system, static, paths, step=0.02, delta=sched, x0=x0,
                                rng=np.random.default_rng(9), disturbance="sine")
        eb = energies_reference(sys_y, dyn, paths, step=0.02, delta=sched, x0=x0,
                                rng=np.random.default_rng(9), disturbance="sine")
        np.testing.assert_allclose(eb[0], ea[0], rtol=1e-9, atol=0)
        np.testing.assert_allclose(eb[1], ea[1], rtol=1e-9, atol=0)
        assert np.all(ea[0] > 0)
    sched = sign_delta(system, 5)
    for p in paths[:2]:
        ca = simulate_continuous(system, static, p, delta=sched, x0=x0, points_per_unit=50)
        cb = simulate_continuous(sys_y, dyn, p, delta=sched, x0=x0, points_per_unit=50)
        assert np.array_equal(ca.t, cb.t)
        for got, want in ((cb.x, ca.x), (cb.u, ca.u), (cb.y, ca.y)):
            assert rel(got, want) < 1e-9
        assert cb.xc.shape == (ca.t.size, n_c) and np.all(cb.xc == 0.0)
        assert rel(cb.ym, ca.x) < 1e-9 and np.array_equal(ca.ym, ca.x)


# ----------------------------------------------------------------------------- (b) observer
@pytest.fixture(scope="module")
def observer(paper):
    """Per FDI mode l: Ac = A_l + B_l K_l - L_l Cy, Bc = L_l, Cc = K_l, Dc = 0, with L_l
    placing the eigenvalues of A_l - L_l Cy at -3, -4 (pole placement on the dual).

    The loop is stable in the matched joint modes but not in the mismatched ones (the
    observer predicts with B_l, the plant moves with B_i; in joint mode (2, 1) the
    largest real part is about 32), so the states grow during detection delays: the
    comparisons below are relative to the largest value, at 1e-9."""
    system, static = paper
    sys_y = system.with_measured_output(CY)
    Ac, Bc, Cc, Dc = [], [], [], []
    for md, K in zip(system.modes, static.gains):
        L = scipy.signal.place_poles(md.A.T, CY.T, [-3.0, -4.0]).gain_matrix.T
        assert L.shape == (2, 1)
        assert np.max(np.linalg.eigvals(md.A - L @ CY).real) < -2.9  # Hurwitz observer
        Ac.append(md.A + md.B @ K - L @ CY)
        Bc.append(L)
        Cc.append(K)
        Dc.append(np.zeros((2, 1)))
    return sys_y, Controller.dynamic(Ac, Bc, Cc, Dc, name="observer-based")


def hand_loop(system, ctrl, path, *, step, sched, x0, rng, kind="paper"):
    """Per grid interval one expm of [[A, B, D], [0, 0, 0]] h for the plant and one of
    [[Ac, Bc], [0, 0]] h for the controller (no caching); the controller reads ``y_m``
    and the FDI mode at the first grid point of each period ``floor((t + tol) / step)``
    (and at the end) and holds them, ``u`` and ``w`` across the jumps inside it; returns
    t, x, xc, u, v (``y_m`` at every point), y."""
    n, nu, _, nw = system.dims
    nc = ctrl.n_c
    segs = delta_segments(system, path, sched, rng)
    t, true, fdi = communication_grid(path, step)
    seg = np.searchsorted(path.times, t[:-1], side="right") - 1
    W = disturbance(kind, nw)(t)
    x, xc = np.asarray(x0, dtype=float), np.zeros(nc)
    out = {key: [] for key in ("x", "xc", "u", "v", "y")}
    period = np.floor((t + GRID_SNAP_RTOL * step) / step)
    for k in range(len(t)):
        r, fdi_k = (true[k], fdi[k]) if k < len(t) - 1 else (true[-1], fdi[-1])
        md = system.modes[r]
        if k in (0, len(t) - 1) or period[k] > period[k - 1]:
            l, v, w = fdi_k, md.Cy @ x, W[k]
            u = ctrl.Cc[l] @ xc + ctrl.Dc[l] @ v
        for key, val in (("x", x), ("xc", xc), ("u", u), ("v", md.Cy @ x), ("y", md.C @ x)):
            out[key].append(val)
        if k == len(t) - 1:
            break
        h = t[k + 1] - t[k]
        d1, d2 = segs[seg[k]]
        A = md.A + md.A1 @ d1 @ md.A2
        B = md.B + md.B1 @ d2 @ md.B2
        M = np.zeros((n + nu + nw, n + nu + nw))
        M[:n, :n], M[:n, n:n + nu], M[:n, n + nu:] = A, B, md.D
        E = scipy.linalg.expm(M * h)
        Mc = np.zeros((nc + 1, nc + 1))
        Mc[:nc, :nc], Mc[:nc, nc:] = ctrl.Ac[l], ctrl.Bc[l]
        Ec = scipy.linalg.expm(Mc * h)
        xc = Ec[:nc, :nc] @ xc + Ec[:nc, nc:] @ v
        x = E[:n, :n] @ x + E[:n, n:] @ np.concatenate([u, w])
    return t, {key: np.array(val) for key, val in out.items()}


@pytest.mark.parametrize("kind", ["zero", "sign", "random"])
def test_observer_controller_matches_a_hand_written_loop(observer, kind) -> None:
    system, ctrl = observer
    sched = sign_delta(system, 6) if kind == "sign" else DeltaSchedule(kind)
    paths = sample_paths(system.chain, 1.5, 3, 31) + edge_paths(2, 1.5, 0.03)
    x0 = np.array([0.8, -0.3])
    res = simulate_reference(system, ctrl, paths, step=0.03, delta=sched, x0=x0, seed=44)
    assert res.options["n_c"] == 2 and "dynamic" in res.options["controller"]
    rng = np.random.default_rng(44)
    for rec, p in zip(res.records, paths):
        t, ref = hand_loop(system, ctrl, p, step=0.03, sched=sched, x0=x0, rng=rng)
        # the record stops at the first grid point where |(x, x_c)| > DIVERGENCE_BOUND
        norms = np.hypot(np.linalg.norm(ref["x"], axis=1), np.linalg.norm(ref["xc"], axis=1))
        crossed = np.flatnonzero(norms > DIVERGENCE_BOUND)
        stop = int(crossed[0]) if crossed.size else t.size
        assert rec.diverged_at == (t[stop] if crossed.size else None)
        t, ref = t[:stop], {key: val[:stop] for key, val in ref.items()}
        assert np.array_equal(rec.t, t)
        assert rec.xc.shape == (t.size, 2) and rec.ym.shape == (t.size, 1)
        for got, key in ((rec.xc, "xc"), (rec.x, "x"), (rec.u, "u"), (rec.ym, "v"), (rec.y, "y")):
            assert rel_running(got, ref[key]) < 1e-9, key
        assert np.max(np.abs(rec.xc)) > 0.05  # the observer state really moves
        assert np.allclose(rec.ym[:, 0], rec.x @ CY[0], rtol=1e-13, atol=1e-15)


@pytest.mark.parametrize("kind", ["zero", "sign", "random"])
def test_observer_energies_equal_the_records_norms(observer, kind, monkeypatch) -> None:
    system, ctrl = observer
    sched = sign_delta(system, 7) if kind == "sign" else DeltaSchedule(kind)
    paths = sample_paths(system.chain, 1.0, 4, 32) + edge_paths(2, 1.0, 0.01) \
        + sample_paths(system.chain, 0.777, 2, 33)  # two horizons
    x0 = [1.0, -1.0]

    def check():
        res = simulate_reference(system, ctrl, paths, step=0.01, delta=sched, x0=x0, seed=12, disturbance="pulse")
        ey, ew = energies_reference(system, ctrl, paths, step=0.01, delta=sched, x0=x0,
                                    rng=np.random.default_rng(12), disturbance="pulse")
        np.testing.assert_allclose(ey, [r.y_norm ** 2 for r in res.records], rtol=1e-9, atol=0)  # inf = inf
        kept = [k for k, r in enumerate(res.records) if r.diverged_at is None]  # a record stops there
        np.testing.assert_allclose(ew[kept], [res.records[k].w_norm ** 2 for k in kept], rtol=1e-9, atol=0)
        return sum(r.diverged_at is not None for r in res.records)

    assert check() >= 1  # this observer loop diverges on some paths (joint mode (2, 1))
    # one regular step per chunk, and the gathered kernel instead of "all ids, then select"
    monkeypatch.setattr(energies_mod, "_CHUNK_DOUBLES", 1)
    monkeypatch.setattr(energies_mod, "_SELECT_LIMIT", 0)
    check()


def test_observer_continuous_loop_is_the_augmented_exponential(observer) -> None:
    """w = 0, constant Delta: xi = (x, xc) at the grid points is the product of expm of
    [[A + B Dc Cy, B Cc], [Bc Cy, Ac]] (perturbed A, B, built here) over the intervals."""
    system, ctrl = observer
    g = np.random.default_rng(8)
    d1, d2 = (0.9 * M / np.linalg.norm(M, 2) for M in (g.standard_normal((2, 2)), g.standard_normal((2, 2))))
    path = ChainPath(np.array([0.0, 0.4, 0.93, 1.7]), np.array([0, 1, 1, 0]), np.array([0, 0, 1, 1]),
                     np.zeros((2, 2)), 2.5)
    x0 = np.array([0.7, -0.2])
    rec = simulate_continuous(system, ctrl, path, delta=DeltaSchedule("constant", d1, d2), disturbance="zero",
                              x0=x0, points_per_unit=20)
    xi = np.concatenate((x0, np.zeros(2)))
    for k in range(len(rec.t)):
        assert rel(np.concatenate((rec.x[k], rec.xc[k])), xi) < 1e-9
        i, j = (rec.true[k], rec.fdi[k]) if k < len(rec.t) - 1 else (rec.true[-1], rec.fdi[-1])
        md = system.modes[i]
        assert rel(rec.u[k], ctrl.Cc[j] @ rec.xc[k] + ctrl.Dc[j] @ CY @ rec.x[k]) < 1e-13
        assert rel(rec.ym[k], md.Cy @ rec.x[k]) < 1e-13
        if k == len(rec.t) - 1:
            break
        A = md.A + md.A1 @ d1 @ md.A2
        B = md.B + md.B1 @ d2 @ md.B2
        Acl = np.block([[A + B @ ctrl.Dc[j] @ CY, B @ ctrl.Cc[j]], [ctrl.Bc[j] @ CY, ctrl.Ac[j]]])
        xi = scipy.linalg.expm(Acl * (rec.t[k + 1] - rec.t[k])) @ xi
    assert np.max(np.abs(rec.xc)) > 0.05


# ----------------------------------------------------------------------------- (c) validation
def test_controller_shape_errors_are_validation_errors(paper, observer) -> None:
    system, static = paper
    sys_y, ctrl = observer
    path = sample_paths(system.chain, 1.0, 1, 0)[0]
    # two measured signals read, the plant has one (Cy is 1 x 2)
    wide = Controller.dynamic(ctrl.Ac, [np.hstack([b, b]) for b in ctrl.Bc], ctrl.Cc,
                              [np.zeros((2, 2))] * 2)
    three = Controller.dynamic(*(getattr(ctrl, k) + getattr(ctrl, k)[:1] for k in ("Ac", "Bc", "Cc", "Dc")))
    narrow = Controller.dynamic(ctrl.Ac, ctrl.Bc, [c[:1] for c in ctrl.Cc], [d[:1] for d in ctrl.Dc])
    cases = [(wide, r"2 columns, but the system has 1 measured outputs"), (three, "3 entries given, the system has 2 modes"),
             (narrow, "1 rows, but the system has 2 inputs")]
    for bad, msg in cases:
        for fn in (simulate_reference, energies_reference):
            with pytest.raises(ValidationError, match=msg):
                fn(sys_y, bad, [path], step=0.1)
        with pytest.raises(ValidationError, match=msg):
            simulate_continuous(sys_y, bad, path, points_per_unit=10)
    # state feedback on a system read through Cy still needs n columns
    with pytest.raises(ValidationError, match="controller: gain\\[1\\]\\.K: 1 columns"):
        simulate_reference(sys_y, Controller.state_feedback([K[:, :1] for K in static.gains]), [path], step=0.1)
    # a bare list of gains is not a controller
    with pytest.raises(ValidationError, match="controller: expected"):
        energies_reference(system, list(static.gains), [path], step=0.1)
