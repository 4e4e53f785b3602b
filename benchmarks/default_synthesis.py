#!/usr/bin/env python
"""Speed of the default synthesis (issue 34, item 5): wall time and certified gamma.

Run from the repository root::

    python benchmarks/default_synthesis.py                       # paper x3, one n = 6 system, one n = 4 planted case
    python benchmarks/default_synthesis.py --runs 5 --large 3 --output-feedback 2
    python benchmarks/default_synthesis.py --large 0 --output-feedback 0   # the paper example only

Cases (goals of issue 34):

* ``paper``: ``ftc-verify synthesize examples/paper.toml -o K.toml --json`` as a
  subprocess (the default ``best`` method, no ``--k-max``; Python start-up, imports, the
  certification and the file included), ``--runs`` times; goal 10 s wall.
* ``n6m3``: ``synthesize()`` (default ``best``, no gain bound) in-process on the first
  ``--large`` systems with ``n = 6``, three modes and three inputs of
  ``benchmarks/synthesis_quality.py`` (``random_system(seed, -k - 1)``); goal 120 s.
* ``of-n4``: ``synthesize_output_feedback(method="auto")`` on the first
  ``--output-feedback`` planted cases of ``benchmarks/synthesis_quality.py`` with ``n = 4``
  (``planted_rows``: the planted order, gain bound twice the planted controller's); goal
  120 s.

Every row records the 1-minute load average before it (the machine is shared: 2 cores).
Output: ``benchmarks/results/default_synthesis.csv`` (``--out``) and a table on stdout.
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
from csvout import write_rows

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

GOALS = {"paper": 10.0, "n6m3": 120.0, "of-n4": 120.0}
FIELDS = ("case", "system", "run", "seconds", "goal_s", "meets_goal", "certified", "gamma", "route", "load_1min")


def paper_rows(runs: int) -> list[dict]:
    rows = []
    for run in range(runs):
        with tempfile.TemporaryDirectory() as tmp:
            load = os.getloadavg()[0]
            t = time.perf_counter()
            proc = subprocess.run([sys.executable, "-m", "ftc_verify", "synthesize", str(ROOT / "examples" / "paper.toml"),
                                   "-o", str(Path(tmp) / "K.toml"), "--json"], capture_output=True, text=True, check=False)
            secs = time.perf_counter() - t
        d = json.loads(proc.stdout) if proc.returncode in (0, 1) and proc.stdout.strip() else {}
        gamma = d.get("gamma_certified")
        rows.append({"case": "paper", "system": "examples/paper.toml", "run": run, "seconds": secs,
                     "certified": bool(d.get("certified")), "gamma": gamma, "route": d.get("start"),
                     "load_1min": load})
    return rows


def large_rows(count: int, seed: int) -> list[dict]:
    from synthesis_quality import random_system

    from ftc_verify.synthesis.state_feedback import synthesize

    rows = []
    for k in range(count):
        system, _, _ = random_system(seed, -k - 1)
        load = os.getloadavg()[0]
        t = time.perf_counter()
        res = synthesize(system, solver="clarabel")
        rows.append({"case": "n6m3", "system": system.name, "run": 0, "seconds": time.perf_counter() - t,
                     "certified": res.certified, "gamma": res.gamma_certified, "route": res.start,
                     "load_1min": load})
    return rows


def output_feedback_rows(count: int, seed: int) -> list[dict]:
    from synthesis_quality import planted_rows, planted_system

    rows: list[dict] = []
    k = 0
    while len(rows) < count and k < 40:
        system, _, _, _ = planted_system(seed, k)
        if system.dims[0] == 4:
            load = os.getloadavg()[0]
            r = planted_rows(seed, k)
            rows.append({"case": "of-n4", "system": r["system"], "run": 0, "seconds": r["seconds"],
                         "certified": r["found_gamma"] is not None, "gamma": r["found_gamma"], "route": r["route"],
                         "load_1min": load})
        k += 1
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3, help="runs of the paper example's CLI")
    ap.add_argument("--large", type=int, default=1, help="n = 6, m = 3 systems")
    ap.add_argument("--output-feedback", type=int, default=1, help="planted n = 4 output-feedback cases")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "default_synthesis.csv"))
    args = ap.parse_args(argv)
    rows = paper_rows(args.runs) + large_rows(args.large, args.seed) + output_feedback_rows(args.output_feedback,
                                                                                            args.seed)
    for r in rows:
        r["goal_s"] = GOALS[r["case"]]
        r["meets_goal"] = bool(r["certified"]) and r["seconds"] <= r["goal_s"]
    out = Path(args.out)
    write_rows(out, rows, FIELDS)
    print(f"{'case':7} {'system':28} {'run':>3} {'seconds':>8} {'goal':>6} {'met':>4} {'gamma':>12} {'load':>5}  route")
    for r in rows:
        gamma = "-" if r["gamma"] is None else f"{r['gamma']:.6g}"
        print(f"{r['case']:7} {r['system'][:28]:28} {r['run']:>3} {r['seconds']:8.2f} {r['goal_s']:6.0f} "
              f"{'yes' if r['meets_goal'] else 'no':>4} {gamma:>12} {r['load_1min']:5.1f}  {r['route']}")
    print(f"written: {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
