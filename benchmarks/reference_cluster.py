#!/usr/bin/env python
"""``simulate --backend reference`` serially, on 1, 2 and 4 local Dask workers (issue 24, item 3),
and on a persistent 2-worker cluster reached by ``--scheduler`` (issue 37: started once by
this script, before the rounds, so its start-up is paid once, as a user's running cluster).
The command with ``--workers`` simulates its first batches in the client while the local
cluster starts (:class:`~ftc_verify.simulation.cluster.ClusterStart`).

Run from the repository root (needs the ``dask`` extra)::

    python benchmarks/reference_cluster.py                 # 20,000 paths, 3 rounds (~2 min)
    python benchmarks/reference_cluster.py --paths 5000 --rounds 1   # smoke run
    python benchmarks/reference_cluster.py --paths 100000 --rounds 1 --configs 0,2,-2 --no-stage

Two measurements, each with the configurations interleaved round by round (serial, 1, 2,
4 workers, the order rotated every round, so that the machine's load hits them alike):

* **the command** a user types, as a subprocess (interpreter start-up, imports, the local
  cluster's start and shut-down included)::

      ftc-verify simulate examples/paper.toml --gains examples/paper_gains.toml \\
          --backend reference --paths P --horizon 30 --step 0.01 --seed 1 --json [--workers N]

  wall seconds, and whether its JSON equals the serial run's (it must: every task
  samples its own paths from their own streams, with the batches of a serial run);
* **the Monte Carlo stage in process**: ``simulate_streaming`` on a
  :class:`~ftc_verify.simulation.paths.PathSpec` of the same run, serially and on a
  cluster started beforehand (the cluster's start and shut-down timed apart), and whether
  ``y_norm``, ``w_norm`` and the switch counts equal the serial run's bitwise.

Table: medians over the rounds and the speed-up over serial. CSV (one row per run):
``benchmarks/results/reference_cluster.csv``.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from csvout import write_rows

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

CONFIGS: tuple[int, ...] = (0, 1, 2, 4, -2)  # 0: serial; -N: a persistent cluster of N workers (--scheduler)
SCHEDULER: dict[str, str] = {}  # the persistent cluster's address, once started


def _label(workers: int) -> str:
    if workers < 0:
        return f"scheduler ({-workers} workers, started once)"
    return "serial" if workers == 0 else f"{workers} workers"


def run_command(workers: int, paths: int, horizon: float, step: float) -> tuple[float, dict[str, Any]]:
    cmd = [sys.executable, "-m", "ftc_verify", "simulate", str(ROOT / "examples" / "paper.toml"), "--gains",
           str(ROOT / "examples" / "paper_gains.toml"), "--backend", "reference", "--paths", str(paths),
           "--horizon", str(horizon), "--step", str(step), "--seed", "1", "--json"]
    cmd += ["--workers", str(workers)] if workers > 0 else ["--scheduler", SCHEDULER["address"]] if workers else []
    t = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=3600)
    wall = time.perf_counter() - t
    if proc.returncode not in (0, 1):
        raise SystemExit(f"{' '.join(cmd)}: exit {proc.returncode}\n{proc.stderr}")
    return wall, json.loads(proc.stdout)


def run_stage(workers: int, spec: Any, system: Any, gains: Any, step: float) -> tuple[dict[str, float], Any]:
    """The Monte Carlo stage in process; with workers, the cluster's start and close apart."""
    from ftc_verify.simulation.cluster import open_client
    from ftc_verify.simulation.streaming import simulate_streaming

    if not workers:
        t = time.perf_counter()
        res = simulate_streaming(system, gains, spec, step=step, seed=1)
        return {"start_s": 0.0, "monte_carlo_s": time.perf_counter() - t, "close_s": 0.0}, res
    t0 = time.perf_counter()
    where = {"scheduler": SCHEDULER["address"]} if workers < 0 else {"workers": workers}
    with open_client(**where) as client:
        client.run(lambda: __import__("ftc_verify.simulation.streaming"))  # what the first task imports
        t1 = time.perf_counter()
        res = simulate_streaming(system, gains, spec, step=step, seed=1, client=client)
        t2 = time.perf_counter()
    return {"start_s": t1 - t0, "monte_carlo_s": t2 - t1, "close_s": time.perf_counter() - t2}, res


def _same(a: Any, b: Any) -> bool:
    return (np.array_equal(a.y_norm, b.y_norm) and np.array_equal(a.w_norm, b.w_norm)
            and np.array_equal(a.switches, b.switches) and np.array_equal(a.betas, b.betas))


