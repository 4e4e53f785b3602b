"""``--connect-timeout`` / ``connect_timeout``: the time box of connecting to ``--scheduler``
is the user's to set (issue 37, item 5), checked like every other option, and honoured
by the API's and the CLI's routes to :func:`~ftc_verify.simulation.cluster.open_client`."""

from __future__ import annotations

import socket
import time
from pathlib import Path

import cli_inprocess
import pytest

from ftc_verify.errors import ValidationError
from ftc_verify.simulation.cluster import CONNECT_TIMEOUT, open_client
from ftc_verify.simulation.spec import SimulationSpec

ROOT = Path(__file__).resolve().parents[1]
PAPER, GAINS = str(ROOT / "examples" / "paper.toml"), str(ROOT / "examples" / "paper_gains.toml")


@pytest.mark.parametrize("value", [0, -1.0, float("nan"), float("inf"), True, "5"])
def test_bad_time_boxes_are_refused_naming_the_field(value: object) -> None:
    with pytest.raises(ValidationError, match=r"connect_timeout: must be positive"):
        with open_client(scheduler="tcp://127.0.0.1:9", connect_timeout=value):  # type: ignore[arg-type]
            pytest.fail("connected")
    with pytest.raises(ValidationError, match=r"^connect_timeout: must be a positive finite number"):
        SimulationSpec(connect_timeout=value)  # type: ignore[arg-type]


def test_the_default_is_the_documented_10_s() -> None:
    assert CONNECT_TIMEOUT == 10.0 and SimulationSpec().connect_timeout == CONNECT_TIMEOUT


def test_a_spec_connects_within_its_time_box() -> None:
    """A server that accepts and never answers: refused after the spec's 1 s, not 10 s."""
    pytest.importorskip("distributed")
    with socket.socket() as srv:
        srv.bind(("127.0.0.1", 0))
        srv.listen()
        address = f"tcp://127.0.0.1:{srv.getsockname()[1]}"
        start = time.monotonic()
        with pytest.raises(ValidationError, match="no Dask scheduler answered within 1 s") as err:
            with SimulationSpec(scheduler=address, connect_timeout=1.0).client():
                pytest.fail("connected to a server that is no scheduler")
        took = time.monotonic() - start
    assert str(err.value).startswith(f"--scheduler {address}: ")
    assert took < CONNECT_TIMEOUT - 3


@pytest.mark.parametrize("args, says", [
    (["--connect-timeout", "0"], "argument --connect-timeout: must be positive and finite, got '0'"),
    (["--connect-timeout", "x"], "argument --connect-timeout: not a number: 'x'"),
    (["--connect-timeout", "5"], "--connect-timeout 5: only with --scheduler"),
    (["--workers", "2", "--connect-timeout", "5"], "--connect-timeout 5: only with --scheduler"),
])
@pytest.mark.parametrize("command, extra", [("simulate", []), ("verify", ["--out", "rep"]), ("risk", ["--horizon", "5"])])
def test_cli_refuses_a_bad_or_idle_time_box(tmp_path: Path, command: str, extra: list[str], args: list[str],
                                            says: str) -> None:
    run = cli_inprocess.run_cli([command, PAPER, "--gains", GAINS, *args, *extra], tmp_path)
    assert run.returncode == 2 and run.stdout == "", run.stderr
    assert says in run.stderr and len(run.stderr.strip().splitlines()) == 1 and "Traceback" not in run.stderr
    assert list(tmp_path.iterdir()) == []
