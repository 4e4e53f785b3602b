#!/usr/bin/env python
"""Certified verdicts and gammas of ``analyze`` against exact references on ill-conditioned loops.

Run from the repository root::

    python benchmarks/certificates.py                      # 74 loops
    python benchmarks/certificates.py --quick              # 12 + 3 + 2 loops (smoke run)
    python benchmarks/certificates.py --transform-max 1e6 --csv /tmp/c.csv
    python benchmarks/certificates.py --against /path/to/other/checkout   # the same loops on other code

The peer family (fixed seeds, every loop nominal, its reference computed in the
well-conditioned original coordinates, the analysed loop moved to bad ones):

1. ``identical``: 60 loops of :func:`ftc_verify.testing.illconditioned.identical_mode_loop`,
   loop ``k`` (seed ``1000 + k``) with ``n = 2 + k % 9`` (2..10) and, from
   ``numpy.random.default_rng(1000 + k)``, the LTI norm log-uniform in [0.1, 800], the
   diagonal condition log-uniform in [1, 1e6] and the transform condition log-uniform in
   [1, ``--transform-max``] (default 1e4). Reference: SLICOT ``ab13dd``
   (``PeerLoop.reference_norm``); true abscissa ``PeerLoop.abscissa``.
2. ``multi``: 10 genuine multi-mode loops of
   :func:`ftc_verify.testing.references.multi_mode_loop` (4 different joint modes, the
   ``beta`` box collapsed to a point, mean-square stable), loop ``k`` (seed ``2000 + k``)
   with ``n = 2 + k % 5`` (2..6), norm and conditions drawn as above and moved by
   :func:`~ftc_verify.testing.illconditioned.similarity`. Reference: the SDP-free
   :func:`~ftc_verify.testing.references.mjls_hinf_norm_of_loop` (lower end of a 1e-6
   bracket); true abscissa of the second-moment generator in the original coordinates.
3. ``unstable``: 4 identical-mode loops (seed ``3000 + k``, ``n = 3 + k``) whose ``A`` is
   shifted so that the true second-moment abscissa is +0.1; reference gamma infinite.

Every loop gets ``analyze(loop, cross_validation=False)``. Counted at the end:

* false verdicts: "stable" with true abscissa >= 0, or "not stable" with true abscissa < 0
  ("undecided" is counted separately, it is not false);
* missing certificates: a stable loop without a certified nominal gamma;
* loose certificates: certified gamma more than 1e-3 relative above the reference;
* certificates below the reference: certified gamma < reference (infinite for the unstable
  loops, so any certificate there counts). Such a certificate would be false: must be 0.

``--against DIR`` also analyses every loop with the ``ftc_verify`` of another checkout (a
child process with ``PYTHONPATH=DIR``, the loops passed as arrays, so the other code
needs only ``JointChain``, ``ClosedLoop`` and ``analyze``; a verdict is its ``mss.verdict``,
or ``stable``/``not stable`` from ``mss.stable`` where it has none) and prints the same
counts for it, side by side in one run.

Output: one CSV row per loop (``--csv``, default ``benchmarks/results/certificates.csv``,
``certificates_quick.csv`` with ``--quick``) and the table. BLAS runs on one thread unless
``OPENBLAS_NUM_THREADS`` (or OMP/MKL) is set (see ``benchmarks/README.md`` on why).
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # before numpy is imported

import argparse
import csv
import math
import sys
import time
import warnings
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from ftc_verify.analysis.analyze import analyze
from ftc_verify.analysis.closedloop import ClosedLoop
from ftc_verify.testing.illconditioned import identical_mode_loop
from ftc_verify.testing.references import multi_mode_loop

RESULTS = ROOT / "benchmarks" / "results"
COUNTS = {"identical": 60, "multi": 10, "unstable": 4}
QUICK_COUNTS = {"identical": 12, "multi": 3, "unstable": 2}
#: A certified gamma more than this above the reference is "loose".
LOOSE_RTOL = 1e-3
#: True second-moment abscissa of the unstable loops.
UNSTABLE_ABSCISSA = 0.1
COLUMNS = ["kind", "seed", "n", "diagonal_condition", "transform_condition", "norm_drawn", "reference_gamma",
           "certified_gamma", "relative_error", "outcome", "verdict", "true_abscissa", "estimated_abscissa",
           "seconds", "reference_seconds", "false_verdict", "missing", "loose", "below", "message"]


def _log_uniform(rng: np.random.Generator, low: float, high: float) -> float:
    return float(math.exp(rng.uniform(math.log(low), math.log(high)))) if high > low else float(low)


def _draw(seed: int, transform_max: float) -> tuple[float, float, float]:
    """``(norm, diagonal condition, transform condition)`` from ``default_rng(seed)``."""
    rng = np.random.default_rng(seed)
    return _log_uniform(rng, 0.1, 800.0), _log_uniform(rng, 1.0, 1e6), _log_uniform(rng, 1.0, transform_max)


def _case(kind: str, seed: int, n: int, drawn: tuple[float, float, float], loop: ClosedLoop, reference: float,
          abscissa: float, reference_seconds: float) -> dict[str, Any]:
    norm, dc, tc = drawn
    return {"kind": kind, "seed": seed, "n": n, "diagonal_condition": dc, "transform_condition": tc,
            "norm_drawn": norm, "loop": loop, "reference_gamma": reference, "true_abscissa": abscissa,
            "reference_seconds": reference_seconds}


def family(counts: dict[str, int], transform_max: float) -> list[dict[str, Any]]:
    """The cases of the module docstring: a dict per loop with the loop and its truth."""
    cases: list[dict[str, Any]] = []
    for k in range(counts["identical"]):
        seed, n = 1000 + k, 2 + k % 9
        drawn = _draw(seed, transform_max)
        t = time.perf_counter()
        p = identical_mode_loop(seed, n, norm=drawn[0], diagonal_condition=drawn[1], transform_condition=drawn[2])
        ref = p.reference_norm()
        cases.append(_case("identical", seed, n, drawn, p.loop, ref, p.abscissa, time.perf_counter() - t))
    for k in range(counts["multi"]):
        seed, n = 2000 + k, 2 + k % 5
        drawn = _draw(seed, transform_max)
        t = time.perf_counter()
        q = multi_mode_loop(seed, n, norm=drawn[0], diagonal_condition=drawn[1], transform_condition=drawn[2])
        ref = q.reference_norm()
        cases.append(_case("multi", seed, n, drawn, q.loop, ref, q.abscissa, time.perf_counter() - t))
    for k in range(counts["unstable"]):
        seed, n = 3000 + k, 3 + k
        drawn = _draw(seed, transform_max)
        p = identical_mode_loop(seed, n, norm=drawn[0], diagonal_condition=drawn[1], transform_condition=drawn[2])
        A = p.original.A[0] + 0.5 * (UNSTABLE_ABSCISSA - p.abscissa) * np.eye(n)  # abscissa 2 max Re eig(A)
        moved = p.S @ A @ np.linalg.inv(p.S)
        loop = replace(p.loop, A=tuple(moved for _ in p.loop.A))
        true = 2.0 * float(np.max(np.linalg.eigvals(A).real))
        cases.append(_case("unstable", seed, n, drawn, loop, math.inf, true, 0.0))
    return cases


def run_case(case: dict[str, Any]) -> dict[str, Any]:
    """``analyze`` one loop and judge its verdict and certificate against the truth."""
    row = {k: v for k, v in case.items() if k != "loop"}
    t = time.perf_counter()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            rep = analyze(case["loop"], cross_validation=False)
    except Exception as exc:
        row.update(seconds=time.perf_counter() - t, verdict="error", outcome="error", certified_gamma=None,
                   relative_error=None, estimated_abscissa=None, message=f"{type(exc).__name__}: {exc}",
                   false_verdict=False, missing=case["true_abscissa"] < 0, loose=False, below=False)
        return row
    seconds = time.perf_counter() - t
    ref, truth = case["reference_gamma"], case["true_abscissa"]
    gamma = rep.nominal.gamma if rep.nominal.certified else None
    verdict = rep.mss.verdict
    row.update(
        seconds=seconds, verdict=verdict, outcome=rep.nominal.outcome, certified_gamma=gamma,
        relative_error=(gamma / ref - 1.0) if gamma is not None and math.isfinite(ref) else None,
        estimated_abscissa=rep.mss.spectral_abscissa,
        message="" if gamma is not None else rep.nominal.message,
        false_verdict=(verdict == "stable" and truth >= 0) or (verdict == "not stable" and truth < 0),
        missing=truth < 0 and gamma is None,
        loose=gamma is not None and gamma > ref * (1.0 + LOOSE_RTOL),
        below=gamma is not None and gamma < ref,
    )
    return row


_CHILD = r"""
import json, math, sys, time, warnings
import numpy as np
from ftc_verify.analysis.analyze import analyze
from ftc_verify.analysis.closedloop import ClosedLoop
from ftc_verify.model.system import JointChain
for path in sys.argv[1:]:
    d = np.load(path)
    chain = JointChain(d["alpha"], d["beta_min"], d["beta_max"])
    S = len(d["A"])
    loop = ClosedLoop(chain, tuple(d["A"]), tuple(d["Bw"]), tuple(d["Cz"]), ((),) * S, "peer family")
    t = time.perf_counter()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            rep = analyze(loop, cross_validation=False)
        verdict = getattr(rep.mss, "verdict", "stable" if rep.mss.stable else "not stable")
        gamma = rep.nominal.gamma if rep.nominal.certified else None
        out = {"verdict": verdict, "gamma": gamma, "outcome": rep.nominal.outcome}
    except Exception as exc:
        out = {"verdict": "error", "gamma": None, "outcome": type(exc).__name__}
    out["seconds"] = time.perf_counter() - t
    print(json.dumps(out), flush=True)
