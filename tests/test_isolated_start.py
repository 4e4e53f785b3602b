"""A watched FMU child that ends before it takes its job (it could not start) is a plant
run error with its exit status, never this process's broken pipe (which the CLI reports
as its own output closed, exit 141)."""

from __future__ import annotations

import shutil

import pytest

from ftc_verify.errors import PlantRunError
from ftc_verify.simulation import isolated


@pytest.mark.skipif(shutil.which("false") is None, reason="needs the false command")
def test_a_child_that_ended_before_its_job_is_a_plant_run_error(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(isolated.sys, "executable", shutil.which("false"))
    proc = isolated.PlantProcess()  # runs `false -m ...`: ends at once with status 1
    try:
        assert proc.child is not None
        assert proc.child.wait() == 1
        proc.send(b"x" * (1 << 20))  # more than a pipe holds: the write meets the closed end
        assert proc.receive() is None
        err = proc.crashed("plant.fmu")
        assert isinstance(err, PlantRunError) and "exit code 1" in str(err)
    finally:
        proc.close()