def _table(rows: list[dict[str, Any]], key: str, title: str) -> None:
    med = {c: statistics.median(r[key] for r in rows if r["config"] == c and r["what"] == title)
           for c in dict.fromkeys(r["config"] for r in rows if r["what"] == title)}
    if not med:
        return
    print(f"{title}: medians of {sum(r['config'] == 'serial' and r['what'] == title for r in rows)} rounds")
    print(f"  {'config':12s} {key:>14s} {'speed-up':>9s}")
    for c, v in med.items():
        print(f"  {c:12s} {v:14.2f} {med['serial'] / v:8.2f}x")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--paths", type=int, default=20000)
    ap.add_argument("--horizon", type=float, default=30.0)
    ap.add_argument("--step", type=float, default=0.01)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--no-stage", action="store_true", help="only the command, not the in-process stage")
    ap.add_argument("--configs", default=",".join(map(str, CONFIGS)),
                    help="worker counts to run (0 serial, -N a persistent N-worker cluster reached by --scheduler), "
                         "default %(default)s")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "reference_cluster.csv"))
    args = ap.parse_args(argv)

    from ftc_verify.controllers import load_controller
    from ftc_verify.model.files import load_system
    from ftc_verify.simulation.paths import PathSpec
    from ftc_verify.simulation.streaming import DASK_BATCH, STREAM_BATCH

    system = load_system(ROOT / "examples" / "paper.toml")
    gains = load_controller(ROOT / "examples" / "paper_gains.toml")
    spec = PathSpec(system.chain, args.horizon, args.paths, 1)
    rows: list[dict[str, Any]] = []
    serial_json: dict[str, Any] | None = None
    serial_res = None
    configs = tuple(int(c) for c in args.configs.split(","))
    persistent = None
    if any(c < 0 for c in configs):  # started once, before every round: what --scheduler amortises
        import logging

        import distributed

        persistent = distributed.LocalCluster(n_workers=-min(configs), threads_per_worker=1, processes=True,
                                              dashboard_address=None, silence_logs=logging.ERROR)
        SCHEDULER["address"] = persistent.scheduler_address
    for rnd in range(args.rounds):
        order = configs[rnd % len(configs):] + configs[:rnd % len(configs)]
        for workers in order:
            wall, out = run_command(workers, args.paths, args.horizon, args.step)
            if workers == 0 and serial_json is None:
                serial_json = out
            rows.append({"what": "command", "config": _label(workers), "workers": workers, "round": rnd,
                         "paths": args.paths, "wall_s": wall, "start_s": "", "monte_carlo_s": "", "close_s": "",
                         "identical_to_serial": None if serial_json is None else out == serial_json})
            print(f"[round {rnd + 1}] command, {_label(workers)}: {wall:.2f} s", file=sys.stderr, flush=True)
            if args.no_stage:
                continue
            times, res = run_stage(workers, spec, system, gains, args.step)
            if workers == 0 and serial_res is None:
                serial_res = res
            rows.append({"what": "stage", "config": _label(workers), "workers": workers, "round": rnd,
                         "paths": args.paths, "wall_s": sum(times.values()), **times,
                         "identical_to_serial": None if serial_res is None else _same(res, serial_res)})
            print(f"[round {rnd + 1}] stage, {_label(workers)}: start {times['start_s']:.2f} s, Monte Carlo "
                  f"{times['monte_carlo_s']:.2f} s, close {times['close_s']:.2f} s", file=sys.stderr, flush=True)
    if persistent is not None:
        persistent.close()
    out = Path(args.out)
    write_rows(out, rows)
    print(f"simulate --backend reference, paper example, {args.paths} paths, horizon {args.horizon:g}, step "
          f"{args.step:g}; batches of {STREAM_BATCH} paths serially, {DASK_BATCH} per Dask task")
    _table(rows, "wall_s", "command")
    if not args.no_stage:
        _table(rows, "monte_carlo_s", "stage")
        for c in dict.fromkeys(r["config"] for r in rows if r["config"] != "serial"):
            st = [r for r in rows if r["what"] == "stage" and r["config"] == c]
            if st:
                print(f"  {c}: cluster start {statistics.median(r['start_s'] for r in st):.2f} s, "
                      f"close {statistics.median(r['close_s'] for r in st):.2f} s (medians)")
    checked = [r["identical_to_serial"] for r in rows if r["identical_to_serial"] is not None]
    same = all(checked)
    print(f"every run identical to the serial one: {same} ({len(checked)} compared)")
    print(f"CSV: {out}")
    return 0 if same else 1


if __name__ == "__main__":
    raise SystemExit(main())
