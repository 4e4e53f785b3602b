#!/usr/bin/env python
"""Which process runs which stage of ``ftc-verify analyze``, and when (issue 37 item 3).

On two cores the wall time of ``analyze`` is set by its processes together: the CLI
process (start-up, imports, loading), the python-control cross-check child
(:mod:`ftc_verify.prestart`), the analysis child (``solvers.interruptible``) and the gamma
program's child (``analyze._gamma_ahead``). This script runs the command as a user does
(``python -m ftc_verify analyze SYSTEM --gains GAINS --json``, one subprocess per run,
``PYTHONPATH`` = the tree, ``OPENBLAS_NUM_THREADS=1``) with the stage functions of
``ftc_verify.analysis.analyze`` and the cross-check child wrapped to record, in every
process, the start and end (``time.perf_counter``, one clock for all processes on Linux,
relative to the interpreter's start) and the CPU seconds of each stage. It prints the
timeline and the CPU of each process, and writes one CSV row per stage and run.

The wrappers add no work to the stages (two clock reads each); the cross-check's job is
wrapped under its own name, so it still pickles by reference.

Usage::

    python benchmarks/analyze_timeline.py --case 8x3u --seed 7401 --against /work/main --repeat 2

Writes ``benchmarks/results/analyze_timeline.csv``.
"""

from __future__ import annotations

import argparse
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
COLUMNS = ["tree", "repeat", "pid", "process", "stage", "start_s", "end_s", "cpu_s"]
STAGES = ("mean_square_stability", "hinf_gamma", "gain_lower_bound", "robust_lower_bound", "mes_known", "mes_lmi")


def inner(log: str, argv: list[str]) -> None:
    """In the measured tree: run the CLI in this process with the stages wrapped."""
    t0 = time.perf_counter()
    fd = os.open(log, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_APPEND, 0o644)
    main_pid = os.getpid()

    def record(name: str, a: float, b: float, cpu: float) -> None:
        row = {"pid": os.getpid(), "process": "cli" if os.getpid() == main_pid else "child", "stage": name,
               "start_s": a - t0, "end_s": b - t0, "cpu_s": cpu}
        os.write(fd, (json.dumps(row) + "\n").encode())

    def wrap(mod: Any, name: str) -> None:
        fn = getattr(mod, name)

        def timed(*args: Any, **kwargs: Any) -> Any:
            a, c = time.perf_counter(), time.process_time()
            try:
                return fn(*args, **kwargs)
            finally:
                label = name + ("(robust)" if kwargs.get("robust") else "")
                record(label, a, time.perf_counter(), time.process_time() - c)

        timed.__qualname__, timed.__module__ = name, mod.__name__  # pickled by reference, like fn
        setattr(mod, name, timed)

    import ftc_verify.cli.main
    cli = sys.modules["ftc_verify.cli.main"]
    record("start-up + CLI import", t0, time.perf_counter(), time.process_time())
    import ftc_verify.prestart as prestart

    child = prestart._child

    def cross_child(*args: Any) -> None:
        a, c = time.perf_counter(), time.process_time()
        try:
            child(*args)
        finally:
            record("cross-check child (import + job)", a, time.perf_counter(), time.process_time() - c)

    prestart._child = cross_child
    import ftc_verify.analysis.analyze  # noqa: F401
    record("analysis import", t0, time.perf_counter(), time.process_time())
    am = sys.modules["ftc_verify.analysis.analyze"]
    for name in STAGES:
        if hasattr(am, name):
            wrap(am, name)
    wrap(sys.modules["ftc_verify.analysis.crossval"], "cross_validate")
    code = cli.main(argv)
    record(f"end (exit {code})", t0, time.perf_counter(), time.process_time())


def measure(system: Path, gains: Path, tree: Path | None) -> list[dict[str, Any]]:
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    if tree is not None:
        env["PYTHONPATH"] = str(tree)
    with tempfile.NamedTemporaryFile(suffix=".jsonl") as log:
        subprocess.run([sys.executable, __file__, "--inner", log.name, "analyze", str(system), "--gains", str(gains),
                        "--json"], env=env, check=False, capture_output=True, cwd=tempfile.gettempdir())
        return [json.loads(line) for line in Path(log.name).read_text().splitlines()]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--case", default="8x3u")
    parser.add_argument("--seed", type=int, default=7401)
    parser.add_argument("--repeat", type=int, default=1)
    parser.add_argument("--against", type=Path, default=None)
    parser.add_argument("--out", type=Path, default=HERE / "results" / "analyze_timeline.csv")
    parser.add_argument("--inner", default=None, help=argparse.SUPPRESS)
    args, rest = parser.parse_known_args()
    if args.inner:
        inner(args.inner, rest)
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
                load = os.getloadavg()[0]
                run = measure(system, gains, tree)
                print(f"{args.case} seed {args.seed} {name} rep {rep} (load {load:.1f}):")
                per_pid: dict[int, float] = {}
                for r in sorted(run, key=lambda r: r["start_s"]):
                    rows.append({"tree": name, "repeat": rep, **r})
                    print(f"    {r['pid']:>7} {r['process']:5s} {r['start_s']:7.3f} -> {r['end_s']:7.3f} s  "
                          f"CPU {r['cpu_s']:6.3f} s  {r['stage']}")
                    if not r["stage"].startswith(("start-up", "analysis import", "end")):
                        per_pid[r["pid"]] = per_pid.get(r["pid"], 0.0) + r["cpu_s"]
                print("    stage CPU per process: " + ", ".join(f"{p}: {c:.2f} s" for p, c in per_pid.items()))
    write_rows(args.out, rows, COLUMNS)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
