#!/usr/bin/env python
"""The lower bounds' float searches alone: dense solves, CPU and brackets (issue 37 item 3).

For a random n x m loop with uncertainty (``benchmarks/analysis.py``'s ``make_case``, the
systems of ``benchmarks/scaling.py``), solves Theorem 3.2 and Lemma 4.1 (not counted), then
times and counts the dense coupled-Lyapunov solves of the nominal lower bound and of the
robust one (the constant-Delta search and the bound at it), in process, and prints the
brackets ``certified gamma / proved lower bound``. Run it once per tree with ``PYTHONPATH``
(a tree without ``analysis.worst_delta`` runs ``worst_constant_delta`` and
``gain_lower_bound`` at the certified robust gamma, as before it)::

    PYTHONPATH=/work/main python benchmarks/lower_bound_solves.py --seeds 6101,7201
    python benchmarks/lower_bound_solves.py --seeds 6101,7201 --out benchmarks/results/lower_bound_solves.csv
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import tempfile
import time
from pathlib import Path
from typing import Any
from csvout import write_rows

HERE = Path(__file__).resolve().parent


def _module(name: str) -> Any:
    spec = importlib.util.spec_from_file_location(f"bench_{name}", HERE / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def measure(n: int, m: int, seed: int) -> dict[str, Any]:
    """One case: CPU seconds and dense solves of each phase, gammas, bounds, the Delta."""
    import ftc_verify.analysis.lower_bound as lb
    from ftc_verify.analysis.closedloop import closed_loop
    from ftc_verify.analysis.lmi_analysis import hinf_gamma
    from ftc_verify.analysis.moments.stability import mean_square_stability
    from ftc_verify.controllers.files import load_controller
    from ftc_verify.model.files import load_system

    with tempfile.TemporaryDirectory() as tmp:
        sys_path, gains_path = _module("scaling").write_case(n, m, True, seed, Path(tmp))
        loop = closed_loop(load_system(sys_path), load_controller(gains_path))
    mss = mean_square_stability(loop, root_lmi=True)
    nominal, robust = hinf_gamma(loop, robust=False), hinf_gamma(loop, robust=True)
    solves = [0]
    solve = lb.lyapunov_stack_solution

    def counted(*args: Any) -> Any:
        solves[0] += 1
        return solve(*args)

    lb.lyapunov_stack_solution = counted  # type: ignore[assignment]
    row: dict[str, Any] = {"n": n, "m": m, "seed": seed, "nominal_gamma": nominal.gamma, "robust_gamma": robust.gamma}

    def phase(name: str, run: Any) -> Any:
        solves[0] = 0
        t = time.process_time()
        out = run()
        row[f"{name}_cpu_s"], row[f"{name}_solves"] = round(time.process_time() - t, 3), solves[0]
        return out

    low = phase("nominal", lambda: lb.gain_lower_bound(loop, worst_rates=mss.worst_beta, upper=nominal.gamma))
    try:
        from ftc_verify.analysis.worst_delta import robust_lower_bound
    except ImportError:  # a tree before analysis.worst_delta
        def robust_lower_bound(loop: Any, rates: Any, *, worst_rates: Any, upper: float) -> Any:
            delta = lb.worst_constant_delta(loop, rates, upper=upper)  # type: ignore[attr-defined]
            return delta, lb.gain_lower_bound(loop, deltas=[delta], worst_rates=worst_rates, upper=robust.gamma)
    (label, _), high = phase("robust", lambda: robust_lower_bound(loop, low.rates, worst_rates=mss.worst_beta,
                                                                     upper=nominal.gamma))
    best = max(low.value or 0.0, (high.value or 0.0) if high is not None else 0.0)
    row.update(nominal_lower=low.value, robust_lower=None if high is None else high.value,
               nominal_bracket=nominal.gamma / low.value if low.value else None,
               robust_bracket=robust.gamma / best if best else None, delta=label,
               load=round(os.getloadavg()[0], 1))
    return row


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", default="6101", help="comma-separated seeds (default 6101)")
    parser.add_argument("--case", default="8x3", help="NxM (with uncertainty; default 8x3)")
    parser.add_argument("--out", type=Path, default=None, help="CSV to write (default: print only)")
    args = parser.parse_args()
    n, m = (int(v) for v in args.case.split("x"))
    rows = [measure(n, m, int(s)) for s in args.seeds.split(",")]
    for r in rows:
        print(f"seed {r['seed']}: nominal {r['nominal_cpu_s']} s / {r['nominal_solves']} solves, robust "
              f"{r['robust_cpu_s']} s / {r['robust_solves']} solves; brackets {r['nominal_bracket']:.5f} / "
              f"{r['robust_bracket']:.5f}; {r['delta']} (load {r['load']})")
    if args.out is not None:
        write_rows(args.out, rows)
        print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
