#!/usr/bin/env python
"""``ftc-verify analyze`` on random loops of growing size: wall time, peak memory, growth (issue 37).

Each case is a random system of ``benchmarks/analysis.py``'s ``make_case`` (``n`` states,
``m`` fault modes, LQR gains per FDI mode; nominal unless the case ends in ``u``, which
adds the 0.05 I uncertainty channels), written to a system file and a gains file in a
temporary directory (``ftc_verify.model.files.save_system``,
``ftc_verify.controllers.files.save_gains``) and analysed by the command a user runs,
``python -m ftc_verify analyze SYSTEM --gains GAINS --json`` (``OPENBLAS_NUM_THREADS=1``),
one child process per run; the wall time, the CPU time of the child and of the
processes it waited for, the load average before the run and the peak RSS (``wait4``) are
recorded with the report's stage times, certified gammas and the route that produced each
(``riccati`` or the SDP solver, for Theorem 3.2, Lemma 4.1 and Theorem 3.1).

``--against DIR`` runs every case also with ``PYTHONPATH=DIR`` (another checkout, e.g. the
first release), interleaved with this tree (the order swapped on odd repetitions), and
reports the ratio of the medians: both CLIs in the same run, on the same machine state.

The growth exponent is the least-squares slope of ``log(wall)`` against ``log(n)`` over
the ``m = 2`` cases, and pairwise between neighbouring sizes.

Usage::

    python benchmarks/scaling.py                               # n = 8..48, m = 2, and 48x3
    python benchmarks/scaling.py --cases 8x3u,12x4u --repeat 3 --against /tmp/old --seed 3790
    python benchmarks/scaling.py --cases 32x2 --timeout 600

Writes ``benchmarks/results/scaling.csv`` (one row per run) and prints a table.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from csvout import write_rows

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
DEFAULT_CASES = "8x2,16x2,24x2,32x2,48x2,48x3"
#: Goals (issue 37): wall seconds, and peak MB where given.
GOALS: dict[str, tuple[float, float | None]] = {"32x2": (20.0, None), "48x3": (120.0, 4096.0), "12x4u": (12.0, None)}
COLUMNS = ["case", "n", "m", "uncertain", "seed", "tree", "repeat", "wall_s", "cpu_s", "load", "peak_mb", "exit", "certified_stable",
           "nominal_gamma", "robust_gamma", "nominal_route", "robust_route", "theorem_3_1_route", "spectral_s", "theorem_3_2_s", "lemma_4_1_s",
           "theorem_3_1_s", "lower_bounds_s", "cross_validation_s"]


def _analysis_module() -> Any:
    spec = importlib.util.spec_from_file_location("bench_analysis", HERE / "analysis.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def parse_case(text: str) -> tuple[int, int, bool]:
    """``"32x2"`` -> ``(32, 2, False)``; ``"8x3u"`` -> ``(8, 3, True)``."""
    uncertain = text.endswith("u")
    n, m = text.rstrip("u").split("x")
    return int(n), int(m), uncertain


def write_case(n: int, m: int, uncertain: bool, seed: int, into: Path) -> tuple[Path, Path]:
    """The system and gains files of one case."""
    from ftc_verify.controllers.files import save_gains
    from ftc_verify.model.files import save_system

    system, gains, _ = _analysis_module().make_case(n, m, seed, uncertain)
    sys_path, gains_path = into / f"n{n}m{m}{'u' if uncertain else ''}.toml", into / f"n{n}m{m}_gains.toml"
    save_system(system, sys_path)
    save_gains(gains, gains_path, name=f"LQR gains of {system.name}")
    return sys_path, gains_path


def run_cli(system: Path, gains: Path, tree: Path | None, timeout: float) -> dict[str, Any]:
    """One ``analyze`` run in a child: wall, peak RSS, the JSON report (``None`` on failure)."""
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    if tree is not None:
        env["PYTHONPATH"] = str(tree)
    cmd = [sys.executable, "-m", "ftc_verify", "analyze", str(system), "--gains", str(gains), "--json"]
    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    with tempfile.TemporaryFile() as out:
        proc = subprocess.Popen(cmd, stdout=out, stderr=subprocess.DEVNULL, env=env, cwd=tempfile.gettempdir())
        deadline = t0 + timeout
        status, usage = 0, None
        while True:
            pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
            if pid:
                break
            if time.perf_counter() > deadline:
                proc.kill()
                _, status, usage = os.wait4(proc.pid, 0)
                break
            time.sleep(0.02)
        wall = time.perf_counter() - t0
        proc.returncode = os.waitstatus_to_exitcode(status)
        out.seek(0)
        text = out.read().decode(errors="replace")
    try:
        report = json.loads(text)
    except json.JSONDecodeError:
        report = None
    return {"wall_s": wall, "peak_mb": usage.ru_maxrss / 1024.0 if usage else math.nan, "load": load,
            "cpu_s": usage.ru_utime + usage.ru_stime if usage else math.nan,
            "exit": proc.returncode if wall <= timeout else "timeout", "report": report}


def row_of(case: str, n: int, m: int, uncertain: bool, seed: int, tree: str, rep: int, run: dict[str, Any]) -> dict[str, Any]:
    rep_json = run["report"] or {}
    seconds = rep_json.get("seconds", {})
    hinf = rep_json.get("hinf", {})
    return {"case": case, "n": n, "m": m, "uncertain": uncertain, "seed": seed, "tree": tree, "repeat": rep,
            "wall_s": round(run["wall_s"], 3), "cpu_s": round(run["cpu_s"], 3), "load": round(run["load"], 1),
            "peak_mb": round(run["peak_mb"], 1), "exit": run["exit"],
            "certified_stable": rep_json.get("certified_stable"), "nominal_gamma": hinf.get("nominal_gamma"),
            "robust_gamma": hinf.get("robust_gamma"), "nominal_route": (hinf.get("nominal") or {}).get("solver"),
            "robust_route": (hinf.get("robust") or {}).get("solver"), "theorem_3_1_route": (rep_json.get("mes_lmi") or {}).get("solver"),
            **{f"{k}_s": round(seconds[k], 3) if k in seconds else None
               for k in ("spectral", "theorem_3_2", "lemma_4_1", "theorem_3_1", "lower_bounds", "cross_validation")}}


def growth(rows: list[dict[str, Any]], key: str = "wall_s") -> tuple[float | None, list[tuple[int, int, float]]]:
    """Least-squares slope of log(median ``key``) on log(n) over the m = 2 cases of this
    tree, and the slopes between neighbouring sizes."""
    by_n: dict[int, list[float]] = {}
    for r in rows:
        if r["tree"] == "this" and r["m"] == 2 and not r["uncertain"] and r["exit"] == 0:
            by_n.setdefault(r["n"], []).append(r[key])
    ns = sorted(by_n)
    if len(ns) < 2:
        return None, []
    walls = [statistics.median(by_n[n]) for n in ns]
    slope = float(np.polyfit(np.log(ns), np.log(walls), 1)[0])
    pairs = [(a, b, math.log(wb / wa) / math.log(b / a)) for a, b, wa, wb in zip(ns, ns[1:], walls, walls[1:])]
    return slope, pairs


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cases", default=DEFAULT_CASES, help=f"comma-separated NxM[u] (default {DEFAULT_CASES})")
    parser.add_argument("--seed", type=int, default=3700, help="seed of the first case (+1 per case; default 3700)")
    parser.add_argument("--repeat", type=int, default=1)
    parser.add_argument("--against", type=Path, default=None, help="another checkout, run with PYTHONPATH")
    parser.add_argument("--timeout", type=float, default=900.0, help="seconds per run (default 900)")
    parser.add_argument("--out", type=Path, default=HERE / "results" / "scaling.csv")
    args = parser.parse_args()
    trees: list[tuple[str, Path | None]] = [("this", None)] + ([("against", args.against)] if args.against else [])
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory() as tmp:
        for k, case in enumerate(args.cases.split(",")):
            n, m, uncertain = parse_case(case)
            seed = args.seed + k
            system, gains = write_case(n, m, uncertain, seed, Path(tmp))
            for rep in range(args.repeat):
                for name, tree in (trees if rep % 2 == 0 else trees[::-1]):
                    run = run_cli(system, gains, tree, args.timeout)
                    row = row_of(case, n, m, uncertain, seed, name, rep, run)
                    rows.append(row)
                    print(f"{case} {name} rep {rep}: {row['wall_s']:.2f} s wall, {row['cpu_s']:.2f} s CPU "
                          f"(load {row['load']}), {row['peak_mb']:.0f} MB, exit {row['exit']}, "
                          f"certified {row['certified_stable']}, gamma {row['nominal_gamma']} ({row['nominal_route']})",
                          flush=True)
    write_rows(args.out, rows, COLUMNS)
    print("\n| case | wall (median) | CPU (median) | peak MB | goal | wall ratio against | CPU ratio against |")
    print("|---|---|---|---|---|---|---|")
    for case in dict.fromkeys(r["case"] for r in rows):
        mine = [r for r in rows if r["case"] == case and r["tree"] == "this"]
        other = [r for r in rows if r["case"] == case and r["tree"] == "against"]
        wall = statistics.median(r["wall_s"] for r in mine)
        peak = max(r["peak_mb"] for r in mine)
        goal = GOALS.get(case)
        met = "" if goal is None else ("met" if wall < goal[0] and (goal[1] is None or peak < goal[1]) else "missed")
        cpu = statistics.median(r["cpu_s"] for r in mine)
        ratio = f"{statistics.median(r['wall_s'] for r in other) / wall:.2f}x" if other else ""
        cpu_ratio = f"{statistics.median(r['cpu_s'] for r in other) / cpu:.2f}x" if other else ""
        print(f"| {case} | {wall:.2f} s | {cpu:.2f} s | {peak:.0f} | {goal[0] if goal else ''} {met} | {ratio} | {cpu_ratio} |")
    for key in ("wall_s", "cpu_s"):
        slope, pairs = growth(rows, key)
        if slope is not None:
            print(f"growth (m = 2): {key[:-2]} ~ n^{slope:.2f} (least squares); "
                  + ", ".join(f"n {a}->{b}: {e:.2f}" for a, b, e in pairs))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
