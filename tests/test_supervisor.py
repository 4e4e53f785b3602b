"""The co-simulation supervisor against the numpy reference simulator.

On the same paths, the same ``Delta`` draws (same seed) and the same grid, the FMU
co-simulation (``backend="fmu"``) and the reference must agree to 1e-8 relative in ``x``
and ``y`` (both integrate exact zero-order-hold steps; the differences are rounding in
two matrix exponentials). The reference is ``ftc_verify.simulation.reference.simulate_reference``;
every case is also checked against ``local_reference`` below, a loop written from the
module docstring of :mod:`ftc_verify.simulation.supervisor` with scipy's ``expm`` (independent of both
backends), so the supervisor stays tested while ``reference_sim`` is absent.

Also: the paper's example and a 3-mode system with non-square ``Delta`` channels (one mode
without a ``B1, B2`` channel), all four ``Delta`` kinds; the named ``fault_during_delay``
variant; full-information gains; a hypothesis property over random small systems; the
instance is loaded and instantiated once and reused across paths and runs; switch counts
and norms are recorded; a renamed FMU works with a user-written map.

Controllers (``ftc_verify.controllers.Controller``): static gains run as
``Controller.state_feedback``; a dynamic controller with a trivial state on ``y_m = x``
reproduces static gains (1e-9); an observer-based controller on ``y_m = [1 2] x`` records
``ym = Cy x`` from the FMU and an ``x_c`` that a hand-written ``expm`` recursion on that
``ym`` reproduces (1e-9), and agrees with the numpy reference.
"""

from __future__ import annotations

import dataclasses

import re
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg
from hypothesis import given, settings
from hypothesis import strategies as st

fmpy = pytest.importorskip("fmpy")
if shutil.which("gcc") is None:  # pragma: no cover
    pytest.skip("gcc is needed to compile the FMU", allow_module_level=True)

from ftc_verify.simulation.paths import sample_points
from ftc_verify.simulation.spec import GRID_SNAP_RTOL
from ftc_verify.controllers import Controller, load_controller
from ftc_verify.errors import ValidationError
from ftc_verify.plants.linear_jump import build_fmu
from ftc_verify.model.system import FTCSystem
from ftc_verify.simulation.paths import communication_grid, disturbance, sample_paths
from ftc_verify.simulation.records import l2_norm
from ftc_verify.simulation.supervisor import FaultInjectionMap, Supervisor, simulate_fmu
from ftc_verify.simulation.delta import DeltaSchedule, delta_segments

from ftc_verify.simulation.reference import energies_reference, simulate_reference

RTOL = 1e-8


@pytest.fixture(scope="module", autouse=True)
def _isolated_cache(tmp_path_factory: pytest.TempPathFactory):
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("FTC_VERIFY_CACHE", str(tmp_path_factory.mktemp("ftc-verify-cache")))
        yield


# ------------------------------------------------------------------------------------------
# An independent reference loop
# ------------------------------------------------------------------------------------------


