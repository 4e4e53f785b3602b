#!/usr/bin/env python
"""``simulate --backend reference``: streaming against the per-path code, and the issue's command.

Run from the repository root::

    python benchmarks/simulate_stream.py             # ~1-2 min on 2 busy cores
    python benchmarks/simulate_stream.py --paths 2000 --out /tmp/stream.csv
    python benchmarks/simulate_stream.py --workers-scan   # + serial vs --workers 1, 2, 4 (Dask)

Two measurements, written to ``benchmarks/results/simulate_stream.csv`` and printed:

* **side by side, in one run** (paper example and gains, horizon 50, step 0.005, Delta
  ``zero``, the same sampled paths): the per-path ``simulate_reference`` (every trajectory
  kept) against ``simulate_streaming`` (norms only), on ``--compare`` paths (200), in
  process, wall seconds; the answers must agree to 1e-12;
* **path sampling**: ``sample_paths(chain, 50, N, 1)`` (per-path streams, all paths'
  jumps advanced together), best and median of 3;
* **the command as a user runs it**: ``ftc-verify simulate examples/paper.toml --gains
  examples/paper_gains.toml --backend reference --paths N --horizon 50 --step 0.005 --json``
  as a subprocess (interpreter start-up and imports included), wall seconds and the child's
  peak resident memory (``resource.getrusage(RUSAGE_CHILDREN).ru_maxrss``); goal: N = 10000
  under 10 s and 500 MB;
* ``--workers-scan``: the same command serially and with ``--workers 1, 2, 4`` (a Dask
  ``LocalCluster``; the cluster's start-up is in the wall time), the speed-up over serial
  and, from ``--workers 1``, the overhead per task. This machine has 2 cores.
"""

from __future__ import annotations

import argparse
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from csvout import write_rows

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--paths", type=int, default=10000, help="paths of the CLI command (default 10000)")
    ap.add_argument("--compare", type=int, default=200, help="paths of the side-by-side comparison (default 200)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "simulate_stream.csv"))
    ap.add_argument("--workers-scan", action="store_true",
                    help="also run the command serially and with --workers 1, 2, 4 (Dask LocalCluster)")
    args = ap.parse_args(argv)

    from ftc_verify.controllers import load_controller
    from ftc_verify.model.files import load_system
    from ftc_verify.simulation.paths import sample_paths
    from ftc_verify.simulation.reference import simulate_reference
    from ftc_verify.simulation.streaming import simulate_streaming

    system = load_system(ROOT / "examples" / "paper.toml")
    gains = load_controller(ROOT / "examples" / "paper_gains.toml")
    paths = sample_paths(system.chain, 50.0, args.compare, 1)
    rows = []
    t = time.perf_counter()
    old = simulate_reference(system, gains, paths, step=0.005)
    t_old = time.perf_counter() - t
    t = time.perf_counter()
    new = simulate_streaming(system, gains, paths, step=0.005)
    t_new = time.perf_counter() - t
    diff = float(np.max(np.abs(new.y_norm - np.array([r.y_norm for r in old.records])) / new.y_norm))
    rows.append({"what": f"per-path simulate_reference, {args.compare} paths", "wall_s": round(t_old, 3),
                 "peak_mb": "", "note": ""})
    rows.append({"what": f"simulate_streaming, same {args.compare} paths", "wall_s": round(t_new, 3), "peak_mb": "",
                 "note": f"speed-up {t_old / t_new:.1f}x, max relative y_norm difference {diff:.1e}"})
    samples = []
    for _ in range(3):
        t = time.perf_counter()
        drawn = sample_paths(system.chain, 50.0, args.paths, 1)
        samples.append(time.perf_counter() - t)
    jumps = sum(len(p.times) - 1 for p in drawn) / len(drawn)
    rows.append({"what": f"sample_paths, {args.paths} paths, horizon 50, beta per path", "wall_s": round(min(samples), 3),
                 "peak_mb": "", "note": f"best of 3 (median {sorted(samples)[1]:.3f} s); {jumps:.1f} jumps per path; "
                                        f"{1e6 * min(samples) / args.paths:.0f} us per path"})
    cmd = [sys.executable, "-m", "ftc_verify", "simulate", str(ROOT / "examples" / "paper.toml"), "--gains",
           str(ROOT / "examples" / "paper_gains.toml"), "--backend", "reference", "--paths", str(args.paths),
           "--horizon", "50", "--step", "0.005", "--json", "--seed", "1"]
    t = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t
    peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024.0
    ok = proc.returncode == 0
    rows.append({"what": f"ftc-verify simulate ... --paths {args.paths} --horizon 50 --step 0.005 --json",
                 "wall_s": round(wall, 2), "peak_mb": round(peak, 1),
                 "note": ("exit 0" if ok else f"exit {proc.returncode}: {proc.stderr.strip()[:100]}")
                 + f"; goal < 10 s and < 500 MB: {'met' if ok and wall < 10 and peak < 500 else 'NOT met'}"})
    if args.workers_scan:
        base = None
        for workers in (0, 1, 2, 4):
            extra = [] if workers == 0 else ["--workers", str(workers)]
            t = time.perf_counter()
            proc = subprocess.run(cmd + extra, capture_output=True, text=True)
            wall = time.perf_counter() - t
            base = wall if workers == 0 else base
            tasks = -(-args.paths // 2000)
            note = ("serial" if workers == 0 else
                    f"speed-up {base / wall:.2f}x over serial; {tasks} tasks")
            if workers == 1:
                note += f"; overhead {(wall - base) / tasks:.2f} s per task (cluster start-up included)"
            rows.append({"what": f"same command, {'serial' if workers == 0 else f'--workers {workers}'}",
                         "wall_s": round(wall, 2), "peak_mb": "",
                         "note": note if proc.returncode == 0 else f"exit {proc.returncode}"})
    out = Path(args.out)
    write_rows(out, rows)
    for r in rows:
        print(f"{r['what']:78s} {r['wall_s']:>8} s {r['peak_mb']!s:>8} MB  {r['note']}")
    print(f"CSV: {out}")
    return 0 if ok and diff < 1e-12 else 1


if __name__ == "__main__":
    raise SystemExit(main())
