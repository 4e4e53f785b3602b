"""``ftc-verify risk``: the probability that the loop leaves its safe envelope within
``[0, T]`` (:mod:`ftc_verify.risk`), with its confidence interval.

Exit codes (:doc:`/reference/exit-codes`): 0 when the estimate was printed at the asked
``--relative-error``; 5 when the path budget (``--max-paths``) ran out first (the
estimate and its wider interval are still printed, ``converged`` false); 2 for bad input,
naming the option and the value, before any path is drawn; 1 when a plant FMU crashed.
"""

from __future__ import annotations

import argparse
from typing import Any

from ..claimtext import upper_text
from ..errors import PlantRunError
from ..jsonable import dumps
from .common import (EXIT_NEGATIVE, EXIT_OK, EXIT_UNDECIDED, PLOT_SUFFIXES, add_connect_timeout, bad, check_output_file,
                     connect_timeout, fmt, load, positive, positive_int, seed_int, strict)

__all__ = ["add_risk_command"]

#: Fewest communication steps a horizon must cover (as ``simulate``).
MIN_STEPS = 10


def _floats(text: str) -> list[float]:
    """Argument type: comma-separated finite numbers."""
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from None
    if not all(abs(v) < float("inf") for v in values):
        raise argparse.ArgumentTypeError(f"numbers must be finite, got {text!r}")
    return values