def local_reference(system, controller, paths, *, step, disturbance_kind="paper", delta=None, x0=None, seed=None):
    """Static state feedback ``controller`` (its gains); per path: grid, ``Delta`` per chain segment (drawn in path order from
    ``default_rng(seed)``), ``u_k = K[l_k] x_k`` (``K[r m + l]`` for ``m^2`` gains), ``w_k``,
    ``y_k = C[r_k] x_k``, one exact ZOH step per interval by scipy's ``expm``; ``u`` and
    ``w`` taken at the first grid point of each period ``floor((t + tol) / step)`` and held
    across the jumps inside it; at ``t_N`` the last interval's modes. Returns
    ``[(t, true, fdi, x, u, w, y)]``."""
    n, nu, ny, nw = system.dims
    m = system.m
    sched = DeltaSchedule("zero") if delta is None else (DeltaSchedule(delta) if isinstance(delta, str) else delta)
    rng = np.random.default_rng(seed)
    gains = list(controller.gains)
    full = len(gains) == m * m
    out = []
    for p in paths:
        segs = delta_segments(system, p, sched, rng)
        t, true, fdi = communication_grid(p, step)
        N = len(t) - 1
        W = disturbance(disturbance_kind, nw)(t)
        seg = np.searchsorted(p.times, t[:-1], side="right") - 1
        cache: dict = {}  # exact per (mode, segment, step size)
        x = np.zeros(n) if x0 is None else np.asarray(x0, dtype=float)
        X, U, Y = np.zeros((N + 1, n)), np.zeros((N + 1, nu)), np.zeros((N + 1, ny))
        period = np.floor((t + GRID_SNAP_RTOL * step) / step)
        for k in range(N + 1):
            r, l = true[min(k, N - 1)], fdi[min(k, N - 1)]
            md = system.modes[r]
            X[k], Y[k] = x, md.C @ x
            if k in (0, N) or period[k] > period[k - 1]:
                u, w = (gains[r * m + l] if full else gains[l]) @ x, W[k]
            U[k] = u
            if k == N:
                break
            key = (r, seg[k], t[k + 1] - t[k])
            E = cache.get(key)
            if E is None:
                d1, d2 = segs[seg[k]]
                A = md.A + (md.A1 @ d1 @ md.A2 if md.A1 is not None else 0.0)
                B = md.B + (md.B1 @ d2 @ md.B2 if md.B1 is not None else 0.0)
                M = np.zeros((n + nu + nw, n + nu + nw))
                M[:n, :n], M[:n, n:n + nu], M[:n, n + nu:] = A, B, md.D
                E = cache[key] = scipy.linalg.expm(M * key[2])
            x = E[:n, :n] @ x + E[:n, n:] @ np.concatenate([u, w])
        out.append((t, true, fdi, X, U, W, Y))
    return out


def rel_err(a: np.ndarray, b: np.ndarray) -> float:
    """``max |a - b| / max(max |b|, 1e-300)`` (relative to the signal's size on the path)."""
    scale = max(float(np.max(np.abs(b))) if b.size else 0.0, 1e-300)
    return float(np.max(np.abs(a - b))) / scale if b.size else 0.0


def assert_matches_local(result, expected) -> None:
    assert len(result.records) == len(expected)
    for rec, (t, true, fdi, X, U, W, Y) in zip(result.records, expected):
        assert np.array_equal(rec.t, t) and np.array_equal(rec.true, true) and np.array_equal(rec.fdi, fdi)
        assert np.array_equal(rec.w, W)
        assert rel_err(rec.x, X) <= RTOL, rel_err(rec.x, X)
        assert rel_err(rec.y, Y) <= RTOL, rel_err(rec.y, Y)
        assert rel_err(rec.u, U) <= RTOL, rel_err(rec.u, U)


def assert_backends_agree(fmu_res, ref_res) -> None:
    assert fmu_res.backend == "fmu"
    assert len(fmu_res.records) == len(ref_res.records)
    assert (fmu_res.step, fmu_res.horizon, fmu_res.disturbance) == (ref_res.step, ref_res.horizon, ref_res.disturbance)
    for a, b in zip(fmu_res.records, ref_res.records):
        assert np.array_equal(a.t, b.t)
        assert np.array_equal(a.true, b.true) and np.array_equal(a.fdi, b.fdi)
        assert np.allclose(a.w, b.w, rtol=1e-15, atol=0)
        for name in ("x", "y", "u"):
            err = rel_err(getattr(a, name), getattr(b, name))
            assert err <= RTOL, (name, err)
        assert a.y_norm == pytest.approx(b.y_norm, rel=RTOL)




# ------------------------------------------------------------------------------------------
# Systems
# ------------------------------------------------------------------------------------------


