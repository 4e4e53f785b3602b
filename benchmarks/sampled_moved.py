#!/usr/bin/env python
"""Experiment (issue 31, item 6): the sampled stages on the paper loop in other units.

The paper loop (``examples/paper.toml`` with ``examples/paper_gains.toml``) moved by a
state similarity :math:`x' = S x` (``ftc_verify.testing.illconditioned.similarity``) and/or
a time scaling :math:`t \\to s t`: both leave the one-period spectrum and ``h_max``
(times ``s``) unchanged, so every moved loop should get the paper loop's verdicts and
bracket. Columns: ``case, verdict`` (at ``0.05 / s``) ``, h_max, h_max_unstable`` (times
``s``) ``, cpu_seconds`` (of ``sampled_analysis``, this process and the children it waited
for) ``, clock_below`` (the clock-dependent certificate, 2 quadratic pieces, at ``0.08 / s``:
proved or not) ``, clock_above`` (at the unstable ``0.1 / s``: must never be proved)
``, clock_cpu_seconds``. Run it with ``PYTHONPATH`` selecting a checkout to compare two.

Usage::

    python benchmarks/sampled_moved.py --out /tmp/moved.csv
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import Any

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

from ftc_verify.analysis.moments.sampled import SampledLoop, sampled_analysis
from ftc_verify.analysis.moments.sampled_clock import clock_stable
from ftc_verify.controllers.controller import Controller
from ftc_verify.controllers.files import load_controller
from ftc_verify.model.files import load_system
from ftc_verify.model.system import FTCSystem, Matrix
from ftc_verify.testing.illconditioned import similarity
from csvout import write_rows

ROOT = Path(__file__).resolve().parents[1]


def moved(system: FTCSystem, controller: Controller, s: float, S: Matrix | None) -> tuple[FTCSystem, Controller]:
    """The nominal paper loop with time ``t -> s t`` and states ``x' = S x``."""
    S = np.eye(system.dims[0]) if S is None else S
    Si = np.linalg.inv(S)
    modes = [{"A": s * S @ md.A @ Si, "B": s * S @ md.B, "C": md.C @ Si, "D": s * S @ md.D} for md in system.modes]
    ch = system.chain
    return (FTCSystem.from_arrays(name="moved", modes=modes, alpha=s * ch.alpha, beta_min=s * ch.beta_min,
                                  beta_max=s * ch.beta_max),
            Controller.state_feedback([K @ Si for K in controller.Dc]))


def _cpu() -> float:
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "sampled_moved.csv"))
    args = p.parse_args()
    system = load_system(ROOT / "examples" / "paper.toml")
    controller = load_controller(ROOT / "examples" / "paper_gains.toml")
    cases: list[tuple[str, float, Matrix | None]] = [
        ("as written", 1.0, None),
        ("similarity 1e2", 1.0, similarity(np.random.default_rng(31), 2, 1.0, 1e2)),
        ("similarity 1e3", 1.0, similarity(np.random.default_rng(31), 2, 1.0, 1e3)),
        ("similarity 1e4", 1.0, similarity(np.random.default_rng(31), 2, 1.0, 1e4)),
        ("similarity 1e4 in units 1e6", 1.0, similarity(np.random.default_rng(31), 2, 1e6, 1e4)),
        ("time 1e-6", 1e-6, None),
        ("time 1e6", 1e6, None),
        ("time 1e-6, similarity 1e4", 1e-6, similarity(np.random.default_rng(7), 2, 1.0, 1e4)),
    ]
    rows: list[dict[str, Any]] = []
    for name, s, S in cases:
        sys_, ctrl = moved(system, controller, s, S)
        c0 = _cpu()
        res = sampled_analysis(sys_, ctrl, 0.05 / s, max_seconds=30.0)
        c1 = _cpu()
        loop = SampledLoop.build(sys_, ctrl)
        below = clock_stable(loop, 0.08 / s, 2, quadratic=True)
        above = clock_stable(loop, 0.1 / s, 2, quadratic=True)
        rows.append({"case": name, "verdict": res.verdict,
                     "h_max": "" if res.h_max is None else f"{res.h_max * s:.7f}",
                     "h_max_unstable": "" if res.h_max_unstable is None else f"{res.h_max_unstable * s:.7f}",
                     "cpu_seconds": f"{c1 - c0:.2f}",
                     "clock_below": bool(below is not None and below.proved),
                     "clock_above": bool(above is not None and above.proved),
                     "clock_cpu_seconds": f"{_cpu() - c1:.2f}"})
        print(rows[-1], flush=True)
    write_rows(args.out, rows)


if __name__ == "__main__":
    main()
