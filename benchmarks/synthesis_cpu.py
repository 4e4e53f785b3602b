#!/usr/bin/env python
"""CPU per ``ftc-verify synthesize`` command, two checkouts side by side.

Runs each command of :data:`COMMANDS` as a subprocess (``python -m ftc_verify``) in each
checkout given, with ``PYTHONPATH`` set to it (its ``examples/`` are the inputs), interleaved (checkout A, checkout B, A, B, ...
per round), and records the CPU seconds of the process and every child it waited for
(``os.wait4``: user + sys), the wall seconds, the exit code, the load average at the
start, and from ``--json`` the certified robust and nominal gamma, the method and the
solver calls -- so that a speed-up is checked to keep the designs' certificates.

Run from the repository root::

    OPENBLAS_NUM_THREADS=1 python benchmarks/synthesis_cpu.py --trees /work/main /work/wt-x --rounds 2 \\
        --out /tmp/synthesis_cpu.csv
    python benchmarks/synthesis_cpu.py --trees . --only paper-best      # one command, one checkout

Output: one CSV row per run (default ``benchmarks/results/synthesis_cpu.csv``) and a
table of the CPU seconds per command and checkout on stdout.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from csvout import write_rows

#: ``name -> arguments of ftc-verify synthesize`` (``-o`` and ``--json`` are added).
COMMANDS = {
    "paper-best": ["examples/paper.toml"],
    "paper-iterative": ["examples/paper.toml", "--method", "iterative"],
    "paper-two-step": ["examples/paper.toml", "--method", "two-step"],
    "phase-type-iterative": ["examples/paper_phase_type.toml", "--method", "iterative"],
    "paper-of-descent": ["examples/paper.toml", "--output-feedback", "--method", "descent"],
    "two-outputs-of-ccl": ["examples/paper_two_outputs.toml", "--output-feedback", "--minimize", "--method", "ccl",
                           "--k-max", "30"],
}


def run(tree: Path, args: list[str]) -> dict[str, object]:
    """One command in the folder ``tree`` with ``PYTHONPATH=tree`` (``python -m`` puts the
    working folder first on ``sys.path``, so the folder must be the checkout measured):
    CPU, wall, exit code and the JSON's numbers."""
    env = dict(os.environ, PYTHONPATH=str(tree))
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-m", "ftc_verify", "synthesize", *args, "-o", str(Path(tmp) / "K.toml"), "--json"]
        load = os.getloadavg()[0]
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, cwd=tree, env=env, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
        out = proc.stdout.read() if proc.stdout is not None else b""
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - t0
        proc.returncode = os.waitstatus_to_exitcode(status)
    row: dict[str, object] = {"cpu_s": round(usage.ru_utime + usage.ru_stime, 3), "wall_s": round(wall, 3),
                              "exit": proc.returncode, "load": load}
    try:
        data = json.loads(out)
    except ValueError:
        return row
    return row | {"gamma_certified": data.get("gamma_certified"),
                  "gamma_nominal_certified": data.get("gamma_nominal_certified"),
                  "certified": data.get("certified"), "solver_calls": data.get("solver_calls"),
                  "start": data.get("start")}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--trees", nargs="+", default=["."], help="checkouts to compare (PYTHONPATH of each run)")
    ap.add_argument("--rounds", type=int, default=1)
    ap.add_argument("--only", nargs="*", default=None, choices=sorted(COMMANDS), help="commands to run")
    ap.add_argument("--out", default="benchmarks/results/synthesis_cpu.csv")
    args = ap.parse_args()
    names = args.only or list(COMMANDS)
    rows = []
    for r in range(args.rounds):
        for name in names:
            for tree in args.trees:
                row = {"round": r + 1, "command": name, "tree": tree} | run(Path(tree).resolve(), COMMANDS[name])
                rows.append(row)
                print(f"{r + 1} {name:22s} {tree:24s} cpu {row['cpu_s']:8.2f} wall {row['wall_s']:8.2f} "
                      f"exit {row['exit']} gamma {row.get('gamma_certified')} load {row['load']:.1f}", flush=True)
    write_rows(args.out, rows, ["round", "command", "tree", "cpu_s", "wall_s", "exit", "load", "gamma_certified",
                                "gamma_nominal_certified", "certified", "solver_calls", "start"])


if __name__ == "__main__":
    main()