def random_system(seed: int, *, n=3, nu=2, ny=2, nw=1, m=3, q1=2, p1=3, q2=1, p2=2,
                  partial=True, fault_during_delay=False) -> FTCSystem:
    """A random stable-ish plant; ``Delta1`` is ``q1 x p1``, ``Delta2`` ``q2 x p2`` (0: none);
    with ``partial`` the last mode lacks the ``B1, B2`` channel."""
    g = np.random.default_rng(seed)
    modes = []
    for i in range(m):
        md = dict(A=g.uniform(-1, 1, (n, n)) - 1.0 * np.eye(n), B=g.uniform(-1, 1, (n, nu)),
                  C=g.uniform(-1, 1, (ny, n)), D=g.uniform(-1, 1, (n, nw)))
        if q1:
            md.update(A1=0.3 * g.uniform(-1, 1, (n, q1)), A2=0.3 * g.uniform(-1, 1, (p1, n)))
        if q2 and not (partial and i == m - 1):
            md.update(B1=0.3 * g.uniform(-1, 1, (n, q2)), B2=0.3 * g.uniform(-1, 1, (p2, nu)))
        modes.append(md)
    alpha = g.uniform(0.3, 1.5, (m, m))
    np.fill_diagonal(alpha, 0.0)
    np.fill_diagonal(alpha, -alpha.sum(axis=1))
    bmin = g.uniform(1.0, 3.0, (m, m))
    np.fill_diagonal(bmin, 0.0)
    return FTCSystem.from_arrays(name=f"random-{seed}", modes=modes, alpha=alpha, beta_min=bmin,
                                 beta_max=bmin * 1.5, fault_during_delay=fault_during_delay)


def random_gains(system: FTCSystem, seed: int, count: int | None = None) -> list[np.ndarray]:
    n, nu, _, _ = system.dims
    g = np.random.default_rng(seed)
    return [0.5 * g.uniform(-1, 1, (nu, n)) for _ in range(count or system.m)]


def delta_cases(system: FTCSystem):
    from ftc_verify.simulation.delta import delta_shapes

    g = np.random.default_rng(99)
    s1, s2 = delta_shapes(system)

    def unit(shape):
        if shape is None:
            return None
        G = g.standard_normal(shape)
        return 0.9 * G / np.linalg.norm(G, 2)

    d1, d2 = unit(s1), unit(s2)
    return {
        "zero": None,
        "constant": DeltaSchedule("constant", d1, d2),
        "sign": DeltaSchedule("sign", d1, d2),
        "random": DeltaSchedule("random"),
    }


@pytest.fixture(scope="module")
def paper_case(paper_system, paper_gains):
    paths = sample_paths(paper_system.chain, 10.0, 6, 2024)
    return paper_system, Controller.state_feedback(list(paper_gains)), paths


@pytest.fixture(scope="module")
def random_case():
    system = random_system(7)
    paths = sample_paths(system.chain, 4.0, 6, 11)
    return system, Controller.state_feedback(random_gains(system, 8)), paths


CASES = [(case, kind) for case in ("paper_case", "random_case") for kind in ("zero", "constant", "sign", "random")]
_FMU_RUNS: dict = {}


def fmu_run(request, case: str, kind: str):
    """The FMU result of a case (computed once per module; both comparisons reuse it)."""
    system, controller, paths = request.getfixturevalue(case)
    if (case, kind) not in _FMU_RUNS:
        x0 = np.linspace(0.5, -0.5, system.dims[0])
        _FMU_RUNS[case, kind] = simulate_fmu(system, controller, paths, step=0.01, disturbance="paper",
                                             delta=delta_cases(system)[kind], x0=x0, seed=31)
    return system, controller, paths, _FMU_RUNS[case, kind]


# ------------------------------------------------------------------------------------------
# Agreement with the reference
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("case, kind", CASES)
def test_fmu_matches_the_local_reference(request, case: str, kind: str) -> None:
    system, controller, paths, res = fmu_run(request, case, kind)
    x0 = np.linspace(0.5, -0.5, system.dims[0])
    expected = local_reference(system, controller, paths, step=0.01, delta=delta_cases(system)[kind], x0=x0, seed=31)
    assert_matches_local(res, expected)
    assert res.options["delta"] == kind and res.seed == 31
    if kind != "zero":  # Delta really acts: the nominal run differs
        nominal = fmu_run(request, case, "zero")[3]
        assert any(not np.allclose(a.x, b.x, rtol=1e-6) for a, b in zip(res.records, nominal.records))


