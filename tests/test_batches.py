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
    assert seen == [5, 5, 5, 5, 3]
    assert batched.options == whole.options and batched.seed == whole.seed == 2
    assert len(batched.records) == 23
    for a, b in zip(batched.records, whole.records):
        np.testing.assert_array_equal(a.x, b.x)
        np.testing.assert_array_equal(a.y, b.y)


def test_streamed_reference_reports_every_batch() -> None:
    paths = sample_paths(SYSTEM.chain, 3.0, 23, 8)
    seen: list[int] = []
    res = simulate_streaming(SYSTEM, GAINS, paths, step=0.01, rng=np.random.default_rng(2), batch=10,
                             done=seen.append)
    assert seen == [10, 10, 3] and len(res.y_norm) == 23
