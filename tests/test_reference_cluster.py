"""Workers sample their own paths (issue 24, item 3): a range of path indices sampled alone
is exactly that slice of ``sample_paths``, a :class:`PathSpec` run gives the numbers of the
pre-sampled paths bitwise, serially and on Dask workers, and the client samples only the
recorded paths."""

from __future__ import annotations

import json
import pickle
import subprocess
import sys
from pathlib import Path

import cli_inprocess
import numpy as np
import pytest

from ftc_verify.controllers import Controller, load_controller
from ftc_verify.errors import ValidationError
from ftc_verify.model.files import load_system
from ftc_verify.simulation import streaming
from ftc_verify.simulation.paths import ChainPath, PathSpec, path_streams, sample_path_range, sample_paths
from ftc_verify.simulation.streaming import simulate_streaming

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "examples" / "paper.toml"
GAINS = ROOT / "examples" / "paper_gains.toml"


def _same_stream(a: np.random.SeedSequence, b: np.random.SeedSequence) -> bool:
    return (a.entropy == b.entropy and a.spawn_key == b.spawn_key and a.pool_size == b.pool_size
            and np.array_equal(a.generate_state(8), b.generate_state(8)))


def _assert_same_paths(a: list[ChainPath], b: list[ChainPath]) -> None:
    assert len(a) == len(b)
    for p, q in zip(a, b):
        for name in ("times", "true", "fdi", "beta"):
            np.testing.assert_array_equal(getattr(p, name), getattr(q, name))
        assert p.horizon == q.horizon and _same_stream(p.stream, q.stream)
        np.testing.assert_array_equal(p.delta_generator().random(4), q.delta_generator().random(4))


@pytest.mark.parametrize("beta", ["random", "mid"])
def test_a_range_of_paths_is_that_slice_of_sample_paths(beta: str) -> None:
    chain = load_system(PAPER).chain
    fixed = None if beta == "random" else chain.midpoint()
    full = sample_paths(chain, 20.0, 300, 11, beta=fixed)
    for first, stop in ((0, 300), (0, 1), (123, 217), (299, 300)):
        _assert_same_paths(sample_path_range(chain, 20.0, 11, first, stop, beta=fixed), full[first:stop])
    children = np.random.SeedSequence(11).spawn(300)
    assert all(_same_stream(a, b) for a, b in zip(path_streams(11, 0, 300), children))


def test_a_seed_sequence_continues_its_numbering_and_is_not_advanced() -> None:
    chain = load_system(PAPER).chain
    used, fresh = np.random.SeedSequence(5), np.random.SeedSequence(5)
    used.spawn(4), fresh.spawn(4)
    full = sample_paths(chain, 10.0, 40, used)  # children 4 .. 43; ``used`` advances
    part = sample_path_range(chain, 10.0, fresh, 10, 25)
    _assert_same_paths(part, full[10:25])
    assert fresh.n_children_spawned == 4 and used.n_children_spawned == 44
    spec = PathSpec(chain, 10.0, 40, fresh)
    fresh.spawn(1)  # the spec keeps its copy
    _assert_same_paths(list(spec), full)


def test_path_spec_is_a_lazy_sequence_of_the_same_paths() -> None:
    chain = load_system(PAPER).chain
    full = sample_paths(chain, 15.0, 1203, 2)
    spec = PathSpec(chain, 15.0, 1203, 2)
    assert len(spec) == 1203 and len(pickle.dumps(spec)) < 5000
    _assert_same_paths(list(spec), full)  # iterated in blocks of 1000
    _assert_same_paths(spec[7:19], full[7:19])
    _assert_same_paths(spec[::250], full[::250])
    _assert_same_paths([spec[-1], spec[0]], [full[-1], full[0]])
    assert spec[5:5] == []
    _assert_same_paths(pickle.loads(pickle.dumps(spec)).sample(1000, 1010), full[1000:1010])
    with pytest.raises(IndexError):
        spec[1203]
    with pytest.raises(ValidationError, match="paths: must be a positive integer"):
        PathSpec(chain, 15.0, 0, 2)
    with pytest.raises(ValidationError, match="seed"):
        PathSpec(chain, 15.0, 3, -1)
    with pytest.raises(ValidationError, match="horizon"):
        PathSpec(chain, float("nan"), 3, 1)