"""


def run_against(other: Path, cases: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Every case analysed by the ``ftc_verify`` under ``other`` (module docstring), judged
    as :func:`run_case` judges this code's answers."""
    import json
    import subprocess
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        files = []
        for i, case in enumerate(cases):
            loop = case["loop"]
            f = Path(tmp) / f"loop{i}.npz"
            np.savez(f, A=np.stack(loop.A), Bw=np.stack(loop.Bw), Cz=np.stack(loop.Cz), alpha=loop.chain.alpha,
                     beta_min=loop.chain.beta_min, beta_max=loop.chain.beta_max)
            files.append(str(f))
        env = dict(os.environ, PYTHONPATH=str(other))
        run = subprocess.run([sys.executable, "-c", _CHILD, *files], capture_output=True, text=True, env=env,
                             cwd=str(other), check=False)
    answers = [json.loads(line) for line in run.stdout.splitlines() if line.startswith("{")]
    if len(answers) != len(cases):
        raise SystemExit(f"--against {other}: the other code answered {len(answers)} of {len(cases)} loops\n"
                         f"{run.stderr[-2000:]}")
    rows = []
    for case, a in zip(cases, answers):
        ref, truth, gamma, verdict = case["reference_gamma"], case["true_abscissa"], a["gamma"], a["verdict"]
        row = {k: v for k, v in case.items() if k != "loop"}
        row.update(seconds=a["seconds"], verdict=verdict, outcome=a["outcome"], certified_gamma=gamma,
                   relative_error=(gamma / ref - 1.0) if gamma is not None and math.isfinite(ref) else None,
                   estimated_abscissa=None, message="",
                   false_verdict=(verdict == "stable" and truth >= 0) or (verdict == "not stable" and truth < 0),
                   missing=truth < 0 and gamma is None,
                   loose=gamma is not None and gamma > ref * (1.0 + LOOSE_RTOL),
                   below=gamma is not None and gamma < ref)
        rows.append(row)
    return rows


