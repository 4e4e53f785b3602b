"""The FMU build cache under concurrent builders (issue 15: Dask workers and test workers
building the same FMU at once): the check and the compilation run under one file lock,
so four processes asking for the same binary at the same moment compile it once and all
get the same, intact file."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from ftc_verify.errors import FMUError
from ftc_verify.plants.build import build_lock

_CHILD = """
from ftc_verify.plants import ode_fmu
runs = []
compiler = ode_fmu.run_compiler
ode_fmu.run_compiler = lambda *args: runs.append(args) or compiler(*args)  # count gcc runs
path = ode_fmu.build_ode_binary(ode_fmu.motor_spec())
print(len(runs), path)
"""


def test_four_concurrent_builders_compile_once(tmp_path: Path) -> None:
    env = os.environ | {"FTC_VERIFY_CACHE": str(tmp_path)}
    procs = [subprocess.Popen([sys.executable, "-c", _CHILD], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True, env=env) for _ in range(4)]
    outs = [p.communicate(timeout=600) for p in procs]
    assert all(p.returncode == 0 for p in procs), [err for _, err in outs]
    counts = [int(out.split()[0]) for out, _ in outs]
    paths = {out.split()[1] for out, _ in outs}
    assert sum(counts) == 1, counts  # one gcc run among the four processes
    assert len(paths) == 1 and Path(paths.pop()).is_file()
    assert not [p for p in (tmp_path / "fmus").iterdir() if p.name.endswith(".tmp") or p.name.startswith(".")]


def test_a_held_lock_times_out_with_one_error(tmp_path: Path) -> None:
    target = tmp_path / "plant.so"
    holder = subprocess.Popen([sys.executable, "-c", (
        "import sys, time\nfrom filelock import FileLock\n"
        f"with FileLock({str(target) + '.lock'!r}):\n    print('held', flush=True)\n    time.sleep(30)\n")],
        stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "held"
        with pytest.raises(FMUError, match=r"plant\.so\.lock: another build has held this lock for more than 0\.5 s"):
            with build_lock(target, timeout=0.5):
                pass
    finally:
        holder.kill()
        holder.wait()
    with build_lock(target, timeout=5):  # released when its holder died
        assert Path(f"{target}.lock").exists()