@pytest.mark.parametrize("delta", ["zero", "random"])
def test_a_spec_run_equals_the_pre_sampled_run_bitwise(delta: str) -> None:
    system, gains = load_system(PAPER), load_controller(GAINS)
    listed = simulate_streaming(system, gains, sample_paths(system.chain, 6.0, 45, 8), step=0.01, delta=delta,
                                seed=8, record=2, batch=10)
    spec = simulate_streaming(system, gains, PathSpec(system.chain, 6.0, 45, 8), step=0.01, delta=delta, seed=8,
                              record=2, batch=10)
    for name in ("y_norm", "w_norm", "switches", "betas"):
        np.testing.assert_array_equal(getattr(spec, name), getattr(listed, name))
    assert json.dumps(spec.to_dict()) == json.dumps(listed.to_dict())
    for a, b in zip(spec.records, listed.records):
        np.testing.assert_array_equal(a.x, b.x)
    assert isinstance(spec.paths, PathSpec) and spec.horizon == 6.0


def test_a_spec_run_finds_divergences_like_the_pre_sampled_run() -> None:
    system = load_system(PAPER)
    unstable = Controller.state_feedback([np.array([[5.0, 0.0], [0.0, 5.0]])] * 2)
    listed = simulate_streaming(system, unstable, sample_paths(system.chain, 30.0, 4, 3), step=0.01,
                                delta="random", seed=3)
    spec = simulate_streaming(system, unstable, PathSpec(system.chain, 30.0, 4, 3), step=0.01, delta="random",
                              seed=3, batch=3)
    assert spec.diverged_at and spec.diverged_at == listed.diverged_at
    assert spec.to_dict()["divergence"] == listed.to_dict()["divergence"]


def test_the_task_malloc_setting_changes_no_number(monkeypatch: pytest.MonkeyPatch) -> None:
    """With Dask's ``MALLOC_TRIM_THRESHOLD_`` the task raises glibc's mmap threshold for the
    batch and restores it; the numbers are the batch's own."""
    system, gains = load_system(PAPER), load_controller(GAINS)
    spec = PathSpec(system.chain, 5.0, 12, 4)
    args = (system, gains, spec, 3, 9, 0.01, "paper", streaming.DeltaSchedule("random"), np.random.default_rng(0))
    plain = streaming._sampled_batch(*args)
    monkeypatch.setenv("MALLOC_TRIM_THRESHOLD_", "65536")
    task = streaming._sampled_task(*args)
    for a, b in zip(plain, task):
        np.testing.assert_array_equal(a, b)


def test_workers_sample_their_paths_and_give_the_serial_numbers(monkeypatch: pytest.MonkeyPatch) -> None:
    """On 2 workers the client samples only the recorded paths (its ``PathSpec.sample``
    calls are counted; the workers are other processes), and the numbers are the serial
    run's bitwise."""
    pytest.importorskip("distributed")
    from ftc_verify.simulation.cluster import open_client

    system, gains = load_system(PAPER), load_controller(GAINS)
    spec = PathSpec(system.chain, 6.0, 50, 9)
    serial = simulate_streaming(system, gains, spec, step=0.01, delta="random", seed=9, record=1, batch=7)
    calls: list[tuple[int, int | None]] = []
    sample = PathSpec.sample

    def counted(self: PathSpec, first: int = 0, stop: int | None = None) -> list[ChainPath]:
        calls.append((first, stop))
        return sample(self, first, stop)

    with open_client(workers=2) as client:
        monkeypatch.setattr(PathSpec, "sample", counted)
        spread = simulate_streaming(system, gains, spec, step=0.01, delta="random", seed=9, record=1, batch=7,
                                    client=client)
    assert calls == [(0, 1)]  # the one recorded path
    for name in ("y_norm", "w_norm", "switches", "betas"):
        np.testing.assert_array_equal(getattr(spread, name), getattr(serial, name))
    np.testing.assert_array_equal(spread.records[0].x, serial.records[0].x)


@pytest.mark.slow(8)  # seconds on 2 busy cores (--durations at load 9, / 4): scheduled first
def test_cli_reference_on_two_workers_equals_serial() -> None:
    pytest.importorskip("distributed")
    base = [sys.executable, "-m", "ftc_verify", "simulate", str(PAPER), "--gains", str(GAINS), "--backend",
            "reference", "--paths", "4500", "--horizon", "3", "--seed", "12", "--delta", "random", "--record", "1",
            "--json"]
    serial = cli_inprocess.run_cli(base[3:])  # in this process (tests/cli_inprocess.py); the Dask run as a user's
    spread = subprocess.run(base + ["--workers", "2"], capture_output=True, text=True, timeout=600)
    assert serial.returncode == 0, serial.stderr
    assert spread.returncode == 0, spread.stderr
    a, b = json.loads(serial.stdout), json.loads(spread.stdout)
    assert a["paths"] == 4500 and a == b  # 3 tasks of up to 2000 paths, sampled on the workers
