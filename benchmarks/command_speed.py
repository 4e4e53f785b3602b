#!/usr/bin/env python
"""Wall time of the main commands (issue 37), this checkout against another, interleaved.

``ftc-verify verify examples/paper.toml --seed 1`` (goal < 6 s) and ``ftc-verify analyze
examples/paper.toml --gains examples/paper_gains.toml --json`` (goal <= 1.2 s) run as a user
runs them (``python -m ftc_verify ...``, a fresh process each time, the cache warm) in this
checkout and in the ``--against`` checkout (an unpacked ``git archive`` of an earlier
commit, first on ``PYTHONPATH``), alternately, ``--repeat`` times. The table gives the
median wall time of each, their ratio, the load average during the runs (the machine is
shared: only the ratio of one run is comparable), and for this checkout the median of each
stage of the ``timings`` breakdown the command writes (``report.json`` / ``--json``). CSV:
``benchmarks/results/command_speed.csv``.

Usage::

    git archive afb8b75 | tar -x -C /tmp/before
    python benchmarks/command_speed.py --against /tmp/before --repeat 5
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PAPER = str(ROOT / "examples" / "paper.toml")
GAINS = str(ROOT / "examples" / "paper_gains.toml")


def _commands(out: str) -> dict[str, list[str]]:
    return {
        "verify (paper)": ["verify", PAPER, "--seed", "1", "--out", out],
        "analyze (paper)": ["analyze", PAPER, "--gains", GAINS, "--json"],
    }


def _run(root: Path, args: list[str], out: str) -> tuple[float, dict[str, float]]:
    """Wall seconds of one run and the ``timings`` it reported (empty when none)."""
    env = os.environ | {"PYTHONPATH": str(root)}
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "ftc_verify", *args], env=env, cwd=root, capture_output=True,
                          text=True, check=False)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"{root}: {' '.join(args)}: exit {proc.returncode}: {proc.stderr.strip()[-300:]}")
    try:
        data = json.loads(proc.stdout) if args[0] == "analyze" else json.loads((Path(out) / "report.json").read_text())
    except (ValueError, OSError):
        return wall, {}
    return wall, {k: float(v) for k, v in (data.get("timings") or {}).items() if v is not None}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--against", type=Path, required=True, help="the other checkout's root folder")
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--only", default=None, help="'verify' or 'analyze'")
    parser.add_argument("--csv", type=Path, default=ROOT / "benchmarks" / "results" / "command_speed.csv")
    args = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        out = str(Path(tmp) / "report")
        for name, cmd in _commands(out).items():
            if args.only and not name.startswith(args.only):
                continue
            here, there, stages, loads = [], [], [], []
            for _ in range(args.repeat):
                wall, timings = _run(ROOT, cmd, out)
                here.append(wall)
                stages.append(timings)
                there.append(_run(args.against, cmd, out)[0])
                loads.append(os.getloadavg()[0])
            a, b = statistics.median(here), statistics.median(there)
            keys = list(dict.fromkeys(k for t in stages for k in t))
            med = {k: statistics.median(t[k] for t in stages if k in t) for k in keys}
            rows.append({"command": name, "this_s": round(a, 3), "against_s": round(b, 3),
                         "speedup": round(b / a, 3), "load_avg": round(statistics.median(loads), 2),
                         "runs": args.repeat, "this_all": " ".join(f"{x:.2f}" for x in here),
                         "against_all": " ".join(f"{x:.2f}" for x in there),
                         "stages": json.dumps({k: round(v, 3) for k, v in med.items()})})
            print(f"{name:18s} this {a:6.2f} s   against {b:6.2f} s   {b / a:5.2f}x   load {rows[-1]['load_avg']}",
                  flush=True)
            for k, v in med.items():
                print(f"    {k:28s} {v:7.3f} s")
    args.csv.parent.mkdir(parents=True, exist_ok=True)
    with open(args.csv, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    print(f"written {args.csv}")


if __name__ == "__main__":
    main()