def _fmt(value: Any, spec: str) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return format("-", ">" + spec.split(".")[0])
    return format(value, spec)


def print_row(i: int, r: dict[str, Any]) -> None:
    flags = "".join(f" {name.upper()}" for name in ("false_verdict", "missing", "loose", "below") if r[name])
    print(f"{i:3d} {r['kind']:<9} {r['n']:>2} {r['diagonal_condition']:9.2e} {r['transform_condition']:9.2e} "
          f"{_fmt(r['reference_gamma'], '12.6g')} {_fmt(r['certified_gamma'], '12.6g')} "
          f"{_fmt(r['relative_error'], '9.2e')} {r['verdict']:<10} {r['true_abscissa']:+9.3g} "
          f"{r['seconds']:7.2f}{flags}", flush=True)


def write_csv(path: Path, rows: list[dict[str, Any]]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=COLUMNS, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({k: ("" if r.get(k) is None else r.get(k)) for k in COLUMNS})


def summary(rows: list[dict[str, Any]], wall: float) -> int:
    """Print the counts; the number of false answers (verdicts plus certificates below)."""
    false_v = [r for r in rows if r["false_verdict"]]
    undecided = [r for r in rows if r["verdict"] == "undecided"]
    errors = [r for r in rows if r["verdict"] == "error"]
    missing = [r for r in rows if r["missing"]]
    loose = [r for r in rows if r["loose"]]
    below = [r for r in rows if r["below"]]
    errs = [abs(r["relative_error"]) for r in rows if r["relative_error"] is not None]

    def ids(sel: list[dict[str, Any]]) -> str:
        return "  " + ", ".join(f"{r['kind']}:{r['seed']}" for r in sel) if sel else ""

    per_kind = ", ".join(f"{k} {sum(r['kind'] == k for r in rows)}" for k in COUNTS)
    print(f"\nloops: {len(rows)} ({per_kind})")
    print(f"false verdicts:                      {len(false_v)}{ids(false_v)}")
    print(f"undecided verdicts:                  {len(undecided)}{ids(undecided)}")
    print(f"analysis errors:                     {len(errors)}{ids(errors)}")
    print(f"missing certificates (stable loop):  {len(missing)}{ids(missing)}")
    print(f"loose certificates (> {LOOSE_RTOL:g} above): {len(loose)}{ids(loose)}")
    print(f"certificates below the reference:    {len(below)}{ids(below)}  (must be 0)")
    if errs:
        print(f"relative error of certified gammas:  median {np.median(errs):.2e}, max {max(errs):.2e}")
    analysed = sum(r["seconds"] for r in rows)
    refs = sum(r["reference_seconds"] for r in rows)
    print(f"time: analyze {analysed:.1f} s, references {refs:.1f} s, total wall {wall:.1f} s")
    return len(false_v) + len(below)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="first 12 identical, 3 multi-mode, 2 unstable loops")
    ap.add_argument("--csv", type=Path, default=None,
                    help="CSV file (default benchmarks/results/certificates.csv, certificates_quick.csv with --quick)")
    ap.add_argument("--transform-max", type=float, default=1e4,
                    help="upper end of the log-uniform transform condition (default 1e4; e.g. 1e6)")
    ap.add_argument("--against", type=Path, default=None, metavar="DIR",
                    help="also analyse every loop with the ftc_verify of this checkout, side by side")
    args = ap.parse_args(argv)
    if not args.transform_max >= 1.0:
        ap.error(f"--transform-max must be >= 1, got {args.transform_max}")
    out = args.csv or RESULTS / ("certificates_quick.csv" if args.quick else "certificates.csv")
    t0 = time.perf_counter()
    counts = QUICK_COUNTS if args.quick else COUNTS
    print(f"certificates benchmark: {counts}, transform condition up to {args.transform_max:g}, "
          f"python {sys.version.split()[0]}, BLAS threads {os.environ['OPENBLAS_NUM_THREADS']}", flush=True)
    cases = family(counts, args.transform_max)
    print(f"{len(cases)} loops and references built in {time.perf_counter() - t0:.1f} s\n")
    print(f"{'#':>3} {'kind':<9} {'n':>2} {'diag cond':>9} {'tf cond':>9} {'ref gamma':>12} {'cert gamma':>12} "
          f"{'rel err':>9} {'verdict':<10} {'abscissa':>9} {'seconds':>7}")
    rows = []
    for i, case in enumerate(cases, start=1):
        rows.append(run_case(case))
        print_row(i, rows[-1])
        write_csv(out, rows)
    false = summary(rows, time.perf_counter() - t0)
    print(f"CSV: {out}")
    if args.against is not None:
        t1 = time.perf_counter()
        other = run_against(args.against, cases)
        print(f"\nthe same loops with the code in {args.against}:")
        for i, r in enumerate(other, start=1):
            print_row(i, r)
        summary(other, time.perf_counter() - t1)
        write_csv(out.with_name(out.stem + "_against.csv"), other)
    return 1 if false else 0


if __name__ == "__main__":
    sys.exit(main())
