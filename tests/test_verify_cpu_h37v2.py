"""Less CPU in ``verify`` for the same report (issue 37): the direct FMU loop's C calls
without ctypes argument conversion, the plant processes started by the CLI first, and
what a plant process imports while it waits. Deterministic: no statistics."""

from __future__ import annotations

import argparse
import ctypes
import ctypes.util
import shutil
import sys

import numpy as np
import pytest

from ftc_verify.simulation import isolated, loop_parts

fmpy = pytest.importorskip("fmpy")


def test_unconverted_call_is_the_c_function() -> None:
    libc = ctypes.CDLL(ctypes.util.find_library("c"))
    labs = libc.labs
    labs.argtypes, labs.restype = [ctypes.c_long], ctypes.c_long
    fast = loop_parts._unconverted(labs)
    assert fast(ctypes.c_long(-7)) == labs(-7) == 7
    assert fast is not labs and not hasattr(fast, "__wrapped__")


def test_a_python_stand_in_gets_the_values() -> None:
    seen: list[object] = []

    def step(c: object, t: float, h: float, flag: object) -> int:
        seen.extend([t, h])
        return 0

    call = loop_parts._unconverted(step)
    assert call(None, ctypes.c_double(0.25), ctypes.c_double(0.01), ctypes.c_int(1)) == 0
    assert seen == [0.25, 0.01] and all(type(v) is float for v in seen)


@pytest.mark.skipif(shutil.which("gcc") is None, reason="gcc builds the FMU")
def test_direct_loop_writes_the_time_before_each_step(paper_system, paper_gains, tmp_path, monkeypatch) -> None:
    from ftc_verify.controllers import Controller
    from ftc_verify.simulation.paths import sample_paths
    from ftc_verify.simulation.supervisor import open_supervisor

    monkeypatch.setenv("FTC_VERIFY_CACHE", str(tmp_path))
    paths = sample_paths(paper_system.chain, 1.0, 1, 4)
    monitor = np.zeros(3)
    with open_supervisor(paper_system) as sup:
        res = sup.run(paths, Controller.state_feedback(list(paper_gains)), step=0.1, disturbance="paper",
                      monitor=monitor)
    t = res.records[0].t
    assert monitor[1] == t[-2]  # the start of the last step, written before it


def test_cli_starts_plant_processes_only_without_a_cluster() -> None:
    from ftc_verify.cli.run_commands import _plant_processes

    assert _plant_processes(argparse.Namespace(workers=2, scheduler=None)) == []
    assert _plant_processes(argparse.Namespace(workers=None, scheduler="tcp://127.0.0.1:1")) == []
    procs = _plant_processes(argparse.Namespace(workers=None, scheduler=None))
    try:
        assert len(procs) == isolated.default_processes()
        assert all(p.child is not None and p.child.poll() is None for p in procs)
    finally:
        for p in procs:
            p.close()
    assert all(p.child is not None and p.child.poll() is not None for p in procs)


class _Proc:
    def __init__(self) -> None:
        self.closed = 0

    def close(self) -> None:
        self.closed += 1


def test_run_verify_closes_given_processes_it_cannot_use(paper_system, monkeypatch) -> None:
    from ftc_verify.simulation.spec import SimulationSpec
    from ftc_verify.verification import verify

    passed: list[list[object]] = []

    def stage(*args: object) -> None:
        passed.append(list(args[13]))  # procs
        raise RuntimeError("stop")

    monkeypatch.setattr(verify, "_run_verify", stage)
    for isolate, used in ((False, False), (True, True)):
        procs = [_Proc(), _Proc()]
        spec = SimulationSpec(n_paths=2, horizon=1.0, seed=1, isolate=isolate)
        with pytest.raises(RuntimeError, match="stop"):
            verify.run_verify(paper_system, spec=spec, processes=procs, cross_check=_Check())
        assert passed[-1] == (procs if used else [])
        assert all(p.closed >= 1 for p in procs)  # closed by run_verify either way


class _Check:
    def cancel(self) -> None:
        pass


def test_plant_process_imports_ahead_and_skips_what_fails(monkeypatch) -> None:
    from ftc_verify.plants import fmi_calls

    monkeypatch.setattr(fmi_calls, "LOADER_MODULES", ("colorsys", "no_such_module_h37v"))
    monkeypatch.delitem(sys.modules, "colorsys", raising=False)
    isolated._import_ahead()
    assert "colorsys" in sys.modules and "no_such_module_h37v" not in sys.modules and "numpy.random" in sys.modules


@pytest.mark.parametrize("n", [1, 2, 3, 4, 5])
def test_the_skip_of_the_divergence_test_implies_it_passes(n: int) -> None:
    """Wherever ``_below`` skips the test, ``|x|^2 <= B^2`` by numpy.dot; NaN and infinite
    entries are never skipped. Edge values at the limit, just above, and random ones."""
    from ftc_verify.simulation.records import DIVERGENCE_BOUND

    bound_sq = DIVERGENCE_BOUND ** 2
    near = np.sqrt(bound_sq) * (1 - 1e-6)
    below = loop_parts._below(n, near)
    lim = near / n
    g = np.random.default_rng(n)
    rows = [[lim] * n, [-lim] * n, [np.nextafter(lim, np.inf)] * n, [near] + [0.0] * (n - 1)]
    rows += [list(g.uniform(-1.2, 1.2, n) * lim) for _ in range(2000)]
    rows += [[np.nan] + [0.0] * (n - 1), [0.0] * (n - 1) + [np.nan], [0.0] * (n - 1) + [np.inf]]
    skipped = 0
    for r in rows:
        x = np.array(r)
        if below(r):
            skipped += 1
            assert float(np.dot(x, x)) <= bound_sq
            assert np.all(np.isfinite(x))
    if n <= 3:  # the per-entry limit, exactly
        assert below([lim] * n) and not below([np.nextafter(lim, np.inf)] + [0.0] * (n - 1))
    assert 0 < skipped < len(rows)
