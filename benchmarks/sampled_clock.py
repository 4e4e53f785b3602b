#!/usr/bin/env python
"""Experiment (issue 31, item 2): how close to the float64 crossing does the clock-dependent
certificate of :mod:`ftc_verify.analysis.moments.sampled_clock` prove the sampled loop
stable over the whole rate box, without sub-boxes?

For each case (the paper example with its gains, random ``n = 2, m = 2`` loops of seeds
``--seeds``, the random ``n = 4, m = 3`` loop of seed 1; the random loops drawn as
``benchmarks/sampled.py`` draws them) and each number of pieces: the float64 crossing
``h_c`` of the worst vertex (largest :math:`\\rho(T)` over every vertex of the box, by
bisection), then a bisection (``--steps`` halvings of ``[low h_c, h_c]``) for the largest
period at which the certificate (affine pieces, or ``--quadratic``) is found and proved in
ball arithmetic. Columns: ``case, seed, pieces, shape, crossing, proved_h, gap`` (``1 - proved_h / crossing``)
``, cpu_seconds`` (of the bisection), ``cpu_per_attempt``.

Usage::

    python benchmarks/sampled_clock.py --pieces 4 8 16 --out /tmp/clock.csv
    python benchmarks/sampled_clock.py --quadratic --pieces 2 4 --low 0.9 --out /tmp/clockq.csv
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

from ftc_verify.analysis.moments.sampled import SampledLoop, spectral_radius
from ftc_verify.analysis.moments.sampled_clock import clock_stable
from ftc_verify.controllers.files import load_controller
from ftc_verify.model.files import load_system
from ftc_verify.testing.sampled_cases import lqr_case
from csvout import write_rows

ROOT = Path(__file__).resolve().parents[1]


def vertex_crossing(loop: SampledLoop, lo: float, hi: float) -> float:
    """The float64 crossing of ``max_v rho(T(h, v))`` over the box's vertices in ``[lo, hi]``."""
    verts = list(loop.chain.vertices())

    def worst(h: float) -> float:
        return max(spectral_radius(loop, h, v) for v in verts)

    while worst(hi) < 1.0:
        hi *= 2.0
    while worst(lo) >= 1.0 and lo > 1e-6:
        lo /= 2.0
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if worst(mid) < 1.0 else (lo, mid)
    return lo


def largest_proved(loop: SampledLoop, crossing: float, pieces: int, steps: int, quadratic: bool,
                   low: float) -> tuple[float | None, int]:
    """The largest period of the bisection proved by the certificate, and the attempts."""
    lo, hi = low * crossing, crossing
    cert = clock_stable(loop, lo, pieces, quadratic)
    if cert is None or not cert.proved:
        return None, 1
    for _ in range(steps):
        mid = 0.5 * (lo + hi)
        cert = clock_stable(loop, mid, pieces, quadratic)
        lo, hi = (mid, hi) if cert is not None and cert.proved else (lo, mid)
    return lo, steps + 1


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default="/tmp/sampled_clock.csv")
    p.add_argument("--pieces", type=int, nargs="+", default=[4, 8, 16])
    p.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4])
    p.add_argument("--steps", type=int, default=10)
    p.add_argument("--quadratic", action="store_true", help="quadratic pieces (S-procedure in the clock)")
    p.add_argument("--low", type=float, default=0.5, help="the bisection's lower end, times the crossing")
    p.add_argument("--cases", nargs="+", default=["paper", "n2", "n4"])
    args = p.parse_args()
    cases: list[tuple[str, int, Any, Any]] = []
    if "paper" in args.cases:
        cases.append(("paper", 0, load_system(ROOT / "examples" / "paper.toml"),
                      load_controller(ROOT / "examples" / "paper_gains.toml")))
    for seed in args.seeds:
        rng = np.random.default_rng(seed)
        c22 = lqr_case(2, 2, rng)
        c43 = lqr_case(4, 3, rng)
        if "n2" in args.cases:
            cases.append(("random n=2 m=2", seed, *c22))
        if "n4" in args.cases and seed == 1:
            cases.append(("random n=4 m=3", seed, *c43))
    rows = []
    for name, seed, system, controller in cases:
        loop = SampledLoop.build(system, controller)
        hc = vertex_crossing(loop, 1e-3, 1.0)
        for pieces in args.pieces:
            cpu = time.process_time()
            h, attempts = largest_proved(loop, hc, pieces, args.steps, args.quadratic, args.low)
            cpu = time.process_time() - cpu
            rows.append({"case": name, "seed": seed, "pieces": pieces,
                         "shape": "quadratic" if args.quadratic else "affine", "crossing": f"{hc:.6f}",
                         "proved_h": "" if h is None else f"{h:.6f}",
                         "gap": "" if h is None else f"{1 - h / hc:.1e}",
                         "cpu_seconds": f"{cpu:.1f}", "cpu_per_attempt": f"{cpu / attempts:.2f}"})
            print(rows[-1], flush=True)
    write_rows(args.out, rows)


if __name__ == "__main__":
    main()
