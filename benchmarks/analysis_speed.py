#!/usr/bin/env python
"""The LMI stage of ``analyze`` against the first release, on fresh random systems (issue 24).

Each run is a child process (``OPENBLAS_NUM_THREADS=1``) that imports ``ftc_verify`` from
one code tree -- this one, the first release (``git archive FIRST_RELEASE``, extracted
into a temporary directory, nothing in the repository changes) or, with ``--before
REF``, another commit -- builds the case, does one untimed warm-up ``analyze`` on a 2x2
system, then times ``analyze(loop)`` once and prints its stage times, gammas and
spectral abscissa as JSON. Runs are interleaved: for each repetition, every case on every
code tree, the order of the trees reversed on odd repetitions; medians are reported.

The cases are ``benchmarks/analysis.py``'s ``make_case`` (random A, B, C, D per mode,
uncertainty channels, LQR gains per FDI mode) with seeds not used by that benchmark
(default 2401 for n = 8, m = 3 and 2402 for n = 12, m = 4). The LMI stage is the wall
time of the ``theorem_3_1``, ``theorem_3_2`` and ``lemma_4_1`` stages of
``report.seconds`` (the latter two overlap where the nominal program runs in a forked
child beside the robust one); the first release runs its default solver choice (SDPA above 300
decision variables, through cvxpy), this tree its own (Clarabel).

Usage::

    python benchmarks/analysis_speed.py                       # 8x3 and 12x4, 3 repetitions
    python benchmarks/analysis_speed.py --only 8x3 --repeat 5
    python benchmarks/analysis_speed.py --before HEAD         # also the code before this change

Writes ``benchmarks/results/analysis_speed.csv`` (one row per run) and prints a table.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from csvout import write_rows

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
#: The first release: the first commit with ``analyze`` and its CLI (version 0.1.0;
#: ``benchmarks/README.md``'s "first version": cvxpy for every solver, SDPA above 300
#: decision variables).
FIRST_RELEASE = "1f25a08"
DEFAULT_CASES = {"8x3": 2401, "12x4": 2402}

#: What a child runs: ``make_case`` from benchmarks/analysis.py, adapted to the import
#: paths of either layout (flat modules in the first release, subpackages since).
CHILD = r'''
import json, math, sys, time
import numpy as np
try:
    from ftc_verify.model.system import FTCSystem
    from ftc_verify.analysis.closedloop import state_feedback_loop
    from ftc_verify.analysis.analyze import analyze
except ImportError:
    from ftc_verify.model import FTCSystem
    from ftc_verify.closedloop import state_feedback_loop
    from ftc_verify.analysis import analyze
src = open(sys.argv[1]).read()
code = src[src.index("def make_case"):src.index("def variables_of")]
code = code.replace("from ftc_verify.model.system import FTCSystem", "pass")
ns = {"np": np, "math": math, "FTCSystem": FTCSystem}
exec("from __future__ import annotations\nfrom typing import Any\n" + code, ns)
n, m, seed = int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
def run(loop):
    try:
        return analyze(loop, cross_validation=False)
    except TypeError:  # the first release has no cross_validation switch
        return analyze(loop)
warm, wg, _ = ns["make_case"](2, 2, 1, False)
run(state_feedback_loop(warm, wg))
system, gains, _ = ns["make_case"](n, m, seed, True)
loop = state_feedback_loop(system, gains)
t = time.perf_counter()
rep = run(loop)
wall = time.perf_counter() - t
res = (rep.mes_lmi, rep.nominal, rep.robust)
print("RESULT " + json.dumps({
    "wall_s": wall, "seconds": rep.seconds,
    "abscissa": float(rep.mss.spectral_abscissa),
    "nominal_gamma": rep.nominal.gamma if rep.nominal.certified else None,
    "robust_gamma": rep.robust.gamma if rep.robust.certified else None,
    "certified": all(r.certified for r in res),
    "solver_calls": sum(len(r.attempts) for r in res),
    "solvers": sorted({a.solver for r in res for a in r.attempts}),
}))
'''


def extract(ref: str, into: Path) -> Path:
    """``git archive REF`` unpacked into ``into`` (read-only for the repository)."""
    into.mkdir(parents=True, exist_ok=True)
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", ref], check=True, capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(into)], input=archive, check=True)
    return into


def run_child(tree: Path, n: int, m: int, seed: int, timeout: float) -> dict:
    """One timed ``analyze`` of case ``(n, m, seed)`` with ``ftc_verify`` from ``tree``."""
    env = dict(os.environ, PYTHONPATH=str(tree), OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1",
               MKL_NUM_THREADS="1", PYTHONWARNINGS="ignore")
    proc = subprocess.run([sys.executable, "-c", CHILD, str(HERE / "analysis.py"), str(n), str(m), str(seed)],
                          env=env, cwd=str(tree), capture_output=True, text=True, timeout=timeout)
    for line in proc.stdout.splitlines():
        if line.startswith("RESULT "):
            return json.loads(line[7:])
    raise RuntimeError(f"child failed ({tree}, n={n}, m={m}):\n{proc.stderr[-3000:]}")


def lmi_seconds(row: dict) -> float:
    """Wall time of the LMI stage (``gammas_wall``: the nominal and robust programs solved
    at the same time, their stage times overlapping)."""
    s = row["seconds"]
    if "gammas_wall" in s:
        return s.get("theorem_3_1", 0.0) + s["gammas_wall"]
    return s.get("theorem_3_1", 0.0) + s.get("theorem_3_2", 0.0) + s.get("lemma_4_1", 0.0)


def rel(a: float | None, b: float | None) -> float | None:
    return None if a is None or b is None else abs(a - b) / abs(b)


def summarise(rows: list[dict], cases: list[str], trees: list[str]) -> list[str]:
    """The printed table: medians per case and tree, ratios against the first release."""
    lines = [f"{'case':6} {'code':8} {'LMI s':>8} {'spectral s':>10} {'total s':>8} {'calls':>5} "
             f"{'LMI ratio':>9} {'total ratio':>11} {'nominal':>10} {'robust':>10} {'abscissa':>11}"]
    for case in cases:
        ref = [r for r in rows if r["case"] == case and r["code"] == "first"]
        ref_lmi = statistics.median(r["lmi_s"] for r in ref)
        ref_tot = statistics.median(r["total_s"] for r in ref)
        for tree in trees:
            mine = [r for r in rows if r["case"] == case and r["code"] == tree]
            lmi, tot = statistics.median(r["lmi_s"] for r in mine), statistics.median(r["total_s"] for r in mine)
            spec = statistics.median(r["spectral_s"] for r in mine)
            last = mine[-1]
            lines.append(f"{case:6} {tree:8} {lmi:8.2f} {spec:10.2f} {tot:8.2f} {last['solver_calls']:5d} "
                         f"{ref_lmi / lmi:9.2f} {ref_tot / tot:11.2f} {last['nominal_gamma'] or float('nan'):10.6f} "
                         f"{last['robust_gamma'] or float('nan'):10.6f} {last['abscissa']:11.7f}")
        for tree in trees[1:]:
            a = [r for r in rows if r["case"] == case and r["code"] == tree][-1]
            b = ref[-1]
            lines.append(f"       {tree} vs first: nominal gamma {rel(a['nominal_gamma'], b['nominal_gamma']):.2e}, "
                         f"robust {rel(a['robust_gamma'], b['robust_gamma']):.2e}, "
                         f"abscissa {rel(a['abscissa'], b['abscissa']):.2e} relative; certified {a['certified']}/{b['certified']}")
    return lines


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--only", default="8x3,12x4", help="cases NxM, comma-separated")
    ap.add_argument("--seed", action="append", default=[], metavar="NxM=SEED", help="seed of a case")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--first", default=None, help="a directory with the first release (default: git archive it)")
    ap.add_argument("--before", default=None, help="also time this commit (e.g. HEAD: the code before this change)")
    ap.add_argument("--timeout", type=float, default=600.0)
    ap.add_argument("--out", default=str(HERE / "results" / "analysis_speed.csv"))
    args = ap.parse_args()
    seeds = dict(DEFAULT_CASES, **dict(s.split("=") for s in args.seed))
    cases = [c for c in args.only.split(",") if c]
    tmp = Path(tempfile.mkdtemp(prefix="ftc-analysis-speed-"))
    trees = {"first": Path(args.first) if args.first else extract(FIRST_RELEASE, tmp / "first")}
    if args.before:
        trees["before"] = extract(args.before, tmp / "before")
    trees["current"] = ROOT
    names = list(trees)
    rows: list[dict] = []
    for rep in range(args.repeat):
        order = names if rep % 2 == 0 else names[::-1]
        for case in cases:
            n, m = (int(v) for v in case.split("x"))
            for tree in order:
                got = run_child(trees[tree], n, m, int(seeds[case]), args.timeout)
                row = {"case": case, "n": n, "m": m, "seed": int(seeds[case]), "code": tree, "repeat": rep,
                       "lmi_s": lmi_seconds(got), "spectral_s": got["seconds"].get("spectral", 0.0),
                       "total_s": got["wall_s"] - got["seconds"].get("cross_validation", 0.0),
                       **{k: got[k] for k in ("abscissa", "nominal_gamma", "robust_gamma", "certified",
                                              "solver_calls")},
                       "solvers": "+".join(got["solvers"])}
                rows.append(row)
                print(f"  run {rep} {case} {tree}: LMI {row['lmi_s']:.2f} s, total {row['total_s']:.2f} s", flush=True)
    write_rows(args.out, rows)
    print("\n".join(summarise(rows, cases, names)))
    print(f"(medians of {args.repeat} interleaved runs; total = analyze() without the cross-check; CSV: {args.out})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
