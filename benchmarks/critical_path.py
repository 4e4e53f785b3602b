#!/usr/bin/env python
"""The CPU seconds of each ``analyze`` stage in the process that ran it, and the critical path.

On a loaded machine wall times say little about what a quiet 2-core machine would show;
the CPU time of each stage, counted in the process that ran it (the analysis process and
the gamma program's forked child, :func:`ftc_verify.analysis.analyze.analyze`), does: the
critical path is the longer of the two processes' sums. Each stage function of
``ftc_verify.analysis.analyze`` (``mean_square_stability``, ``hinf_gamma``, ``mes_known``,
``mes_lmi``, the lower bounds) is wrapped to record ``time.process_time()`` around its call
(a forked child's record comes back inside the ``LMIResult`` it returns).

``--against DIR`` runs the same in a child with ``PYTHONPATH=DIR`` (another checkout),
interleaved, for a side-by-side table. The case is a random loop of
``benchmarks/scaling.py`` (``--case 12x4u --seed 6111``). ``OPENBLAS_NUM_THREADS=1``.

Usage::

    python benchmarks/critical_path.py --case 12x4u --seed 6111 --against /work/main --repeat 2

Writes ``benchmarks/results/critical_path.csv`` (one row per stage and run) and prints a table.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any
from csvout import write_rows

HERE = Path(__file__).resolve().parent
COLUMNS = ["tree", "repeat", "stage", "process", "cpu_s"]
STAGES = ("mean_square_stability", "hinf_gamma", "mes_known", "mes_lmi", "gain_lower_bound", "worst_constant_delta")


def inner(system: str, gains: str) -> None:
    """In the measured tree: run ``analyze`` with every stage wrapped; print one JSON line."""
    import ftc_verify as fv

    am = importlib.import_module("ftc_verify.analysis.analyze")
    loop = fv.closed_loop(fv.load_system(system), fv.load_controller(gains))
    main_pid = os.getpid()
    log: list[dict[str, Any]] = []
    tag = "##stage##"

    def wrap(name: str, fn: Any) -> Any:
        def timed(*args: Any, **kwargs: Any) -> Any:
            start = time.process_time()
            out = fn(*args, **kwargs)
            label = name + ("(robust)" if kwargs.get("robust") else "")
            entry = {"stage": label, "process": "analysis" if os.getpid() == main_pid else "child",
                     "cpu_s": time.process_time() - start}
            if entry["process"] == "child" and isinstance(out, am.LMIResult):
                out = dataclasses.replace(out, message=out.message + tag + json.dumps(entry))
            log.append(entry)
            return out
        return timed

    for name in STAGES:
        if hasattr(am, name):
            setattr(am, name, wrap(name, getattr(am, name)))
    rep = am.analyze(loop, cross_validation=False)
    for res in (rep.nominal, rep.robust):
        if tag in res.message:
            child = json.loads(res.message.split(tag)[1])
            if child not in log:
                log.append(child)
    print(json.dumps({"stages": log, "nominal": rep.nominal.gamma, "robust": rep.robust.gamma}))


def measure(system: Path, gains: Path, tree: Path | None) -> dict[str, Any]:
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    if tree is not None:
        env["PYTHONPATH"] = str(tree)
    out = subprocess.run([sys.executable, __file__, "--inner", str(system), str(gains)], env=env, check=True,
                         capture_output=True, text=True, cwd=tempfile.gettempdir())
    return dict(json.loads(out.stdout.strip().splitlines()[-1]))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--case", default="12x4u")
    parser.add_argument("--seed", type=int, default=6111)
    parser.add_argument("--repeat", type=int, default=1)
    parser.add_argument("--against", type=Path, default=None)
    parser.add_argument("--out", type=Path, default=HERE / "results" / "critical_path.csv")
    parser.add_argument("--inner", nargs=2, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.inner:
        inner(*args.inner)
        return 0
    sys.path.insert(0, str(HERE))
    import scaling

    trees: list[tuple[str, Path | None]] = [("this", None)] + ([("against", args.against)] if args.against else [])
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory() as tmp:
        n, m, uncertain = scaling.parse_case(args.case)
        system, gains = scaling.write_case(n, m, uncertain, args.seed, Path(tmp))
        for rep in range(args.repeat):
            for name, tree in (trees if rep % 2 == 0 else trees[::-1]):
                run = measure(system, gains, tree)
                for st in run["stages"]:
                    rows.append({"tree": name, "repeat": rep, **st})
                paths = {p: sum(s["cpu_s"] for s in run["stages"] if s["process"] == p) for p in ("analysis", "child")}
                print(f"{args.case} seed {args.seed} {name} rep {rep}: analysis process {paths['analysis']:.2f} s CPU, "
                      f"forked child {paths['child']:.2f} s, critical path {max(paths.values()):.2f} s; "
                      f"gammas {run['nominal']!r} / {run['robust']!r}", flush=True)
                for st in run["stages"]:
                    print(f"    {st['process']:8s} {st['stage']:24s} {st['cpu_s']:.3f} s")
    write_rows(args.out, rows, COLUMNS)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