@pytest.mark.parametrize("case, kind", CASES)
def test_fmu_matches_simulate_reference(request, case: str, kind: str) -> None:
    system, controller, paths, res = fmu_run(request, case, kind)
    x0 = np.linspace(0.5, -0.5, system.dims[0])
    ref = simulate_reference(system, controller, paths, step=0.01, disturbance="paper",
                             delta=delta_cases(system)[kind], x0=x0, seed=31)
    assert_backends_agree(res, ref)
    # the Monte-Carlo fast path: same energies
    Ey, Ew = energies_reference(system, controller, paths, step=0.01, disturbance="paper",
                                delta=delta_cases(system)[kind], x0=x0, rng=np.random.default_rng(31))
    assert np.allclose(Ey, [r.y_norm ** 2 for r in res.records], rtol=RTOL, atol=0)
    assert np.allclose(Ew, [r.w_norm ** 2 for r in res.records], rtol=RTOL, atol=0)


def test_delta_draws_come_from_the_path_or_from_rng_and_seed(random_case) -> None:
    """A sampled path draws ``Delta`` from its own stream, whatever ``seed`` says; a
    hand-built path (no stream) from ``rng`` or ``default_rng(seed)``, alike."""
    system, controller, paths = random_case
    own = [simulate_fmu(system, controller, paths[:2], step=0.05, delta="random", seed=s) for s in (5, 6)]
    bare = [dataclasses.replace(p, stream=None) for p in paths[:2]]
    a = simulate_fmu(system, controller, bare, step=0.05, delta="random", seed=5)
    b = simulate_fmu(system, controller, bare, step=0.05, delta="random", rng=np.random.default_rng(5))
    c = simulate_fmu(system, controller, bare, step=0.05, delta="random", seed=6)
    for r5, r6, ra, rb, rc in zip(own[0].records, own[1].records, a.records, b.records, c.records):
        assert np.array_equal(r5.x, r6.x)
        assert np.array_equal(ra.x, rb.x)
        assert not np.array_equal(ra.x, rc.x)
        assert not np.array_equal(r5.x, ra.x)


def test_fault_during_delay_variant_and_full_information_gains() -> None:
    """The named variant needs nothing special: its paths (fault jumps while the FDI lags)
    are followed like any other; ``m^2`` gains pick ``K[r m + l]``."""
    system = random_system(3, n=2, nu=1, ny=1, nw=2, m=2, q1=0, q2=1, p2=1, partial=False,
                           fault_during_delay=True)
    paths = sample_paths(system.chain, 6.0, 8, 4)
    lagging_jumps = sum(
        int(np.count_nonzero((np.diff(p.true) != 0) & (p.true[:-1] != p.fdi[:-1]))) for p in paths
    )
    assert lagging_jumps > 0  # the variant actually happens on these paths
    for controller in (Controller.state_feedback(random_gains(system, 1)),
                       Controller.state_feedback(random_gains(system, 2, count=4))):
        res = simulate_fmu(system, controller, paths, step=0.02, delta="random", seed=9, disturbance="sine")
        assert_matches_local(res, local_reference(system, controller, paths, step=0.02, delta="random", seed=9,
                                                  disturbance_kind="sine"))
        assert res.options["fault_during_delay"] is True
        assert res.options["gains"] == ("fdi" if controller.entries == 2 else "full-information")
        assert_backends_agree(res, simulate_reference(system, controller, paths, step=0.02, disturbance="sine",
                                                      delta="random", seed=9))


# ------------------------------------------------------------------------------------------
# Property: random small systems and seeds
# ------------------------------------------------------------------------------------------


@st.composite
def small_problems(draw):
    m = draw(st.integers(2, 3))
    n = draw(st.integers(1, 3))
    nu = draw(st.integers(1, 2))
    ny = draw(st.integers(1, 2))
    nw = draw(st.integers(1, 2))
    q1 = draw(st.integers(0, 2))
    q2 = draw(st.integers(0, 1))
    system = random_system(draw(st.integers(0, 2**31 - 1)), n=n, nu=nu, ny=ny, nw=nw, m=m,
                           q1=q1, p1=draw(st.integers(1, 2)) if q1 else 0, q2=q2, p2=1 if q2 else 0,
                           partial=draw(st.booleans()), fault_during_delay=draw(st.booleans()))
    controller = Controller.state_feedback(random_gains(system, draw(st.integers(0, 1000))))
    seed = draw(st.integers(0, 2**31 - 1))
    paths = sample_paths(system.chain, draw(st.sampled_from([0.5, 1.7, 3.0])), 2, seed)
    step = draw(st.sampled_from([0.013, 0.05, 0.1]))
    kind = draw(st.sampled_from(["zero", "sign", "random"]))
    delta = delta_cases(system)["sign"] if kind == "sign" else kind
    dist = draw(st.sampled_from(["paper", "step", "pulse"]))
    x0 = draw(st.lists(st.floats(-1, 1), min_size=n, max_size=n))
    return system, controller, paths, step, delta, dist, x0, seed


