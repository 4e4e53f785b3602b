"""The supervisor's direct loop for static controllers (``loop_parts.StaticLoop``) against its general loop.

``StaticLoop`` makes the FMI 2.0 calls itself (the status checked inline) and keeps the rows
as lists; it must give the records of the general loop (``PathInputs``/``PathController``/
``PathRecorder``, forced here by making ``StaticLoop.applies`` false) bit for bit: state
feedback with random ``Delta`` and an initial state, full-information gains on a 3-mode
plant, static output feedback on ``y_m``, a diverging path (truncated at the same grid
point), and a ``fmi2DoStep`` returning ``fmi2Error`` in the loop (the same failed record
and message). Deterministic: fixed seeds, no statistics.
"""

from __future__ import annotations

import dataclasses
import shutil

import numpy as np
import pytest

fmpy = pytest.importorskip("fmpy")
if shutil.which("gcc") is None:  # pragma: no cover
    pytest.skip("gcc is needed to compile the FMU", allow_module_level=True)

from ftc_verify.controllers import Controller
from ftc_verify.model.system import FTCSystem
from ftc_verify.simulation import loop_parts
from ftc_verify.simulation.paths import sample_paths
from ftc_verify.simulation.supervisor import open_supervisor


@pytest.fixture(scope="module", autouse=True)
def _isolated_cache(tmp_path_factory: pytest.TempPathFactory):
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("FTC_VERIFY_CACHE", str(tmp_path_factory.mktemp("ftc-verify-cache")))
        yield


def three_mode_system() -> FTCSystem:
    g = np.random.default_rng(5)
    modes = [dict(A=g.uniform(-1, 1, (3, 3)) - np.eye(3), B=g.uniform(-1, 1, (3, 2)), C=g.uniform(-1, 1, (2, 3)),
                  D=g.uniform(-1, 1, (3, 1)), A1=0.3 * g.uniform(-1, 1, (3, 2)), A2=0.3 * g.uniform(-1, 1, (2, 3)))
             for _ in range(3)]
    alpha = g.uniform(0.5, 1.5, (3, 3))
    np.fill_diagonal(alpha, 0.0)
    np.fill_diagonal(alpha, -alpha.sum(axis=1))
    bmin = g.uniform(1.0, 3.0, (3, 3))
    np.fill_diagonal(bmin, 0.0)
    return FTCSystem.from_arrays(name="three-modes", modes=modes, alpha=alpha, beta_min=bmin, beta_max=1.5 * bmin)


def run_both(system: FTCSystem, controller: Controller, paths, monkeypatch: pytest.MonkeyPatch, **options):
    """``(direct, general)``: the result of the direct loop and of the general loop on one
    supervisor, and how many paths the direct loop ran."""
    used = []
    run = loop_parts.StaticLoop.run

    def counted(self, *args):
        used.append(1)
        return run(self, *args)

    with open_supervisor(system) as sup:
        with monkeypatch.context() as mp:
            mp.setattr(loop_parts.StaticLoop, "run", counted)
            direct = sup.run(paths, controller, seed=3, **options)
        with monkeypatch.context() as mp:
            mp.setattr(loop_parts.StaticLoop, "applies", staticmethod(lambda *a: False))
            general = sup.run(paths, controller, seed=3, **options)
    assert len(used) == len(paths)  # the direct loop ran every path of the first run
    return direct, general


def assert_same_records(a, b) -> None:
    assert len(a.records) == len(b.records)
    for ra, rb in zip(a.records, b.records, strict=True):
        for key in ("t", "true", "fdi", "x", "u", "w", "y", "xc", "ym"):
            va, vb = getattr(ra, key), getattr(rb, key)
            assert va.shape == vb.shape and va.tobytes() == vb.tobytes(), key
        assert ra.diverged_at == rb.diverged_at and ra.failure == rb.failure
    assert a.options == b.options


def test_state_feedback_random_delta_bit_for_bit(paper_system, paper_gains, monkeypatch) -> None:
    paths = sample_paths(paper_system.chain, 3.0, 4, 7)
    ctrl = Controller.state_feedback(list(paper_gains))
    direct, general = run_both(paper_system, ctrl, paths, monkeypatch, step=0.01, disturbance="paper",
                               delta="random", x0=[0.4, -0.3])
    assert_same_records(direct, general)
    assert all(np.any(r.u != 0) for r in direct.records)


def test_full_information_gains_on_three_modes(monkeypatch) -> None:
    system = three_mode_system()
    g = np.random.default_rng(2)
    ctrl = Controller.state_feedback([0.3 * g.uniform(-1, 1, (2, 3)) for _ in range(9)])
    paths = sample_paths(system.chain, 2.0, 3, 4)
    direct, general = run_both(system, ctrl, paths, monkeypatch, step=0.02, disturbance="paper", delta="random")
    assert_same_records(direct, general)
    assert {int(v) for r in direct.records for v in r.true} != {0}  # the paths switch modes


def test_static_output_feedback_on_ym(paper_system, monkeypatch) -> None:
    Dc = [np.array([[-0.5], [0.2]]), np.array([[-0.3], [0.1]])]
    ctrl = Controller.dynamic([np.zeros((0, 0))] * 2, [np.zeros((0, 1))] * 2, [np.zeros((2, 0))] * 2, Dc)
    paths = sample_paths(paper_system.chain, 2.0, 3, 9)
    direct, general = run_both(paper_system, ctrl, paths, monkeypatch, step=0.01, disturbance="paper",
                               x0=[0.2, 0.1])
    assert_same_records(direct, general)
    assert np.array_equal(direct.records[0].ym[:, 0], direct.records[0].y[:, 0])  # y_m = C x here


def test_diverging_path_stops_at_the_same_point(paper_system, monkeypatch) -> None:
    ctrl = Controller.state_feedback([np.full((2, 2), 40.0)] * 2)  # destabilising
    paths = sample_paths(paper_system.chain, 5.0, 2, 1)
    direct, general = run_both(paper_system, ctrl, paths, monkeypatch, step=0.01, x0=[1.0, 1.0])
    assert_same_records(direct, general)
    assert all(r.diverged_at is not None for r in direct.records)


def test_failing_step_gives_the_same_failed_record(paper_system, paper_gains, monkeypatch) -> None:
    """``fmi2DoStep`` returns fmi2Error (3) from t = 0.5 on: a failed record kept up to
    that point, the message naming the call and the time, in both loops."""
    paths = sample_paths(paper_system.chain, 1.0, 2, 3)
    ctrl = Controller.state_feedback(list(paper_gains))
    results = []
    for direct in (True, False):
        with open_supervisor(paper_system) as sup, monkeypatch.context() as mp:
            s = sup.session
            get, put, step, _ = s.raw_calls()

            def failing(c, t, h, flag, step=step):
                return 3 if t >= 0.5 else step(c, t, h, flag)

            def checked(c, t, h, failing=failing):
                status = failing(c, t, h, 1)
                if status > 1:
                    raise fmpy.fmi1.FMICallException(function="fmi2DoStep", status=status)
                return status

            mp.setattr(s, "_calls", dataclasses.replace(s._calls, do_step=checked, raw=(get, put, failing)))
            if not direct:
                mp.setattr(loop_parts.StaticLoop, "applies", staticmethod(lambda *a: False))
            results.append(sup.run(paths, ctrl, step=0.1, disturbance="paper"))
    assert_same_records(*results)
    for r in results[0].records:
        assert "fmi2DoStep returned Error" in r.failure and "t = 0.5" in r.failure
        assert r.t[-1] == pytest.approx(0.5)
