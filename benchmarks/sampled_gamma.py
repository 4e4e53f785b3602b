#!/usr/bin/env python
"""Benchmark of the sampled loop's proved gain (:mod:`ftc_verify.analysis.moments.sampled_gamma`).

The paper's example with its gains at the periods 0.001, 0.01, 0.05, 0.07, 0.08 (the
loop is stable up to ``h_max = 0.0842``): the proved nominal and robust gamma (empty when
none was proved), the pieces ``N`` used, the float64 lower estimates, the continuous
certificates for comparison, and the seconds each certificate took. Columns:
``period, nominal_gamma, nominal_pieces, nominal_seconds, robust_gamma, robust_pieces,
robust_seconds, nominal_lower, robust_lower, continuous_nominal, continuous_robust``.

Usage::

    python benchmarks/sampled_gamma.py            # writes benchmarks/results/sampled_gamma.csv
    python benchmarks/sampled_gamma.py --out x.csv
"""

from __future__ import annotations

import argparse
import csv
import os
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from ftc_verify.analysis.closedloop import closed_loop
from ftc_verify.analysis.lmi_analysis import hinf_gamma
from ftc_verify.analysis.moments.sampled_gamma import gain_lower_estimate, sampled_gamma
from ftc_verify.analysis.moments.sampled_lower import sampled_lower_bound
from ftc_verify.controllers.files import load_controller
from ftc_verify.model.files import load_system

ROOT = Path(__file__).resolve().parents[1]
PERIODS = (0.001, 0.01, 0.05, 0.07, 0.08)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "sampled_gamma.csv")
    args = parser.parse_args()
    system = load_system(ROOT / "examples" / "paper.toml")
    controller = load_controller(ROOT / "examples" / "paper_gains.toml")
    loop = closed_loop(system, controller)
    cont = [hinf_gamma(loop, robust=r).gamma for r in (False, True)]
    rows = []
    for h in PERIODS:
        certs = [sampled_gamma(system, controller, h, robust=r) for r in (False, True)]
        lows = [gain_lower_estimate(system, controller, h, robust=r)[0] for r in (False, True)]
        proved = []
        for r in (False, True):
            t0 = time.perf_counter()
            b = sampled_lower_bound(system, controller, h, robust=r)
            proved += ["" if b.value is None else b.value, round(time.perf_counter() - t0, 2)]
        rows.append([h] + [v for c in certs for v in ("" if c.gamma is None else c.gamma, c.pieces, round(c.seconds, 2))]
                    + ["" if v is None else v for v in lows] + cont + proved)
        print(rows[-1], flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    with args.out.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["period", "nominal_gamma", "nominal_pieces", "nominal_seconds", "robust_gamma", "robust_pieces",
                    "robust_seconds", "nominal_lower", "robust_lower", "continuous_nominal", "continuous_robust",
                    "nominal_lower_proved", "nominal_lower_seconds", "robust_lower_proved", "robust_lower_seconds"])
        w.writerows(rows)


if __name__ == "__main__":
    main()
