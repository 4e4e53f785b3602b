#!/usr/bin/env python
"""Benchmark of ``ftc-verify build-fmu``: Modelica model to a checked FMU.

Each repetition builds ``examples/three_tank/ThreeTank.mo`` into a fresh cache folder (so
gcc really compiles) as a user runs it -- ``python -m ftc_verify build-fmu ... -o X.fmu``
in a subprocess, interpreter start-up and imports included -- and once more with a warm
cache (no compile). Writes a CSV and prints a table; goal (issue 12): a fresh build under
5 s wall.

Usage::

    python benchmarks/modelica_build.py [--repeat 5] [--out benchmarks/results/modelica_build.csv]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from csvout import write_rows

ROOT = Path(__file__).resolve().parents[1]
MODEL = ROOT / "examples" / "three_tank" / "ThreeTank.mo"
GOAL_SECONDS = 5.0


def _build(cache: Path, out: Path) -> float:
    env = dict(os.environ, FTC_VERIFY_CACHE=str(cache))
    start = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "ftc_verify", "build-fmu", str(MODEL), "-o", str(out)],
                          capture_output=True, text=True, env=env)
    elapsed = time.perf_counter() - start
    if proc.returncode != 0:
        raise SystemExit(f"build-fmu failed ({proc.returncode}): {proc.stderr.strip()}")
    return elapsed


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "modelica_build.csv"))
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(args.repeat):
            cache = Path(tmp) / f"cache{k}"
            fresh = _build(cache, Path(tmp) / f"fresh{k}.fmu")
            warm = _build(cache, Path(tmp) / f"warm{k}.fmu")
            rows.append({"repeat": k, "fresh_s": round(fresh, 3), "warm_s": round(warm, 3)})
    write_rows(args.out, rows)
    fresh_med = statistics.median(r["fresh_s"] for r in rows)
    warm_med = statistics.median(r["warm_s"] for r in rows)
    print(f"{'case':<28}{'median s':>10}{'min s':>10}{'max s':>10}")
    for key, label in (("fresh_s", "fresh cache (gcc compiles)"), ("warm_s", "warm cache")):
        vals = [r[key] for r in rows]
        print(f"{label:<28}{statistics.median(vals):>10.3f}{min(vals):>10.3f}{max(vals):>10.3f}")
    verdict = "met" if fresh_med < GOAL_SECONDS else "NOT met"
    print(f"goal: fresh build under {GOAL_SECONDS:g} s wall -- {verdict} (median {fresh_med:.2f} s, "
          f"warm {warm_med:.2f} s); CSV: {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
