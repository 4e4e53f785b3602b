#!/usr/bin/env python
"""Throughput of ``ftc_verify.simulation.reference.energies_reference`` (path-steps per second).

Cases: the paper's example (n = 2, m = 2, its gains) and a random stable plant with
n = 10 states (m = 2, the paper's chain), each with 10,000 paths on ``[0, 10]`` and
``step = 0.01`` (1,000 steps), ``w = exp(-0.1 t) sin t``, ``x0 = 1``. The paths are
sampled first (timed separately); the figure is ``paths * steps / seconds`` of
``energies_reference`` alone, best of ``--repeat`` runs. The controllers are
:class:`ftc_verify.controllers.Controller` objects (static state feedback here);
``--dynamic`` adds a dynamic controller on the paper's plant (its gains behind a
first-order filter of bandwidth 50, ``n_c = 2``; no goal, for information).

Goals: >= 2e7 path-steps/s at n = 2 and >= 5e6 at n = 10.

BLAS threads: tiny LAPACK calls slow down badly when OpenBLAS threads compete for busy
cores, so run with ``OPENBLAS_NUM_THREADS=1`` (or 2 on an idle machine) for stable
numbers; the value in force is printed.

Usage::

    OPENBLAS_NUM_THREADS=1 python benchmarks/reference_sim.py
    python benchmarks/reference_sim.py --paths 2000 --repeat 1      # quick
    python benchmarks/reference_sim.py --dynamic                    # + n_c = 2 controller
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import time
from pathlib import Path

import numpy as np

from ftc_verify.controllers import Controller, load_controller
from ftc_verify.model.files import load_system
from ftc_verify.model.system import FTCSystem
from ftc_verify.simulation.paths import sample_paths
from ftc_verify.simulation.reference import energies_reference

REPO = Path(__file__).resolve().parent.parent
GOALS = {2: 2e7, 10: 5e6}


def random_case(n: int, seed: int) -> tuple[FTCSystem, Controller]:
    """A random n-state, 2-input, 2-mode plant with the paper's chain and gains that make
    every frozen mode stable (``A_i + B_i K_j = A_i - B_i B_i' / 2 - ...`` shifted)."""
    g = np.random.default_rng(seed)
    modes = []
    for _ in range(2):
        A = g.standard_normal((n, n)) / np.sqrt(n) - 1.5 * np.eye(n)
        modes.append({"A": A, "B": g.standard_normal((n, 2)) / np.sqrt(n), "C": g.standard_normal((1, n)),
                      "D": g.standard_normal((n, 1))})
    system = FTCSystem.from_arrays(name=f"random-n{n}", modes=modes, alpha=[[-0.5, 0.5], [1.0, -1.0]],
                                   beta_min=[[0, 2.0], [2.5, 0]], beta_max=[[0, 3.0], [3.5, 0]])
    gains = [-0.3 * g.standard_normal((2, n)) / np.sqrt(n) for _ in range(2)]
    return system, Controller.state_feedback(gains, name=f"random-n{n}")


def filtered_case(system: FTCSystem, static: Controller, bandwidth: float = 50.0) -> tuple[FTCSystem, Controller]:
    """The paper's plant read through ``y_m = I x`` and, per FDI mode, state feedback through a
    first-order filter: ``x_c' = a (y_m - x_c)``, ``u = K x_c`` (``Ac = -a I, Bc = a I, Cc = K,
    Dc = 0``, ``n_c = 2``; every frozen joint mode is stable for ``a = 50``)."""
    n = system.dims[0]
    sys_y = dataclasses.replace(system, modes=tuple(dataclasses.replace(md, Cy=np.eye(n)) for md in system.modes))
    K = static.gains
    ctrl = Controller.dynamic([-bandwidth * np.eye(n)] * len(K), [bandwidth * np.eye(n)] * len(K), list(K),
                              [np.zeros((k.shape[0], n)) for k in K], name="filtered state feedback")
    return sys_y, ctrl


def run(paths_count: int, horizon: float, step: float, repeat: int, seed: int, dynamic: bool = False) -> None:
    print(f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', '(unset)')}, "
          f"{paths_count} paths, horizon {horizon}, step {step}")
    paper = load_system(REPO / "examples" / "paper.toml")
    paper_ctrl = load_controller(REPO / "examples" / "paper_gains.toml")
    cases: list[tuple[str, int, FTCSystem, Controller]] = [("paper (n=2)", 2, paper, paper_ctrl)]
    system10, ctrl10 = random_case(10, seed)
    cases.append(("random (n=10)", 10, system10, ctrl10))
    if dynamic:
        cases.append(("filtered n_c=2", 2, *filtered_case(paper, paper_ctrl)))
    for label, n, system, controller in cases:
        t0 = time.perf_counter()
        paths = sample_paths(system.chain, horizon, paths_count, seed)
        sample_s = time.perf_counter() - t0
        steps = round(horizon / step)
        jumps = sum(p.times.size - 1 for p in paths)
        best = np.inf
        for _ in range(repeat):
            t0 = time.perf_counter()
            ey, ew = energies_reference(system, controller, paths, step=step, x0=np.ones(n))
            best = min(best, time.perf_counter() - t0)
        rate = paths_count * steps / best
        if controller.is_state_feedback:
            goal = GOALS[n]
            verdict = f"goal {goal:.0e}: {'met' if rate >= goal else 'NOT met'}"
        else:
            verdict = "no goal"
        print(f"{label:14s} jumps/path {jumps / paths_count:5.1f}  sampling {sample_s:6.2f} s  "
              f"energies {best:6.3f} s  {rate:.3g} path-steps/s  {verdict}  "
              f"(mean ||y||^2 {np.mean(ey):.4g}, ||w||^2 {ew[0]:.5g})")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--paths", type=int, default=10_000)
    ap.add_argument("--horizon", type=float, default=10.0)
    ap.add_argument("--step", type=float, default=0.01)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--dynamic", action="store_true", help="also time a dynamic controller (n_c = 2)")
    a = ap.parse_args()
    run(a.paths, a.horizon, a.step, a.repeat, a.seed, a.dynamic)


if __name__ == "__main__":
    main()
