"""Streaming reference simulation (ftc_verify.simulation.streaming): the same numbers as the
per-path simulator on the same paths and ``Delta`` draws (1e-12), divergences at the same
times, trajectories only for the recorded paths, batches that do not change the answer."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import cli_inprocess
import numpy as np
import pytest

from ftc_verify.controllers import Controller, load_controller
from ftc_verify.model.files import load_system
from ftc_verify.simulation.paths import sample_paths
from ftc_verify.simulation.reference import simulate_reference
from ftc_verify.simulation.streaming import simulate_streaming

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "examples" / "paper.toml"


@pytest.mark.parametrize("delta, own_stream", [("zero", True), ("random", True), ("random", False), ("sign", True)])
def test_streaming_equals_per_path(delta: str, own_stream: bool) -> None:
    """Sampled paths draw ``Delta`` from their own streams; hand-built ones (no stream)
    from the one generator, in path order, which the batches replay."""
    system, gains = load_system(PAPER), load_controller(ROOT / "examples" / "paper_gains.toml")
    paths = sample_paths(system.chain, 8.0, 12, 1)
    if not own_stream:
        paths = [dataclasses.replace(p, stream=None) for p in paths]
    a = simulate_reference(system, gains, paths, step=0.01, delta=delta, rng=np.random.default_rng(7), seed=7)
    b = simulate_streaming(system, gains, paths, step=0.01, delta=delta, rng=np.random.default_rng(7), seed=7,
                           record=3, batch=5)
    ya = np.array([r.y_norm for r in a.records])
    wa = np.array([r.w_norm for r in a.records])
    np.testing.assert_allclose(b.y_norm, ya, rtol=1e-12)
    np.testing.assert_allclose(b.w_norm, wa, rtol=1e-12)
    da, db = a.to_dict(), b.to_dict()
    assert set(da) == set(db) and da["switches"] == db["switches"] and da["beta"] == db["beta"]
    assert len(b.records) == 3
    for ra, rb in zip(a.records, b.records):
        np.testing.assert_array_equal(ra.x, rb.x)  # the recorded paths see the same Delta draws


def test_a_path_gives_the_same_numbers_in_any_company() -> None:
    """Per-path streams (``SeedSequence(seed).spawn``): paths 7..9 of a run of 12 give the
    same energies simulated alone, in other batches, as in the full run."""
    system, gains = load_system(PAPER), load_controller(ROOT / "examples" / "paper_gains.toml")
    paths = sample_paths(system.chain, 8.0, 12, 4)
    full = simulate_streaming(system, gains, paths, step=0.01, delta="random", batch=5)
    part = simulate_streaming(system, gains, paths[7:10], step=0.01, delta="random", batch=2)
    np.testing.assert_allclose(part.y_norm, full.y_norm[7:10], rtol=1e-12)
    np.testing.assert_allclose(part.w_norm, full.w_norm[7:10], rtol=1e-12)
    assert len(set(full.y_norm.tolist())) == 12


def test_streaming_reports_divergence_times_like_per_path() -> None:
    system = load_system(PAPER)
    unstable = Controller.state_feedback([np.array([[5.0, 0.0], [0.0, 5.0]])] * 2)
    paths = sample_paths(system.chain, 30.0, 4, 3)
    a = simulate_reference(system, unstable, paths, step=0.01, delta="random", rng=np.random.default_rng(5))
    b = simulate_streaming(system, unstable, paths, step=0.01, delta="random", rng=np.random.default_rng(5), record=1)
    times = {k: r.diverged_at for k, r in enumerate(a.records) if r.diverged_at is not None}
    assert times and b.diverged_at == pytest.approx(times)
    assert b.to_dict()["divergence"] == a.to_dict()["divergence"]
    assert np.all(np.isinf(b.y_norm[list(times)]))


def test_cli_simulate_reference_streams(tmp_path: Path) -> None:
    out = cli_inprocess.run_cli(["simulate", str(PAPER), "--gains", str(ROOT / "examples" / "paper_gains.toml"),
                                 "--backend", "reference", "--paths", "30", "--horizon", "5", "--seed", "2", "--json"])
    assert out.returncode == 0, out.stderr
    d = json.loads(out.stdout)
    assert d["paths"] == 30 and len(d["y_norm"]) == 30 and d["options"]["streamed"] and d["options"]["recorded"] == 0
    out = cli_inprocess.run_cli(["simulate", str(PAPER), "--gains", str(ROOT / "examples" / "paper_gains.toml"),
                                 "--backend", "reference", "--record", "-1"])
    assert out.returncode == 2 and "--record" in out.stderr


class _StillStarting:
    """A local cluster that never finishes starting (the ``ClusterStart`` protocol)."""

    def __init__(self) -> None:
        self.asked = 0

    def ready(self) -> bool:
        self.asked += 1
        return False

    def client(self) -> None:
        raise AssertionError("the cluster was waited for although every range could run here")


def test_ranges_run_here_while_the_cluster_starts_with_the_serial_numbers() -> None:
    """While a local cluster starts, the reference backend simulates the next range of paths
    in this process (issue 37): with a cluster that never gets ready every range runs here,
    the cluster is never waited for, and the norms equal the serial run's bitwise."""
    from ftc_verify.simulation.paths import PathSpec

    system, gains = load_system(PAPER), load_controller(ROOT / "examples" / "paper_gains.toml")
    pspec = PathSpec(system.chain, 2.0, 30, 7)
    serial = simulate_streaming(system, gains, pspec, step=0.01, seed=7, delta="random", batch=8)
    starting = _StillStarting()
    here = simulate_streaming(system, gains, pspec, step=0.01, seed=7, delta="random", batch=8, client=starting)
    assert starting.asked == 4  # once before each of the 4 ranges of 8, 8, 8, 6 paths
    np.testing.assert_array_equal(here.y_norm, serial.y_norm)
    np.testing.assert_array_equal(here.w_norm, serial.w_norm)
