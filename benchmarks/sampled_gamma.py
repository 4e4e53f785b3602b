#!/usr/bin/env python
"""Benchmark of the sampled loop's proved gain (:mod:`ftc_verify.analysis.moments.sampled_gamma`).

Cases: the paper's example with its gains at the periods 0.001, 0.01, 0.05, 0.07, 0.075,
0.08, 0.083 (the loop is stable up to ``h_max = 0.0842``), and random held-out loops
(``--seeds``; two modes, two states, uncertainty channels, an LQR gain per FDI mode,
drawn with ``numpy.random.default_rng(seed)``) at 0.5, 0.8, 0.9 and 0.95 of their
proved ``h_max``. Per case what ``analyze --period`` computes
(:func:`~ftc_verify.analysis.moments.sampled_gamma.sampled_performance`: the proved
lower bounds first, then the nominal and robust certificates, side by side in two
processes): the proved gammas (empty when none), the pieces ``N`` and the storage's
degree in the clock (1 affine, 2 quadratic) used, the rows of that program (the schedule
stops at ``MAX_ROWS``: the same numbers on every machine), each certificate's CPU seconds,
the lower bounds and their kind, the continuous certificates, the total wall and CPU
seconds (this process and its reaped children). Columns:
``case, h_max, period, fraction, nominal_gamma, nominal_pieces, nominal_degree, nominal_rows,
nominal_seconds, robust_gamma, robust_pieces, robust_degree, robust_rows, robust_seconds, nominal_lower,
robust_lower, lower_kind,
continuous_nominal, continuous_robust, wall_seconds, cpu_seconds, note``.

Usage::

    python benchmarks/sampled_gamma.py            # writes benchmarks/results/sampled_gamma.csv
    python benchmarks/sampled_gamma.py --out x.csv --seeds 101,202 --paper-only
"""

from __future__ import annotations

import argparse
import csv
import os
import resource
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np
import scipy.linalg

from ftc_verify.analysis.closedloop import closed_loop
from ftc_verify.analysis.lmi_analysis import hinf_gamma
from ftc_verify.analysis.moments.sampled import sampled_analysis
from ftc_verify.analysis.moments.sampled_gamma import sampled_performance
from ftc_verify.controllers.controller import Controller
from ftc_verify.controllers.files import load_controller
from ftc_verify.model.files import load_system
from ftc_verify.model.system import FTCSystem

ROOT = Path(__file__).resolve().parents[1]
PERIODS = (0.001, 0.01, 0.05, 0.07, 0.075, 0.08, 0.083)
FRACTIONS = (0.5, 0.8, 0.9, 0.95)
COLUMNS = ["case", "h_max", "period", "fraction", "nominal_gamma", "nominal_pieces", "nominal_degree", "nominal_rows",
           "nominal_seconds", "robust_gamma", "robust_pieces", "robust_degree", "robust_rows", "robust_seconds",
           "nominal_lower", "robust_lower", "lower_kind",
           "continuous_nominal", "continuous_robust", "wall_seconds", "cpu_seconds", "note"]


def random_case(seed: int) -> tuple[FTCSystem, Controller]:
    """Two modes of a random 2-state plant (shifted by -0.3 I, the second with its input
    halved: a fault), uncertainty channels 0.1 I, and the LQR gain of each FDI mode's plant."""
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((2, 2)) * 0.8 - 0.3 * np.eye(2)
    B = rng.standard_normal((2, 2))
    modes, gains = [], []
    for eff in (1.0, 0.5):
        modes.append({"A": A, "B": B * eff, "C": rng.standard_normal((1, 2)), "D": 0.5 * np.ones((2, 1)),
                      "A1": 0.1 * np.eye(2), "A2": 0.1 * np.eye(2), "B1": 0.1 * np.eye(2), "B2": 0.1 * np.eye(2)})
        P = scipy.linalg.solve_continuous_are(A, B * eff, 4.0 * np.eye(2), np.eye(2))
        gains.append(-(B * eff).T @ P)
    system = FTCSystem.from_arrays(name=f"random seed {seed}", modes=modes, alpha=[[-0.5, 0.5], [1.0, -1.0]],
                                   beta_min=[[0.0, 2.0], [2.5, 0.0]], beta_max=[[0.0, 3.0], [3.5, 0.0]])
    return system, Controller.state_feedback(gains)


def cpu() -> float:
    """CPU seconds of this process and its reaped children (the forked robust certificate)."""
    a, b = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return a.ru_utime + a.ru_stime + b.ru_utime + b.ru_stime


def row(case: str, system: FTCSystem, controller: Controller, h: float, h_max: float | None,
        cont: list[Any]) -> list[Any]:
    t0, c0 = time.perf_counter(), cpu()
    perf = sampled_performance(system, controller, h)
    wall, used = time.perf_counter() - t0, cpu() - c0
    certs = [perf.nominal, perf.robust]
    out: list[Any] = [case, "" if h_max is None else round(h_max, 6), h, "" if not h_max else round(h / h_max, 3)]
    for c in certs:
        out += ["", "", "", "", ""] if c is None else ["" if c.gamma is None else c.gamma, c.pieces, c.degree,
                                                       c.rows, round(c.seconds, 2)]
    out += ["" if v is None else v for v in (perf.nominal_lower, perf.robust_lower)]
    out += [perf.nominal_lower_kind if perf.nominal_lower_kind == perf.robust_lower_kind else "mixed"]
    out += cont + [round(wall, 2), round(used, 2)]
    notes = [c.note for c in certs if c is not None and c.gamma is None]
    return out + [" | ".join(notes)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "sampled_gamma.csv")
    parser.add_argument("--seeds", default="101,202", help="seeds of the random held-out loops (comma-separated)")
    parser.add_argument("--paper-only", action="store_true")
    parser.add_argument("--periods", default=",".join(map(str, PERIODS)), help="the paper example's periods")
    args = parser.parse_args()
    cases: list[tuple[str, FTCSystem, Controller, tuple[float, ...] | None]] = [
        ("paper", load_system(ROOT / "examples" / "paper.toml"), load_controller(ROOT / "examples" / "paper_gains.toml"),
         tuple(float(v) for v in args.periods.split(",")))]
    if not args.paper_only:
        cases += [(f"random seed {s}", *random_case(int(s)), None) for s in args.seeds.split(",") if s]
    rows = []
    for name, system, controller, periods in cases:
        loop = closed_loop(system, controller)
        cont = [hinf_gamma(loop, robust=r).gamma for r in (False, True)]
        h_max = sampled_analysis(system, controller, 0.001).h_max
        hs = periods if periods is not None else tuple(f * h_max for f in FRACTIONS) if h_max else ()
        for h in hs:
            rows.append(row(name, system, controller, h, h_max, cont))
            print(dict(zip(COLUMNS, rows[-1])), flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    with args.out.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(COLUMNS)
        w.writerows(rows)


if __name__ == "__main__":
    main()
