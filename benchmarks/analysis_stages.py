#!/usr/bin/env python
"""The analysis stages alone, in process, side by side with another checkout (issue 37 item 3).

``benchmarks/scaling.py`` times the whole command (interpreter start, imports, the
python-control child); on a loaded machine its wall times move by a factor 2. This script
times only ``ftc_verify.analysis.analyze.analyze(loop, cross_validation=False)`` on the
random systems of ``benchmarks/analysis.py``'s ``make_case``: one child process per run
(``PYTHONPATH`` = the tree; ``OPENBLAS_NUM_THREADS=1``), the trees interleaved (order
swapped on odd repetitions), and records the CPU time of the call (``getrusage`` of the
child and of the processes it waited for: the forked Theorem 3.2 solve included), its
wall time, the stage times the report gives, the certified gammas and the proved lower
bounds.

Usage::

    python benchmarks/analysis_stages.py --cases 8x3,8x3u --seed 5401 --against /tmp/old --repeat 3

Prints a table (medians, ratios against the other tree) and writes
``benchmarks/results/analysis_stages.csv``.
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
from typing import Any

from csvout import write_rows

HERE = Path(__file__).resolve().parent
CHILD = r"""
import json, resource, sys, time
from ftc_verify.analysis.analyze import analyze
from ftc_verify.analysis.closedloop import closed_loop
from ftc_verify.controllers.files import load_controller
from ftc_verify.model.files import load_system
loop = closed_loop(load_system(sys.argv[1]), load_controller(sys.argv[2]))
def cpu():
    a, b = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return a.ru_utime + a.ru_stime + b.ru_utime + b.ru_stime
c0, t0 = cpu(), time.perf_counter()
rep = analyze(loop, cross_validation=False)
wall, used = time.perf_counter() - t0, cpu() - c0
low = lambda b: None if b is None else b.value
print(json.dumps({"cpu_s": used, "wall_s": wall, "seconds": rep.seconds, "nominal": rep.nominal.gamma,
                  "robust": rep.robust.gamma, "stable": bool(rep.certified_stable),
                  "nominal_lower": low(getattr(rep, "nominal_lower", None)),
                  "robust_lower": low(getattr(rep, "robust_lower", None))}))
"""


def run(system: Path, gains: Path, tree: Path | None) -> dict[str, Any]:
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    if tree is not None:
        env["PYTHONPATH"] = str(tree)
    load = os.getloadavg()[0]
    out = subprocess.run([sys.executable, "-c", CHILD, str(system), str(gains)], env=env, capture_output=True,
                         text=True, cwd=tempfile.gettempdir(), check=False)
    if out.returncode != 0:
        return {"error": out.stderr.strip().splitlines()[-1:] or ["?"], "load": load}
    return json.loads(out.stdout.strip().splitlines()[-1]) | {"load": load}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cases", default="8x3,8x3u")
    parser.add_argument("--seed", type=int, default=5401, help="seed of the first case (+1 per case)")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--against", type=Path, required=True, help="another checkout, run with PYTHONPATH")
    parser.add_argument("--out", type=Path, default=HERE / "results" / "analysis_stages.csv")
    args = parser.parse_args()
    scaling = HERE / "scaling.py"
    import importlib.util

    spec = importlib.util.spec_from_file_location("bench_scaling", scaling)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    trees: list[tuple[str, Path | None]] = [("this", None), ("against", args.against)]
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory() as tmp:
        for k, case in enumerate(args.cases.split(",")):
            n, m, uncertain = module.parse_case(case)
            system, gains = module.write_case(n, m, uncertain, args.seed + k, Path(tmp))
            for rep in range(args.repeat):
                for name, tree in (trees if rep % 2 == 0 else trees[::-1]):
                    r = run(system, gains, tree)
                    row = {"case": case, "seed": args.seed + k, "tree": name, "repeat": rep, **{
                        key: r.get(key) for key in ("cpu_s", "wall_s", "load", "nominal", "robust", "stable",
                                                    "nominal_lower", "robust_lower")},
                           "seconds": json.dumps(r.get("seconds")), "error": r.get("error")}
                    rows.append(row)
                    print(f"{case} {name} rep {rep}: {row['cpu_s']} s CPU, {row['wall_s']} s wall (load {row['load']:.1f}) "
                          f"gamma {row['nominal']} / {row['robust']}, lower {row['nominal_lower']} / {row['robust_lower']}",
                          flush=True)
    write_rows(args.out, rows)
    print("\n| case | CPU this | CPU against | CPU ratio | wall this | wall against | wall ratio |")
    print("|---|---|---|---|---|---|---|")
    for case in dict.fromkeys(r["case"] for r in rows):
        med = {t: {key: statistics.median(r[key] for r in rows if r["case"] == case and r["tree"] == t and r["cpu_s"])
                   for key in ("cpu_s", "wall_s")} for t in ("this", "against")}
        print(f"| {case} | {med['this']['cpu_s']:.2f} s | {med['against']['cpu_s']:.2f} s | "
              f"{med['against']['cpu_s'] / med['this']['cpu_s']:.2f}x | {med['this']['wall_s']:.2f} s | "
              f"{med['against']['wall_s']:.2f} s | {med['against']['wall_s'] / med['this']['wall_s']:.2f}x |")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
