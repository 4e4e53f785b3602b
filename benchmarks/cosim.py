#!/usr/bin/env python
"""Benchmark of the co-simulation supervisor and of the numpy reference simulator.

Part 1 -- supervisor overhead. The paper's plant as the ``LinearJumpPlant`` FMU, the
paper's gains (``load_controller``: static state feedback), sampled paths of its chain,
``step = 0.01``. Measured in the same process, interleaved (``--repeats`` rounds, median
of each):

* ``supervisor``: :meth:`ftc_verify.simulation.supervisor.Supervisor.run` with a
  :class:`~ftc_verify.controllers.Controller` on all paths (grid, modes, gain switches,
  ``u = K[l] x``, ``w(t_k)``, records and the result object included);
* ``bare``: a bare fmpy loop on the same FMU and the same grids, per path
  ``reset/setupExperiment/enter/exitInitializationMode`` then per step
  ``setReal([u, w] refs, values) / doStep / getReal([x, y] refs)`` with fmpy's list API;
* ``bare-ctypes`` (for information): the same loop through preallocated ctypes arrays
  (``fmi2SetReal/fmi2DoStep/fmi2GetReal``), the floor of any Python master.

Cost per communication step = time / total steps; goal: supervisor <= 1.5 x bare.

Part 2 -- reference throughput: ``ftc_verify.simulation.reference.energies_reference`` on
10,000 paths x 1,000 steps for n = 2 (the paper's plant) and n = 10 (a random 2-mode
plant, nu = 2, ny = 2, nw = 1), in path-steps per second; goals 2e7 and 5e6. Skipped with
a message when ``reference_sim`` is not available.

Usage::

    python benchmarks/cosim.py            # full run (a minute or two)
    python benchmarks/cosim.py --quick    # smoke run, a few seconds
    python benchmarks/cosim.py --out x.csv --seed 3 --repeats 7

Writes ``benchmarks/results/cosim.csv`` (or ``--out``) and prints a table.
"""

from __future__ import annotations

import argparse
import csv
import inspect
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from ftc_verify.plants.linear_jump import build_fmu
from ftc_verify.model.system import FTCSystem
from ftc_verify.simulation.paths import communication_grid, sample_paths
from ftc_verify.model.files import load_system
from ftc_verify.controllers import Controller, load_controller
from ftc_verify.simulation.supervisor import FaultInjectionMap, Supervisor

DEFAULT_OUT = REPO / "benchmarks" / "results" / "cosim.csv"
RATIO_GOAL = 1.5
THROUGHPUT_GOALS = {2: 2e7, 10: 5e6}
COLUMNS = ["part", "case", "n", "m", "paths", "steps", "seconds", "us_per_step", "path_steps_per_s",
           "ratio_to_bare", "goal", "meets_goal", "status", "note"]


# ------------------------------------------------------------------------------------------
# Part 1
# ------------------------------------------------------------------------------------------


def bare_loop(slave: Any, grids: list[np.ndarray], uw_vr: list[int], xy_vr: list[int]) -> int:
    """fmpy's list API: setReal / doStep / getReal per step. Returns the number of steps."""
    values = [0.1] * len(uw_vr)
    steps = 0
    for t in grids:
        slave.reset()
        slave.setupExperiment(startTime=0.0)
        slave.enterInitializationMode()
        slave.exitInitializationMode()
        tl = t.tolist()
        for k in range(len(tl) - 1):
            slave.setReal(uw_vr, values)
            slave.doStep(tl[k], tl[k + 1] - tl[k])
            slave.getReal(xy_vr)
        steps += len(tl) - 1
    return steps


def bare_ctypes_loop(slave: Any, grids: list[np.ndarray], uw_vr: list[int], xy_vr: list[int]) -> int:
    from fmpy.fmi2 import fmi2Real, fmi2ValueReference

    uw = (fmi2ValueReference * len(uw_vr))(*uw_vr)
    xy = (fmi2ValueReference * len(xy_vr))(*xy_vr)
    vals = (fmi2Real * len(uw_vr))(*([0.1] * len(uw_vr)))
    out = (fmi2Real * len(xy_vr))()
    c = slave.component
    sr, ds, gr = slave.fmi2SetReal, slave.fmi2DoStep, slave.fmi2GetReal
    nuw, nxy = len(uw_vr), len(xy_vr)
    steps = 0
    for t in grids:
        slave.reset()
        slave.setupExperiment(startTime=0.0)
        slave.enterInitializationMode()
        slave.exitInitializationMode()
        tl = t.tolist()
        hl = np.diff(t).tolist()
        for k in range(len(hl)):
            sr(c, uw, nuw, vals)
            ds(c, tl[k], hl[k], 1)
            gr(c, xy, nxy, out)
        steps += len(hl)
    return steps