@settings(max_examples=8)
@given(small_problems())
def test_property_backends_agree_on_random_systems(problem) -> None:
    system, controller, paths, step, delta, dist, x0, seed = problem
    res = simulate_fmu(system, controller, paths, step=step, disturbance=dist, delta=delta, x0=x0, seed=seed)
    ref = simulate_reference(system, controller, paths, step=step, disturbance=dist, delta=delta, x0=x0, seed=seed)
    assert_backends_agree(res, ref)


# ------------------------------------------------------------------------------------------
# Instance reuse, records
# ------------------------------------------------------------------------------------------


def test_library_loaded_and_instantiated_once(paper_case, monkeypatch: pytest.MonkeyPatch) -> None:
    from fmpy.fmi2 import FMU2Slave

    system, controller, paths = paper_case
    calls = {"init": 0, "instantiate": 0}
    orig_init, orig_inst = FMU2Slave.__init__, FMU2Slave.instantiate

    def counting_init(self, *a, **kw):
        calls["init"] += 1
        orig_init(self, *a, **kw)

    def counting_inst(self, *a, **kw):
        calls["instantiate"] += 1
        return orig_inst(self, *a, **kw)

    monkeypatch.setattr(FMU2Slave, "__init__", counting_init)
    monkeypatch.setattr(FMU2Slave, "instantiate", counting_inst)
    fmu = build_fmu(system)
    with Supervisor(fmu, system=system) as sup:
        slave = sup.slave
        first = sup.run(paths, controller, step=0.05, x0=[1.0, -1.0])
        second = sup.run(paths[::-1], controller, step=0.05, x0=[1.0, -1.0])
        assert sup.slave is slave
        assert sup.stats["library_loads"] == sup.stats["instantiations"] == 1
        assert sup.stats["resets"] == 2 * len(paths) - 1 and sup.stats["paths"] == 2 * len(paths)
        assert sup.stats["steps"] == sum(len(r.t) - 1 for r in first.records + second.records)
    assert calls == {"init": 1, "instantiate": 1}
    # a reset instance gives bit-identical results, in any order of paths
    for a, b in zip(first.records, second.records[::-1]):
        assert a.path is b.path and np.array_equal(a.x, b.x) and np.array_equal(a.y, b.y)
    with Supervisor(fmu, system=system) as fresh:
        again = fresh.run([paths[-1]], controller, step=0.05, x0=[1.0, -1.0])
    assert np.array_equal(again.records[0].x, first.records[-1].x)
    assert sup.closed and sup.slave is None and sup.extraction_dir is None


