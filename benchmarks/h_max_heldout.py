"""The proved ``h_max`` bracket on loops not in the repository's tests: random loops of
:func:`ftc_verify.testing.sampled_cases.lqr_case` (``n`` states, ``m`` modes, wide
detection-rate boxes), the default bracket of
:func:`~ftc_verify.analysis.moments.sampled.sampled_analysis` and, with ``--work W``,
the refinement :func:`~ftc_verify.analysis.moments.sampled_refine.refine_result`
(``analyze --h-max-work W``).

Draw: ``numpy.random.default_rng(seed)``; for ``n = 4, m = 3`` first an ``n = 2, m = 2``
case is drawn and discarded (as ``benchmarks/sampled.py --seed S`` draws its ``n = 4``
loop), other sizes are drawn directly. ``--find`` lists the seeds whose loop has an
``h_max`` in the scanned range (float64 scan only).

    python benchmarks/h_max_heldout.py --n 4 --m 3 --seeds 9 13 17 26 --work 70000 --out /tmp/heldout.csv

One CSV row per loop (seed, sizes, ``h_max``, ``h_max_unstable``, default bracket,
refined bracket, CPU and wall seconds of each stage, the load average at the start);
a table on stdout.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path
from typing import Any

import numpy as np

from csvout import write_rows

__all__ = ["draw", "main"]


def _cpu() -> float:
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def draw(n: int, m: int, seed: int) -> Any:
    """The held-out loop ``(system, controller)`` of ``seed`` (module docstring)."""
    from ftc_verify.testing.sampled_cases import lqr_case

    rng = np.random.default_rng(seed)
    if (n, m) == (4, 3):
        lqr_case(2, 2, rng)
    return lqr_case(n, m, rng)


def _gap(lo: float | None, hi: float | None) -> float | None:
    return None if lo is None or hi is None else (hi - lo) / hi


def _row(n: int, m: int, seed: int, period: float, work: float, max_seconds: float) -> dict[str, Any]:
    from ftc_verify.analysis.moments.sampled import sampled_analysis
    from ftc_verify.analysis.moments.sampled_refine import refine_result

    system, controller = draw(n, m, seed)
    load = os.getloadavg()[0]
    t, c = time.perf_counter(), _cpu()
    res = sampled_analysis(system, controller, period, max_seconds=max_seconds)
    wall, cpu = time.perf_counter() - t, _cpu() - c
    row: dict[str, Any] = {"n": n, "m": m, "seed": seed, "load": round(load, 2), "h_max": res.h_max,
                           "h_max_unstable": res.h_max_unstable, "bracket": _gap(res.h_max, res.h_max_unstable),
                           "cpu_s": round(cpu, 2), "wall_s": round(wall, 2), "work": work}
    if work > 0:
        t, c = time.perf_counter(), _cpu()
        ref = refine_result(system, controller, res, work)
        row |= {"refined_h_max": ref.h_max, "refined_bracket": _gap(ref.h_max, ref.h_max_unstable),
                "refine_cpu_s": round(_cpu() - c, 2), "refine_wall_s": round(time.perf_counter() - t, 2),
                "note": ref.h_max_note}
    else:
        row["note"] = res.h_max_note
    return row


def _has_h_max(n: int, m: int, seed: int, period: float) -> bool:
    from ftc_verify.analysis.moments.sampled import SampledLoop, scan_periods, scan_range, stability_intervals

    loop = SampledLoop.build(*draw(n, m, seed))
    lo, hi = scan_range(loop, period)
    hs, rho = scan_periods(loop, lo, hi)
    iv = stability_intervals(loop, hs, rho)
    return bool(iv) and iv[0][0] <= hs[0] and iv[0][1] < hs[-1]


def main(argv: list[str] | None = None) -> int:
    """Command line (module docstring)."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--n", type=int, default=4)
    p.add_argument("--m", type=int, default=3)
    p.add_argument("--seeds", type=int, nargs="+", default=[9, 13, 17, 26])
    p.add_argument("--period", type=float, default=0.01, help="the analysed period (default 0.01)")
    p.add_argument("--work", type=float, default=0.0, help="refinement budget in work units (default 0: none)")
    p.add_argument("--max-seconds", type=float, default=600.0,
                   help="sampled_analysis's wall-time safety valve (default 600: under load the CLI's 60 s "
                        "can cut the bracket short; its budget is otherwise in work units)")
    p.add_argument("--find", action="store_true", help="only list the seeds whose loop has an h_max")
    p.add_argument("--out", default="benchmarks/results/h_max_heldout.csv")
    args = p.parse_args(argv)
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    if args.find:
        for s in args.seeds:
            print(s, "has h_max" if _has_h_max(args.n, args.m, s, args.period) else "no", flush=True)
        return 0
    rows = []
    for s in args.seeds:
        rows.append(_row(args.n, args.m, s, args.period, args.work, args.max_seconds))
        r = rows[-1]
        print(f"n={r['n']} m={r['m']} seed {s}: h_max {r['h_max']} unstable {r['h_max_unstable']} bracket "
              f"{r['bracket'] if r['bracket'] is None else format(r['bracket'], '.1e')} cpu {r['cpu_s']} wall "
              f"{r['wall_s']} load {r['load']}"
              + ("" if args.work <= 0 else f" | refined {r['refined_bracket'] if r['refined_bracket'] is None else format(r['refined_bracket'], '.1e')}"
                 f" cpu {r['refine_cpu_s']} wall {r['refine_wall_s']}"), flush=True)
    cols = ["n", "m", "seed", "load", "h_max", "h_max_unstable", "bracket", "cpu_s", "wall_s", "work",
            "refined_h_max", "refined_bracket", "refine_cpu_s", "refine_wall_s", "note"]
    write_rows(Path(args.out), [{k: r.get(k) for k in cols} for r in rows], cols)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
