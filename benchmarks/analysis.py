#!/usr/bin/env python
"""Benchmark of ``ftc_verify.analysis.analyze.analyze``: model build vs. solver time.

Random FTC systems with ``n`` states and ``m`` fault modes (grid ``n`` in {2, 4, 8, 16}
x ``m`` in {2, 3, 4}, plus ``n = 12, m = 4``) are analysed with the automatic solver
choice and with ``solver="clarabel"`` side by side. Each case runs in its own child
process (forkserver, heavy modules preloaded, one warm-up analysis first) under a hard
time limit, so a runaway case is stopped and reported instead of stalling the run.

Also measured, as subprocesses (median of 5): the Python start-up alone,
``python -c "import control"`` (the one heavy import ``analyze`` needs: python-control
for the cross-check) and the paper's example through the console
script, ``ftc-verify analyze examples/paper.toml --gains examples/paper_gains.toml --json``.

Goals checked (issue 15): the paper's example in < 1 s wall including start-up; n = 8,
m = 3 in < 1.5 s; n = 12, m = 4 in < 12 s (both in-process ``analyze``, warm).

Side by side against other code: ``PYTHONPATH=/path/to/other/checkout python
benchmarks/analysis.py --out other.csv`` runs every case (and the CLI) on that code;
the cvxpy compile columns (``canon_s``, ``solver_core_s``) are 0 on the native Clarabel
path.

Usage::

    python benchmarks/analysis.py                 # default grid, ~10 min
    python benchmarks/analysis.py --quick         # smoke run, < 30 s
    python benchmarks/analysis.py --out x.csv --seed 7

See ``benchmarks/README.md`` for the columns and how the random systems are made.
"""

from __future__ import annotations

import argparse
import csv
import math
import multiprocessing as mp
import os
import statistics
import subprocess
import sys
import time
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parent.parent
DEFAULT_OUT = REPO / "benchmarks" / "results" / "analysis.csv"

GRID = [(n, m) for n in (2, 4, 8, 16) for m in (2, 3, 4)] + [(12, 4)]
QUICK_GRID = [(2, 2), (2, 3)]
#: Goals (seconds). The paper goal is wall time of the CLI subprocess incl. start-up;
#: the others are the in-process ``analyze`` total with the automatic solver.
PAPER_GOAL_S = 1.0
GOALS = {(8, 3): 1.5, (12, 4): 12.0}

COLUMNS = [
    # the columns asked for, in this order
    "n", "m", "seed", "solver", "variables", "spectral_s", "build_s", "solve_s",
    "crossval_s", "total_s", "certified", "nominal_gamma", "robust_gamma", "goal_s",
    "meets_goal",
    # extras
    "case", "status", "uncertain", "solvers_used", "canon_s", "solver_core_s",
    "th31_s", "th32_s", "lem41_s", "lmi_other_s", "spectral_evals", "solver_calls",
    "repeats", "peak_rss_mb", "blas_threads", "note",
]

PRELOAD = ["numpy", "scipy.linalg", "cvxpy", "control", "clarabel", "sdpap",
           "ftc_verify.analysis.analyze", "ftc_verify.analysis.lmi_analysis", "ftc_verify.analysis.moments.stability",
           "ftc_verify.analysis.crossval", "ftc_verify.analysis.closedloop", "ftc_verify.model.system"]


# --------------------------------------------------------------------------- systems

def uncertain_default(n: int, m: int) -> bool:
    """Uncertainty weights 0.05 I on every case with m >= 3 (so the goal cases run the
    full robust analysis); m = 2 cases are nominal (Lemma 4.1 reduces to Theorem 3.2)."""
    return m >= 3