def _fraction(text: str) -> float:
    """Argument type: a number strictly between 0 and 1."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not 0.0 < value < 1.0:
        raise argparse.ArgumentTypeError(f"must be between 0 and 1 (exclusive), got {text!r}")
    return value


def _at_least_two(text: str) -> int:
    """Argument type: an integer, at least 2."""
    value = positive_int(text)
    if value < 2:
        raise argparse.ArgumentTypeError(f"must be at least 2, got {text!r}")
    return value


def _envelope(args: argparse.Namespace, system: Any) -> Any:
    """The envelope of ``--output`` / ``--state`` / ``--region`` with ``--limit``."""
    from ..risk.envelope import output_envelope, region_envelope, state_envelope

    if args.region is not None:
        if args.limit is not None or args.state is not None or args.output:
            raise bad(f"--region {args.region}: the map's region is the envelope; drop --limit, --state and --output")
        from ..plants.plant_map import load_plant_map

        pm = load_plant_map(args.region)
        if len(pm.states) != system.dims[0]:
            raise bad(f"--region {args.region}: the map has {len(pm.states)} states, {args.system} has "
                      f"{system.dims[0]}")
        if pm.states_op is None:
            raise bad(f"--region {args.region}: the map has no [operating_point].states (run `ftc-verify plant "
                      f"--trim` first)")
        return region_envelope(pm.states_min, pm.states_max, pm.states_op, args.region)
    if args.limit is None:
        raise bad("--limit: required (with --output or --state I), unless --region MAP gives the envelope")
    if args.state is not None:
        if args.output:
            raise bad(f"--state {args.state}: choose --output or --state, not both")
        return state_envelope(system, args.state - 1, args.limit)
    return output_envelope(args.limit)


def _check(args: argparse.Namespace, system: Any, controller: Any) -> None:
    """Every option against the loop, before any work."""
    if args.step is None:
        from_file = controller.period is not None
        args.step = controller.period if from_file else 0.01
        source = f"the period of {args.controller}" if from_file else "the default --step"
        step = f"{args.step:g} ({source})"
    else:
        step = f"--step {args.step:g}"
    if args.horizon < MIN_STEPS * args.step:
        raise bad(f"--horizon {args.horizon:g}: must cover at least {MIN_STEPS} steps of {step} "
                  f"(at least {MIN_STEPS * args.step:g})")
    n = system.dims[0]
    if args.x0 is not None and len(args.x0) != n:
        raise bad(f"--x0 {','.join(f'{v:g}' for v in args.x0)}: {len(args.x0)} numbers for the {n} plant states")
    connect_timeout(args)
    if args.workers is not None or args.scheduler is not None:
        from ..simulation.cluster import check_cluster_options

        check_cluster_options(args.workers, args.scheduler)
    if args.plot is not None:
        check_output_file(args.plot, "--plot", PLOT_SUFFIXES, inputs=(args.system, args.controller))


def _plant(args: argparse.Namespace, system: Any, controller: Any) -> Any:
    """The ``--plant`` map (``None`` without it), checked against the system and controller."""
    if args.plant is None:
        return None
    if args.backend != "fmu":
        raise bad(f"--plant {args.plant}: a plant map is co-simulated; it needs --backend fmu")
    from ..plants.plant_map import check_against_system, check_controller, load_plant_map

    plant = load_plant_map(args.plant)
    check_against_system(plant, system)
    check_controller(plant, controller, args.controller)
    plant.require_states_op("co-simulation")
    return plant


def _cmd_risk(args: argparse.Namespace) -> int:
    from ..risk.estimate import Settings
    from ..risk.run import available_stages, run_risk

    system, controller = load(args.system, args.controller)
    _check(args, system, controller)
    envelope = _envelope(args, system)
    plant = _plant(args, system, controller)
    beta = {"min": system.chain.rate_min, "max": system.chain.rate_max, "mid": system.chain.midpoint()}[args.beta]
    settings = Settings(method=args.method, relative_error=args.relative_error, confidence=args.confidence,
                        max_paths=args.max_paths, pilot_paths=args.pilot_paths, seed=args.seed)
    bound, timing = available_stages()
    try:
        res = run_risk(system, controller, envelope, horizon=args.horizon, step=args.step, settings=settings,
                       x0=args.x0, disturbance=args.disturbance, beta=beta, backend=args.backend,
                       plant=plant, bound=bound, timing=timing, interval=args.ftti, workers=args.workers,
                       scheduler=args.scheduler, connect_timeout=connect_timeout(args))
    except PlantRunError as exc:
        print(f"ftc-verify risk: the plant FMU failed: {exc}")
        print("verdict: fail (the plant FMU crashed; no estimate)")
        return EXIT_NEGATIVE
    if args.plot is not None:
        _plot(args, system, controller, envelope, settings, plant, res.estimate)
    d = strict(res.to_dict())
    converged = res.estimate.converged
    verdict = "estimated" if converged else "imprecise (path budget spent before --relative-error)"
    if args.json:
        print(dumps(d | {"verdict": "estimated" if converged else "imprecise"}))
    else:
        _print(d, args)
        print(f"  verdict: {verdict}")
    return EXIT_OK if converged else EXIT_UNDECIDED


def _plot(args: argparse.Namespace, system: Any, controller: Any, envelope: Any, settings: Any, plant: Any,
          last: Any) -> None:
    """``--plot``: the estimate at the horizons ``k T / 5`` (those covering 10 steps) and at ``T``."""
    from ..risk.horizon import plot_risk_by_horizon, risk_by_horizon

    horizons = [k * args.horizon / 5 for k in range(1, 5) if k * args.horizon / 5 >= MIN_STEPS * args.step]
    estimates = risk_by_horizon(system, controller, envelope, horizons, step=args.step, settings=settings,
                                x0=args.x0, disturbance=args.disturbance, backend=args.backend, plant=plant)
    plot_risk_by_horizon([*horizons, args.horizon], [*estimates, last], args.plot,
                         title=f"{system.name}: {envelope.description} ({last.method}, seed {last.seed})")


def _print(d: dict[str, Any], args: argparse.Namespace) -> None:
    """The estimate as a few lines."""
    lo, hi = d["ci"]
    print(f"ftc-verify risk: {d['system']}: P(leave {d['envelope']} within [0, {fmt(d['horizon'])}])")
    print(f"  estimate: {fmt(d['probability'], 4)}  {int(100 * d['confidence'])} % interval "
          f"[{fmt(lo, 4)}, {fmt(hi, 4)}] ({d['interval']}; relative error {fmt(d['relative_error'], 3)})")
    print(f"  {d['method']} sampling: {d['paths']} paths ({d['hits']} left the envelope), "
          f"{d['pilot_paths']} pilot paths, seed {d['seed']}")
    if d["method"] == "importance":
        print("  tilt: " + ", ".join(f"{k} x{fmt(v, 3)}" for k, v in d["tilt"].items()))
        top = max(d["levels"], default=0.0)
        if top < 1.0:
            print(f"  note: no pilot round reached the limit (highest elite level {fmt(top, 3)} of 1): the tilt "
                  "was learned from paths that stay inside, the estimate may need far more paths")
    print(f"  backend {d['backend']}, step {fmt(d['step'])}, disturbance {d['disturbance']}; checked {d['evaluated']}")
    if d["failed_paths"]:
        print(f"  {d['failed_paths']} paths diverged or their plant failed (counted as leaving)")
    if d["upper_bound"] is not None:
        print(f"  upper bound: {upper_text(d['upper_bound'].get('value'), 4)} ({d['upper_bound'].get('reason', '')})")
    if d["timing"] is not None:
        t = d["timing"]
        events = ", ".join(f"{e.get('label')} {fmt(e.get('probability'), 4)}" for e in t.get("events", []))
        print(f"  FDI timing (--ftti {fmt(args.ftti)}): P(detection later than the interval) worst "
              f"{fmt(t.get('worst'), 4)} ({t.get('worst_event')}); {events}")


def add_risk_command(sub: Any) -> None:
    """Register ``risk`` on the CLI's subparsers."""
    r = sub.add_parser("risk", help="probability of leaving the safe envelope, with a confidence interval "
                                    "(importance sampling of the fault/FDI chain)")
    r.add_argument("system", help="system TOML file")
    r.add_argument("--controller", "--gains", dest="controller", required=True,
                   help="controller TOML file (static gains or dynamic; --gains is an alias)")
    r.add_argument("--limit", type=positive, default=None, help="the envelope's limit L (with --output or --state)")
    r.add_argument("--output", action="store_true", help="envelope: the norm of the performance output z below L (the default)")
    r.add_argument("--state", type=positive_int, default=None, help="envelope: the absolute value of plant state I (1-based) below L")
    r.add_argument("--region", default=None, metavar="MAP",
                   help="envelope: the [region] box of this plant map around its operating point")
    r.add_argument("--horizon", type=positive, required=True, help="T: the envelope is watched on [0, T]")
    r.add_argument("--x0", type=_floats, default=None, help="initial plant state, comma-separated (default 0)")
    r.add_argument("--disturbance", default="paper", choices=["paper", "zero", "step", "pulse", "sine"],
                   help="w(t) on every input channel (as simulate; default %(default)s)")
    r.add_argument("--step", type=positive, default=None,
                   help="control period h (sample-and-hold; default: the controller file's period, else 0.01)")
    r.add_argument("--backend", default="reference", choices=["reference", "fmu"],
                   help="reference: the numpy sampled-data loop (vectorised); fmu: the LinearJumpPlant FMU, "
                        "isolated as in simulate (default %(default)s)")
    r.add_argument("--plant", default=None, metavar="MAP",
                   help="with --backend fmu: co-simulate this plant map's FMU instead of the LinearJumpPlant")
    r.add_argument("--workers", type=positive_int, default=None,
                   help="run the batches (FMU) or chunks of 250 paths (reference) on a local Dask cluster of N "
                        "worker processes (the same numbers as without)")
    r.add_argument("--scheduler", default=None, metavar="ADDR",
                   help="as --workers, on the Dask scheduler at HOST:PORT")
    add_connect_timeout(r)
    r.add_argument("--beta", default="mid", choices=["min", "max", "mid"],
                   help="the rate array of the chain: lower corner, upper corner or midpoint of its box "
                        "(default %(default)s)")
    r.add_argument("--method", default="importance", choices=["importance", "crude"],
                   help="importance: tilted chain, cross-entropy pilot; crude: plain Monte Carlo (default %(default)s)")
    r.add_argument("--relative-error", type=positive, default=0.2,
                   help="stop when the interval's half width is at most this fraction of the estimate "
                        "(default %(default)s)")
    r.add_argument("--confidence", type=_fraction, default=0.95, help="of the interval (default %(default)s)")
    r.add_argument("--max-paths", type=_at_least_two, default=100_000,
                   help="path budget of the estimate, pilot not included (default %(default)s)")
    r.add_argument("--pilot-paths", type=_at_least_two, default=500,
                   help="paths per cross-entropy round of the importance-sampling pilot, at least 2 "
                        "(default %(default)s; fewer for a slow FMU)")
    r.add_argument("--ftti", type=positive, default=None,
                   help="fault-tolerant time interval: adds the probability that a detection delay exceeds it")
    r.add_argument("--plot", default=None, metavar="FILE",
                   help="also draw the estimate against the horizon (T/5 .. T) into FILE (.png, .pdf, .svg)")
    r.add_argument("--seed", type=seed_int, default=0, help="root seed of every stream (default %(default)s)")
    r.add_argument("--json", action="store_true", help="print one JSON object instead of a summary")
    r.set_defaults(func=_cmd_risk)
