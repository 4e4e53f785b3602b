#!/usr/bin/env python
"""``ftc-verify verify`` of this checkout against another one, interleaved, in one run.

Run from the repository root::

    python benchmarks/verify_ab.py --other /work/main            # 5 rounds
    python benchmarks/verify_ab.py --other /tmp/old --rounds 3 --out /tmp/ab.csv

Each round runs ``python -m ftc_verify verify examples/paper.toml --seed S --out TMP``
once with this checkout and once with ``--other`` (``PYTHONPATH`` set to the checkout, so
its plant processes run its code too), alternating which goes first, with
``OPENBLAS_NUM_THREADS=1`` as the CLI sets by default. Per run it records the wall time,
the CPU seconds (user + system) of the command and of all its child processes
(``os.wait4``), the load average at the start, and from ``report.json`` the stages'
wall times (``timings``: synthesis, monte_carlo, sampled, reference, report_plots,
imports_and_load, total) and the verdict. Both runs of a round must write the same
``report.json`` apart from times, and the same figures (``same_report``), or the row's
status is ``DIFFERENT``.

On a busy machine the wall times move with the load; the ratio of the medians (this /
other) of runs side by side, and the CPU seconds, are what compare. Writes one CSV
(default ``benchmarks/results/verify_ab.csv``) and prints the medians.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any
from csvout import write_rows

REPO = Path(__file__).resolve().parent.parent
DEFAULT_OUT = REPO / "benchmarks" / "results" / "verify_ab.csv"
STAGES = ("imports_and_load", "synthesis", "monte_carlo", "sampled", "reference", "report_plots", "total")
COLUMNS = ["round", "code", "wall_s", "cpu_s", "load1", "verdict", "same_report", *STAGES]


def _without_times(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _without_times(v) for k, v in value.items()
                if k not in ("timings", "spans") and not k.endswith("seconds")}
    if isinstance(value, list):
        return [_without_times(v) for v in value]
    return value


def run_once(code: Path, seed: int, out: Path) -> dict[str, Any]:
    """One ``verify`` with the package of ``code``: wall, CPU, stages."""
    env = dict(os.environ, PYTHONPATH=str(code), OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    probe = subprocess.run([sys.executable, "-c", "import ftc_verify; print(ftc_verify.__file__)"], env=env,
                           cwd=out.parent, capture_output=True, text=True, check=True).stdout.strip()
    if not probe.startswith(str(code)):
        raise SystemExit(f"{code}: python imports ftc_verify from {probe}, not from this checkout")
    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "ftc_verify", "verify", str(REPO / "examples" / "paper.toml"),
                             "--seed", str(seed), "--out", str(out)], env=env, stdout=subprocess.DEVNULL,
                            cwd=out.parent)  # not a checkout: ``-m`` puts the working directory first on sys.path
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    proc.returncode = os.waitstatus_to_exitcode(status)
    written = out / "report.json"  # none when the run ended early (killed, failed)
    report = json.loads(written.read_text()) if written.exists() else {"verdict": "no report"}
    timings = report.get("timings", {})
    return {"code": str(code), "wall_s": round(wall, 3), "cpu_s": round(usage.ru_utime + usage.ru_stime, 3),
            "load1": round(load, 2), "verdict": report["verdict"] if proc.returncode == 0 else f"exit {proc.returncode}",
            **{k: round(float(timings.get(k, float("nan"))), 3) for k in STAGES}}


def same_outputs(a: Path, b: Path) -> bool:
    """The same report (apart from times) and the same figures."""
    if not ((a / "report.json").exists() and (b / "report.json").exists()):
        return False
    ja, jb = (_without_times(json.loads((p / "report.json").read_text())) for p in (a, b))
    pngs = sorted(p.name for p in a.glob("*.png"))
    return ja == jb and pngs == sorted(p.name for p in b.glob("*.png")) and all(
        (a / n).read_bytes() == (b / n).read_bytes() for n in pngs)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[1])
    ap.add_argument("--other", required=True, help="the checkout to compare with (a folder holding ftc_verify/)")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = ap.parse_args()
    codes = [REPO, Path(args.other).resolve()]
    rows = []
    with tempfile.TemporaryDirectory(prefix="verify-ab-") as tmp:
        for r in range(args.rounds):
            order = codes if r % 2 == 0 else codes[::-1]
            outs = {}
            for code in order:
                outs[code] = Path(tmp) / f"r{r}-{'this' if code == REPO else 'other'}"
                rows.append({"round": r, **run_once(code, args.seed, outs[code])})
            same = same_outputs(outs[codes[0]], outs[codes[1]])
            for row in rows[-2:]:
                row["same_report"] = same
    write_rows(args.out, rows, COLUMNS)
    done = [r for r in rows if r["verdict"] in ("pass", "fail")]  # runs that wrote their report
    med = {c: {k: statistics.median([float(r[k]) for r in done if r["code"] == str(c)] or [float("nan")])
               for k in ("wall_s", "cpu_s", *STAGES)} for c in codes}
    print(f"{'':18}" + "".join(f"{k:>17}" for k in ("wall_s", "cpu_s", *STAGES)))
    for c in codes:
        print(f"{('this' if c == REPO else 'other'):18}" + "".join(f"{med[c][k]:17.3f}" for k in ("wall_s", "cpu_s", *STAGES)))
    print(f"{'ratio this/other':18}" + "".join(f"{med[codes[0]][k] / med[codes[1]][k]:17.3f}" if med[codes[1]][k]
                                               else f"{'-':>17}" for k in ("wall_s", "cpu_s", *STAGES)))
    print(f"same report and figures in every round: {all(r['same_report'] for r in rows)}; wrote {args.out}")
    return 0 if all(r["same_report"] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
