"""Command-line interface: ``ftc-verify COMMAND ...`` (also ``python -m ftc_verify``).

Exit codes are a contract (README "Exit codes and what they promise"):

* 0 -- the claim holds (certified / pass / done) and its verdict line was printed;
* 1 -- a negative answer that was shown: instability, a bound exceeded, a failed check;
* 2 -- bad input: one line on stderr naming the field or file and the value, no
  traceback, no output written;
* 3 -- the exact spectral test says mean-square stable but no LMI certificate was found
  (neither a proof of stability nor of instability);
* 4 -- an internal error (a bug): one line on stderr, never a traceback;
* 130 / 143 -- interrupted by SIGINT / SIGTERM (temporary files removed);
* 141 -- the output pipe closed before the answer was printed (e.g. ``| head -1``).

Every command checks its output paths and options before any work starts.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import threading
import warnings
from collections.abc import Iterator, Sequence
from contextlib import contextmanager, nullcontext
from pathlib import Path
from typing import Any

from .. import __version__
from ..errors import FTCError

__all__ = ["main", "build_parser"]

EXIT_OK, EXIT_NEGATIVE, EXIT_BAD_INPUT, EXIT_UNCERTIFIED, EXIT_INTERNAL, EXIT_UNDECIDED = 0, 1, 2, 3, 4, 5
EXIT_INTERRUPTED, EXIT_PIPE, EXIT_TERMINATED = 130, 141, 143
#: Image formats ``--plot`` accepts (what matplotlib's Agg canvas writes).
PLOT_SUFFIXES = (".png", ".pdf", ".svg")


class _Terminated(BaseException):
    """Raised in the main thread by SIGTERM so that every ``finally`` cleans up."""


def _bad(message: str) -> "FTCError":
    from ..errors import ValidationError

    return ValidationError(message)


def _check_output_file(path: str, option: str, suffixes: tuple[str, ...] | None = None,
                       inputs: tuple[str, ...] = ()) -> None:
    """A file the command will write: not a folder, not one of the command's ``inputs``,
    in a writable folder, right suffix."""
    p = Path(path)
    for given in inputs:
        if p.resolve() == Path(given).resolve():
            raise _bad(f"{option} {path}: is the input file {given}; writing it would replace the input "
                       "(choose another output file)")
    if p.is_dir():
        raise _bad(f"{option} {path}: is a folder; give a file name")
    if suffixes is not None and p.suffix.lower() not in suffixes:
        raise _bad(f"{option} {path}: unsupported file type {p.suffix or '(none)'!r}; use one of {', '.join(suffixes)}")
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        raise _bad(f"{option} {path}: folder {parent} does not exist")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise _bad(f"{option} {path}: folder {parent} is not writable")


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # one line, exit 2, no usage dump
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message}\n")


def _fmt(x: float | None, digits: int = 6) -> str:
    return "-" if x is None else f"{x:.{digits}g}"


def _print_analysis(rep: Any, *, lmi: bool = True) -> None:
    d = rep.to_dict()
    mss = d["mss"]
    vert = f"worst of {mss['vertices_evaluated']} beta vertices" + ("" if mss["exhaustive"] else ", greedy search")
    print(f"ftc-verify analyze: {rep.name} ({rep.controller})")
    word = {"stable": "stable", "not stable": "NOT stable", "undecided": "UNDECIDED"}[mss["verdict"]]
    print(f"  mean-square stability    spectral abscissa {_fmt(mss['spectral_abscissa'])} ({vert}): {word}")
    print(f"      proved: {mss['verified_by']}")
    if not lmi:
        print("  LMI certificates         not requested (--no-lmi)")
    for label, res in (("Theorem 3.1 LMI", rep.mes_lmi), ("nominal gamma (Th. 3.2)", rep.nominal),
                       ("robust gamma (Lem. 4.1)", rep.robust)) if lmi else ():
        value = "" if res.gamma is None or label.startswith("Theorem") else f"{res.gamma:.6g}  "
        status = res.outcome + (f" ({res.solver}, status {res.solver_status})" if res.solver else "")
        print(f"  {label:<24} {value}{status}")
        if not res.certified and res.message:
            print(f"      {res.message}")
    print("  per joint mode (true, fdi): frozen poles, H-inf norm, python-control")
    for m in rep.per_mode:
        poles = ", ".join(f"{p.real:.4g}{p.imag:+.4g}j" if abs(p.imag) > 1e-12 else f"{p.real:.4g}" for p in m.poles)
        norm = "inf (unstable)" if m.hinf_norm == float("inf") else f"{m.hinf_norm:.6g}"
        print(f"    ({m.true_mode}, {m.fdi_mode})  poles [{poles}]  norm {norm}  {m.detail}")
    if rep.certified_stable:
        verdict = "certified stable"
    elif rep.mss.stable and not lmi:
        print("  verdict: stable by the exact spectral test (LMI certificates not requested: --no-lmi)")
        return
    elif rep.mss.stable:
        verdict = "stable by the exact spectral test, but NO LMI certificate found (not a proof either way)"
    elif rep.mss.undecided:
        verdict = ("UNDECIDED: neither stability nor instability could be proved at some beta vertex "
                   "(float64 and the higher-precision retries)")
    else:
        verdict = "NOT stable (proved at some beta vertex)"
    print(f"  verdict: {verdict}; certificates {'all passed' if rep.certificate_ok else 'NOT all passed'}")


def _load(system_path: str, controller_path: str | None) -> tuple[Any, Any]:
    """The system and (when a path is given) the controller checked against it."""
    from ..controllers.files import load_controller
    from ..model.files import load_system

    system = load_system(system_path)
    if controller_path is None:
        return system, None
    return system, load_controller(controller_path).check(system, source=str(controller_path))


def _strict(value: Any) -> Any:
    """JSON-ready with every non-finite float replaced by ``None`` (strict JSON)."""
    from ..analysis.analyze import json_ready

    return json_ready(value)


def _cmd_analyze(args: argparse.Namespace) -> int:
    from ..analysis.analyze import analyze
    from ..analysis.closedloop import closed_loop

    system, controller = _load(args.system, args.controller)
    rep = analyze(closed_loop(system, controller), solver=args.solver, name=system.name, lmi=not args.no_lmi)
    if args.json:
        print(json.dumps(rep.to_dict() | {"lmi_requested": not args.no_lmi}, indent=2, allow_nan=False))
    else:
        _print_analysis(rep, lmi=not args.no_lmi)
    if rep.certified_stable or (args.no_lmi and rep.mss.stable):
        return EXIT_OK
    if rep.mss.undecided:
        return EXIT_UNDECIDED
    return EXIT_UNCERTIFIED if rep.mss.stable else EXIT_NEGATIVE


def _positive(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not (value > 0 and value < float("inf")):
        raise argparse.ArgumentTypeError(f"must be positive and finite, got {text!r}")
    return value


def _nonneg_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be 0 or more, got {text!r}")
    return value


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {text!r}")
    return value


def _seed(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer seed: {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"seeds are non-negative, got {text!r}")
    return value


#: Fewest communication steps a horizon must cover (shorter runs measure nothing).
MIN_STEPS = 10


def _check_horizon(step: float, horizon: float) -> None:
    if horizon < MIN_STEPS * step:
        raise _bad(f"--horizon {horizon:g}: must cover at least {MIN_STEPS} steps of --step {step:g} "
                   f"(at least {MIN_STEPS * step:g})")


#: Bytes per recorded number of a path record: the float64 arrays measured 8.05 bytes per
#: number at peak (tracemalloc, reference backend, 100 paths of the paper example); twice
#: that leaves room for the FMU backend's buffers and the plot.
RECORD_BYTES_PER_NUMBER = 16


def _check_records_memory(system: Any, controller: Any, paths: int, horizon: float, step: float) -> None:
    """Refuse before simulating when the kept trajectories would not fit in memory."""
    from ..limits import check_memory

    n, nu, ny, nw = system.dims
    jumps = 2.0 * horizon * float(max(-system.chain.alpha.min(), system.chain.beta_max.max()))
    points = horizon / step + jumps + 2
    numbers = n + nu + ny + nw + controller.n_c + controller.n_v + 3
    check_memory(paths * points * numbers * RECORD_BYTES_PER_NUMBER,
                 f"{paths} recorded paths of about {points:.3g} grid points each",
                 hint="use fewer --paths, a shorter --horizon or a larger --step")


def _check_fmu_dims(system: Any, source: str) -> None:
    """The FMU has one Delta input per channel: the modes must agree on its shape."""
    from ..plants.linear_jump import fmu_dims

    try:
        fmu_dims(system)
    except FTCError as exc:
        raise _bad(f"{source}: {exc}") from None


def _cmd_simulate(args: argparse.Namespace) -> int:
    import numpy as np

    from ..model.system import FTCSystem, JointChain
    from ..simulation.delta import DeltaSchedule
    from ..simulation.paths import sample_paths

    _check_horizon(args.step, args.horizon)
    if args.plot:
        _check_output_file(args.plot, "--plot", PLOT_SUFFIXES)
    _check_cluster(args)
    system, controller = _load(args.system, args.controller)
    record = max(args.record, 1 if args.plot else 0)
    kept = args.paths if args.backend == "fmu" else min(record, args.paths)  # the reference backend streams
    _check_records_memory(system, controller, kept, args.horizon, args.step)
    plant = _load_plant(args, system)
    if args.backend == "fmu" and plant is None:
        _check_fmu_dims(system, args.system)
    if args.fault_during_delay:
        ch = system.chain
        system = FTCSystem(system.name, system.modes, JointChain(ch.alpha, ch.beta_min, ch.beta_max, True))
    seed = args.seed if args.seed is not None else int(np.random.SeedSequence().entropy % 2**63)
    beta = {"random": None, "min": system.chain.beta_min, "max": system.chain.beta_max,
            "mid": system.chain.midpoint()}[args.beta]
    paths = sample_paths(system.chain, args.horizon, args.paths, seed, beta=beta)
    delta = DeltaSchedule(args.delta if system.uncertain and (plant is None or plant.delta1 or plant.delta2) else "zero")
    from ..simulation.batches import fmu_monte_carlo, progress_bar
    from ..simulation.cluster import open_client
    from ..simulation.streaming import simulate_streaming

    bar = progress_bar(args.paths, f"simulate ({args.backend})", sys.stderr.isatty())
    done = None if bar is None else bar.update
    try:
        with open_client(args.workers, args.scheduler) as client:
            if args.backend == "fmu":
                res = fmu_monte_carlo(system, controller, paths, step=args.step, delta=delta,
                                      disturbance=args.disturbance, seed=seed, plant=plant, client=client,
                                      log=_fmu_logger(args), done=done)
            else:
                res = simulate_streaming(system, controller, paths, step=args.step, disturbance=args.disturbance,
                                         delta=delta, seed=seed, record=record, client=client, done=done)
    finally:
        if bar is not None:
            bar.close()
    if args.plot:
        from ..verification.plots import plot_path

        plot_path(res.records[0], args.plot, title=f"{system.name}: path 1 ({args.backend}, seed {seed})")
    d = _strict(res.to_dict())
    verdict = "fail (a path diverged)" if d["divergence"] else "done"
    if args.json:
        print(json.dumps(d | {"verdict": "fail" if d["divergence"] else "done"}, indent=2, allow_nan=False))
    else:
        _print_simulation(d, res, system.name, args, delta.kind)
        print(f"  verdict: {verdict}")
    return EXIT_NEGATIVE if d["divergence"] else EXIT_OK


def _print_simulation(d: dict[str, Any], res: Any, name: str, args: argparse.Namespace, delta: str) -> None:
    """The text summary of ``simulate`` (norms over the paths that did not diverge)."""
    import numpy as np

    print(f"ftc-verify simulate: {name}, backend {res.backend}, {len(d['y_norm'])} paths, horizon {args.horizon:g}, "
          f"step {args.step:g}, seed {res.seed}, disturbance {args.disturbance}, Delta {delta}")
    if res.backend == "fmu":
        print(f"  FMU {d['fmu']} (model identifier {d['model_identifier']}); jump times moved by at most "
              f"{res.options['timing_error']:.3g} to the FMU's step grid")
    ok = [k for k, y in enumerate(d["y_norm"]) if y is not None]
    if d["divergence"]:
        print(f"  DIVERGED: {d['divergence']}")
    if ok:
        y, w = np.array([d["y_norm"][k] for k in ok]), np.array([d["w_norm"][k] for k in ok])
        print(f"  ||w||_2 = {np.mean(w):.6g} (mean over {len(ok)} paths)")
        print(f"  ||y||_2: mean {np.mean(y):.6g}, min {np.min(y):.6g}, max {np.max(y):.6g}")
        print(f"  ||y||_2/||w||_2: mean {np.mean(y / w):.6g}, max {np.max(y / w):.6g}")
    sw = d["switches"]
    print(f"  switches per path: fault {np.mean([s['fault'] for s in sw]):.3g}, FDI {np.mean([s['fdi'] for s in sw]):.3g} (mean)")
    if args.plot:
        print(f"  plot written to {args.plot}")


def _load_plant(args: argparse.Namespace, system: Any) -> Any:
    """The ``--plant`` map checked against the system (None without ``--plant``)."""
    if getattr(args, "plant", None) is None:
        return None
    if getattr(args, "backend", "fmu") != "fmu":
        raise _bad(f"--plant {args.plant}: a plant map is co-simulated; it needs --backend fmu")
    from ..plants.plant_map import check_against_system, load_plant_map

    plant = load_plant_map(args.plant)
    check_against_system(plant, system)
    plant.require_states_op("co-simulation")
    return plant


def _fmu_logger(args: argparse.Namespace) -> Any:
    """With ``--fmu-log``: print every message the FMU logs to stderr."""
    if not getattr(args, "fmu_log", False):
        return None

    def log(status: str, category: str, message: str) -> None:
        print(f"[FMU {status}] {category}: {message}", file=sys.stderr)

    return log


def _cmd_verify(args: argparse.Namespace) -> int:
    from ..verification.report import check_out_dir, write_report
    from ..verification.verify import run_verify

    if args.paths < 2:
        raise _bad(f"--paths {args.paths}: the Monte Carlo bound needs at least 2 paths")
    _check_horizon(args.step, args.horizon)
    check_out_dir(args.out)
    system, controller = _load(args.system, args.controller)
    plant = _load_plant(args, system)
    if plant is None:
        _check_fmu_dims(system, args.system)
    if controller is not None:
        _check_records_memory(system, controller, args.paths, args.horizon, args.step)
    _check_cluster(args)
    k_max = None if args.no_gain_bound else args.k_max
    from ..simulation.cluster import open_client

    with open_client(args.workers, args.scheduler) as client:
        rep = run_verify(system, gamma=args.gamma, method=args.method, k_max=k_max, controller=controller,
                         paths=args.paths, step=args.step, horizon=args.horizon, seed=args.seed, solver=args.solver,
                         progress=sys.stderr.isatty(), plant=plant, fmu_log=_fmu_logger(args),
                         measure=args.measure, client=client)
    written = write_report(rep, args.out)
    d = rep.to_dict()
    print(f"ftc-verify verify: {system.name}")
    for c in d["checks"]:
        print(f"  [{'pass' if c['ok'] else 'FAIL'}] {c['name']}: {c['detail']}")
    print(f"  report: {', '.join(str(p) for p in written)}")
    print(f"  verdict: {d['verdict']}")
    if rep.verdict == "pass":
        return EXIT_OK
    if rep.analysis is not None and rep.analysis.mss.undecided:
        return EXIT_UNDECIDED
    stable_uncertified = rep.gamma_certified is None and rep.analysis is not None and rep.analysis.mss.stable
    return EXIT_UNCERTIFIED if stable_uncertified else EXIT_NEGATIVE


def _cmd_build_fmus(args: argparse.Namespace) -> int:
    from ..plants.linear_jump import FMUError, build_binary, build_fmu, validate
    from ..model.files import load_system

    lib = build_binary(force=args.force)
    print(f"binary: {lib}")
    systems = args.systems or []
    for path in systems:
        fmu = build_fmu(load_system(path))
        problems = validate(fmu)
        if problems:
            raise FMUError(f"{fmu}: validation found problems: {'; '.join(problems)}")
        print(f"{path}: {fmu} (validated, no problems)")
    print(f"verdict: built ({len(systems)} FMU{'s' if len(systems) != 1 else ''} validated)")
    return EXIT_OK


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``ftc-verify``."""
    p = _Parser(prog="ftc-verify", description=__doc__.splitlines()[0])
    p.add_argument("--version", action="version", version=f"ftc-verify {__version__}")
    sub = p.add_subparsers(dest="command", required=True, parser_class=_Parser)
    a = sub.add_parser("analyze", help="analyse a closed loop: exact MSS, certified LMIs, cross-validation")
    a.add_argument("system", help="system TOML file")
    a.add_argument("--controller", "--gains", dest="controller", required=True,
                   help="controller TOML file: [[gain]] K (state feedback) or [[controller]] Ac, Bc, Cc, Dc "
                        "(dynamic output feedback), one table per FDI mode; --gains is an alias")
    a.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    a.add_argument("--solver", default="auto", choices=["auto", "clarabel", "sdpa", "scs"],
                   help="LMI solver (default: auto = clarabel at every size; sdpa and scs on request)")
    a.add_argument("--no-lmi", action="store_true",
                   help="only the exact spectral test and the per-mode cross-check (no LMI certificates): "
                        "for loops whose LMIs would not fit in memory or time")
    a.set_defaults(func=_cmd_analyze)

    m = sub.add_parser("simulate", help="simulate the sampled-data loop under Markov faults and delayed FDI")
    m.add_argument("system", help="system TOML file")
    m.add_argument("--controller", "--gains", dest="controller", required=True,
                   help="controller TOML file (static gains or dynamic; --gains is an alias)")
    m.add_argument("--backend", default="fmu", choices=["fmu", "reference"])
    m.add_argument("--paths", type=_positive_int, default=10)
    m.add_argument("--horizon", type=_positive, default=30.0)
    m.add_argument("--step", type=_positive, default=0.01, help="control period h (sample-and-hold)")
    m.add_argument("--seed", type=_seed, default=None, help="seed of the numpy Generator (recorded in the output)")
    m.add_argument("--disturbance", default="paper", choices=["paper", "zero", "step", "pulse", "sine"])
    m.add_argument("--record", type=_nonneg_int, default=0,
                   help="reference backend: keep full trajectories of the first N paths (default 0, 1 with --plot); "
                        "every path's norms are computed either way, vectorised and in batches")
    _cluster_options(m)
    m.add_argument("--beta", default="random", choices=["random", "min", "max", "mid"],
                   help="detection rates: drawn per path in their box (default) or fixed")
    m.add_argument("--delta", default="zero", choices=["zero", "random", "sign", "constant"],
                   help="time-varying uncertainty (random: a new Delta per chain segment)")
    m.add_argument("--fault-during-delay", action="store_true",
                   help="named variant: faults keep occurring during a detection delay (not the paper's model)")
    m.add_argument("--json", action="store_true")
    m.add_argument("--plot", default=None, help="PNG file for the paper's Fig. 1 of the first path")
    _plant_options(m)
    m.set_defaults(func=_cmd_simulate)

    v = sub.add_parser("verify", help="the main job: synthesize, certify, cross-validate, co-simulate, report")
    v.add_argument("system", help="system TOML file")
    v.add_argument("--gamma", type=_positive, default=None, help="attenuation level (default: minimise)")
    v.add_argument("--method", default="iterative", choices=["two-step", "iterative", "full-info", "common"])
    v.add_argument("--controller", "--gains", dest="controller", default=None,
                   help="verify this controller file (static gains or dynamic) instead of synthesizing; "
                        "--gains is an alias")
    v.add_argument("--k-max", type=_positive, default=30.0, help="gain norm bound for synthesis (default 30)")
    v.add_argument("--no-gain-bound", action="store_true", help="synthesize without a gain bound")
    v.add_argument("--paths", type=_positive_int, default=200, help="Monte Carlo paths on the FMU (default 200)")
    v.add_argument("--step", type=_positive, default=0.01)
    v.add_argument("--horizon", type=_positive, default=30.0)
    v.add_argument("--seed", type=_seed, default=None)
    v.add_argument("--out", default="ftc-verify-report", help="output folder (default ./ftc-verify-report)")
    v.add_argument("--solver", default="auto", choices=["auto", "clarabel", "sdpa", "scs"])
    v.add_argument("--measure", default="total", choices=["total", "incremental"],
                   help="Monte Carlo ratio of the real paths (total, default) or of each path's response to w "
                        "alone, y(w) - y(w = 0) on the same path (incremental: for plants whose faults move the "
                        "equilibrium)")
    _plant_options(v)
    _cluster_options(v)
    v.set_defaults(func=_cmd_verify)

    b = sub.add_parser("build-fmus", help="compile the plant FMU binary (and FMUs for given systems), validate")
    b.add_argument("systems", nargs="*", help="system TOML files to build FMUs for")
    b.add_argument("--force", action="store_true", help="recompile even when the cached binary is up to date")
    b.set_defaults(func=_cmd_build_fmus)
    from .plant_commands import add_plant_commands
    from .synthesis_commands import add_synthesis_command

    add_synthesis_command(sub)
    add_plant_commands(sub)
    return p