def test_switches_norms_and_grid_are_recorded(request) -> None:
    _system, controller, paths, res = fmu_run(request, "paper_case", "random")
    summary = res.to_dict()
    assert summary["backend"] == "fmu" and summary["paths"] == len(paths) and summary["step"] == 0.01
    assert summary["horizon"] == 10.0 and summary["disturbance"] == "paper"
    assert any(s["fault"] > 0 for s in summary["switches"])
    for rec, path, sw, yn, wn in zip(res.records, paths, summary["switches"], summary["y_norm"], summary["w_norm"]):
        assert rec.path is path
        assert sw == {"fault": path.fault_switches, "fdi": path.fdi_switches}
        # the grid holds every jump time, and the recorded modes switch exactly there
        assert set(path.times[1:]) <= set(rec.t)
        assert int(np.count_nonzero(np.diff(rec.true))) == path.fault_switches
        assert int(np.count_nonzero(np.diff(rec.fdi))) == path.fdi_switches
        assert rec.x.shape == (len(rec.t), 2) and rec.u.shape == (len(rec.t), 2)
        assert rec.w.shape == rec.y.shape == (len(rec.t), 1)
        assert yn == l2_norm(rec.t, rec.y) and wn == l2_norm(rec.t, rec.w)
        assert np.all(np.isfinite(rec.x)) and rec.x[0] == pytest.approx([0.5, -0.5])
        # u is the held control: K[fdi] x at each sample k step (last point: last FDI mode),
        # the same value at the jump times inside the period
        l_at = np.append(rec.fdi, rec.fdi[-1])
        fresh = np.einsum("kij,kj->ki", np.stack(controller.gains)[l_at], rec.x)
        last = np.maximum.accumulate(np.where(sample_points(path, 0.01, rec.t), np.arange(len(rec.t)), 0))
        assert np.allclose(rec.u, fresh[last], rtol=1e-13, atol=1e-15)
        assert np.any(last != np.arange(len(rec.t)))  # some jump falls inside a period
    # the paper's ||w||_2 on [0, 10] for w = exp(-0.1 t) sin t (READING-NOTES: 1.5733 on [0, inf))
    assert 1.40 < summary["w_norm"][0] < 1.5733


def test_single_path_and_argument_checks(paper_case) -> None:
    system, controller, paths = paper_case
    res = simulate_fmu(system, controller, paths[0], step=0.1, disturbance="zero")
    assert len(res.records) == 1 and np.all(res.records[0].x == 0.0)  # x0 = 0, w = 0: stays at rest
    with pytest.raises(ValidationError, match="unknown kind"):
        simulate_fmu(system, controller, paths[:1], step=0.1, disturbance="wind")
    with pytest.raises(ValidationError, match="delta: unknown kind"):
        simulate_fmu(system, controller, paths[:1], step=0.1, delta="wild")
    with pytest.raises(ValidationError, match="paths"):
        simulate_fmu(system, controller, [], step=0.1)


# ------------------------------------------------------------------------------------------
# A user's FMU: same plant, other names, a hand-written map
# ------------------------------------------------------------------------------------------

RENAMES = {
    r"x0\[(\d+)\]": r"init.x\1", r"u\[(\d+)\]": r"actuators.u\1", r"w\[(\d+)\]": r"environment.gust\1",
    r"Delta1\[(\d+),(\d+)\]": r"uncertainty.dA_\1_\2", r"Delta2\[(\d+),(\d+)\]": r"uncertainty.dB_\1_\2",
    r"x\[(\d+)\]": r"plant.state\1", r"y\[(\d+)\]": r"sensors.y\1", r"mode": r"health.faultIndex",
}


def test_user_map_on_a_renamed_fmu(paper_case, tmp_path: Path) -> None:
    system, controller, paths = paper_case
    original = build_fmu(system, tmp_path / "original.fmu")

    def rename(xml: str) -> str:
        for pattern, repl in RENAMES.items():
            xml = re.sub(f'name="{pattern}"', f'name="{repl}"', xml)
        return xml.replace('variableNamingConvention="structured"', 'variableNamingConvention="flat"')

    renamed = tmp_path / "Renamed.fmu"
    with zipfile.ZipFile(original) as zin, zipfile.ZipFile(renamed, "w") as zout:
        for item in zin.infolist():
            data = zin.read(item)
            if item.filename == "modelDescription.xml":
                data = rename(data.decode()).encode()
                assert b'name="u[1]"' not in data and b'name="health.faultIndex"' in data
            zout.writestr(item, data)
    user_map = FaultInjectionMap(
        fault="health.faultIndex", fault_values=(1, 2),
        inputs=["actuators.u1", "actuators.u2"], disturbances=["environment.gust1"],
        states=["plant.state1", "plant.state2"], outputs=["sensors.y1"],
        initial_states=["init.x1", "init.x2"],
        delta1=[f"uncertainty.dA_{i}_{j}" for i in (1, 2) for j in (1, 2)],
        delta2=[f"uncertainty.dB_{i}_{j}" for i in (1, 2) for j in (1, 2)],
    )
    kw = dict(step=0.02, delta="random", x0=[0.3, 0.1], seed=4)
    with Supervisor(renamed, user_map, system=system) as sup:
        mine = sup.run(paths[:3], controller, **kw)
    theirs = simulate_fmu(system, controller, paths[:3], **kw)
    for a, b in zip(mine.records, theirs.records):
        for name in ("t", "x", "u", "w", "y"):
            assert np.array_equal(getattr(a, name), getattr(b, name)), name
    # without the system (no Delta), a user FMU still runs with a nominal plant
    with Supervisor(renamed, FaultInjectionMap(fault="health.faultIndex", inputs=user_map.inputs,
                                               states=user_map.states, disturbances=user_map.disturbances,
                                               outputs=user_map.outputs)) as sup:
        nominal = sup.run(paths[:1], controller, step=0.02)
        with pytest.raises(ValidationError, match="needs the system"):
            sup.run(paths[:1], controller, step=0.02, delta="random")
        with pytest.raises(ValidationError, match="no initial_states"):
            sup.run(paths[:1], controller, step=0.02, x0=[1.0, 0.0])
    assert np.array_equal(nominal.records[0].x, simulate_fmu(system, controller, paths[:1], step=0.02).records[0].x)


