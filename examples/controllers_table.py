"""Print the README's controller comparison table for the paper's example.

Usage: python examples/controllers_table.py [--k-max V] [--solver NAME]

One row per controller: the paper's K1, K2; two-step at gamma = 0.8; two-step minimised;
iterative; full-info; common. Every gain set is verified by the same core analysis
(``ftc_verify.analysis.analyze.analyze``); wall time covers synthesis plus verification.
Certified gammas are printed to 4 digits rounded up (:func:`ftc_verify.claimtext.upper_text`),
as everywhere else: a printed certificate is never below the one proved.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from ftc_verify.analysis.analyze import analyze
from ftc_verify.analysis.closedloop import state_feedback_loop
from ftc_verify.claimtext import upper_text
from ftc_verify.model.files import load_system
from ftc_verify.controllers.files import load_gains
from ftc_verify.synthesis.state_feedback import synthesize

HERE = Path(__file__).resolve().parent


def fmt(x: float | None) -> str:
    return "-" if x is None else f"{x:.4g}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--k-max", type=float, default=None)
    ap.add_argument("--solver", default=None)
    args = ap.parse_args()
    system = load_system(HERE / "paper.toml")
    rows = []
    t0 = time.perf_counter()
    gains = load_gains(HERE / "paper_gains.toml")
    rep = analyze(state_feedback_loop(system, gains), solver=args.solver, cross_validation=False)
    norm = max(float(np.linalg.norm(K, 2)) for K in gains)
    ok = args.k_max is None or norm <= args.k_max
    rows.append(("paper K1, K2", rep.nominal.gamma if ok else None, rep.robust.gamma if ok else None,
                 rep.mss.spectral_abscissa, norm, time.perf_counter() - t0,
                 "" if ok else f"exceeds k_max (norm {norm:.4g})"))
    cases = [("two-step, gamma = 0.8", "two-step", 0.8), ("two-step, minimised", "two-step", None),
             ("iterative", "iterative", None), ("full-info", "full-info", None),
             ("common", "common", None)]
    for label, method, gamma in cases:
        r = synthesize(system, method=method, gamma=gamma, k_max=args.k_max, solver=args.solver)
        d = r.to_dict()
        note = "" if r.certified else r.message
        if method == "iterative" and r.history:
            note = f"history {' -> '.join(upper_text(g, 4) for g in r.history)}; {r.solver_calls} solver calls"
        rows.append((label, d["gamma_nominal_certified"], d["gamma_certified"], d["spectral_abscissa"],
                     d["max_gain_norm"], r.wall_seconds, note))
    bound = f", k_max = {args.k_max:g}" if args.k_max else ""
    print(f"paper example{bound}; solver {args.solver or 'auto'}")
    print("| controller | certified nominal gamma | certified robust gamma | spectral abscissa | max gain norm | wall time (s) | note |")
    print("|---|---|---|---|---|---|---|")
    for label, gn, gr, sa, kn, wall, note in rows:
        print(f"| {label} | {upper_text(gn, 4)} | {upper_text(gr, 4)} | {fmt(sa)} | {fmt(kn)} | {wall:.2f} | {note} |")


if __name__ == "__main__":
    main()
