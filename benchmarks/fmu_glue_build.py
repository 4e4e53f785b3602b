#!/usr/bin/env python
"""Benchmark of the FMU builders' compile step: one shared C glue source or not.

Each repetition runs, for every source tree given (``--tree``; default this checkout),
every builder of the package once in a fresh subprocess with a fresh, empty
``FTC_VERIFY_CACHE`` (so gcc really compiles): the ``LinearJumpPlant`` binary
(``build_binary(force=True)``), the DC motor ODE FMU binary of FMI 2.0 and of FMI 3.0
(``build_ode_binary``, ``build_ode_binary3``) and the paper's gains as a controller FMU of
FMI 2.0 and 3.0 (``build_controller_fmu``, which always compiles). The trees are
interleaved within each repetition so that a load change hits both alike. Reported per
build: wall seconds of the call and the CPU seconds of the compiler processes it ran
(``RUSAGE_CHILDREN``). Writes a CSV and prints the medians and their ratio to the first tree.

Usage::

    OPENBLAS_NUM_THREADS=1 python benchmarks/fmu_glue_build.py --tree /tmp/base --tree . \
        [--repeat 5] [--out benchmarks/results/fmu_glue_build.csv]
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

ROOT = Path(__file__).resolve().parents[1]

_PRELUDE = """
import json, resource, sys, tempfile, time
from pathlib import Path
root = Path(sys.argv[1])
"""
BUILDERS = {
    "LinearJumpPlant": "from ftc_verify.plants.linear_jump import build_binary\nrun = lambda: build_binary(force=True)",
    "ode-fmi2": ("from ftc_verify.plants.ode_fmu import build_ode_binary, motor_spec\n"
                 "spec = motor_spec()\nrun = lambda: build_ode_binary(spec, force=True)"),
    "ode-fmi3": ("from ftc_verify.plants.ode_fmu import motor_spec\nfrom ftc_verify.plants.ode_fmu3 import build_ode_binary3\n"
                 "spec = motor_spec()\nrun = lambda: build_ode_binary3(spec, force=True)"),
}
_CTRL = """
from ftc_verify.controllers.files import load_controller
from ftc_verify.model.files import load_system
from ftc_verify.export.ccode import controller_tables, controller_c_source
from ftc_verify.export.controller_fmu import build_controller_fmu
s = load_system(root / "examples" / "paper.toml")
t = controller_tables(load_controller(root / "examples" / "paper_gains.toml"), 0.01, s.m)
src = controller_c_source(t, title="bench")
out = Path(tempfile.mkdtemp()) / "K.fmu"
run = lambda: build_controller_fmu(t, src, out, fmi_version="{v}", description="bench", certificate={{}}, resources={{}})
"""
BUILDERS["ctrl-fmi2"] = _CTRL.format(v="2.0")
BUILDERS["ctrl-fmi3"] = _CTRL.format(v="3.0")
_TIMED = """
c0 = resource.getrusage(resource.RUSAGE_CHILDREN)
t0 = time.perf_counter()
run()
wall = time.perf_counter() - t0
c1 = resource.getrusage(resource.RUSAGE_CHILDREN)
print(json.dumps({"wall": wall, "cpu": (c1.ru_utime + c1.ru_stime) - (c0.ru_utime + c0.ru_stime)}))
"""


def _one(tree: Path, builder: str) -> dict[str, float]:
    with tempfile.TemporaryDirectory(prefix="ftc-bench-cache-") as cache:
        env = dict(os.environ, FTC_VERIFY_CACHE=cache, PYTHONPATH=str(tree), OPENBLAS_NUM_THREADS="1")
        code = _PRELUDE + BUILDERS[builder] + _TIMED
        proc = subprocess.run([sys.executable, "-c", code, str(tree)], capture_output=True, text=True, env=env,
                              cwd=cache)
        if proc.returncode != 0:
            raise SystemExit(f"{tree} {builder}: failed ({proc.returncode}): {proc.stderr.strip()[-2000:]}")
        return dict(json.loads(proc.stdout.strip().splitlines()[-1]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--tree", action="append", type=Path, help="a source checkout (repeatable; default: this one)")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "fmu_glue_build.csv"))
    args = ap.parse_args()
    trees = [t.resolve() for t in (args.tree or [ROOT])]
    rows = []
    for rep in range(args.repeat):
        for builder in BUILDERS:
            for tree in trees:
                r = _one(tree, builder)
                rows.append({"repeat": rep, "tree": str(tree), "builder": builder, "wall_s": round(r["wall"], 4),
                             "compiler_cpu_s": round(r["cpu"], 4)})
    write_rows(args.out, rows)
    print(f"load average {os.getloadavg()[0]:.2f}; medians over {args.repeat} repetitions")
    print(f"{'builder':16s} {'tree':40s} {'wall s':>8s} {'cpu s':>8s} {'wall/first':>10s} {'cpu/first':>10s}")
    for builder in BUILDERS:
        first = None
        for tree in trees:
            sel = [r for r in rows if r["builder"] == builder and r["tree"] == str(tree)]
            wall = statistics.median(float(r["wall_s"]) for r in sel)
            cpu = statistics.median(float(r["compiler_cpu_s"]) for r in sel)
            first = first or (wall, cpu)
            print(f"{builder:16s} {str(tree)[-40:]:40s} {wall:8.3f} {cpu:8.3f} {wall / first[0]:10.3f} "
                  f"{cpu / first[1]:10.3f}")


if __name__ == "__main__":
    main()
