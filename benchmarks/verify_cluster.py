#!/usr/bin/env python
"""Speed-up of the FMU Monte Carlo of ``ftc-verify verify`` on 1, 2 and 4 local Dask workers.

Run from the repository root (needs the ``dask`` extra)::

    python benchmarks/verify_cluster.py                  # 400 paths, horizon 30 (~3 min)
    python benchmarks/verify_cluster.py --paths 100      # smoke run

Each configuration runs the command a user types, as a subprocess::

    ftc-verify verify examples/paper.toml --gains examples/paper_gains.toml \\
        --paths P --horizon 30 --seed 1 --out TMP [--workers N]

first serially, then with ``--workers 1``, ``2`` and ``4`` (configurations interleaved over
``--repeats`` rounds, so that the machine's load hits them alike). Recorded per run: the
wall time of the command (cluster start-up included) and the ``monte_carlo`` stage of
``report.json`` (``seconds``), and whether report.json equals the serial run's apart from
timings (it must). Table: medians, the speed-up of the Monte Carlo stage against the
serial run, and the overhead per task, ``(MC(1 worker) - MC(serial)) / tasks`` with
``tasks = ceil(P / FMU_TASK_PATHS)``. CSV: ``benchmarks/results/verify_cluster.csv``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from ftc_verify.simulation.batches import FMU_TASK_PATHS
from csvout import write_rows

CONFIGS: tuple[int | None, ...] = (None, 1, 2, 4)


def _without_timings(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _without_timings(v) for k, v in value.items() if not k.endswith("seconds")}
    if isinstance(value, list):
        return [_without_timings(v) for v in value]
    return value


def run_once(workers: int | None, paths: int, horizon: float, out: Path) -> tuple[float, dict[str, Any]]:
    cmd = [sys.executable, "-m", "ftc_verify", "verify", str(ROOT / "examples" / "paper.toml"),
           "--gains", str(ROOT / "examples" / "paper_gains.toml"), "--paths", str(paths), "--horizon", str(horizon),
           "--seed", "1", "--out", str(out)] + ([] if workers is None else ["--workers", str(workers)])
    t = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=3600)
    wall = time.perf_counter() - t
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)}: exit {proc.returncode}\n{proc.stderr}")
    return wall, json.loads((out / "report.json").read_text())


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--paths", type=int, default=400)
    ap.add_argument("--horizon", type=float, default=30.0)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "verify_cluster.csv"))
    args = ap.parse_args(argv)
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    rows: list[dict[str, Any]] = []
    serial_report = None
    with tempfile.TemporaryDirectory() as tmp:
        for rnd in range(args.repeats):
            for workers in CONFIGS:
                label = "serial" if workers is None else f"{workers} workers"
                wall, report = run_once(workers, args.paths, args.horizon, Path(tmp) / f"{label}-{rnd}")
                if workers is None and serial_report is None:
                    serial_report = _without_timings(report)
                same = _without_timings(report) == serial_report
                rows.append({"config": label, "workers": workers or 0, "round": rnd, "paths": args.paths,
                             "horizon": args.horizon, "wall_s": wall, "monte_carlo_s": report["seconds"]["monte_carlo"],
                             "identical_to_serial": same})
                print(f"[{label}, round {rnd + 1}] wall {wall:.1f} s, Monte Carlo {rows[-1]['monte_carlo_s']:.1f} s, "
                      f"identical {same}", file=sys.stderr, flush=True)
    out = Path(args.out)
    write_rows(out, rows)
    med = {c: (statistics.median(r["wall_s"] for r in rows if r["config"] == c),
               statistics.median(r["monte_carlo_s"] for r in rows if r["config"] == c))
           for c in dict.fromkeys(r["config"] for r in rows)}
    tasks = math.ceil(args.paths / FMU_TASK_PATHS)
    print(f"verify, {args.paths} FMU paths, horizon {args.horizon:g}, {tasks} tasks of {FMU_TASK_PATHS} paths, "
          f"medians of {args.repeats}")
    print(f"{'config':12s} {'wall s':>8s} {'MC s':>8s} {'MC speed-up':>12s}")
    for c, (wall, mc) in med.items():
        print(f"{c:12s} {wall:8.2f} {mc:8.2f} {med['serial'][1] / mc:11.2f}x")
    print(f"overhead per task (1 worker vs serial): {(med['1 workers'][1] - med['serial'][1]) / tasks * 1e3:.0f} ms")
    print(f"every report identical to the serial one apart from timings: {all(r['identical_to_serial'] for r in rows)}")
    print(f"CSV: {out}")
    return 0 if all(r["identical_to_serial"] for r in rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())