def make_case(n: int, m: int, seed: int, uncertain: bool, max_draws: int = 50) -> tuple[Any, list[np.ndarray], int]:
    """A random FTC system and LQR gains; returns ``(system, gains, draws)``.

    ``numpy.random.default_rng(seed)``; per mode ``A_i = A0 + 0.1 N_i / sqrt(n)`` with
    ``A0`` entries N(0, 1)/sqrt(n); ``B_i = e_i B0`` (actuator effectiveness ``e_0 = 1``,
    ``e_i`` in U[0.6, 0.9] for faulty modes), ``B0`` n x max(1, n//2) N(0, 1); ``C`` 1 x n
    (n <= 4) or 2 x n; ``D`` n x 1. Gains: per FDI mode j the LQR gain of (A_j, B_j)
    with Q = I, R = I (its gain margin [1/2, inf) keeps every frozen joint mode stable
    for effectiveness ratios >= 0.6). ``alpha`` off-diagonal in U[0.2, 1]; ``beta`` in
    ``[b, b + 1]``, ``b`` in U[1.5, 2.5]. A draw whose frozen joint modes are not all
    Hurwitz is redrawn from the same stream (``draws`` counts the draws).
    """
    import scipy.linalg

    from ftc_verify.model.system import FTCSystem

    rng = np.random.default_rng(seed)
    nu, ny = max(1, n // 2), (1 if n <= 4 else 2)
    for draw in range(1, max_draws + 1):
        A0 = rng.normal(size=(n, n)) / math.sqrt(n)
        B0 = rng.normal(size=(n, nu))
        C = rng.normal(size=(ny, n))
        D = rng.normal(size=(n, 1))
        eff = np.concatenate([[1.0], rng.uniform(0.6, 0.9, m - 1)])
        modes: list[dict[str, np.ndarray]] = []
        for i in range(m):
            A = A0 if i == 0 else A0 + 0.1 * rng.normal(size=(n, n)) / math.sqrt(n)
            md = {"A": A, "B": eff[i] * B0, "C": C, "D": D}
            if uncertain:
                md.update(A1=0.05 * np.eye(n), A2=0.05 * np.eye(n), B1=0.05 * np.eye(n), B2=0.05 * np.eye(n, nu))
            modes.append(md)
        alpha = rng.uniform(0.2, 1.0, (m, m))
        np.fill_diagonal(alpha, 0.0)
        np.fill_diagonal(alpha, -alpha.sum(axis=1))
        bmin = rng.uniform(1.5, 2.5, (m, m))
        np.fill_diagonal(bmin, 0.0)
        bmax = bmin + 1.0
        np.fill_diagonal(bmax, 0.0)
        try:
            gains = []
            for md in modes:
                X = scipy.linalg.solve_continuous_are(md["A"], md["B"], np.eye(n), np.eye(nu))
                gains.append(-md["B"].T @ X)
        except (np.linalg.LinAlgError, ValueError):
            continue
        frozen = [modes[i]["A"] + modes[i]["B"] @ gains[j] for i in range(m) for j in range(m)]
        if max(float(np.max(np.linalg.eigvals(F).real)) for F in frozen) >= -1e-6:
            continue
        system = FTCSystem.from_arrays(name=f"random-n{n}-m{m}-seed{seed}", modes=modes,
                                       alpha=alpha, beta_min=bmin, beta_max=bmax)
        return system, gains, draw
    raise RuntimeError(f"no stabilisable draw for n={n}, m={m}, seed={seed} in {max_draws} draws")


def variables_of(n: int, m: int, uncertain: bool) -> int:
    """Decision variables of the robust LMIs, without building the loop (as
    ``decision_size(loop, robust=True)``: 2 channels per joint mode when uncertain)."""
    return m * m * n * (n + 1) // 2 + 1 + (2 * m * m if uncertain else 0)


# --------------------------------------------------------------------------- child side

def _instrument(conn: Any, events: dict[str, Any]) -> None:
    """Wrap (in this child process only) the names ``analyze`` looks up, to record
    per-call times and stream stage progress to the parent. Nothing is changed in
    behaviour: each wrapper calls the original and returns its result."""
    import importlib

    # import_module, not ``import a.b as x``: the package re-exports a function named
    # ``analyze`` that shadows the submodule attribute
    fa = importlib.import_module("ftc_verify.analysis.analyze")
    la = importlib.import_module("ftc_verify.analysis.lmi_analysis")
    st = importlib.import_module("ftc_verify.analysis.moments.stability")

    if hasattr(la, "solve_conic"):  # the native conic path: solve_conic(problem, name) -> (outcome, x)
        orig_conic = la.solve_conic

        def solve_conic(problem: Any, name: str) -> Any:
            out, x = orig_conic(problem, name)
            events["solves"].append((name, out.seconds, None, None, out.status))
            conn.send(("solve", name, out.seconds))
            return out, x

        la.solve_conic = solve_conic
        if hasattr(la, "solve_conic_dual"):  # the one-solve path of issue 24 (Clarabel with its dual)
            orig_dual = la.solve_conic_dual

            def solve_conic_dual(problem: Any) -> Any:
                out, x, z = orig_dual(problem)
                events["solves"].append(("clarabel", out.seconds, None, None, out.status))
                conn.send(("solve", "clarabel", out.seconds))
                return out, x, z

            la.solve_conic_dual = solve_conic_dual
    else:  # the cvxpy path (code before the native path, for side-by-side runs)
        orig_solve = la.solve

        def solve(problem: Any, name: str) -> Any:
            out = orig_solve(problem, name)
            canon = getattr(problem, "compilation_time", None)
            core = getattr(problem, "_solve_time", None)
            events["solves"].append((name, out.seconds, canon, core, out.status))
            conn.send(("solve", name, out.seconds))
            return out

        la.solve = solve

    orig_sa = st.spectral_abscissa

    def spectral_abscissa(loop: Any, beta: Any) -> float:
        t = time.perf_counter()
        value = orig_sa(loop, beta)
        dt = time.perf_counter() - t
        events["spectral"].append(dt)
        conn.send(("spectral_eval", dt))
        return value

    st.spectral_abscissa = spectral_abscissa

    def stage(fn: Any, label: str) -> Any:
        def wrapped(*args: Any, **kwargs: Any) -> Any:
            t = time.perf_counter()
            out = fn(*args, **kwargs)
            conn.send(("stage", label, time.perf_counter() - t))
            return out
        return wrapped

    fa.mean_square_stability = stage(fa.mean_square_stability, "spectral")
    fa.mes_lmi = stage(fa.mes_lmi, "theorem_3_1")
    fa.hinf_gamma = stage(fa.hinf_gamma, "hinf_gamma")
    fa.cross_validate = stage(fa.cross_validate, "cross_validation")


def _row_from_report(rep: Any, events: dict[str, Any]) -> dict[str, Any]:
    lmis = [rep.mes_lmi, rep.nominal] + ([rep.robust] if rep.robust is not rep.nominal else [])
    sec = rep.seconds
    build = sum(r.build_seconds for r in lmis)
    solve = sum(r.solve_seconds for r in lmis)
    used = sorted({a.solver for r in lmis for a in r.attempts})
    solves = events["solves"]
    canon = sum(c for _, _, c, _, _ in solves if c is not None)
    core = sum(c for _, _, _, c, _ in solves if c is not None)
    lmi_stages = sec["theorem_3_1"] + sec["theorem_3_2"] + sec["lemma_4_1"]
    certified = bool(rep.certified_stable and rep.certificate_ok)
    notes = []
    if not rep.mss.stable:
        notes.append(f"spectral abscissa {rep.mss.spectral_abscissa:.3g} >= 0")
    for r in lmis:
        if not r.certified:
            notes.append(f"{r.condition}: {r.outcome} ({r.solver}, {r.solver_status})")
    if not rep.mss.exhaustive:
        notes.append(f"greedy vertex search ({rep.mss.vertices_evaluated} vertices)")
    return {
        "spectral_s": sec["spectral"],
        "build_s": build,
        "solve_s": solve,
        "crossval_s": sec["cross_validation"],
        "total_s": sum(sec.values()),
        "certified": certified,
        "nominal_gamma": rep.nominal.gamma if rep.nominal.certified else None,
        "robust_gamma": rep.robust.gamma if rep.robust.certified else None,
        "solvers_used": "+".join(used),
        "canon_s": canon,
        "solver_core_s": core,
        "th31_s": sec["theorem_3_1"],
        "th32_s": sec["theorem_3_2"],
        "lem41_s": sec["lemma_4_1"],
        "lmi_other_s": lmi_stages - build - solve,
        "spectral_evals": len(events["spectral"]),
        "solver_calls": len(solves),
        "note": "; ".join(notes),
    }


def _child(conn: Any, n: int, m: int, seed: int, uncertain: bool, solver: str | None, repeat_below: float) -> None:
    """Run one case and send ("result", row) (or ("error", text)) to the parent."""
    import resource

    warnings.simplefilter("ignore")
    try:
        from ftc_verify.analysis.analyze import analyze
        from ftc_verify.analysis.closedloop import state_feedback_loop
        from ftc_verify.analysis.lmi_size import decision_size

        # warm-up (not timed): lazy imports and first-call costs. Clarabel only: an SDPA
        # solve of another problem changes later SDPA answers in the same process
        # (sdpa-python 0.2.3; see README), so SDPA is only imported (preloaded).
        wsys, wgains, _ = make_case(2, 2, 0, True)
        analyze(state_feedback_loop(wsys, wgains), solver="clarabel")

        system, gains, draws = make_case(n, m, seed, uncertain)
        loop = state_feedback_loop(system, gains)
        conn.send(("variables", decision_size(loop, robust=True), draws))
        events: dict[str, Any] = {"solves": [], "spectral": []}
        _instrument(conn, events)
        runs = []
        for _ in range(3):
            events["solves"].clear()
            events["spectral"].clear()
            rep = analyze(loop, solver=solver, name=system.name)
            runs.append(_row_from_report(rep, events))
            # repeat only fast all-Clarabel runs: repeated SDPA solves in one process are
            # not reproducible (sdpa-python 0.2.3, see README)
            if runs[-1]["total_s"] >= repeat_below or "sdpa" in runs[-1]["solvers_used"]:
                break
        rows = sorted(runs, key=lambda r: r["total_s"])
        row = rows[len(rows) // 2]
        row["repeats"] = len(rows)
        row["variables"] = decision_size(loop, robust=True)
        row["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
        if draws > 1:
            row["note"] = (row["note"] + "; " if row["note"] else "") + f"draw {draws} of the seeded stream"
        if len(rows) > 1:
            row["note"] = (row["note"] + "; " if row["note"] else "") + \
                "median of " + ", ".join(f"{r['total_s']:.3f}" for r in sorted(rows, key=lambda r: r["total_s"])) + " s"
        conn.send(("result", row))
    except Exception as exc:  # reported as a row, never a crash of the benchmark
        import traceback

        conn.send(("error", f"{type(exc).__name__}: {exc}", traceback.format_exc(limit=3)))
    finally:
        conn.close()


def _child_paper(conn: Any) -> None:
    """The paper's example analysed in-process (warm), auto solver."""
    import resource

    warnings.simplefilter("ignore")
    try:
        from ftc_verify.analysis.analyze import analyze
        from ftc_verify.analysis.closedloop import state_feedback_loop
        from ftc_verify.analysis.lmi_size import decision_size
        from ftc_verify.model.files import load_system
        from ftc_verify.controllers.files import check_gains, load_gains

        system = load_system(str(REPO / "examples" / "paper.toml"))
        gains = check_gains(system, load_gains(str(REPO / "examples" / "paper_gains.toml")))
        loop = state_feedback_loop(system, gains)
        analyze(loop)  # warm-up
        events: dict[str, Any] = {"solves": [], "spectral": []}
        _instrument(conn, events)
        rows = []
        for _ in range(3):
            events["solves"].clear()
            events["spectral"].clear()
            rows.append(_row_from_report(analyze(loop, name=system.name), events))
        rows.sort(key=lambda r: r["total_s"])
        row = rows[1]
        row.update(repeats=3, variables=decision_size(loop, robust=True),
                   peak_rss_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
                   note=(row["note"] + "; " if row["note"] else "") + "warm, in-process; median of "
                   + ", ".join(f"{r['total_s']:.3f}" for r in rows) + " s")
        conn.send(("result", row))
    except Exception as exc:
        conn.send(("error", f"{type(exc).__name__}: {exc}", ""))
    finally:
        conn.close()


# --------------------------------------------------------------------------- parent side

class Runner:
    """Runs cases in forkserver children with a hard time limit."""

    def __init__(self) -> None:
        self.ctx = mp.get_context("forkserver")
        self.ctx.set_forkserver_preload(PRELOAD)

    def run(self, target: Any, args: tuple[Any, ...], timeout: float) -> dict[str, Any]:
        """Returns {"status": ok|timeout|error|crash, "row": ..., "progress": ...}."""
        recv, send = self.ctx.Pipe(duplex=False)
        proc = self.ctx.Process(target=target, args=(send, *args), daemon=True)
        start = time.perf_counter()
        proc.start()
        send.close()
        progress: dict[str, Any] = {"stages": {}, "spectral": [], "solves": [], "variables": None}
        result: dict[str, Any] = {"status": "crash", "row": None, "progress": progress, "elapsed": 0.0}
        deadline = start + timeout
        try:
            while True:
                left = deadline - time.perf_counter()
                if left <= 0:
                    result["status"] = "timeout"
                    break
                if not recv.poll(min(left, 1.0)):
                    if not proc.is_alive() and not recv.poll(0):
                        break
                    continue
                try:
                    msg = recv.recv()
                except EOFError:
                    break
                kind = msg[0]
                if kind == "spectral_eval":
                    progress["spectral"].append(msg[1])
                elif kind == "solve":
                    progress["solves"].append((msg[1], msg[2]))
                elif kind == "stage":
                    progress["stages"].setdefault(msg[1], []).append(msg[2])
                elif kind == "variables":
                    progress["variables"] = msg[1]
                elif kind == "result":
                    result.update(status="ok", row=msg[1])
                    break
                elif kind == "error":
                    result.update(status="error", row={"note": msg[1]})
                    break
        finally:
            result["elapsed"] = time.perf_counter() - start
            if proc.is_alive() and result["status"] != "ok":
                proc.kill()  # our own child, by its handle
            proc.join(10)
            recv.close()
        return result


def _median_cmd(cmd: Sequence[str], reps: int) -> tuple[float, list[float], int]:
    times, rc = [], 0
    for _ in range(reps):
        t = time.perf_counter()
        proc = subprocess.run(cmd, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        times.append(time.perf_counter() - t)
        rc = proc.returncode
    return statistics.median(times), times, rc


def _console_script() -> list[str]:
    exe = Path(sys.executable).parent / "ftc-verify"
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "ftc_verify"]


def startup_rows(reps: int) -> list[dict[str, Any]]:
    """Subprocess wall times: bare interpreter, the heavy imports, the paper via the CLI."""
    paper_cmd = _console_script() + ["analyze", "examples/paper.toml", "--gains", "examples/paper_gains.toml", "--json"]
    specs = [
        ("startup: python -c pass", [sys.executable, "-c", "pass"], None),
        ("startup: import control", [sys.executable, "-c", "import control"], None),
        ("paper-cli: " + " ".join(["ftc-verify"] + paper_cmd[len(_console_script()):]), paper_cmd, PAPER_GOAL_S),
    ]
    rows = []
    for label, cmd, goal in specs:
        med, times, rc = _median_cmd(cmd, reps)
        row: dict[str, Any] = {
            "case": label, "n": 2 if goal else "", "m": 2 if goal else "", "solver": "auto" if goal else "",
            "total_s": med, "status": "ok" if rc in (0,) else f"exit {rc}", "repeats": reps,
            "note": f"wall incl. start-up, median of {', '.join(f'{t:.3f}' for t in times)} s",
        }
        if goal:
            row.update(goal_s=goal, meets_goal=med < goal, certified=rc == 0)
        rows.append(row)
        print(f"  {label:<44} median {med:6.3f} s  ({', '.join(f'{t:.2f}' for t in times)})", flush=True)
    return rows


def fit_clarabel(points: list[tuple[int, float]]) -> tuple[float, float, int] | None:
    """Power law ``t = t0 (v / v0) ** p`` through the (variables, LMI seconds) of the
    largest measured Clarabel cases (up to 3 with v >= 100; p clamped to [1.5, 4]).
    With one point, p = 2.5. Returns ``(t0, p, v0)``."""
    pts = sorted((v, t) for v, t in points if v >= 100 and t > 0)[-3:]
    if not pts:
        return None
    v0, t0 = pts[-1]
    if len(pts) == 1 or pts[0][0] == v0:
        return t0, 2.5, v0
    x = np.log([v for v, _ in pts])
    y = np.log([t for _, t in pts])
    p = float(np.polyfit(x, y, 1)[0])
    return t0, min(4.0, max(1.5, p)), v0


def _partial_row(res: dict[str, Any], n: int, m: int) -> dict[str, Any]:
    """Row of a case stopped at its time limit: the stages it finished, the spectral
    evaluations it did, and a lower bound when it was stopped in the spectral stage."""
    prog = res["progress"]
    row: dict[str, Any] = {"total_s": res["elapsed"], "spectral_evals": len(prog["spectral"]),
                           "solver_calls": len(prog["solves"])}
    done = ", ".join(f"{k} {sum(v):.1f} s" for k, v in prog["stages"].items()) or "none"
    note = f"stopped after {res['elapsed']:.0f} s; stages finished: {done}"
    if "spectral" not in prog["stages"] and prog["spectral"]:
        per = statistics.mean(prog["spectral"])
        pairs = m * (m - 1)
        at_least = 2 * (pairs + 1) if 2 ** pairs > 256 and pairs >= 3 else 2 ** pairs
        row["spectral_s"] = sum(prog["spectral"])
        note += (f"; in the spectral stage: {len(prog['spectral'])} vertex evaluations at {per:.1f} s each, "
                 f"the stage needs >= {at_least} -> >= {at_least * per:.0f} s for the spectral test alone")
    elif "spectral" in prog["stages"]:
        row["spectral_s"] = sum(prog["stages"]["spectral"])
    row["_spectral_done"] = "spectral" in prog["stages"]
    row["note"] = note
    return row


def run_grid(args: argparse.Namespace, grid: list[tuple[int, int]], runner: Runner, out_rows: list[dict[str, Any]],
             flush: Any, blas: str) -> None:
    cases = sorted(grid, key=lambda nm: (variables_of(nm[0], nm[1], uncertain_default(*nm)), nm))
    clarabel_pts: list[tuple[int, float]] = []
    for n, m in cases:
        unc = {"all": True, "none": False}.get(args.uncertain, uncertain_default(n, m))
        base = {"case": "random", "n": n, "m": m, "seed": args.seed, "uncertain": unc, "blas_threads": blas,
                "variables": variables_of(n, m, unc)}
        goal = GOALS.get((n, m))
        auto_row: dict[str, Any] | None = None
        for solver in ("auto", "clarabel"):
            row = dict(base, solver=solver)
            if goal is not None:
                row["goal_s"] = goal
            limit = args.case_timeout
            pred_note = ""
            if solver == "clarabel":
                assert auto_row is not None
                why = ""
                fit = fit_clarabel(clarabel_pts)
                fixed = None  # seconds of the solver-independent stages, from the auto run
                status = auto_row.get("status")
                if status == "ok":
                    if auto_row["solvers_used"] != "clarabel":
                        fixed = auto_row["total_s"] - auto_row["build_s"] - auto_row["solve_s"]
                elif status == "timeout" and auto_row.get("_spectral_done"):
                    fixed = auto_row["spectral_s"]
                elif status == "timeout":
                    why = (f"skipped: the auto run was stopped after {auto_row.get('total_s', 0):.0f} s before finishing "
                           "the spectral test, which does not depend on the solver")
                else:
                    why = f"skipped: the auto run ended '{status}'"
                if fixed is not None and fit is not None:
                    t0, p, v0 = fit
                    lmi_pred = t0 * (row["variables"] / v0) ** p
                    pred = fixed + lmi_pred
                    pred_note = (f"extrapolated {pred:.0f} s = LMIs {lmi_pred:.0f} s (t = {t0:.2f} s * (v/{v0})^{p:.2f}, "
                                 f"fit to the measured Clarabel cases) + other stages {fixed:.0f} s (auto run)")
                    if pred > args.clarabel_limit:
                        why = f"skipped: {pred_note} > {args.clarabel_limit:.0f} s limit"
                elif fixed is not None and auto_row.get("status") != "ok":
                    why = f"skipped: the auto run ended '{auto_row.get('status')}' and no Clarabel case was measured to extrapolate from"
                if why:
                    row.update(status="skipped", note=why)
                    out_rows.append(row)
                    flush()
                    print(f"  n={n:<2} m={m} clarabel  {why}", flush=True)
                    continue
                limit = min(limit, 1.5 * args.clarabel_limit)
            res = runner.run(_child, (n, m, args.seed, unc, None if solver == "auto" else solver, args.repeat_below), limit)
            if res["status"] == "ok":
                row.update(res["row"], status="ok")
                row["note"] = "; ".join(x for x in (pred_note, res["row"]["note"]) if x)
                if goal is not None:
                    row["meets_goal"] = row["total_s"] < goal
            elif res["status"] == "timeout":
                row.update(_partial_row(res, n, m), status="timeout")
                if pred_note:
                    row["note"] = pred_note + "; " + row["note"]
                if goal is not None:
                    row["meets_goal"] = False
            else:
                row.update(status=res["status"], total_s=res["elapsed"], note=(res["row"] or {}).get("note", "child died"))
            if res["progress"]["variables"]:
                row["variables"] = res["progress"]["variables"]
            if solver == "auto":
                auto_row = row
            elif row["status"] == "ok":
                clarabel_pts.append((row["variables"], row["build_s"] + row["solve_s"]))
            out_rows.append(row)
            flush()
            print(f"  n={n:<2} m={m} {solver:<8} {row['status']:<7} total {row.get('total_s', float('nan')):8.2f} s"
                  f"  ({row.get('solvers_used', '-')})", flush=True)


# --------------------------------------------------------------------------- output

def _f(x: Any, w: int, d: int = 2) -> str:
    if x is None or x == "":
        return "-".rjust(w)
    if isinstance(x, bool):
        return ("yes" if x else "no").rjust(w)
    if isinstance(x, float):
        if not math.isfinite(x):
            return "-".rjust(w)
        return f"{x:{w}.{d}f}"
    return str(x).rjust(w)


def write_csv(path: Path, rows: list[dict[str, Any]]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    with open(tmp, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=COLUMNS, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()})
    os.replace(tmp, path)


def print_table(rows: list[dict[str, Any]]) -> None:
    hdr = (f"{'case':<10}{'n':>3}{'m':>3}{'vars':>6} {'unc':>3} {'solver':<9}{'used':<14}{'spectral':>9}{'build':>7}"
           f"{'solve':>8}{'canon':>7}{'core':>8}{'xval':>6}{'total':>8} {'cert':>4}{'g_nom':>8}{'g_rob':>8}"
           f"{'goal':>6} {'meets':<7}{'status':<8}")
    print(hdr)
    print("-" * len(hdr))
    for r in rows:
        if not str(r.get("case", "")).startswith(("random", "paper")):
            continue
        case = "paper" if str(r["case"]).startswith("paper") else "random"
        if str(r["case"]).startswith("paper-cli"):
            case = "paper-cli"
        unc = "" if r.get("uncertain", "") == "" else ("y" if r["uncertain"] else "n")
        print(f"{case:<10}{_f(r.get('n'), 3)}{_f(r.get('m'), 3)}{_f(r.get('variables'), 6)} {unc:>3} "
              f"{r.get('solver', '')!s:<9}{r.get('solvers_used', '') or '-'!s:<14}"
              f"{_f(r.get('spectral_s'), 9)}{_f(r.get('build_s'), 7)}{_f(r.get('solve_s'), 8)}"
              f"{_f(r.get('canon_s'), 7)}{_f(r.get('solver_core_s'), 8)}{_f(r.get('crossval_s'), 6)}"
              f"{_f(r.get('total_s'), 8)} {_f(r.get('certified'), 4)}{_f(r.get('nominal_gamma'), 8, 3)}"
              f"{_f(r.get('robust_gamma'), 8, 3)}{_f(r.get('goal_s'), 6, 1)} "
              f"{('MET' if r.get('meets_goal') else 'MISSED') if r.get('meets_goal', '') != '' else '':<7}"
              f"{r.get('status', ''):<8}")


def print_summary(rows: list[dict[str, Any]], wall: float) -> None:
    by = {(r.get("case"), r.get("n"), r.get("m"), r.get("solver")): r for r in rows}
    start = {r["case"]: r for r in rows if str(r.get("case", "")).startswith(("startup", "paper-cli"))}
    print("\nGoals")
    py = start.get("startup: python -c pass")
    imp = start.get("startup: import control")
    cli = next((r for k, r in start.items() if k.startswith("paper-cli")), None)
    paper = next((r for r in rows if r.get("case") == "paper (in-process)"), None)
    if cli:
        verdict = "MET" if cli.get("meets_goal") else "MISSED"
        print(f"  paper example via CLI (incl. start-up) < {PAPER_GOAL_S} s: {cli['total_s']:.2f} s  {verdict}")
        if imp and py:
            print(f"    of which: python start-up {py['total_s']:.2f} s, `import control` (the cross-check) "
                  f"{imp['total_s']:.2f} s (incl. start-up, {100 * imp['total_s'] / cli['total_s']:.0f}% of the CLI run)")
        if paper and paper.get("status") == "ok":
            print(f"    analyze() itself, warm in-process: {paper['total_s']:.3f} s "
                  f"(spectral {paper['spectral_s']:.3f}, LMI build {paper['build_s']:.3f}, solve {paper['solve_s']:.3f}, "
                  f"cross-validation {paper['crossval_s']:.3f})")
    for (n, m), goal in GOALS.items():
        r = by.get(("random", n, m, "auto"))
        if r is None:
            print(f"  n={n}, m={m} < {goal:g} s: not run")
            continue
        stages = ", ".join(f"{k.replace('_s', '')} {r[k]:.2f}" for k in ("spectral_s", "build_s", "solve_s", "crossval_s")
                           if isinstance(r.get(k), float))
        verdict = "MET" if r.get("meets_goal") else "MISSED"
        print(f"  n={n}, m={m} < {goal:g} s (auto, in-process): {r['total_s']:.2f} s  {verdict}  [{r['status']}; {stages}]")
        c = by.get(("random", n, m, "clarabel"))
        if c is not None and c.get("status") == "ok":
            print(f"    clarabel alone: {c['total_s']:.2f} s  {'MET' if c.get('meets_goal') else 'MISSED'}")
    print("\nClarabel vs auto (LMI build+solve time; total time)")
    for r in rows:
        if r.get("case") != "random" or r.get("solver") != "auto" or r.get("status") != "ok":
            continue
        c = by.get(("random", r["n"], r["m"], "clarabel"))
        a_lmi = r["build_s"] + r["solve_s"]
        if c is None or c.get("status") != "ok":
            why = (c or {}).get("status", "not run")
            print(f"  n={r['n']:<2} m={r['m']} vars {r['variables']:>5}: auto={r['solvers_used']:<14} LMI {a_lmi:7.2f} s; "
                  f"clarabel {why}" + (f" ({c['note']})" if c and c.get("note") else ""))
            continue
        c_lmi = c["build_s"] + c["solve_s"]
        print(f"  n={r['n']:<2} m={r['m']} vars {r['variables']:>5}: auto={r['solvers_used']:<14} LMI {a_lmi:7.2f} s, "
              f"clarabel {c_lmi:7.2f} s, ratio clarabel/auto {c_lmi / a_lmi:5.2f}; total {r['total_s']:.2f} vs {c['total_s']:.2f} s")
    for r in rows:
        if r.get("status") in ("timeout", "error", "crash") :
            print(f"\n  n={r.get('n')} m={r.get('m')} {r.get('solver')}: {r['status']}: {r.get('note', '')}")
    print(f"\nBenchmark wall time: {wall:.1f} s")


# --------------------------------------------------------------------------- main

def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="small grid, 1 start-up repetition (smoke run, < 30 s)")
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"CSV file (default {DEFAULT_OUT.relative_to(REPO)})")
    p.add_argument("--seed", type=int, default=1, help="seed of numpy.random.default_rng for every random case")
    p.add_argument("--case-timeout", type=float, default=150.0, help="hard limit per case in seconds (default 150)")
    p.add_argument("--clarabel-limit", type=float, default=120.0,
                   help="skip the clarabel-alone run when its predicted time exceeds this (default 120 s)")
    p.add_argument("--repeat-below", type=float, default=None,
                   help="cases faster than this are run 3 times and the median reported (default 1 s; 0 with --quick)")
    p.add_argument("--uncertain", choices=["default", "all", "none"], default="default",
                   help="uncertainty weights 0.05 I: default = on for m >= 3")
    p.add_argument("--only", default="", help="comma list of NxM cases to run instead of the grid, e.g. 8x3,12x4")
    p.add_argument("--no-startup", action="store_true", help="skip the subprocess start-up measurements")
    p.add_argument("--blas-threads", default="1",
                   help="OPENBLAS/OMP/MKL_NUM_THREADS for the in-process cases: a number, or 'default' to leave "
                        "the environment alone (default 1: multi-threaded OpenBLAS is 5-10x slower on a loaded "
                        "2-core machine; the start-up/CLI runs always use the environment as it is)")
    args = p.parse_args(argv)

    t_start = time.perf_counter()
    grid = QUICK_GRID if args.quick else GRID
    if args.repeat_below is None:
        args.repeat_below = 0.0 if args.quick else 1.0
    if args.only:
        grid = [tuple(int(v) for v in item.lower().split("x")) for item in args.only.split(",")]  # type: ignore[misc]
    rows: list[dict[str, Any]] = []

    def flush() -> None:
        write_csv(args.out, rows)

    print(f"ftc_verify analyze benchmark: seed {args.seed}, grid {grid}, case limit {args.case_timeout:.0f} s, "
          f"clarabel limit {args.clarabel_limit:.0f} s, python {sys.version.split()[0]}, {os.cpu_count()} cpus", flush=True)
    if not args.no_startup:
        print("Start-up (subprocess wall time):", flush=True)
        rows += startup_rows(1 if args.quick else 5)
        flush()
    if args.blas_threads != "default":
        for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
            os.environ[var] = str(int(args.blas_threads))  # inherited by the forkserver only
    blas = args.blas_threads if args.blas_threads != "default" else os.environ.get("OPENBLAS_NUM_THREADS", "default")
    runner = Runner()
    print("In-process analyze (one child process per case):", flush=True)
    res = runner.run(_child_paper, (), args.case_timeout)
    prow = {"case": "paper (in-process)", "n": 2, "m": 2, "seed": "", "solver": "auto", "uncertain": True,
            "status": res["status"], "blas_threads": blas}
    prow.update(res["row"] or {"total_s": res["elapsed"]})
    rows.append(prow)
    flush()
    print(f"  paper    auto     {prow['status']:<7} total {prow.get('total_s', float('nan')):8.3f} s", flush=True)
    run_grid(args, grid, runner, rows, flush, blas)
    wall = time.perf_counter() - t_start
    flush()
    print()
    print_table(rows)
    print_summary(rows, wall)
    print(f"CSV: {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