def part1(quick: bool, seed: int, repeats: int) -> list[dict[str, Any]]:
    from fmpy import read_model_description
    from fmpy.fmi2 import FMU2Slave

    system = load_system(REPO / "examples" / "paper.toml")
    controller = load_controller(REPO / "examples" / "paper_gains.toml")
    count, horizon, step = (4, 2.0, 0.01) if quick else (20, 10.0, 0.01)
    paths = sample_paths(system.chain, horizon, count, seed)
    grids = [communication_grid(p, step)[0] for p in paths]
    total = sum(len(t) - 1 for t in grids)
    fmu = build_fmu(system)
    fmap = FaultInjectionMap.for_linear_jump_plant(system)
    md = read_model_description(str(fmu))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    uw_vr = [vr[n] for n in fmap.inputs + fmap.disturbances]
    xy_vr = [vr[n] for n in fmap.states + fmap.outputs]

    times: dict[str, list[float]] = {"supervisor": [], "bare": [], "bare-ctypes": []}
    with tempfile.TemporaryDirectory(prefix="cosim-bench-") as unzip, Supervisor(fmu, fmap, system=system) as sup:
        import zipfile

        with zipfile.ZipFile(fmu) as zf:
            zf.extractall(unzip)
        slave = FMU2Slave(guid=md.guid, unzipDirectory=unzip, modelIdentifier=md.coSimulation.modelIdentifier,
                          instanceName="bare")
        slave.instantiate()
        slave.setupExperiment(startTime=0.0)
        slave.enterInitializationMode()
        slave.exitInitializationMode()
        try:
            # warm-up (discretisation caches, first-call overheads)
            sup.run(paths[:1], controller, step=step)
            bare_loop(slave, grids[:1], uw_vr, xy_vr)
            for _ in range(repeats):
                t0 = time.perf_counter()
                sup.run(paths, controller, step=step, disturbance="paper", delta=None, x0=[0.5, -0.5])
                times["supervisor"].append(time.perf_counter() - t0)
                t0 = time.perf_counter()
                assert bare_loop(slave, grids, uw_vr, xy_vr) == total
                times["bare"].append(time.perf_counter() - t0)
                t0 = time.perf_counter()
                assert bare_ctypes_loop(slave, grids, uw_vr, xy_vr) == total
                times["bare-ctypes"].append(time.perf_counter() - t0)
        finally:
            slave.terminate()
            slave.freeInstance()
    med = {k: statistics.median(v) for k, v in times.items()}
    rows = []
    for case in ("supervisor", "bare", "bare-ctypes"):
        ratio = med[case] / med["bare"]
        rows.append(dict(
            part="cosim", case=case, n=2, m=2, paths=count, steps=total, seconds=med[case],
            us_per_step=1e6 * med[case] / total, path_steps_per_s=total / med[case], ratio_to_bare=ratio,
            goal=RATIO_GOAL if case == "supervisor" else "",
            meets_goal=(ratio <= RATIO_GOAL) if case == "supervisor" else "",
            status="ok", note=f"median of {repeats}; min {1e6 * min(times[case]) / total:.3f} us/step",
        ))
    return rows


# ------------------------------------------------------------------------------------------
# Part 2
# ------------------------------------------------------------------------------------------


def random_plant(n: int, seed: int) -> FTCSystem:
    g = np.random.default_rng(seed)
    modes = [dict(A=g.uniform(-1, 1, (n, n)) / np.sqrt(n) - np.eye(n), B=g.uniform(-1, 1, (n, 2)),
                  C=g.uniform(-1, 1, (2, n)), D=g.uniform(-1, 1, (n, 1))) for _ in range(2)]
    return FTCSystem.from_arrays(name=f"random-n{n}", modes=modes, alpha=[[-0.5, 0.5], [1.0, -1.0]],
                                 beta_min=[[0, 2.0], [2.5, 0]], beta_max=[[0, 3.0], [3.5, 0]])


