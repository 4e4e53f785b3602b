"""Signals during native calls that call back into Python (ftc_verify.interrupts).

Reproduction first: Clarabel's Rust code imports SciPy's LAPACK bindings (Python code) on
its first solve in a process; a SIGTERM handler's exception raised there comes out of
``solve()`` as a ``PanicException`` (with a Rust backtrace on stderr), which the solver
layer must count as a solver failure -- so a SIGTERM early in ``analyze`` became "no
certificate" (exit 3). The signal is made to arrive exactly there, deterministically, by
an import hook that sends it when that module is imported, in a fresh interpreter. Under
:func:`deferred_signals` the same signal is held during the solve and raised, as itself,
right after it.
"""

from __future__ import annotations

import signal
import subprocess
import sys

import pytest

from ftc_verify.interrupts import deferred_signals

SCRIPT = r'''
import os, signal, sys
import numpy as np, scipy.sparse as sp, clarabel
from ftc_verify.interrupts import deferred_signals

class Stop(BaseException):
    pass

def handler(signum, frame):
    raise Stop()

class SendOnLapack:  # the signal arrives while clarabel imports the LAPACK bindings
    def find_spec(self, name, path=None, target=None):
        if name == "scipy.linalg.cython_lapack":
            os.kill(os.getpid(), signal.SIGTERM)
        return None

signal.signal(signal.SIGTERM, handler)
sys.meta_path.insert(0, SendOnLapack())
settings = clarabel.DefaultSettings()
settings.verbose = False
problem = (sp.csc_matrix((3, 3)), np.array([1.0, 0.0, 1.0]), -sp.identity(3, format="csc"),
           np.array([1.0, 0.0, 1.0]), [clarabel.PSDTriangleConeT(2)], settings)  # PSD cones need LAPACK
try:
    if sys.argv[1] == "deferred":
        with deferred_signals():
            status = clarabel.DefaultSolver(*problem).solve().status
            print("solved", status, flush=True)
    else:
        clarabel.DefaultSolver(*problem).solve()
except BaseException as exc:
    print("raised", type(exc).__name__)
'''


def _run(mode: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-c", SCRIPT, mode], capture_output=True, text=True, timeout=120)


def test_a_signal_inside_clarabel_is_held_and_raised_after_it() -> None:
    plain = _run("plain")
    assert plain.stdout.strip() == "raised PanicException", plain  # the reproduction: the signal is disguised
    deferred = _run("deferred")
    assert deferred.stdout.strip().splitlines() == ["solved Solved", "raised Stop"], deferred
    assert "panicked" not in deferred.stderr


def test_handlers_are_restored() -> None:
    before = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    with deferred_signals():
        assert signal.getsignal(signal.SIGTERM) is not before[1]
    assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == before


def test_outside_the_main_thread_it_does_nothing() -> None:
    import threading

    seen = []

    def body() -> None:
        with deferred_signals():
            seen.append(signal.getsignal(signal.SIGTERM))

    t = threading.Thread(target=body)
    t.start()
    t.join()
    assert seen == [signal.getsignal(signal.SIGTERM)]
    with pytest.raises(ZeroDivisionError):  # an exception in the block passes through
        with deferred_signals():
            1 / 0  # noqa: B018 - the division raises
