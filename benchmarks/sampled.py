#!/usr/bin/env python
"""Benchmark of the sampled-loop analysis (:func:`ftc_verify.analysis.moments.sampled.sampled_analysis`).

Cases: the paper's example with its gains at h = 0.1 (goal, issue 31: within 3 s), and
random systems with ``n`` states, ``m`` modes and two inputs (``n = 4, m = 3``: the
``h_max`` scan within 10 s) drawn by :func:`ftc_verify.testing.sampled_cases.lqr_case`
(each mode's gain an LQR gain of the mode's own plant, the detection rates in ``[2, 4]``). Columns:
``case, n, m, joint_states, map_rows, period, verdict, spectral_radius, h_max,
h_max_unstable, sub_boxes, exp, bracket`` (relative width of the proved ``h_max``
bracket) ``, seconds, cpu_seconds``. ``--seed`` draws other random systems (held-out
checks).

Usage::

    python benchmarks/sampled.py                 # writes benchmarks/results/sampled.csv
    python benchmarks/sampled.py --out x.csv --seed 3
    python benchmarks/sampled.py --exp float64-balls --case sys.toml K.toml 0.6722 --only-cases

``--case SYSTEM GAINS PERIOD`` (repeatable) adds a loop from files (named by the system
file), ``--only-cases`` runs those alone.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

from ftc_verify.analysis.moments import sampled_proof
from ftc_verify.analysis.moments.sampled import SampledLoop, sampled_analysis
from ftc_verify.controllers.files import load_controller
from ftc_verify.model.files import load_system
from ftc_verify.testing.sampled_cases import lqr_case
from csvout import write_rows

ROOT = Path(__file__).resolve().parents[1]


@contextlib.contextmanager
def exponential(kind: str) -> Iterator[None]:
    """The proofs' ball exponential: ``float64-balls`` (as the code is) or ``arb``
    (``arb_mat.exp``, patched in for the comparison and restored after)."""
    saved = sampled_proof.arb_expm, sampled_proof.map_ball
    if kind == "arb":
        sampled_proof.arb_expm = lambda m: m.exp()  # type: ignore[assignment]
        sampled_proof.map_ball = lambda *a: None  # type: ignore[assignment]
    try:
        yield
    finally:
        sampled_proof.arb_expm, sampled_proof.map_ball = saved  # type: ignore[assignment]


def table(rows: list[dict[str, Any]]) -> str:
    keys = ["case", "exp", "verdict", "h_max", "h_max_unstable", "bracket", "sub_boxes", "seconds", "cpu_seconds"]
    cells = [[str(r[k]) for k in keys] for r in rows]
    widths = [max(len(k), *(len(c[i]) for c in cells)) for i, k in enumerate(keys)]
    lines = ["  ".join(k.ljust(w) for k, w in zip(keys, widths))]
    lines += ["  ".join(c.ljust(w) for c, w in zip(row, widths)) for row in cells]
    return "\n".join(lines)


def _cpu() -> float:
    """CPU seconds of this process and of the children it waited for (the bracket's
    clock-dependent certificate runs in a forked child)."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "sampled.csv"))
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--exp", choices=["both", "float64-balls", "arb"], default="both")
    p.add_argument("--case", nargs=3, action="append", default=[], metavar=("SYSTEM", "GAINS", "PERIOD"),
                   help="also run this loop (system file, controller file, period)")
    p.add_argument("--only-cases", action="store_true", help="run the --case loops only")
    args = p.parse_args()
    rng = np.random.default_rng(args.seed)
    cases = [("paper", load_system(ROOT / "examples" / "paper.toml"),
              load_controller(ROOT / "examples" / "paper_gains.toml"), 0.1)]
    for n, m in ((2, 2), (4, 3)):
        system, controller = lqr_case(n, m, rng)
        cases.append((f"random n={n} m={m}", system, controller, 0.01))
    if args.only_cases:
        cases = []
    for sys_path, gains_path, period in args.case:
        cases.append((Path(sys_path).stem, load_system(sys_path), load_controller(gains_path), float(period)))
    rows = []
    kinds = ["float64-balls", "arb"] if args.exp == "both" else [args.exp]
    for name, system, controller, h in cases:
        for kind in kinds:
            with exponential(kind):
                t, cpu = time.perf_counter(), _cpu()
                res = sampled_analysis(system, controller, h)
                seconds, cpu = time.perf_counter() - t, _cpu() - cpu
            loop = SampledLoop.build(system, controller)
            rows.append({"case": name, "n": system.dims[0], "m": system.m, "joint_states": loop.states,
                         "map_rows": loop.size, "period": h, "verdict": res.verdict,
                         "spectral_radius": f"{res.spectral_radius:.6g}", "h_max": res.h_max,
                         "h_max_unstable": res.h_max_unstable, "sub_boxes": res.boxes, "exp": kind,
                         "bracket": "" if res.h_max is None or res.h_max_unstable is None else
                         f"{(res.h_max_unstable - res.h_max) / res.h_max_unstable:.1e}",
                         "seconds": f"{seconds:.2f}", "cpu_seconds": f"{cpu:.2f}"})
            print(rows[-1], flush=True)
    write_rows(args.out, rows)
    print(table(rows))


if __name__ == "__main__":
    main()
