#!/usr/bin/env python
"""CPU time of the output-feedback descent (``ftc_verify.synthesis.descent``).

Run from the repository root (``PYTHONPATH=<checkout>`` to time another checkout's
descent, side by side)::

    OPENBLAS_NUM_THREADS=1 python benchmarks/descent_speed.py --out /tmp/descent_speed.csv

Cases: ``stabilise`` (every start, no wall-time budget), ``gain_scan`` (bounds 10 and
100, 60 iterations) and ``deepen`` (to -0.1, 40 iterations) on the paper plant at orders 2
and 0, the two-output plant at order 1, and ``stabilise`` on the paper plant with doubled
detection rates. Per case the process CPU seconds and a digest (SHA-256 of every iterate
``theta``, abscissa, evaluation count and kappa path) that must be the same for every
checkout whose descent computes the same numbers. Writes a CSV (``--out``) and prints it.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from csvout import write_rows
from ftc_verify.model.files import load_system
from ftc_verify.synthesis import descent

ROOT = Path(__file__).resolve().parents[1]
FIELDS = ["case", "cpu_seconds", "digest"]


def _cases() -> list[tuple[str, Callable[[], Any]]]:
    out: list[tuple[str, Callable[[], Any]]] = []
    for example, order in (("paper.toml", 2), ("paper.toml", 0), ("paper_two_outputs.toml", 1)):
        system = load_system(ROOT / "examples" / example)

        def stab(system: Any = system, order: int = order) -> Any:
            return [(r.start, r.abscissa, r.evaluations, r.theta.tobytes(), r.history)
                    for r in descent.stabilise(system, order, seed=0, budget_seconds=1e9)]

        def scan(system: Any = system, order: int = order) -> Any:
            return descent.gain_scan(system, order, bounds=(10.0, 100.0), max_iter=60)

        def deep(system: Any = system, order: int = order) -> Any:
            first = descent.stabilise(system, order, seed=0, budget_seconds=0.0)[0]
            x, f = descent.deepen(system, order, first.theta, -0.1, max_iter=40)
            return f, x.tobytes()

        tag = f"{example} order {order}"
        out += [(f"stabilise {tag}", stab), (f"gain_scan {tag}", scan), (f"deepen {tag}", deep)]
    paper = load_system(ROOT / "examples" / "paper.toml")
    ch = paper.chain
    doubled = dataclasses.replace(paper, chain=dataclasses.replace(ch, beta_min=2 * ch.beta_min,
                                                                   beta_max=2 * ch.beta_max))
    out.append(("stabilise paper.toml doubled rates order 2",
                lambda: [(r.start, r.abscissa, r.evaluations, r.theta.tobytes())
                         for r in descent.stabilise(doubled, 2, seed=3, budget_seconds=1e9)]))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="/tmp/descent_speed.csv")
    args = ap.parse_args()
    rows = []
    for name, run in _cases():
        c0 = time.process_time()
        value = run()
        cpu = time.process_time() - c0
        rows.append({"case": name, "cpu_seconds": round(cpu, 3),
                     "digest": hashlib.sha256(repr(value).encode()).hexdigest()[:16]})
    rows.append({"case": "total", "cpu_seconds": round(sum(r["cpu_seconds"] for r in rows), 3),
                 "digest": hashlib.sha256("".join(r["digest"] for r in rows).encode()).hexdigest()[:16]})
    write_rows(args.out, rows, FIELDS)
    for r in rows:
        print(f"{r['case']:48s} {r['cpu_seconds']:8.3f}  {r['digest']}", file=sys.stdout)


if __name__ == "__main__":
    main()