# ------------------------------------------------------------------------------------------
# Controllers: dynamic, output feedback
# ------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def paper_from_files():
    from ftc_verify.model.files import load_system

    examples = Path(__file__).resolve().parents[1] / "examples"
    return load_system(examples / "paper.toml"), load_controller(examples / "paper_gains.toml")


def test_dynamic_controller_with_trivial_state_equals_static_gains(paper_from_files) -> None:
    """``Ac = -I, Bc = 0, Cc = 0, Dc = K`` on ``y_m = I x`` is ``u = K x``: the same paths (1e-9)."""
    paper, static = paper_from_files
    assert static.is_state_feedback
    system = paper.with_measured_output(np.eye(2))
    K = static.gains
    dynamic = Controller.dynamic([-np.eye(2)] * 2, [np.zeros((2, 2))] * 2, [np.zeros((2, 2))] * 2, list(K))
    paths = sample_paths(system.chain, 6.0, 4, 8)
    kw = dict(step=0.01, delta="random", x0=[0.8, -0.4], seed=12)
    dyn = simulate_fmu(system, dynamic, paths, **kw)
    ref = simulate_fmu(paper, static, paths, **kw)
    static_output = Controller.dynamic([np.zeros((0, 0))] * 2, [np.zeros((0, 2))] * 2, [np.zeros((2, 0))] * 2,
                                       list(K))  # u = K y_m, n_c = 0
    sof = simulate_fmu(system, static_output, paths, **kw)
    assert dyn.options["controller"] != ref.options["controller"]
    for a, b, c in zip(dyn.records, ref.records, sof.records):
        assert c.xc.shape == (len(c.t), 0) and np.allclose(c.x, b.x, rtol=1e-9, atol=1e-12)
        assert np.array_equal(a.t, b.t) and np.array_equal(a.fdi, b.fdi)
        for name in ("x", "u", "y"):
            assert np.allclose(getattr(a, name), getattr(b, name), rtol=1e-9, atol=1e-12), name
        assert a.xc.shape == (len(a.t), 2) and np.all(a.xc == 0.0)  # Bc = 0: x_c stays at 0
        assert b.xc.shape == (len(b.t), 0) and np.array_equal(b.ym, b.x)  # static: v = x
        assert np.allclose(a.ym, a.x, rtol=1e-14, atol=1e-15)  # Cy = I: the FMU's ym is x
        assert np.any(np.abs(a.u) > 0.1)  # the control acts


#: Observer gains for the paper example with ``Cy = [1 2]``: ``A_l - L_l Cy`` and the controller
#: matrix ``A_l + B_l K_l - L_l Cy`` are both Hurwitz (so replaying ``ym`` through ``x_c`` is stable).
PAPER_L = (np.array([[7.9], [-2.8]]), np.array([[57.5], [-25.5]]))


