"""The float64 augmented loop, sample jumps and coordinates computed once for the gain
certificate and the lower bound (:func:`ftc_verify.analysis.moments.sampled_frame.float_frame`).

The shared frame must be the same bits as computing it afresh (it is the same float64
operations), be computed once per loop and period however many stages read it, and leave
the certificate and the proved lower bound bit for bit as they are when each stage has a
loop of its own (the values of ``main`` before the change were compared in
``benchmarks/results/h31r.md``: identical hex on the paper loop and a similarity of condition 1e3).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

import ftc_verify.analysis.moments.sampled_frame as frame_module
from ftc_verify.analysis.moments.sampled import SampledLoop
from ftc_verify.analysis.moments.sampled_frame import coordinates, float_frame
from ftc_verify.analysis.moments.sampled_gamma import augmented_loop, sample_jumps, sampled_gamma
from ftc_verify.analysis.moments.sampled_lower import sampled_lower_bound
from ftc_verify.controllers.controller import Controller
from ftc_verify.controllers.files import load_controller
from ftc_verify.model.files import load_system
from ftc_verify.model.system import FTCSystem
from ftc_verify.testing.illconditioned import similarity

ROOT = Path(__file__).resolve().parents[1]
H = 0.05


def _moved(system: FTCSystem, controller: Controller, T: np.ndarray) -> tuple[FTCSystem, Controller]:
    """The loop in the states ``x' = T x`` (same chain; nominal)."""
    Ti = np.linalg.inv(T)
    modes = [{"A": T @ md.A @ Ti, "B": T @ md.B, "C": md.C @ Ti, "D": T @ md.D} for md in system.modes]
    ch = system.chain
    moved = FTCSystem.from_arrays(name="moved", modes=modes, alpha=ch.alpha, beta_min=ch.beta_min, beta_max=ch.beta_max)
    return moved, Controller.state_feedback([K @ Ti for K in controller.Dc])


@pytest.fixture(scope="module", params=["paper", "similarity 1e3"])
def case(request: pytest.FixtureRequest) -> tuple[FTCSystem, Controller]:
    system = load_system(ROOT / "examples" / "paper.toml")
    controller = load_controller(ROOT / "examples" / "paper_gains.toml")
    if request.param == "paper":
        return system, controller
    return _moved(system, controller, similarity(np.random.default_rng(31), 2, 1e4, 1e3))


def _same(a: np.ndarray | None, b: np.ndarray | None) -> bool:
    if a is None or b is None:
        return a is None and b is None
    return bool(np.array_equal(np.asarray(a), np.asarray(b)) and np.asarray(a).dtype == np.asarray(b).dtype)


def test_frame_is_the_fresh_computation_bit_for_bit(case: tuple[FTCSystem, Controller]) -> None:
    system, controller = case
    loop = SampledLoop.build(system, controller)
    frame = float_frame(loop, system, H)
    aug, jumps = augmented_loop(loop, system), sample_jumps(loop, H)
    coords = coordinates(aug, jumps, loop, system)
    for name in ("A", "Bw", "Cz"):
        assert all(_same(x, y) for x, y in zip(getattr(frame.aug, name), getattr(aug, name), strict=True))
    assert all(_same(x, y) for x, y in zip(frame.jumps, jumps, strict=True))
    assert (frame.coords.w_scale, frame.coords.z_scale) == (coords.w_scale, coords.z_scale)
    assert _same(frame.coords.T, coords.T) and _same(frame.coords.T_inv, coords.T_inv)
    assert float_frame(loop, system, H) is frame  # kept
    assert float_frame(loop, system, 2 * H) is not frame  # per period
    assert dataclasses.replace(loop).memo == {}  # a copy starts empty


def test_one_frame_for_the_certificate_and_the_lower_bound(case: tuple[FTCSystem, Controller],
                                                           monkeypatch: pytest.MonkeyPatch) -> None:
    """Both stages on one loop compute the coordinates once (they were computed three
    times: the certificate and the lower bound's float search and proof), and give the
    same bits as each on a loop of its own."""
    system, controller = case
    alone_gamma = sampled_gamma(system, controller, H, robust=False, pieces=(4,),
                                loop=SampledLoop.build(system, controller)).gamma
    alone_lower = sampled_lower_bound(system, controller, H, robust=False,
                                      loop=SampledLoop.build(system, controller)).value
    calls = []
    real = frame_module.coordinates

    def counted(*args: object) -> object:
        calls.append(1)
        return real(*args)  # type: ignore[arg-type]

    monkeypatch.setattr(frame_module, "coordinates", counted)
    loop = SampledLoop.build(system, controller)
    lower = sampled_lower_bound(system, controller, H, robust=False, loop=loop).value
    gamma = sampled_gamma(system, controller, H, robust=False, pieces=(4,), loop=loop).gamma
    assert len(calls) == 1
    assert gamma is not None and alone_gamma is not None and gamma.hex() == alone_gamma.hex()
    assert lower is not None and alone_lower is not None and lower.hex() == alone_lower.hex()
    assert lower <= gamma
