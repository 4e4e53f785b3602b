"""When a running ``ftc-verify`` command's plant process is stepping its FMU, seen from
outside (Linux ``/proc``), so that a signal test sends its signal once the FMU Monte
Carlo is under way instead of after a fixed sleep (issue 37, item 5).

An FMU Monte Carlo runs in plant processes (:mod:`ftc_verify.simulation.isolated`: fresh
interpreters ``python -m ftc_verify.simulation.isolated``, children of the command); each
extracts the FMU into an ``ftc-verify-fmu-*`` folder of the command's temporary folder
and then steps it. :func:`wait_for_fmu_steps` waits until a plant process has extracted
its FMU and then used ``seconds`` more CPU: it is inside the Monte Carlo, stepping.
"""

from __future__ import annotations

import subprocess
from pathlib import Path

from process_stages import children, cpu_seconds, wait_for_stage

__all__ = ["plant_processes", "wait_for_fmu_steps"]

_MODULE = b"ftc_verify.simulation.isolated"


def plant_processes(pid: int) -> list[int]:
    """The live plant processes (:mod:`ftc_verify.simulation.isolated`) that are children of ``pid``."""
    found = []
    for child in sorted(children(pid)):
        try:
            argv = Path(f"/proc/{child}/cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        if _MODULE in argv:
            found.append(child)
    return found


def wait_for_fmu_steps(proc: subprocess.Popen[str], tmp: Path, seconds: float) -> None:
    """Wait until the FMU is extracted in ``tmp`` (the command's ``TMPDIR``) and one of the
    command's plant processes has used ``seconds`` of CPU since: it is stepping the FMU
    (fails, as :func:`process_stages.wait_for_stage` does, if the command ends first)."""
    wait_for_stage(proc, lambda: any(tmp.rglob("ftc-verify-fmu-*")) and bool(plant_processes(proc.pid)),
                   "the FMU extracted by a plant process")
    start = {p: cpu_seconds(p) for p in plant_processes(proc.pid)}
    wait_for_stage(proc, lambda: any(cpu_seconds(p) >= c + seconds for p, c in start.items()),
                   f"{seconds} s of CPU of a plant process stepping the FMU")
