"""Monte Carlo in batches (ftc_verify.simulation.batches): the batched FMU run equals one
``Supervisor.run`` over every path, and each finished batch is reported (the progress bar
of ``simulate`` and ``verify``), on the FMU and on the streamed reference backend."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ftc_verify.controllers import load_controller
from ftc_verify.model.files import load_system
from ftc_verify.simulation.batches import fmu_monte_carlo
from ftc_verify.simulation.delta import DeltaSchedule
from ftc_verify.simulation.paths import sample_paths
from ftc_verify.simulation.streaming import simulate_streaming
from ftc_verify.simulation.supervisor import simulate_fmu

ROOT = Path(__file__).resolve().parents[1]
SYSTEM = load_system(ROOT / "examples" / "paper.toml")
GAINS = load_controller(ROOT / "examples" / "paper_gains.toml")


def test_batched_fmu_run_equals_one_run_and_reports_every_batch() -> None:
    paths = sample_paths(SYSTEM.chain, 3.0, 23, 8)
    delta = DeltaSchedule("random")
    whole = simulate_fmu(SYSTEM, GAINS, paths, step=0.01, delta=delta, rng=np.random.default_rng(2), seed=2)
    seen: list[int] = []
    batched = fmu_monte_carlo(SYSTEM, GAINS, paths, step=0.01, delta=delta, rng=np.random.default_rng(2), seed=2,
                              batch=5, done=seen.append)
    assert sorted(seen) == [3, 5, 5, 5, 5]  # once per batch; two watched children report as they finish
    assert batched.options == whole.options and batched.seed == whole.seed == 2
    assert len(batched.records) == 23
    for a, b in zip(batched.records, whole.records):
        np.testing.assert_array_equal(a.x, b.x)
        np.testing.assert_array_equal(a.y, b.y)


def test_isolated_children_continue_the_serial_generator() -> None:
    """Paths without their own stream draw ``Delta`` from the shared generator in turn; the
    batches split over two watched children (``isolate``, the default) start from the
    states a serial in-process run has there: the same records, and the generator ends
    where the serial run leaves it."""
    import dataclasses

    from ftc_verify.simulation.isolated import plant_processes

    paths = [dataclasses.replace(p, stream=None) for p in sample_paths(SYSTEM.chain, 2.0, 7, 3)]
    delta = DeltaSchedule("random")
    rng_serial, rng_split = np.random.default_rng(5), np.random.default_rng(5)
    serial = fmu_monte_carlo(SYSTEM, GAINS, paths, step=0.01, delta=delta, rng=rng_serial, batch=2, isolate=False)
    split = fmu_monte_carlo(SYSTEM, GAINS, paths, step=0.01, delta=delta, rng=rng_split, batch=2,
                            processes=plant_processes(2))
    assert len(split.records) == 7
    for a, b in zip(split.records, serial.records, strict=True):
        np.testing.assert_array_equal(a.x, b.x)
        np.testing.assert_array_equal(a.u, b.u)
    assert rng_split.bit_generator.state == rng_serial.bit_generator.state


def test_streamed_reference_reports_every_batch() -> None:
    paths = sample_paths(SYSTEM.chain, 3.0, 23, 8)
    seen: list[int] = []
    res = simulate_streaming(SYSTEM, GAINS, paths, step=0.01, rng=np.random.default_rng(2), batch=10,
                             done=seen.append)
    assert seen == [10, 10, 3] and len(res.y_norm) == 23
