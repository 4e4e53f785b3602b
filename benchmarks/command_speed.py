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

The other side is either a checkout (``--against``) or an installed command
(``--against-cli``, e.g. another worktree's ``.venv/bin/ftc-verify``); ``--this-cli`` runs
this side as an installed command too (``ftc-verify`` of this checkout's venv, as a user
does). Beside the wall time each run's CPU time (user + system of the command and every
process it started) is recorded, and for ``verify`` whether both sides wrote the same
``report.json`` apart from times (``identical``: the speed-ups must not change a number).

Usage::

    git archive afb8b75 | tar -x -C /tmp/before
    python benchmarks/command_speed.py --against /tmp/before --repeat 5
    python benchmarks/command_speed.py --this-cli .venv/bin/ftc-verify --against-cli ../main/.venv/bin/ftc-verify
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any
from csvout import write_rows

ROOT = Path(__file__).resolve().parents[1]
PAPER = str(ROOT / "examples" / "paper.toml")
GAINS = str(ROOT / "examples" / "paper_gains.toml")


def _commands(out: str) -> dict[str, list[str]]:
    return {
        "verify (paper)": ["verify", PAPER, "--seed", "1", "--out", out],
        "analyze (paper)": ["analyze", PAPER, "--gains", GAINS, "--json"],
    }


def _without_times(value: Any) -> Any:
    """``value`` without its times (``timings``, ``*seconds``): what must be equal."""
    if isinstance(value, dict):
        return {k: _without_times(v) for k, v in value.items() if not (k == "timings" or k.endswith("seconds"))}
    if isinstance(value, list):
        return [_without_times(v) for v in value]
    return value


def _run(side: Path | str, args: list[str], out: str) -> tuple[float, float, dict[str, float], Any]:
    """Wall and CPU seconds of one run, the ``timings`` it reported (empty when none) and
    its output without times. ``side``: a checkout's root (run as ``python -m ftc_verify``
    with it first on ``PYTHONPATH``) or an installed ``ftc-verify`` command (a str)."""
    if isinstance(side, Path):
        env, cmd, cwd = os.environ | {"PYTHONPATH": str(side)}, [sys.executable, "-m", "ftc_verify"], side
    else:
        env, cmd, cwd = dict(os.environ), [side], ROOT
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run([*cmd, *args], env=env, cwd=cwd, capture_output=True, text=True, check=False)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime
    if proc.returncode != 0:
        raise SystemExit(f"{side}: {' '.join(args)}: exit {proc.returncode}: {proc.stderr.strip()[-300:]}")
    try:
        data = json.loads(proc.stdout) if args[0] == "analyze" else json.loads((Path(out) / "report.json").read_text())
    except (ValueError, OSError):
        return wall, cpu, {}, None
    timings = {k: float(v) for k, v in (data.get("timings") or {}).items() if isinstance(v, (int, float))}
    return wall, cpu, timings, _without_times(data)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--against", type=Path, default=None, help="the other checkout's root folder")
    parser.add_argument("--against-cli", default=None, help="or the other side's installed ftc-verify command")
    parser.add_argument("--this-cli", default=None, help="run this side as this installed ftc-verify command")
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--only", default=None, help="'verify' or 'analyze'")
    parser.add_argument("--csv", type=Path, default=ROOT / "benchmarks" / "results" / "command_speed.csv")
    args = parser.parse_args()
    if (args.against is None) == (args.against_cli is None):
        parser.error("give one of --against and --against-cli")
    this: Path | str = args.this_cli or ROOT
    other: Path | str = args.against_cli or args.against
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        out = str(Path(tmp) / "report")
        for name, cmd in _commands(out).items():
            if args.only and not name.startswith(args.only):
                continue
            here, there, cpu_here, cpu_there, stages, loads, same = [], [], [], [], [], [], []
            for _ in range(args.repeat):
                wall, cpu, timings, found = _run(this, cmd, out)
                here.append(wall)
                cpu_here.append(cpu)
                stages.append(timings)
                wall, cpu, _, found_there = _run(other, cmd, out)
                there.append(wall)
                cpu_there.append(cpu)
                same.append(found == found_there)
                loads.append(os.getloadavg()[0])
            a, b = statistics.median(here), statistics.median(there)
            keys = list(dict.fromkeys(k for t in stages for k in t))
            med = {k: statistics.median(t[k] for t in stages if k in t) for k in keys}
            rows.append({"command": name, "this_s": round(a, 3), "against_s": round(b, 3),
                         "speedup": round(b / a, 3), "this_cpu_s": round(statistics.median(cpu_here), 3),
                         "against_cpu_s": round(statistics.median(cpu_there), 3),
                         "identical_outputs": f"{sum(same)}/{len(same)}",
                         "load_avg": round(statistics.median(loads), 2),
                         "loads": " ".join(f"{x:.2f}" for x in loads),
                         "runs": args.repeat, "this_all": " ".join(f"{x:.2f}" for x in here),
                         "against_all": " ".join(f"{x:.2f}" for x in there),
                         "stages": json.dumps({k: round(v, 3) for k, v in med.items()})})
            print(f"{name:18s} this {a:6.2f} s   against {b:6.2f} s   {b / a:5.2f}x   cpu {rows[-1]['this_cpu_s']} "
                  f"against {rows[-1]['against_cpu_s']} s   load {rows[-1]['load_avg']}   "
                  f"identical {rows[-1]['identical_outputs']}", flush=True)
            print(f"    this: {rows[-1]['this_all']}   against: {rows[-1]['against_all']}")
            for k, v in med.items():
                print(f"    {k:28s} {v:7.3f} s")
    write_rows(args.csv, rows)
    print(f"written {args.csv}")


if __name__ == "__main__":
    main()
