#!/usr/bin/env python
"""Benchmark of the main job ``ftc-verify verify`` and of exact moments against Monte Carlo.

Run from the repository root::

    python benchmarks/verify.py               # default run (about 2-3 min on 2 busy cores)
    python benchmarks/verify.py --quick       # smoke run (< 60 s)
    python benchmarks/verify.py --seed 3 --out /tmp/verify.csv

Writes one CSV (default ``benchmarks/results/verify.csv``) and prints two fixed-width tables.
BLAS runs single-threaded (``OPENBLAS_NUM_THREADS=1``, also OMP/MKL) unless already set,
as the CLI does by default; the setting is recorded in every row.

Part 1 -- ``verify`` wall time by stage (``part = verify``)
---------------------------------------------------------
* ``cli total``: ``ftc-verify verify examples/paper.toml --seed S --out TMP`` as a subprocess
  (default settings otherwise: iterative synthesis, k_max 30, 200 FMU paths, h = 0.01,
  horizon 30), wall time including Python start-up and report writing, median of
  ``--repeats`` (3; 1 with ``--quick``). Goal: **under 60 s**. The exit code and the
  printed verdict are checked (status ``fail`` otherwise).
* per stage: in-process ``run_verify(load_system("examples/paper.toml"), seed=S)``, same
  number of runs, the median of each entry of ``VerifyReport.seconds`` (synthesis,
  analysis, cross_validation, exact_energy, gamma_bracket, monte_carlo, reference);
  ``run_verify total`` is the median wall time of the call, ``(not in .seconds)`` the
  median of wall minus the time the stages cover (the union of their ``VerifyReport.spans``:
  stages run beside each other, so their sum exceeds the wall time); ``write_report`` times
  :func:`ftc_verify.verification.report.write_report` of each run's report into a temporary folder
  (plots included); ``import`` is the first import of ``ftc_verify.verification.verify`` and
  ``ftc_verify.verification.report`` in this process. ``first_s`` shows the first (cold) run, which
  pays lazy imports (cvxpy, solvers, fmpy, matplotlib) and the FMU build.
  ``cli - in-process`` is the CLI median minus the in-process medians of run_verify and
  write_report: Python start-up plus imports, roughly.

Part 2 -- exact moments against Monte Carlo for the same accuracy (``part = moments``)
-------------------------------------------------------------------------------------
The paper's example with its gains (``examples/paper_gains.toml``), nominal loop,
``beta`` fixed at the midpoint of its box, start mode (1, 1), x0 = 0, the paper's
disturbance, horizon T = 15. The quantity is ``E int_0^T |y|^2 dt``.

* ``exact``: ``moments.exact_energy(loop, beta=midpoint, horizon=15)`` (one matrix
  exponential, exact to rounding), median of 21 calls (``sample_s`` holds building the
  closed loop).
* ``reference N``: for N in {1e3, 1e4, 1e5} (``--quick``: {1e3, 1e4}), independent
  paths from ``paths.sample_paths(chain, 15, N, SeedSequence([seed, N]),
  beta=midpoint)`` (``sample_s``), then ``reference_sim.energies_reference`` at h = 0.01
  and at h/2 on the same paths (``energies_s``, both). The sample-and-hold bias is first
  order in h, so the estimator is Richardson's ``2 E(h/2) - E(h)`` per path (as
  ``tests/test_moments.py``). ``estimate`` is its mean, ``std_err`` = s / sqrt(N),
  ``rel_err`` = (estimate - exact) / exact, ``z`` = (estimate - exact) / std_err,
  ``rel_half_width`` = q s / (sqrt(N) estimate) with q the two-sided Student-t quantile at
  alpha = 1e-6 (``t_{1 - alpha/2, N-1}``, about 4.89). ``hold_rel_err`` is the relative
  error of the plain h = 0.01 mean (no Richardson), to show the bias that Richardson removes.
* extrapolation: ``n_for_1pct`` / ``n_for_0p1pct`` = the N at which
  q s / (sqrt(N) estimate) reaches 1 % / 0.1 % (q re-evaluated at that N), from the row's
  own s; ``s_for_*`` = that N times the row's per-path cost (sampling + both energy
  runs). Per-path costs fall with N (vectorised), so the largest N is the best basis.
  These count the statistical half-width only; the residual bias (next row) must also be
  well below the target.
* ``richardson residual``: on the first 1e4 paths (1e3 with ``--quick``) of the largest
  run, also ``energies_reference`` at h/4; ``estimate`` = mean over paths of
  ``R(h) - R(h/2)`` with ``R(h) = 2 E(h/2) - E(h)`` and ``R(h/2) = 2 E(h/4) - E(h/2)``
  (common paths, so the noise largely cancels); ``rel_err`` = that / exact. For an
  O(h^2) residual it is about 3/4 of the bias of ``R(h)``. ``energies_s`` is the h/4 run.
* ``fmu N``: the same estimator on the FMU backend, ``supervisor.simulate_fmu(system,
  gains, paths, step=h)`` and ``step=h/2`` on N = 100 new paths (20 with ``--quick``),
  after one untimed 1-path warm-up (FMU build / cache, fmpy load). ``energies_s`` is the
  two FMU runs (each ``simulate_fmu`` call includes opening the FMU: extraction,
  loading, instantiation). The extrapolated ``n_for_*`` use s of the largest reference run
  (the two backends simulate the same loop; their per-path energies on these paths are
  compared, see ``note``), and ``s_for_*`` the FMU per-path cost plus the reference
  run's per-path sampling cost.

Columns: ``part, case, paths, runs, seconds`` (median wall; for Monte Carlo rows
sample + energies), ``first_s, min_s, max_s, sample_s, energies_s, per_path_ms, estimate,
exact, std_err, rel_err, z, rel_half_width, hold_rel_err, n_for_1pct, s_for_1pct,
n_for_0p1pct, s_for_0p1pct, goal_s, meets_goal, status, seed, blas_threads, code, note``.
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse
import csv
import math
import platform
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import scipy.stats

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

PAPER = REPO / "examples" / "paper.toml"
PAPER_GAINS = REPO / "examples" / "paper_gains.toml"
DEFAULT_OUT = REPO / "benchmarks" / "results" / "verify.csv"
CLI_GOAL_S = 60.0
STAGES = ("synthesis", "analysis", "cross_validation", "exact_energy", "gamma_bracket", "monte_carlo", "reference")
HORIZON = 15.0
STEP = 0.01
ALPHA = 1e-6  # two-sided: q = t_{1 - alpha/2}
TARGETS = (0.01, 0.001)
COLUMNS = ["part", "case", "paths", "runs", "seconds", "first_s", "min_s", "max_s", "sample_s", "energies_s",
           "per_path_ms", "estimate", "exact", "std_err", "rel_err", "z", "rel_half_width", "hold_rel_err",
           "n_for_1pct", "s_for_1pct", "n_for_0p1pct", "s_for_0p1pct", "goal_s", "meets_goal", "status", "seed",
           "blas_threads", "code", "note"]



def _covered(spans: list[tuple[float, float]]) -> float:
    """Seconds covered by the union of the ``(start, end)`` intervals ``spans``."""
    total, end = 0.0, -math.inf
    for a, b in sorted(spans):
        if b > end:
            total += b - max(a, end)
            end = b
    return total

def git_code() -> str:
    try:
        out = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short", "HEAD"], capture_output=True,
                             text=True, timeout=10)
        dirty = subprocess.run(["git", "-C", str(REPO), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, timeout=10)
        return out.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return ""


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


# ------------------------------------------------------------------------------------------
# Part 1: verify by stage
# ------------------------------------------------------------------------------------------


def cli_command(seed: int, out: str) -> list[str]:
    exe = Path(sys.executable).parent / "ftc-verify"
    if not exe.exists():
        found = shutil.which("ftc-verify")
        exe = Path(found) if found else None  # type: ignore[assignment]
    head = [str(exe)] if exe is not None else [sys.executable, "-m", "ftc_verify"]
    return head + ["verify", str(PAPER), "--seed", str(seed), "--out", out]


def part_cli(seed: int, runs: int, log: Any) -> tuple[list[dict[str, Any]], str]:
    times: list[float] = []
    cpu: list[float] = []
    problems: list[str] = []
    verdict_line = cli_output = ""
    for r in range(runs):
        with tempfile.TemporaryDirectory(prefix="verify-bench-") as tmp:
            cmd = cli_command(seed, str(Path(tmp) / "report"))
            before = resource.getrusage(resource.RUSAGE_CHILDREN)
            t0 = time.perf_counter()
            proc = subprocess.run(cmd, capture_output=True, text=True, cwd=tmp, timeout=900)
            elapsed = time.perf_counter() - t0
            after = resource.getrusage(resource.RUSAGE_CHILDREN)
        times.append(elapsed)
        cpu.append((after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime))
        lines = proc.stdout.strip().splitlines()
        verdict_line = lines[-1].strip() if lines else ""
        if proc.returncode != 0 or verdict_line != "verdict: pass":
            problems.append(f"run {r + 1}: exit {proc.returncode}, {verdict_line or proc.stderr.strip()[-200:]}")
        log(f"  cli run {r + 1}/{runs}: {elapsed:.2f} s wall, {cpu[-1]:.2f} s cpu, exit {proc.returncode}")
        if r == 0:
            cli_output = proc.stdout
    med = statistics.median(times)
    note = (f"`{' '.join(cli_command(seed, 'TMP'))}`; wall {', '.join(f'{t:.2f}' for t in times)} s; "
            f"child cpu median {statistics.median(cpu):.2f} s")
    if problems:
        note += "; " + "; ".join(problems)
    row = dict(part="verify", case="cli total", runs=runs, seconds=med, first_s=times[0], min_s=min(times),
               max_s=max(times), goal_s=CLI_GOAL_S, meets_goal=med < CLI_GOAL_S and not problems,
               status="fail" if problems else "ok", note=note)
    return [row], cli_output


def part_inprocess(seed: int, runs: int, log: Any) -> list[dict[str, Any]]:
    t0 = time.perf_counter()
    from ftc_verify.model.files import load_system
    from ftc_verify.verification.report import write_report
    from ftc_verify.verification.verify import run_verify

    import_s = time.perf_counter() - t0
    stage_times: dict[str, list[float]] = {k: [] for k in STAGES}
    other_stages: dict[str, list[float]] = {}
    walls: list[float] = []
    rest: list[float] = []
    writes: list[float] = []
    verdicts: list[str] = []
    gammas: list[float | None] = []
    for r in range(runs):
        system = load_system(PAPER)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # as the CLI: solver chatter
            t = time.perf_counter()
            rep = run_verify(system, seed=seed)
            wall = time.perf_counter() - t
        walls.append(wall)
        secs = dict(rep.seconds)
        for k in STAGES:
            stage_times[k].append(float(secs.pop(k, float("nan"))))
        for k, v in secs.items():  # stages this benchmark does not know yet
            other_stages.setdefault(k, []).append(float(v))
        rest.append(wall - _covered(list(rep.spans.values())))
        with tempfile.TemporaryDirectory(prefix="verify-bench-") as tmp:
            t = time.perf_counter()
            write_report(rep, Path(tmp) / "report")
            writes.append(time.perf_counter() - t)
        verdicts.append(rep.verdict)
        gammas.append(rep.gamma_certified)
        log(f"  in-process run {r + 1}/{runs}: run_verify {wall:.2f} s, write_report {writes[-1]:.2f} s, "
            f"verdict {rep.verdict}, " + ", ".join(f"{k} {v:.2f}" for k, v in rep.seconds.items()))

    def row(case: str, vals: list[float], note: str = "", **extra: Any) -> dict[str, Any]:
        finite = [v for v in vals if math.isfinite(v)]
        if not finite:
            return dict(part="verify", case=case, runs=runs, status="missing",
                        note=note or "not in VerifyReport.seconds")
        return dict(part="verify", case=case, runs=len(finite), seconds=statistics.median(finite), first_s=vals[0],
                    min_s=min(finite), max_s=max(finite), status="ok", note=note, **extra)

    rows = [dict(part="verify", case="import", runs=1, seconds=import_s, first_s=import_s, status="ok",
                 note="first import of ftc_verify.verification.verify, .report, .problem_files in this process")]
    for k in STAGES:
        rows.append(row(f"stage {k}", stage_times[k]))
    for k, v in other_stages.items():
        rows.append(row(f"stage {k}", v, note="extra entry of VerifyReport.seconds"))
    rows.append(row("(not in .seconds)", rest, note="run_verify wall minus the time covered by its stages "
                    "(the union of VerifyReport.spans: stages overlap)"))
    ok = all(v == "pass" for v in verdicts)
    rows.append(row("run_verify total", walls,
                    note=f"verdicts {', '.join(verdicts)}; certified gamma "
                         f"{', '.join('-' if g is None else f'{g:.6g}' for g in gammas)}; seed {seed}"))
    if not ok:
        rows[-1]["status"] = "fail"
    rows.append(row("write_report", writes, note="report.json, report.md, plots (not in run_verify)"))
    return rows


# ------------------------------------------------------------------------------------------
# Part 2: exact moments against Monte Carlo
# ------------------------------------------------------------------------------------------


def quantile(n: int) -> float:
    return float(scipy.stats.t.ppf(1.0 - ALPHA / 2.0, max(n - 1, 1)))


def paths_needed(rel_sd: float, target: float) -> int:
    """Smallest N with t_{1-alpha/2, N-1} rel_sd / sqrt(N) <= target (fixed point on q)."""
    n = max(2, math.ceil((quantile(10**9) * rel_sd / target) ** 2))
    for _ in range(20):
        new = max(2, math.ceil((quantile(n) * rel_sd / target) ** 2))
        if new == n:
            break
        n = new
    return n


def mc_stats(r: np.ndarray, exact: float) -> dict[str, float]:
    n = r.size
    mean = float(np.mean(r))
    sd = float(np.std(r, ddof=1))
    se = sd / math.sqrt(n)
    return dict(estimate=mean, std_err=se, rel_err=(mean - exact) / exact, z=(mean - exact) / se if se > 0 else math.nan,
                rel_half_width=quantile(n) * se / abs(mean), rel_sd=sd / abs(mean))


def extrapolate(rel_sd: float, per_path_s: float) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for target, key in zip(TARGETS, ("1pct", "0p1pct")):
        n = paths_needed(rel_sd, target)
        out[f"n_for_{key}"] = n
        out[f"s_for_{key}"] = n * per_path_s
    return out


def part_moments(seed: int, quick: bool, log: Any) -> list[dict[str, Any]]:
    from ftc_verify.analysis.closedloop import state_feedback_loop
    from ftc_verify.analysis.moments.energy import exact_energy
    from ftc_verify.simulation.paths import sample_paths
    from ftc_verify.model.files import load_system
    from ftc_verify.controllers.files import load_controller
    from ftc_verify.simulation.reference import energies_reference
    from ftc_verify.simulation.supervisor import simulate_fmu

    system = load_system(PAPER)
    gains = load_controller(PAPER_GAINS)
    beta = system.chain.midpoint()
    rows: list[dict[str, Any]] = []

    # exact
    t = time.perf_counter()
    loop = state_feedback_loop(system, gains).nominal()
    build_s = time.perf_counter() - t
    ex_times = []
    for _ in range(21):
        t = time.perf_counter()
        ex = exact_energy(loop, beta=beta, horizon=HORIZON)
        ex_times.append(time.perf_counter() - t)
    exact = ex.y_energy
    rows.append(dict(part="moments", case="exact", runs=len(ex_times), seconds=statistics.median(ex_times),
                     first_s=ex_times[0], min_s=min(ex_times), max_s=max(ex_times), sample_s=build_s,
                     estimate=exact, exact=exact, rel_err=0.0, status="ok",
                     note=f"exact_energy(loop, beta=midpoint, horizon={HORIZON:g}); "
                          f"||w||^2 = {ex.w_energy:.10g}; sample_s = building the loop"))
    log(f"  exact: E int|y|^2 = {exact:.10g} in {statistics.median(ex_times) * 1e3:.3f} ms")

    # Monte Carlo on the numpy reference
    counts = (1_000, 10_000) if quick else (1_000, 10_000, 100_000)
    largest_paths = None
    largest_row: dict[str, Any] = {}
    for n in counts:
        t = time.perf_counter()
        paths = sample_paths(system.chain, HORIZON, n, np.random.SeedSequence([seed, n]), beta=beta)
        sample_s = time.perf_counter() - t
        t = time.perf_counter()
        y_h, w_h = energies_reference(system, gains, paths, step=STEP)
        y_h2, _ = energies_reference(system, gains, paths, step=STEP / 2)
        energies_s = time.perf_counter() - t
        st = mc_stats(2.0 * y_h2 - y_h, exact)
        per_path = (sample_s + energies_s) / n
        row = dict(part="moments", case=f"reference N={n:.0e}".replace("+0", ""), paths=n, runs=1,
                   seconds=sample_s + energies_s, sample_s=sample_s, energies_s=energies_s,
                   per_path_ms=1e3 * per_path, exact=exact, hold_rel_err=(float(np.mean(y_h)) - exact) / exact,
                   status="ok", note=f"Richardson 2E(h/2)-E(h), h = {STEP:g}; per-path sd / mean {st['rel_sd']:.4g}; "
                                     f"mean ||w||^2 (trapezoid, h) {float(np.mean(w_h)):.10g}; "
                                     f"peak RSS {peak_rss_mb():.0f} MB",
                   **{k: v for k, v in st.items() if k != "rel_sd"}, **extrapolate(st["rel_sd"], per_path))
        rows.append(row)
        log(f"  reference N={n}: sample {sample_s:.2f} s, energies {energies_s:.2f} s, rel err {st['rel_err']:+.3e}, "
            f"z {st['z']:+.2f}, rel half-width {st['rel_half_width']:.3e}")
        largest_paths, largest_row, largest_rel_sd = paths, row, st["rel_sd"]
        largest_yh, largest_yh2 = y_h, y_h2

    # residual bias of Richardson on common paths (h/4)
    k = min(len(largest_paths), 1_000 if quick else 10_000)
    sub = largest_paths[:k]
    t = time.perf_counter()
    y_h4, _ = energies_reference(system, gains, sub, step=STEP / 4)
    e4_s = time.perf_counter() - t
    r_h = 2.0 * largest_yh2[:k] - largest_yh[:k]
    r_h2 = 2.0 * y_h4 - largest_yh2[:k]
    diff = r_h - r_h2
    d_mean = float(np.mean(diff))
    d_se = float(np.std(diff, ddof=1)) / math.sqrt(k)
    rows.append(dict(part="moments", case="richardson residual", paths=k, runs=1, seconds=e4_s, energies_s=e4_s,
                     per_path_ms=1e3 * e4_s / k, estimate=d_mean, exact=exact, std_err=d_se, rel_err=d_mean / exact,
                     z=d_mean / d_se if d_se > 0 else math.nan, status="ok",
                     note=f"mean of R(h) - R(h/2) on the first {k} paths of the largest run (h/4 = {STEP / 4:g}); "
                          f"R(h/2) alone: rel err {(float(np.mean(r_h2)) - exact) / exact:+.3e}, "
                          f"R(h) on the same paths: {(float(np.mean(r_h)) - exact) / exact:+.3e}"))
    log(f"  richardson residual on {k} paths: {d_mean / exact:+.3e} relative (se {d_se / exact:.1e})")

    # FMU backend
    n_fmu = 20 if quick else 100
    streams = np.random.SeedSequence([seed, 7, n_fmu])
    t = time.perf_counter()
    warm = sample_paths(system.chain, HORIZON, 1, streams, beta=beta)
    simulate_fmu(system, gains, warm, step=STEP)
    warm_s = time.perf_counter() - t
    t = time.perf_counter()
    fpaths = sample_paths(system.chain, HORIZON, n_fmu, streams, beta=beta)
    fsample_s = time.perf_counter() - t
    t = time.perf_counter()
    res_h = simulate_fmu(system, gains, fpaths, step=STEP)
    fh_s = time.perf_counter() - t
    t = time.perf_counter()
    res_h2 = simulate_fmu(system, gains, fpaths, step=STEP / 2)
    fh2_s = time.perf_counter() - t
    fy_h = np.array([r.y_norm ** 2 for r in res_h.records])
    fy_h2 = np.array([r.y_norm ** 2 for r in res_h2.records])
    st = mc_stats(2.0 * fy_h2 - fy_h, exact)
    ref_h, _ = energies_reference(system, gains, fpaths, step=STEP)
    agree = float(np.max(np.abs(ref_h - fy_h) / np.abs(ref_h)))
    fmu_per_path = (fh_s + fh2_s) / n_fmu
    sample_per_path = largest_row["sample_s"] / largest_row["paths"]
    rows.append(dict(part="moments", case=f"fmu N={n_fmu}", paths=n_fmu, runs=1, seconds=fsample_s + fh_s + fh2_s,
                     sample_s=fsample_s, energies_s=fh_s + fh2_s, per_path_ms=1e3 * (fmu_per_path + sample_per_path),
                     exact=exact, hold_rel_err=(float(np.mean(fy_h)) - exact) / exact, status="ok",
                     note=f"simulate_fmu at h {fh_s:.2f} s + h/2 {fh2_s:.2f} s ({1e3 * fh_s / n_fmu:.1f} + "
                          f"{1e3 * fh2_s / n_fmu:.1f} ms/path); warm-up {warm_s:.2f} s untimed; n_for_* from the "
                          f"{largest_row['case']} sd ({largest_rel_sd:.4g}), s_for_* = N x (FMU h + h/2 + sampling "
                          f"{1e3 * sample_per_path:.3f} ms) per path; FMU vs reference energies at h: max rel diff "
                          f"{agree:.2e}; own sd / mean {st['rel_sd']:.4g}",
                     **{k2: v for k2, v in st.items() if k2 != "rel_sd"},
                     **extrapolate(largest_rel_sd, fmu_per_path + sample_per_path)))
    log(f"  fmu N={n_fmu}: {fh_s:.2f} + {fh2_s:.2f} s, rel err {st['rel_err']:+.3e}, agreement {agree:.1e}")
    return rows


# ------------------------------------------------------------------------------------------
# Output
# ------------------------------------------------------------------------------------------


def fmt(v: Any) -> str:
    if v is None:
        return ""
    if isinstance(v, bool):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return ""
        return f"{v:.6g}"
    return str(v)


def human_s(v: Any) -> str:
    if not isinstance(v, (int, float)) or (isinstance(v, float) and math.isnan(v)):
        return ""
    if v < 1e-3:
        return f"{v * 1e6:.0f} us"
    if v < 1:
        return f"{v * 1e3:.3g} ms"
    if v < 120:
        return f"{v:.3g} s"
    if v < 7200:
        return f"{v / 60:.3g} min"
    if v < 2 * 86400:
        return f"{v / 3600:.3g} h"
    return f"{v / 86400:.3g} d"


def short(v: Any, spec: str) -> str:
    if v is None or v == "" or (isinstance(v, float) and math.isnan(v)):
        return ""
    if isinstance(v, bool):
        return "yes" if v else "NO"
    if isinstance(v, (int, float)):
        return format(v, spec)
    return str(v)


def print_table(header: list[str], body: list[list[str]]) -> None:
    widths = [max(len(h), *(len(r[i]) for r in body)) for i, h in enumerate(header)]
    print("  ".join(h.ljust(w) for h, w in zip(header, widths)).rstrip())
    print("  ".join("-" * w for w in widths))
    for r in body:
        print("  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip())


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="smoke run (< 60 s): 1 run each, N up to 1e4, 20 FMU paths")
    ap.add_argument("--seed", type=int, default=1, help="seed of verify (--seed) and of the path samples (default 1)")
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"CSV file (default {DEFAULT_OUT})")
    ap.add_argument("--repeats", type=int, default=None, help="runs of the CLI and of run_verify (default 3, quick 1)")
    ap.add_argument("--skip-verify", action="store_true", help="part 2 only")
    ap.add_argument("--skip-moments", action="store_true", help="part 1 only")
    args = ap.parse_args(argv)
    runs = args.repeats or (1 if args.quick else 3)
    started = time.perf_counter()

    def log(msg: str) -> None:
        print(f"[{time.perf_counter() - started:6.1f} s] {msg}", file=sys.stderr, flush=True)

    blas = os.environ.get("OPENBLAS_NUM_THREADS", "")
    print(f"python {platform.python_version()}, numpy {np.__version__}, {os.cpu_count()} cpu(s), "
          f"OPENBLAS_NUM_THREADS={blas}, load average {', '.join(f'{x:.2f}' for x in os.getloadavg())}, "
          f"{'quick' if args.quick else 'default'} run, seed {args.seed}")
    rows: list[dict[str, Any]] = []
    cli_output = ""
    if not args.skip_verify:
        log("part 1: ftc-verify verify as a subprocess")
        cli_rows, cli_output = part_cli(args.seed, runs, log)
        log("part 1: run_verify in-process")
        inproc = part_inprocess(args.seed, runs, log)
        med = {r["case"]: r.get("seconds") for r in inproc}
        if med.get("run_verify total") is not None and med.get("write_report") is not None:
            gap = cli_rows[0]["seconds"] - med["run_verify total"] - med["write_report"]
            inproc.append(dict(part="verify", case="cli - in-process", runs=runs, seconds=gap, status="ok",
                               note="CLI median - run_verify median - write_report median: start-up, imports, "
                                    "cold caches"))
        rows += cli_rows + inproc
    if not args.skip_moments:
        log("part 2: exact moments against Monte Carlo")
        rows += part_moments(args.seed, args.quick, log)
    code = git_code()
    for r in rows:
        r.setdefault("seed", args.seed)
        r["blas_threads"] = blas
        r["code"] = code

    args.out.parent.mkdir(parents=True, exist_ok=True)
    with open(args.out, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=COLUMNS)
        writer.writeheader()
        for r in rows:
            writer.writerow({k: fmt(r.get(k)) for k in COLUMNS})

    vrows = [r for r in rows if r["part"] == "verify"]
    if vrows:
        print("\nPart 1: ftc-verify verify examples/paper.toml (default settings), wall seconds")
        print_table(["case", "runs", "median_s", "min_s", "max_s", "first_s", "goal_s", "meets_goal", "status"],
                    [[r["case"], short(r.get("runs"), "d"), short(r.get("seconds"), ".3f"), short(r.get("min_s"), ".3f"),
                      short(r.get("max_s"), ".3f"), short(r.get("first_s"), ".3f"), short(r.get("goal_s"), ".0f"),
                      short(r.get("meets_goal"), ""), r.get("status", "")] for r in vrows])
    mrows = [r for r in rows if r["part"] == "moments"]
    if mrows:
        print(f"\nPart 2: E int_0^{HORIZON:g} |y|^2 (paper example, paper gains, beta midpoint); "
              f"Monte Carlo = Richardson 2E(h/2)-E(h), h = {STEP:g}; half-widths two-sided at alpha = {ALPHA:g} "
              f"(q = {quantile(10**9):.3f} for large N)")
        print_table(["case", "N", "time", "sample", "energies", "ms/path", "estimate", "std_err", "rel_err", "z",
                     "rel_hw", "hold_err", "N(1%)", "time(1%)", "N(0.1%)", "time(0.1%)"],
                    [[r["case"], short(r.get("paths"), ",d"), human_s(r.get("seconds")), human_s(r.get("sample_s")), human_s(r.get("energies_s")),
                      short(r.get("per_path_ms"), ".3g"), short(r.get("estimate"), ".7g"),
                      short(r.get("std_err"), ".2e"), short(r.get("rel_err"), "+.2e"), short(r.get("z"), "+.2f"),
                      short(r.get("rel_half_width"), ".2e"), short(r.get("hold_rel_err"), "+.2e"),
                      short(r.get("n_for_1pct"), ",d"), human_s(r.get("s_for_1pct")),
                      short(r.get("n_for_0p1pct"), ",d"), human_s(r.get("s_for_0p1pct"))]
                     for r in mrows])
        ex = next(r for r in mrows if r["case"] == "exact")
        print(f"exact: {human_s(ex['seconds'])} per exact_energy call (median of {ex['runs']}), exact to rounding")
        for r in mrows:
            if r["case"] != "exact":
                print(f"  {r['case']}: {r['note']}")
    bad = [r for r in rows if r.get("status") not in ("ok",)]
    cli = next((r for r in rows if r["case"] == "cli total"), None)
    if cli is not None:
        print(f"\nCLI total {cli['seconds']:.2f} s (goal < {CLI_GOAL_S:g} s: {'met' if cli['meets_goal'] else 'MISSED'}); "
              f"{cli['note']}")
    if cli_output:
        print("first CLI run printed:\n" + "\n".join("  " + line for line in cli_output.rstrip().splitlines()))
    print(f"\nwrote {args.out} ({len(rows)} rows) in {time.perf_counter() - started:.0f} s"
          + (f"; {len(bad)} row(s) not ok" if bad else ""))
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
