"""``cluster.worker_start``: the command line's local Dask workers start from a fork server
(issue 37, item 5); the configuration is Dask's own again after the block, a start method
the user configured is kept, and a command without ``--workers`` does not touch Dask."""

from __future__ import annotations

import argparse

import pytest

dask = pytest.importorskip("dask")
pytest.importorskip("distributed")

from ftc_verify.cli.main import _worker_start
from ftc_verify.simulation.cluster import WORKER_MODULES, worker_start

KEY = "distributed.worker.multiprocessing-method"


@pytest.fixture(autouse=True)
def _dask_default() -> object:
    """Dask's default start method, whatever the environment configures."""
    with dask.config.set({KEY: "spawn"}):
        yield


def test_the_block_starts_workers_from_the_fork_server_and_restores_the_method() -> None:
    with worker_start():
        assert dask.config.get(KEY) == "forkserver"
        from distributed.utils import get_mp_context

        assert get_mp_context().get_start_method() == "forkserver"
        assert "distributed" in WORKER_MODULES and "ftc_verify.simulation.fmu_workers" in WORKER_MODULES
    assert dask.config.get(KEY) == "spawn"


def test_a_configured_start_method_is_kept() -> None:
    with dask.config.set({KEY: "fork"}), worker_start():
        assert dask.config.get(KEY) == "fork"


def test_only_worker_runs_of_the_command_line_use_it() -> None:
    with _worker_start(argparse.Namespace(workers=None)):
        assert dask.config.get(KEY) == "spawn"
    with _worker_start(argparse.Namespace()):  # commands without the option
        assert dask.config.get(KEY) == "spawn"
    with _worker_start(argparse.Namespace(workers=2)):
        assert dask.config.get(KEY) == "forkserver"
    assert dask.config.get(KEY) == "spawn"
