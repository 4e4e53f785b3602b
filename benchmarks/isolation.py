#!/usr/bin/env python
"""What the watched child process costs the FMU Monte Carlo (issue 22).

``fmu_monte_carlo`` runs the plant FMU in a watched child process by default
(``isolate=True``, :mod:`ftc_verify.simulation.isolated`), so that a crashing plant is
reported instead of ending the command. This script times the same Monte Carlo with
``isolate=True`` and ``isolate=False`` (in this process), interleaved, on the paper's
example (its ``LinearJumpPlant`` FMU and gains, ``step = 0.01``, horizon 30, random
``Delta`` per segment), for a few path counts, best of ``--repeat`` runs each; checks
that both give identical records; writes ``benchmarks/results/isolation.csv`` and prints
a table with the ratio isolated / in-process.

Usage::

    python benchmarks/isolation.py                 # 20, 200 paths, best of 3
    python benchmarks/isolation.py --paths 20 --repeat 1
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from ftc_verify.controllers import load_controller
from ftc_verify.model.files import load_system
from ftc_verify.simulation.batches import fmu_monte_carlo
from ftc_verify.simulation.delta import DeltaSchedule
from ftc_verify.simulation.paths import sample_paths
from csvout import write_rows

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--paths", type=int, nargs="+", default=[20, 200])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args()
    system = load_system(ROOT / "examples" / "paper.toml")
    gains = load_controller(ROOT / "examples" / "paper_gains.toml")
    rows = []
    for count in args.paths:
        paths = sample_paths(system.chain, 30.0, count, args.seed)
        best = {True: float("inf"), False: float("inf")}
        records = {}
        for _ in range(args.repeat):
            for isolate in (True, False):  # interleaved: the machine's noise hits both
                t0 = time.perf_counter()
                res = fmu_monte_carlo(system, gains, paths, step=0.01, delta=DeltaSchedule("random"),
                                      seed=args.seed, isolate=isolate)
                best[isolate] = min(best[isolate], time.perf_counter() - t0)
                records[isolate] = res.records
        same = all(np.array_equal(a.x, b.x) for a, b in zip(records[True], records[False]))
        rows.append({"paths": count, "isolated_s": best[True], "in_process_s": best[False],
                     "ratio": best[True] / best[False], "identical_records": same})
    out = ROOT / "benchmarks" / "results" / "isolation.csv"
    write_rows(out, rows)
    print(f"{'paths':>6} {'isolated s':>11} {'in-process s':>13} {'ratio':>6}  identical")
    for r in rows:
        print(f"{r['paths']:>6} {r['isolated_s']:>11.3f} {r['in_process_s']:>13.3f} {r['ratio']:>6.2f}  "
              f"{r['identical_records']}")
    print(f"written {out}")


if __name__ == "__main__":
    main()
