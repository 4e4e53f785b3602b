"""The run commands of the CLI: ``ftc-verify simulate`` and ``ftc-verify verify``.

Both follow the exit-code contract of :mod:`ftc_verify.cli.main`. A plant FMU that fails
during a run is a result, not bad input: a path on which the FMU returned ``fmi2Error``
or ``fmi2Discard`` is reported as failed (like a diverged path), and a plant FMU that
crashes or returns ``fmi2Fatal`` (:class:`~ftc_verify.errors.PlantRunError`) ends the
Monte Carlo with the FMU, the path and the time named; both give exit 1, with the JSON
(``simulate --json``) or the report (``verify``) written.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from ..errors import FTCError, PlantRunError
from ..jsonable import dumps
from .export_commands import add_controller_fmu_option, load_loop
from .common import (EXIT_NEGATIVE, EXIT_OK, EXIT_UNCERTIFIED, EXIT_UNDECIDED, PLOT_SUFFIXES, add_connect_timeout, bad,
                     check_output_file, connect_timeout, gamma_level, nonneg_int, positive, positive_int, seed_int,
                     strict)

if TYPE_CHECKING:
    from ..simulation.paths import ChainPath
    from ..simulation.records import SimulationResult
    from ..simulation.streaming import StreamedResult

__all__ = ["add_run_commands"]


#: Fewest communication steps a horizon must cover (shorter runs measure nothing).
MIN_STEPS = 10


def _check_horizon(step: float, horizon: float, option: str = "--step") -> None:
    if horizon < MIN_STEPS * step:
        raise bad(f"--horizon {horizon:g}: must cover at least {MIN_STEPS} steps of {option} {step:g} "
                   f"(at least {MIN_STEPS * step:g})")


def _load_with_step(args: argparse.Namespace) -> tuple[Any, Any]:
    """:func:`~ftc_verify.cli.export_commands.load_loop`, then ``args.step`` resolved
    (:func:`_resolve_step`); an exported controller FMU is checked against the step
    given (``--period``, ``--step``, else the default)."""
    if getattr(args, "controller_fmu", None) is not None and args.step is None:
        from .export_commands import DEFAULT_STEP

        args.step = args.period if args.period is not None else DEFAULT_STEP
    system, controller = load_loop(args)
    _resolve_step(args, controller)
    return system, controller


def _resolve_step(args: argparse.Namespace, controller: Any) -> None:
    """``args.step`` from ``--period``, ``--step`` or the controller file's period
    (:func:`~ftc_verify.cli.sampled_lines.resolve_step`), checked against ``--horizon``."""
    from .sampled_lines import resolve_step

    if args.period is not None or args.step is not None:
        option = "--period" if args.period is not None else "--step"
    elif controller is not None and controller.period is not None:
        option = f"the period in {args.controller}"
    else:
        option = "the default step"
    args.step = resolve_step(args, controller)
    _check_horizon(args.step, args.horizon, option)


def _check_fmu_dims(system: Any, source: str) -> None:
    """The FMU has one Delta input per channel: the modes must agree on its shape."""
    from ..plants.linear_jump import fmu_dims

    try:
        fmu_dims(system)
    except FTCError as exc:
        raise bad(f"{source}: {exc}") from None


def _cmd_simulate(args: argparse.Namespace) -> int:
    from ..simulation.spec import SimulationSpec
    from .sampled_lines import check_period_option

    check_period_option(args)
    if args.step is not None or args.period is not None:
        _check_horizon(args.period or args.step, args.horizon, "--period" if args.period else "--step")
    if args.plot:
        check_output_file(args.plot, "--plot", PLOT_SUFFIXES)
    _check_cluster(args)
    system, controller = _load_with_step(args)
    record = max(args.record, 1 if args.plot else 0)
    # the reference backend streams: its records, and one path's worth of grid (a batch's time
    # grid, a diverged path simulated again with its record), besides every path's summary
    kept = args.paths if args.backend == "fmu" else max(1, min(record, args.paths))
    spec = SimulationSpec(step=args.step, horizon=args.horizon, n_paths=args.paths, seed=args.seed,
                          disturbance=args.disturbance, delta=args.delta, record=record, workers=args.workers,
                          scheduler=args.scheduler, connect_timeout=connect_timeout(args))
    spec.check_memory(system, controller, kept, summaries=args.paths)
    plant = _load_plant(args, system, controller)
    if args.backend == "fmu" and plant is None:
        _check_fmu_dims(system, args.system)
    if args.fault_during_delay:
        system = dataclasses.replace(system, chain=dataclasses.replace(system.chain, fault_during_delay=True))
    beta = {"random": None, "min": system.chain.rate_min, "max": system.chain.rate_max,
            "mid": system.chain.midpoint()}[args.beta]
    spec, _ = dataclasses.replace(spec, beta=beta).with_seed().resolve_delta(system, plant)
    seed = spec.seed
    paths: Sequence[ChainPath]
    if args.backend == "fmu":
        paths = spec.sample_paths(system.chain)
    else:  # the reference backend samples each batch where it runs: in turn here, or on the Dask workers
        paths = spec.path_spec(system.chain)
    from ..simulation.batches import fmu_monte_carlo, progress_bar
    from ..simulation.streaming import simulate_streaming

    bar = progress_bar(args.paths, f"simulate ({args.backend})", sys.stderr.isatty())
    done = None if bar is None else bar.update
    res: SimulationResult | StreamedResult
    try:  # the reference backend simulates its first batches here while a local cluster starts
        with spec.client(wait=args.backend == "fmu") as client:
            if args.backend == "fmu":
                res = fmu_monte_carlo(system, controller, paths, spec=spec, plant=plant, client=client,
                                      log=_fmu_logger(args), done=done)
            else:
                res = simulate_streaming(system, controller, paths, spec=spec, client=client, done=done)
    except PlantRunError as exc:
        return _plant_failed(exc, args, system.name, seed)
    finally:
        if bar is not None:
            bar.close()
    if args.plot:
        from ..verification.plots import plot_path

        plot_path(res.records[0], args.plot, title=f"{system.name}: path 1 ({args.backend}, seed {seed})")
    d = strict(res.to_dict())
    verdict = "fail (a path diverged or the plant FMU failed)" if d["divergence"] else "done"
    if args.json:
        print(dumps(d | {"fdi_model": system.chain.describe(), "verdict": "fail" if d["divergence"] else "done"}))
    else:
        _print_simulation(d, res, system.name, args, spec.schedule.kind)
        print(f"  {system.chain.describe()}")
        print(f"  verdict: {verdict}")
    return EXIT_NEGATIVE if d["divergence"] else EXIT_OK


def _plant_failed(exc: PlantRunError, args: argparse.Namespace, name: str, seed: int | None) -> int:
    """``simulate`` when the plant FMU crashed or returned fmi2Fatal: the failure, exit 1."""
    if args.json:
        failure = {"fmu": exc.fmu, "path": exc.path, "time": exc.time, "detail": exc.detail}
        print(dumps({"backend": args.backend, "seed": seed, "plant_failure": failure, "verdict": "fail"}))
    else:
        print(f"ftc-verify simulate: {name}, backend {args.backend}, seed {seed}")
        print(f"  PLANT FMU FAILED: {exc}")
        print("  verdict: fail (the plant FMU failed; the run stopped there)")
    return EXIT_NEGATIVE


def _print_simulation(d: dict[str, Any], res: Any, name: str, args: argparse.Namespace, delta: str) -> None:
    """The text summary of ``simulate`` (norms over the paths that did not diverge)."""
    import numpy as np

    print(f"ftc-verify simulate: {name}, backend {res.backend}, {len(d['y_norm'])} paths, horizon {args.horizon:g}, "
          f"step {args.step:g}, seed {res.seed}, disturbance {args.disturbance}, Delta {delta}")
    if res.backend == "fmu":
        print(f"  FMU {d['fmu']} (model identifier {d['model_identifier']}); jump times moved by at most "
              f"{res.options['timing_error']:.3g} to the FMU's step grid")
        if res.options.get("controller_fmu"):
            print(f"  controller FMU {res.options['controller_fmu']} (u and x_c computed by the exported controller)")
    ok = [k for k, y in enumerate(d["y_norm"]) if y is not None]
    if d["divergence"]:
        print(f"  DIVERGED OR FAILED: {d['divergence']}")
    if ok:
        y, w = np.array([d["y_norm"][k] for k in ok]), np.array([d["w_norm"][k] for k in ok])
        print(f"  ||w||_2 = {np.mean(w):.6g} (mean over {len(ok)} paths)")
        print(f"  ||y||_2: mean {np.mean(y):.6g}, min {np.min(y):.6g}, max {np.max(y):.6g}")
        print(f"  ||y||_2/||w||_2: mean {np.mean(y / w):.6g}, max {np.max(y / w):.6g}")
    sw = d["switches"]
    print(f"  switches per path: fault {np.mean([s['fault'] for s in sw]):.3g}, FDI {np.mean([s['fdi'] for s in sw]):.3g} (mean)")
    if args.plot:
        print(f"  plot written to {args.plot}")


def _load_plant(args: argparse.Namespace, system: Any, controller: Any) -> Any:
    """The ``--plant`` map checked against the system and, when given, the controller
    (None without ``--plant``): every mismatch is refused before any work starts."""
    if getattr(args, "plant", None) is None:
        return None
    if getattr(args, "backend", "fmu") != "fmu":
        raise bad(f"--plant {args.plant}: a plant map is co-simulated; it needs --backend fmu")
    from ..plants.plant_map import check_against_system, check_controller, load_plant_map

    plant = load_plant_map(args.plant)
    check_against_system(plant, system)
    if controller is not None:
        check_controller(plant, controller, args.controller)
    plant.require_states_op("co-simulation")
    return plant


def _fmu_logger(args: argparse.Namespace) -> Any:
    """With ``--fmu-log``: print every message the FMU logs to stderr."""
    if not getattr(args, "fmu_log", False):
        return None

    def log(status: str, category: str, message: str) -> None:
        print(f"[FMU {status}] {category}: {message}", file=sys.stderr)

    return log


def _risk_stage() -> Any:
    """``verify``'s risk stage (``ftc_verify.risk.verify_stage``), ``None`` when the risk
    package is not installed."""
    try:
        from ..risk.verify_stage import verify_risk_stage
    except ModuleNotFoundError:
        return None
    return verify_risk_stage


def _cmd_verify(args: argparse.Namespace) -> int:
    """``verify``. This process only computes and writes files: scipy's and matplotlib's
    import-time docstring generation is switched off first
    (:func:`~ftc_verify.prestart.skip_docstring_generation`, as in the cross-check child;
    only ``__doc__`` strings change), before ``scipy.stats`` and matplotlib are imported:
    about 0.3 s of CPU on the way to the first stage (issue 37)."""
    from ..prestart import skip_docstring_generation
    from .common import with_cross_check

    skip_docstring_generation()
    procs = _plant_processes(args)
    try:
        return with_cross_check(args, lambda a, watch, check: _verify_command(a, watch, check, procs),
                                "ftc_verify.verification.verify")
    finally:
        for proc in procs:
            proc.close()


def _plant_processes(args: argparse.Namespace) -> list[Any]:
    """The Monte Carlo's plant processes (:func:`~ftc_verify.simulation.isolated.plant_processes`),
    started first, so that their interpreters start beside this process's imports, when it
    runs on this machine (no ``--workers``/``--scheduler``); ``run_verify`` uses and closes them."""
    if args.workers or args.scheduler:
        return []
    from ..simulation.isolated import plant_processes

    return list(plant_processes())


def _verify_command(args: argparse.Namespace, watch: Any, check: Any, procs: list[Any] | None = None) -> int:
    from ..simulation.spec import SimulationSpec
    from ..verification.report import EarlyFigures, check_out_dir, write_report
    from ..verification.verify import run_verify

    from .sampled_lines import check_period_option

    if args.paths < 2:
        raise bad(f"--paths {args.paths}: the Monte Carlo bound needs at least 2 paths")
    check_period_option(args)
    if args.step is not None or args.period is not None:
        _check_horizon(args.period or args.step, args.horizon, "--period" if args.period else "--step")
    check_out_dir(args.out)
    _check_cluster(args)
    system, controller = _load_with_step(args)
    plant = _load_plant(args, system, controller)
    if plant is None:
        _check_fmu_dims(system, args.system)
    spec = SimulationSpec(step=args.step, horizon=args.horizon, n_paths=args.paths, seed=args.seed,
                          delta="random", delta_explicit=False, workers=args.workers, scheduler=args.scheduler,
                          connect_timeout=connect_timeout(args))
    sampled_loop = None  # built once, for the memory check and the sampled stages
    if args.h_max_work is not None and controller is not None:  # refused before any work, as analyze
        from ..analysis.moments.sampled import SampledLoop
        from ..analysis.moments.sampled_cover import cubic_memory
        from ..analysis.moments.sampled_refine import check_refine

        sampled_loop = SampledLoop.build(system, controller)
        check_refine(system, controller, args.step, args.h_max_work, loop=sampled_loop)
        # the refinement runs in the sampled-loop child while the Monte Carlo keeps its records
        spec.check_memory(system, controller, args.paths,
                          beside=(cubic_memory(sampled_loop), "the h_max refinement's clock program beside them"))
    elif controller is not None:
        spec.check_memory(system, controller, args.paths)
    k_max = None if args.no_gain_bound else args.k_max
    watch.mark("imports_and_load")
    figures = EarlyFigures(args.out)  # drawn while the sampled-loop stages finish in their child
    try:
        with spec.client() as client:  # started before the synthesis: a bad cluster is refused before any work
            watch.mark("cluster_start")
            rep = run_verify(system, gamma=args.gamma, method=args.method, k_max=k_max, controller=controller,
                             spec=spec, solver=args.solver, progress=sys.stderr.isatty(), plant=plant,
                             fmu_log=_fmu_logger(args), measure=args.measure, client=client, cross_check=check,
                             risk=_risk_stage(), meanwhile=figures, processes=procs, h_max_work=args.h_max_work,
                             sampled_loop=sampled_loop)
            watch.mark("stages")
        watch.mark("cluster_stop")
        written = write_report(rep, args.out, watch, figures)
    finally:
        figures.close()
    from ..verification.summary import verify_summary

    print(verify_summary(rep, written=written))
    if rep.verdict == "pass":
        return EXIT_OK
    if rep.analysis is not None and rep.analysis.mss.undecided:
        return EXIT_UNDECIDED
    stable_uncertified = rep.gamma_certified is None and rep.analysis is not None and rep.analysis.mss.stable
    return EXIT_UNCERTIFIED if stable_uncertified else EXIT_NEGATIVE



def add_run_commands(sub: Any) -> None:
    """Register ``simulate`` and ``verify`` on the CLI's subparsers."""
    m = sub.add_parser("simulate", help="simulate the sampled-data loop under Markov faults and delayed FDI")
    m.add_argument("system", help="system TOML file")
    m.add_argument("--controller", "--gains", dest="controller", default=None,
                   help="controller TOML file (static gains or dynamic; --gains is an alias)")
    m.add_argument("--backend", default="fmu", choices=["fmu", "reference"],
                   help="fmu: co-simulate the LinearJumpPlant FMU (or --plant's FMU); reference: the same "
                        "sampled-data loop in numpy (default %(default)s)")
    m.add_argument("--paths", type=positive_int, default=10, help="Monte Carlo paths (default %(default)s)")
    m.add_argument("--horizon", type=positive, default=30.0,
                   help="simulated time per path, in the system's time unit (default %(default)s)")
    m.add_argument("--step", type=positive, default=None,
                   help="control period h (sample-and-hold), in the system's time unit (default: --period, the "
                        "controller file's period, else 0.01)")
    m.add_argument("--period", type=positive, default=None,
                   help="the controller's sampling period H, in the system's time unit (sets --step; at most "
                        "--horizon; default: the controller file's period)")
    m.add_argument("--seed", type=seed_int, default=None, help="seed of the numpy Generator (recorded in the output)")
    m.add_argument("--disturbance", default="paper", choices=["paper", "zero", "step", "pulse", "sine"],
                   help="w(t) on every input channel: paper = exp(-0.1 t) sin t (Section VI), zero, step = 1, "
                        "pulse = 1 for t < 1, sine = sin t (default %(default)s)")
    m.add_argument("--record", type=nonneg_int, default=0,
                   help="reference backend: keep full trajectories of the first N paths (default 0, 1 with --plot); "
                        "every path's norms are computed either way, vectorised and in batches")
    _cluster_options(m)
    m.add_argument("--beta", default="random", choices=["random", "min", "max", "mid"],
                   help="detection rates: drawn per path in their box (random, the default) or fixed at its "
                        "lower corner, upper corner or midpoint")
    m.add_argument("--delta", default="zero", choices=["zero", "random", "sign", "constant"],
                   help="time-varying uncertainty (random: a new Delta per chain segment; default %(default)s)")
    m.add_argument("--fault-during-delay", action="store_true",
                   help="named variant: faults keep occurring during a detection delay (not the paper's model)")
    m.add_argument("--json", action="store_true", help="print one JSON object instead of a summary")
    m.add_argument("--plot", default=None, help="PNG file for the paper's Fig. 1 of the first path")
    _plant_options(m)
    add_controller_fmu_option(m)
    m.set_defaults(func=_cmd_simulate)

    v = sub.add_parser("verify", help="the main job: synthesize, certify, cross-validate, co-simulate, report")
    v.add_argument("system", help="system TOML file")
    v.add_argument("--gamma", type=gamma_level, default=None,
                   help="attenuation level, 0 < G <= 1e150 (default: minimise)")
    v.add_argument("--method", default="iterative", choices=["two-step", "iterative", "full-info", "common"],
                   help="state-feedback synthesis method (synthesize --method; default %(default)s); "
                        "ignored with --controller")
    v.add_argument("--controller", "--gains", dest="controller", default=None,
                   help="verify this controller file (static gains or dynamic) instead of synthesizing; "
                        "--gains is an alias")
    v.add_argument("--k-max", type=positive, default=30.0, help="gain norm bound for synthesis (default 30)")
    v.add_argument("--no-gain-bound", action="store_true", help="synthesize without a gain bound")
    v.add_argument("--paths", type=positive_int, default=200, help="Monte Carlo paths on the FMU (default 200)")
    v.add_argument("--step", type=positive, default=None,
                   help="control period h of the Monte Carlo (sample-and-hold), in the system's time unit, "
                        "analysed as a sampled loop (default: --period, the controller file's period, else 0.01)")
    v.add_argument("--period", type=positive, default=None,
                   help="the controller's sampling period H, in the system's time unit (sets --step; at most "
                        "--horizon; default: the controller file's period)")
    v.add_argument("--horizon", type=positive, default=30.0,
                   help="simulated time per Monte Carlo path, in the system's time unit (default %(default)s)")
    v.add_argument("--seed", type=seed_int, default=None,
                   help="seed of every random draw (default: fresh entropy; the seed used is in the report)")
    v.add_argument("--out", default="ftc-verify-report", help="output folder (default ./ftc-verify-report)")
    v.add_argument("--solver", default="auto", choices=["auto", "clarabel", "sdpa", "scs"],
                   help="LMI solver of synthesis and certificates (default: auto = clarabel at every size; "
                        "sdpa and scs on request)")
    v.add_argument("--measure", default="total", choices=["total", "incremental"],
                   help="Monte Carlo ratio of the real paths (total, default) or of each path's response to w "
                        "alone, y(w) - y(w = 0) on the same path (incremental: for plants whose faults move the "
                        "equilibrium)")
    from .sampled_lines import add_h_max_work_option

    add_h_max_work_option(v)
    _plant_options(v)
    add_controller_fmu_option(v)
    _cluster_options(v)
    v.set_defaults(func=_cmd_verify)



def _check_cluster(args: argparse.Namespace) -> None:
    """``--workers`` / ``--scheduler`` checked before any work: the worker count within the
    machine's bound, the address's syntax, no ``--fmu-log`` with them, ``--connect-timeout``
    only with ``--scheduler``."""
    connect_timeout(args)
    if args.fmu_log and (args.workers or args.scheduler):
        raise bad("--fmu-log: the FMU's messages stay on the Dask workers; leave out --workers/--scheduler to see them")
    if args.workers or args.scheduler:
        from ..simulation.cluster import check_cluster_options

        check_cluster_options(args.workers, args.scheduler)


def _cluster_options(parser: argparse.ArgumentParser) -> None:
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--workers", type=positive_int, default=None,
                       help="run the Monte Carlo batches on a local Dask cluster of N worker processes")
    where.add_argument("--scheduler", default=None,
                       help="run the Monte Carlo batches on the Dask cluster at this address (tcp://host:port)")
    add_connect_timeout(parser)


def _plant_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--plant", default=None,
                        help="plant map TOML file: co-simulate this FMU instead of the built LinearJumpPlant")
    parser.add_argument("--fmu-log", action="store_true", help="print the FMU's log messages to stderr")