def _check_cluster(args: argparse.Namespace) -> None:
    if args.fmu_log and (args.workers or args.scheduler):
        raise _bad("--fmu-log: the FMU's messages stay on the Dask workers; leave out --workers/--scheduler to see them")


def _cluster_options(parser: argparse.ArgumentParser) -> None:
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--workers", type=_positive_int, default=None,
                       help="run the Monte Carlo batches on a local Dask cluster of N worker processes")
    where.add_argument("--scheduler", default=None,
                       help="run the Monte Carlo batches on the Dask cluster at this address (tcp://host:port)")


def _plant_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--plant", default=None,
                        help="plant map TOML file: co-simulate this FMU instead of the built LinearJumpPlant")
    parser.add_argument("--fmu-log", action="store_true", help="print the FMU's log messages to stderr")


@contextmanager
def _sigterm_raises() -> Iterator[None]:
    """While the command runs, SIGTERM raises :class:`_Terminated` in the main thread so
    that cleanup runs as for Ctrl-C; the previous handler is restored afterwards."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum: int, frame: Any) -> None:
        raise _Terminated()

    previous = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _closed_pipe() -> int:
    """stdout's reader went away: silence the final flush and report exit 141."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):
        pass
    print("ftc-verify: output pipe closed before the answer was printed", file=sys.stderr)
    return EXIT_PIPE


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit code (module docstring).

    Unless set by the caller, BLAS runs single-threaded (``OPENBLAS_NUM_THREADS=1``; set
    before numpy is first imported): these problems are small, and on a busy 2-core
    machine threaded OpenBLAS made small matrix exponentials 1000x slower (measured).
    """
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")
    args = build_parser().parse_args(argv)
    try:
        from .working import working

        own_bars = args.command in ("simulate", "verify")  # tqdm bars over their paths
        with _sigterm_raises(), warnings.catch_warnings(), nullcontext() if own_bars else working(args.command):
            warnings.simplefilter("ignore")  # solver chatter; statuses are reported in the results
            code = int(args.func(args))
            sys.stdout.flush()
            return code
    except FTCError as exc:
        print(f"ftc-verify: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except BrokenPipeError:
        return _closed_pipe()
    except KeyboardInterrupt:
        print("ftc-verify: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except _Terminated:
        print("ftc-verify: terminated", file=sys.stderr)
        return EXIT_TERMINATED
    except MemoryError:
        print("ftc-verify: error: out of memory (the problem is too large for this machine)", file=sys.stderr)
        return EXIT_BAD_INPUT
    except Exception as exc:  # a bug: one line, never a traceback, never exit 0 or 1
        print(f"ftc-verify: internal error: {type(exc).__name__}: {exc} (please report)", file=sys.stderr)
        return EXIT_INTERNAL


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