def observer_controller(system: FTCSystem, K, Cy: np.ndarray, Ls=PAPER_L) -> Controller:
    """Per FDI mode l: ``Ac = A_l + B_l K_l - L_l Cy, Bc = L_l, Cc = K_l, Dc = 0``."""
    Ac, Bc, Cc, Dc = [], [], [], []
    for md, Kl, L in zip(system.modes, K, Ls):
        assert np.all(np.linalg.eigvals(md.A - L @ Cy).real < -0.2)  # the observer converges
        Ac.append(md.A + md.B @ Kl - L @ Cy)
        assert np.all(np.linalg.eigvals(Ac[-1]).real < -0.2)
        Bc.append(L)
        Cc.append(np.asarray(Kl))
        Dc.append(np.zeros((Kl.shape[0], Cy.shape[0])))
    return Controller.dynamic(Ac, Bc, Cc, Dc, name="observer")


def test_observer_based_controller_xc_recursion(paper_from_files) -> None:
    """An observer-based controller on ``y_m = [1 2] x``: the FMU's recorded ``ym`` is
    ``Cy x``; ``x_c`` follows the exact recursion of a hand-written ``scipy.linalg.expm``
    loop on that ``ym`` (1e-9), ``u = Cc x_c``; and the numpy reference agrees."""
    paper, static = paper_from_files
    Cy = np.array([[1.0, 2.0]])
    system = paper.with_measured_output(Cy)
    ctrl = observer_controller(system, static.gains, Cy)
    paths = sample_paths(system.chain, 5.0, 4, 21)
    assert any(p.fdi_switches for p in paths)
    res = simulate_fmu(system, ctrl, paths, step=0.01, delta="sign", x0=[0.5, -0.3], seed=3)
    nc = ctrl.n_c
    for rec in res.records:
        N = len(rec.t) - 1
        assert rec.ym.shape == (N + 1, 1) and rec.xc.shape == (N + 1, nc)
        assert np.allclose(rec.ym, rec.x @ Cy.T, rtol=1e-13, atol=1e-14)
        xc = np.zeros(nc)
        sample = sample_points(rec.path, 0.01, rec.t)  # entry, ym and u held between samples
        for k in range(N + 1):
            if sample[k]:
                e, v = int(rec.fdi[min(k, N - 1)]), rec.ym[k]
                u = ctrl.Cc[e] @ xc + ctrl.Dc[e] @ v
            assert rel_err(rec.xc[k], xc) <= 1e-9 or np.max(np.abs(rec.xc[k] - xc)) <= 1e-12, k
            assert np.allclose(rec.u[k], u, rtol=1e-9, atol=1e-12), k
            if k == N:
                break
            M = np.zeros((nc + 1, nc + 1))
            M[:nc, :nc], M[:nc, nc:] = ctrl.Ac[e], ctrl.Bc[e]
            E = scipy.linalg.expm(M * (rec.t[k + 1] - rec.t[k]))
            xc = E[:nc, :nc] @ xc + E[:nc, nc:] @ v
        assert np.max(np.abs(rec.xc)) > 1e-3  # the observer state moves
    ref = simulate_reference(system, ctrl, paths, step=0.01, delta="sign", x0=[0.5, -0.3], seed=3)
    for a, b in zip(res.records, ref.records):
        for name in ("x", "y", "u", "xc", "ym"):
            assert rel_err(getattr(a, name), getattr(b, name)) <= 1e-9, name


def test_output_feedback_needs_matching_measured_outputs(paper_case) -> None:
    system, controller, paths = paper_case
    Cy = np.array([[1.0, 2.0]])
    ctrl = observer_controller(system.with_measured_output(Cy), controller.gains, Cy)
    wide = Controller.dynamic(ctrl.Ac, [np.hstack([b, b]) for b in ctrl.Bc], ctrl.Cc,
                              [np.zeros((2, 2))] * 2)  # reads 2 measured outputs, the system has 1
    with Supervisor(build_fmu(system), system=system) as sup:
        with pytest.raises(ValidationError, match="measured outputs"):
            sup.run(paths[:1], wide, step=0.05)
        assert sup.run(paths[:1], ctrl, step=0.05).records[0].xc.shape[1] == 2
        assert sup.stats["paths"] == 1
