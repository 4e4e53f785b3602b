"""``ftc-verify synthesize``: state-feedback or output-feedback synthesis, certified by the
core analysis; the controller file is written only when certified. Exit codes: 0
certified, 1 not found or not certified (with the diagnosis), 2 bad input (an output file
that is the input system file included: never replaced)."""

from __future__ import annotations

import argparse
from typing import Any

from ..jsonable import dumps
from .common import EXIT_NEGATIVE, EXIT_OK, bad, check_output_file, fmt, positive, seed_int

__all__ = ["add_synthesis_command"]


def _print_synthesis(res: Any) -> None:
    d = res.to_dict()
    print(f"ftc-verify synthesize: method {res.method} ({res.solver}, {res.solver_calls} solver calls, "
          f"{res.solve_seconds:.2f} s solving, {res.wall_seconds:.2f} s wall)")
    print(f"  {res.message}")
    for row in d["starts"]:
        found = (f"certified gamma {row['gamma_certified']:.6g}" if row["gamma_certified"] is not None
                 else f"not counted: {row['reason']}")
        mark = "*" if row["name"] == res.start else " "
        print(f"  {mark} start {row['name']:22s} {found}" + (f" ({row['note']})" if row["note"] else ""))
    if res.diagnosis:
        print(f"  diagnosis: {res.diagnosis['reason']}")
        if "descent" in res.diagnosis:
            print(f"  descent: {res.diagnosis['descent']['message']}")
    if not res.feasible:
        print("  no gains")
        return
    print(f"  synthesis-side gamma     {fmt(d['synthesis_gamma'])}")
    print(f"  certified robust gamma   {fmt(d['gamma_certified'])}"
          + ("  (Lemma 4.1 not certified: the nominal gamma is the certificate)"
             if d["certified_gamma_kind"] == "nominal" else ""))
    print(f"  certified nominal gamma  {fmt(d['gamma_nominal_certified'])}")
    print(f"  spectral abscissa        {fmt(d['spectral_abscissa'])}")
    print(f"  max gain norm            {fmt(d['max_gain_norm'])}" + (f" (bound {res.k_max:g})" if res.k_max else ""))
    if res.history:
        print("  iterate history          " + " -> ".join(f"{g:.6g}" for g in res.history))
    if res.ccl_history:
        print(f"  CCL residuals            {' -> '.join(f'{r:.3g}' for r in res.ccl_history)} "
              f"({len(res.ccl_history)} iterations)")


def _cmd_synthesize(args: argparse.Namespace) -> int:
    from ..controllers.controller import Controller
    from ..controllers.files import dump_controller
    from ..analysis.solvers import interruptible
    from ..model.files import load_system, write_atomic
    from ..synthesis.state_feedback import synthesize

    of_methods = ("auto", "ccl", "observer", "vk", "descent")
    if args.output_feedback and args.method not in (None, *of_methods):
        raise bad(f"--method {args.method}: with --output-feedback choose one of {list(of_methods)}")
    if not args.output_feedback and args.method in (None, *of_methods):
        raise bad(f"--method {args.method}: needs --output-feedback" if args.method else
                   "--method: required for state feedback (two-step, iterative, full-info, common)")
    if args.order is not None and not args.output_feedback:
        raise bad(f"--order {args.order}: needs --output-feedback")
    if args.order is not None and args.order < 0:
        raise bad(f"--order {args.order}: must be >= 0 (0 is static output feedback)")
    check_output_file(args.output, "-o/--output", inputs=(args.system,))
    system = load_system(args.system)
    if args.output_feedback:
        from ..synthesis.output_feedback import synthesize_output_feedback

        n = system.dims[0]
        if args.order is not None and args.order != n and args.method not in (None, "auto", "descent"):
            raise bad(f"--order {args.order}: method {args.method} designs order n = {n} only; use --method descent")
        _check_order_memory(system, n if args.order is None else args.order, args.order is None)
        res = interruptible(lambda: synthesize_output_feedback(
            system, method=args.method or "auto", gamma=args.gamma, k_max=args.k_max, solver=args.solver,
            order=args.order, seed=args.seed), "the output-feedback synthesis")
    else:
        res = interruptible(lambda: synthesize(system, method=args.method, gamma=args.gamma, k_max=args.k_max,
                                               solver=args.solver), "the synthesis")
    if res.certified and res.controller is not None:
        named = res.controller if args.output_feedback else Controller.state_feedback(
            res.gains, name=f"{system.name} {res.method}")
        write_atomic(args.output, dump_controller(named))
    verdict = "certified" if res.certified else "NOT certified"
    if args.json:
        print(dumps(res.to_dict() | {"verdict": verdict}))
    else:
        _print_synthesis(res)
        print(f"  controller {'written to ' + str(args.output) if res.certified else 'not written (not certified)'}")
        print(f"  verdict: {verdict}")
    return EXIT_OK if res.certified else EXIT_NEGATIVE



def _check_order_memory(system: Any, order: int, default: bool) -> None:
    """Refuse, before any work, an output-feedback problem whose dense second-moment
    generator (the descent's objective and the exact spectral test of every candidate,
    on the loop of order ``n + order``) would not fit under the memory limit
    (:func:`ftc_verify.limits.dense_generator_estimate`)."""
    from ..limits import check_memory, dense_generator_estimate

    n_loop = system.dims[0] + order
    option = f"--order {order}" + (" (the default, n)" if default else "")
    check_memory(dense_generator_estimate(n_loop, system.chain.n_states),
                 f"{option}: the second-moment generator of the closed loop of order {n_loop} on "
                 f"{system.chain.n_states} joint states",
                 hint="choose a smaller --order")


def add_synthesis_command(sub: Any) -> None:
    """Register ``synthesize`` on the subparsers ``sub``."""
    y = sub.add_parser("synthesize", help="synthesize a controller (state or output feedback) and certify it")
    y.add_argument("system", help="system TOML file")
    level = y.add_mutually_exclusive_group()
    level.add_argument("--gamma", type=positive, help="attenuation level to achieve (feasibility)")
    level.add_argument("--minimize", action="store_true", help="make gamma as small as possible (default)")
    y.add_argument("--method", default=None, choices=["two-step", "iterative", "full-info", "common",
                                                       "auto", "ccl", "observer", "vk", "descent"],
                   help="state feedback: two-step, iterative, full-info, common (required); with "
                        "--output-feedback: auto (default: every route, the best certified), ccl, observer, vk, "
                        "descent (nonsmooth descent on the exact stability test, any order)")
    y.add_argument("--output-feedback", action="store_true",
                   help="a dynamic controller per FDI mode reading y_m = Cy x (Theorem 5.1)")
    y.add_argument("--order", type=int, default=None,
                   help="output feedback: controller order (default n; 0 = static output feedback u = Dc y_m; "
                        "orders below n only by the descent)")
    y.add_argument("--seed", type=seed_int, default=0, help="seed of the descent's random starts (default 0)")
    y.add_argument("--k-max", type=positive, default=None,
                   help="bound on the spectral norm of every gain (output feedback: of every controller block)")
    y.add_argument("-o", "--output", required=True, help="controller TOML file to write (only when certified; not the system file)")
    y.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    y.add_argument("--solver", default="auto", choices=["auto", "clarabel", "sdpa", "scs"],
                   help="LMI solver (default: auto = clarabel at every size; sdpa and scs on request)")
    y.set_defaults(func=_cmd_synthesize)

