#!/usr/bin/env python
"""Benchmark of verify's two-sided sampled-loop Monte Carlo
(:func:`ftc_verify.verification.sampled_stage.sampled_mc_stage`).

The paper example with its gains at h = 0.01 and 0.05, 200 and 2000 paths (horizon 30,
so 400 periods are simulated). Columns: ``period, paths, horizon, exact, mean,
half_width, inside, seconds``.

Usage::

    python benchmarks/sampled_mc.py              # writes benchmarks/results/sampled_mc.csv
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from ftc_verify.controllers.files import load_controller
from ftc_verify.model.files import load_system
from ftc_verify.verification.sampled_stage import sampled_mc_stage
from csvout import write_rows

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "sampled_mc.csv"))
    p.add_argument("--seed", type=int, default=5)
    args = p.parse_args()
    system = load_system(ROOT / "examples" / "paper.toml")
    controller = load_controller(ROOT / "examples" / "paper_gains.toml")
    rows = []
    for h in (0.01, 0.05):
        for paths in (200, 2000):
            t = time.perf_counter()
            found, check = sampled_mc_stage(system, controller, h, 30.0, paths, args.seed, object())  # type: ignore[arg-type]
            seconds = time.perf_counter() - t
            assert found is not None
            rows.append({"period": h, "paths": paths, "horizon": found["horizon"], "exact": f"{found['exact']:.6g}",
                         "mean": f"{found['mean']:.6g}",
                         "half_width": f"{(found['interval'][1] - found['interval'][0]) / 2:.3g}",
                         "inside": check.ok, "seconds": f"{seconds:.2f}"})
            print(rows[-1], flush=True)
    write_rows(args.out, rows)


if __name__ == "__main__":
    main()
