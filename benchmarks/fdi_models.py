#!/usr/bin/env python
"""What the FDI model changes (issue 23): phase-type delays and false alarms on the paper's example.

For the paper's example (``examples/paper.toml``, same mean delays ``1/beta`` in the same
box) with ``delay_phases`` k = 1, 2, 4, 8 and, at each k, false-alarm rates of 0, 0.05 and
0.2 per unit time (the same rate from each mode to the other, a known rate: an interval of
zero width), this prints and writes (``benchmarks/results/fdi_models.csv``):

* ``gamma_paper``: the certified robust gamma (Lemma 4.1, :func:`ftc_verify.analysis.analyze`)
  of the paper's gains (``examples/paper_gains.toml``), and whether it is certified stable;
* ``gamma_iterative``: the certified robust gamma of the ``iterative`` state-feedback design
  synthesized for that FDI model (gain bound 30, as ``verify``);
* ``exact_paper``: the exact expected energy ratio ``max E||y||^2/||w||^2`` of the paper's
  gains over the rate vertices (the paper's disturbance, infinite horizon, Delta = 0), and
  its square root ``sqrt_exact``; ``lower_bound``: the proved lower bound of the robust
  gain that ``analyze`` reports beside the certified gamma (:mod:`ftc_verify.analysis.lower_bound`);
* ``ratio``: ``gamma_paper / lower_bound``, how far the box certificate can stand above
  the true worst-case gain (1 = no conservatism left).

Usage::

    python benchmarks/fdi_models.py                # the whole grid (a few minutes)
    python benchmarks/fdi_models.py --phases 1 2 --false-alarms 0
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np

from ftc_verify.analysis.analyze import analyze
from ftc_verify.analysis.closedloop import closed_loop
from ftc_verify.controllers import load_controller
from ftc_verify.model.files import load_system
from ftc_verify.model.system import FTCSystem, JointChain
from ftc_verify.synthesis.state_feedback import synthesize
from ftc_verify.analysis.moments.energy import exact_energy
from csvout import write_rows

ROOT = Path(__file__).resolve().parents[1]


def variant(base: FTCSystem, phases: int, false_alarm: float) -> FTCSystem:
    """The paper's system with Erlang-``phases`` delays and a known false-alarm rate."""
    ch = base.chain
    fa = None if false_alarm == 0 else false_alarm * (1.0 - np.eye(ch.m))
    chain = JointChain(ch.alpha, ch.beta_min, ch.beta_max, ch.fault_during_delay, phases, fa, fa)
    return FTCSystem(base.name, base.modes, chain)


def gamma_of(report: object) -> float | None:
    return report.robust.gamma if report.certified_stable and report.robust.certified else None  # type: ignore[attr-defined]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--phases", type=int, nargs="+", default=[1, 2, 4, 8])
    parser.add_argument("--false-alarms", type=float, nargs="+", default=[0.0, 0.05, 0.2])
    args = parser.parse_args()
    base = load_system(ROOT / "examples" / "paper.toml")
    gains = load_controller(ROOT / "examples" / "paper_gains.toml")
    rows = []
    for fa in args.false_alarms:
        for k in args.phases:
            t0 = time.perf_counter()
            system = variant(base, k, fa)
            loop = closed_loop(system, gains)
            rep = analyze(loop, name=system.name, cross_validation=False)
            exact = [(exact_energy(loop.nominal(), beta=b).ratio, b) for b in system.chain.vertices()]
            worst_ratio, _ = max(exact, key=lambda e: e[0])
            lower = None if rep.robust_lower is None else rep.robust_lower.value
            design = synthesize(system, method="iterative", k_max=30.0)
            g_paper, g_iter = gamma_of(rep), (gamma_of(design.report) if design.report is not None else None)
            rows.append({"false_alarm": fa, "phases": k, "states": system.chain.n_states,
                         "paper_certified_stable": rep.certified_stable, "gamma_paper": g_paper,
                         "gamma_iterative": g_iter, "exact_paper": worst_ratio, "sqrt_exact": math.sqrt(worst_ratio),
                         "lower_bound": lower,
                         "ratio": None if g_paper is None or not lower else g_paper / lower,
                         "abscissa": rep.mss.spectral_abscissa, "seconds": time.perf_counter() - t0})
            r = rows[-1]
            print(f"fa {fa:<5g} k {k:<2d} states {r['states']:<3d} gamma paper {_f(g_paper)}  iterative {_f(g_iter)}  "
                  f"exact {worst_ratio:.5g} (sqrt {math.sqrt(worst_ratio):.5g})  proved lower bound {_f(lower)}  "
                  f"ratio {_f(r['ratio'])}  ({r['seconds']:.1f} s)", flush=True)
    out = ROOT / "benchmarks" / "results" / "fdi_models.csv"
    write_rows(out, rows)
    print(f"written {out}")


def _f(x: float | None) -> str:
    return "-" if x is None else f"{x:.5g}"


if __name__ == "__main__":
    main()