def part2(quick: bool, seed: int) -> list[dict[str, Any]]:
    count, steps = (1000, 100) if quick else (10_000, 1_000)
    step = 0.01
    try:
        from ftc_verify.simulation.reference import energies_reference
    except ImportError as exc:
        msg = f"skipped: ftc_verify.simulation.reference.energies_reference is not available ({exc})"
        print(msg)
        return [dict(part="reference", case=f"energies_reference n={n}", n=n, m=2, paths=count, steps="",
                     seconds="", us_per_step="", path_steps_per_s="", ratio_to_bare="", goal=goal,
                     meets_goal="", status="skipped", note=msg) for n, goal in THROUGHPUT_GOALS.items()]
    rows = []
    for n, goal in THROUGHPUT_GOALS.items():
        if n == 2:
            system = load_system(REPO / "examples" / "paper.toml")
            controller = load_controller(REPO / "examples" / "paper_gains.toml")
        else:
            system = random_plant(n, seed)
            g = np.random.default_rng(seed + 1)
            controller = Controller.state_feedback([0.2 * g.uniform(-1, 1, (2, n)) for _ in range(2)])
        paths = sample_paths(system.chain, steps * step, count, seed)
        total = sum(len(communication_grid(p, step)[0]) - 1 for p in paths)
        try:
            kwargs: dict[str, Any] = dict(step=step, disturbance="paper", seed=seed)
            params = inspect.signature(energies_reference).parameters
            kwargs = {k: v for k, v in kwargs.items() if k in params or any(
                p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values())}
            energies_reference(system, controller, paths[: max(1, count // 100)], **kwargs)  # warm-up
            t0 = time.perf_counter()
            energies_reference(system, controller, paths, **kwargs)
            elapsed = time.perf_counter() - t0
        except Exception as exc:  # report, do not hide
            rows.append(dict(part="reference", case=f"energies_reference n={n}", n=n, m=2, paths=count, steps=total,
                             seconds="", us_per_step="", path_steps_per_s="", ratio_to_bare="", goal=goal,
                             meets_goal="", status="error", note=f"{type(exc).__name__}: {exc}"))
            continue
        rate = total / elapsed
        rows.append(dict(part="reference", case=f"energies_reference n={n}", n=n, m=2, paths=count, steps=total,
                         seconds=elapsed, us_per_step=1e6 * elapsed / total, path_steps_per_s=rate,
                         ratio_to_bare="", goal=goal, meets_goal=rate >= goal, status="ok",
                         note=f"{count} paths x {steps} steps"))
    return rows


# ------------------------------------------------------------------------------------------


def fmt(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="small smoke run")
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"CSV file (default {DEFAULT_OUT})")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--repeats", type=int, default=None, help="rounds of part 1 (default 5, quick 3)")
    ap.add_argument("--skip-reference", action="store_true", help="part 1 only")
    args = ap.parse_args(argv)
    repeats = args.repeats or (3 if args.quick else 5)

    print(f"python {platform.python_version()}, numpy {np.__version__}, {os.cpu_count()} cpu(s), "
          f"{'quick' if args.quick else 'full'} run")
    rows = part1(args.quick, args.seed, repeats)
    if not args.skip_reference:
        rows += part2(args.quick, args.seed)

    args.out.parent.mkdir(parents=True, exist_ok=True)
    with open(args.out, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=COLUMNS)
        writer.writeheader()
        for row in rows:
            writer.writerow({k: fmt(row.get(k, "")) for k in COLUMNS})

    shown = ["part", "case", "n", "paths", "steps", "us_per_step", "path_steps_per_s", "ratio_to_bare", "goal",
             "meets_goal", "status"]
    table = [[fmt(r.get(k, "")) for k in shown] for r in rows]
    widths = [max(len(h), *(len(row[i]) for row in table)) for i, h in enumerate(shown)]
    print("  ".join(h.ljust(w) for h, w in zip(shown, widths)))
    for row in table:
        print("  ".join(c.ljust(w) for c, w in zip(row, widths)))
    sup = next(r for r in rows if r["case"] == "supervisor")
    print(f"\nsupervisor / bare fmpy loop = {sup['ratio_to_bare']:.3f} (goal <= {RATIO_GOAL})")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
