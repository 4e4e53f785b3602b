#!/usr/bin/env python
"""Start-up of the command line (issue 24): wall time of short commands, this checkout
against another one, interleaved.

Each command runs as a user runs it (``python -m ftc_verify ...`` in a fresh process) in
this checkout's folder and with it first on ``PYTHONPATH``, then with the ``--against`` checkout (e.g. an
unpacked ``git archive`` of an earlier commit), alternately, ``--repeat`` times; the table
gives the median wall time of each and their ratio, and ``benchmarks/results/startup.csv``
the same. Goals: ``--help`` under 0.3 s, ``analyze`` of the paper's example under 0.6 s.

Usage::

    git archive d8237fb | tar -x -C /tmp/before
    python benchmarks/startup.py --against /tmp/before
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path
from csvout import write_rows

ROOT = Path(__file__).resolve().parents[1]
PAPER = str(ROOT / "examples" / "paper.toml")
GAINS = str(ROOT / "examples" / "paper_gains.toml")
COMMANDS = {
    "--help": ["--help"],
    "analyze (paper)": ["analyze", PAPER, "--gains", GAINS],
    "analyze --no-lmi (paper)": ["analyze", PAPER, "--gains", GAINS, "--no-lmi"],
    "simulate reference (paper, 10 paths)": ["simulate", PAPER, "--gains", GAINS, "--backend", "reference",
                                             "--paths", "10", "--horizon", "5", "--seed", "1"],
}


def _wall(root: Path, args: list[str]) -> float:
    env = os.environ | {"PYTHONPATH": str(root)}
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "ftc_verify", *args], env=env, cwd=root, capture_output=True, check=False)
    return time.perf_counter() - t0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--against", type=Path, required=True, help="the other checkout's root folder")
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    rows = []
    for name, cmd in COMMANDS.items():
        here, there = [], []
        for _ in range(args.repeat):
            here.append(_wall(ROOT, cmd))
            there.append(_wall(args.against, cmd))
        a, b = statistics.median(here), statistics.median(there)
        rows.append({"command": name, "this_s": a, "against_s": b, "speedup": b / a})
        print(f"{name:40s} this {a:6.3f} s   against {b:6.3f} s   {b / a:5.2f}x", flush=True)
    out = ROOT / "benchmarks" / "results" / "startup.csv"
    write_rows(out, rows)
    print(f"written {out}")


if __name__ == "__main__":
    main()
