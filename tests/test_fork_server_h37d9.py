"""Local Dask workers forked from a fork server (``ftc_verify.simulation.cluster.start_fork_server``):
they start with the batch code loaded, see the client's environment and their run folder
as it is when the cluster starts, and where the server's socket cannot be made (a
temporary folder whose path is too long for a Unix socket: pytest-xdist's folders are
near the limit) the workers are spawned as Dask does by default, and the run works."""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

distributed = pytest.importorskip("distributed")

from ftc_verify.simulation.cluster import WORKER_PRELOAD, open_client, start_fork_server

ROOT = Path(__file__).resolve().parents[1]


def _worker_view() -> dict[str, object]:
    """Run on a worker: what it has loaded and sees before any task."""
    return {"preloaded": [m for m in WORKER_PRELOAD if m in sys.modules], "marker": os.environ.get("FTC_H37D9_MARK"),
            "tmpdir": os.environ.get("TMPDIR"), "gettempdir": tempfile.gettempdir()}


@pytest.mark.skipif("forkserver" not in __import__("multiprocessing").get_all_start_methods(), reason="no fork server")
def test_workers_start_with_the_batch_code_and_the_clients_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    """The server is started (and kept) before this test's variable is set; the worker still
    sees it (the client's environment at the cluster's start), its ``TMPDIR`` and
    ``tempfile`` folder are the run folder, and the batch modules are loaded before any task
    (a spawned worker imports only Dask and its preload, ``ftc_verify.simulation.cluster``)."""
    assert start_fork_server()
    monkeypatch.setenv("FTC_H37D9_MARK", "set after the server started")
    with open_client(workers=1) as client:
        (view,) = client.run(_worker_view).values()
    assert view["marker"] == "set after the server started"
    assert set(WORKER_PRELOAD) - {"fmpy.fmi2"} <= set(view["preloaded"])  # type: ignore[arg-type]
    assert Path(str(view["tmpdir"])).name.startswith("ftc-verify-cluster-") and view["gettempdir"] == view["tmpdir"]


_PROBE = """
import sys, tempfile
from ftc_verify.simulation.cluster import open_client, start_fork_server
used = start_fork_server()
with open_client(workers=1) as client:
    (fmu_loaded,) = client.run(lambda: "ftc_verify.simulation.fmu_workers" in sys.modules).values()
    total = client.submit(sum, [1, 2, 3]).result()
print(used, fmu_loaded, total)
"""


@pytest.mark.slow(4)  # seconds on 2 busy cores: scheduled first
def test_a_temporary_folder_too_long_for_the_socket_spawns_the_workers(tmp_path: Path) -> None:
    """``TMPDIR`` of 100 bytes: the server's socket path would pass the 107-byte limit, so no
    server is started (it used to be ``OSError: AF_UNIX path too long``, exit 4, in the
    contract tests under pytest-xdist), the worker is spawned (nothing preloaded) and
    computes; what the process made there is gone when it exits."""
    long = tmp_path / ("x" * max(1, 100 - len(str(tmp_path)) - 1))
    long.mkdir()
    assert len(str(long)) >= 99
    run = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True, timeout=300, cwd=ROOT,
                         env=os.environ | {"TMPDIR": str(long)})
    assert run.returncode == 0, run.stderr
    assert run.stdout.split() == ["False", "False", "6"]
    assert list(long.iterdir()) == []
