"""``ftc-verify synthesize``: state-feedback or output-feedback synthesis, certified by the
core analysis; the controller file is written only when certified (with ``--period H``:
only when the sampled loop at ``H`` is also proved mean-square stable,
:mod:`ftc_verify.synthesis.at_period`; the file then records ``period = H``). Exit codes: 0
certified, 1 not found or not certified (with the diagnosis), 2 bad input (an output file
that is the input system file included: never replaced)."""

from __future__ import annotations

import argparse
from typing import Any

from ..claimtext import upper_text
from ..jsonable import dumps
from .common import EXIT_NEGATIVE, EXIT_OK, bad, check_output_file, fmt, gamma_level, positive, seed_int

__all__ = ["add_synthesis_command"]


def _print_synthesis(res: Any) -> None:
    d = res.to_dict()
    print(f"ftc-verify synthesize: method {res.method} ({res.solver}, {res.solver_calls} solver calls, "
          f"{res.solve_seconds:.2f} s solving, {res.wall_seconds:.2f} s wall)")
    print(f"  {res.message}")
    for row in d["starts"]:
        found = (f"certified gamma {upper_text(row['gamma_certified'])}" if row["gamma_certified"] is not None
                 else f"not counted: {row['reason']}")
        mark = "*" if row["name"] == res.start else " "
        took = f" [{row['seconds']:.2f} s]" if row.get("seconds") is not None else ""
        kind = "route" if res.method == "best" else "start"
        print(f"  {mark} {kind} {row['name']:22s} {found}{took}" + (f" ({row['note']})" if row["note"] else ""))
    ref = d.get("reference")
    if ref:
        found = (f"LMI gamma {fmt(ref['lmi_gamma'])} without a gain bound, its gains certified gamma "
                 f"{upper_text(ref['gamma_certified'])}" + (f" ({ref['reason']})" if ref["reason"] else "")
                 + (f", max gain norm {ref['max_gain_norm']:.4g}" if ref.get("max_gain_norm") else ""))
        print(f"  reference: {ref['name']}: {found}")
    if res.diagnosis:
        print(f"  diagnosis: {res.diagnosis['reason']}")
        if "descent" in res.diagnosis:
            print(f"  descent: {res.diagnosis['descent']['message']}")
    if not res.feasible:
        print("  no gains")
        return
    print(f"  synthesis-side gamma     {fmt(d['synthesis_gamma'])}")
    print(f"  certified robust gamma   {upper_text(d['gamma_certified'])}"
          + ("  (Lemma 4.1 not certified: the nominal gamma is the certificate)"
             if d["certified_gamma_kind"] == "nominal" else ""))
    print(f"  certified nominal gamma  {upper_text(d['gamma_nominal_certified'])}")
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

    of_methods = ("auto", "ccl", "observer", "vk", "descent", "hinf")
    if args.output_feedback and args.method not in (None, *of_methods):
        raise bad(f"--method {args.method}: with --output-feedback choose one of {list(of_methods)}")
    if not args.output_feedback and args.method in of_methods:
        raise bad(f"--method {args.method}: needs --output-feedback")
    if args.order is not None and not args.output_feedback:
        raise bad(f"--order {args.order}: needs --output-feedback")
    if args.order is not None and args.order < 0:
        raise bad(f"--order {args.order}: must be >= 0 (0 is static output feedback)")
    check_output_file(args.output, "-o/--output", inputs=(args.system,))
    system = load_system(args.system)

    def design(k_max: float | None) -> Any:
        if args.output_feedback:
            from ..synthesis.output_feedback import synthesize_output_feedback

            return interruptible(lambda: synthesize_output_feedback(
                system, method=args.method or "auto", gamma=args.gamma, k_max=k_max, solver=args.solver,
                order=args.order, seed=args.seed), "the output-feedback synthesis")
        return interruptible(lambda: synthesize(system, method=args.method or "best", gamma=args.gamma, k_max=k_max,
                                                solver=args.solver), "the synthesis")

    def controller_of(res: Any) -> Controller:
        return res.controller if args.output_feedback else Controller.state_feedback(
            res.gains, name=f"{system.name} {res.method}")

    if args.output_feedback:
        n = system.dims[0]
        if args.order is not None and args.order != n and args.method not in (None, "auto", "descent", "hinf"):
            raise bad(f"--order {args.order}: method {args.method} designs order n = {n} only; use --method descent "
                      "or hinf")
        _check_order_memory(system, n if args.order is None else args.order, args.order is None)
    at_period = None
    if args.period is not None:  # the loop that runs: proved stable at the period, or nothing written
        from ..synthesis.at_period import synthesize_at_period

        at_period = synthesize_at_period(system, args.period, design, controller_of, k_max=args.k_max)
        res = at_period.result
    else:
        res = design(args.k_max)
    certified = res.certified and (at_period is None or at_period.found)
    if certified:
        named = controller_of(res) if at_period is None or at_period.controller is None else at_period.controller
        write_atomic(args.output, dump_controller(named))
    if not args.json:
        _print_synthesis(res)
    if at_period is not None:
        from .sampled_lines import print_period_design

        if not args.json:
            print_period_design(at_period, args.period)
    elif res.certified:
        from .sampled_lines import warn_short_h_max

        warn_short_h_max(system, controller_of(res))
    verdict = "certified" if certified else "NOT certified"
    if args.json:
        extra = {} if at_period is None else {
            "period": args.period, "period_attempts": list(at_period.attempts),
            "sampled": None if at_period.sampled is None else at_period.sampled.to_dict()}
        print(dumps(res.to_dict() | extra | {"verdict": verdict}))
    else:
        print(f"  controller {'written to ' + str(args.output) if certified else 'not written (not certified)'}")
        print(f"  verdict: {verdict}")
    return EXIT_OK if certified else EXIT_NEGATIVE


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
    level.add_argument("--gamma", type=gamma_level, help="attenuation level to achieve (feasibility); 0 < G <= 1e150")
    level.add_argument("--minimize", action="store_true", help="make gamma as small as possible (default)")
    y.add_argument("--method", default=None, choices=["best", "two-step", "iterative", "full-info", "common",
                                                       "common-fdi", "dilated", "auto", "ccl", "observer", "vk",
                                                       "descent", "hinf"],
                   help="state feedback: best (default: every route, the best certified), two-step, iterative, "
                        "full-info, common, common-fdi, dilated; with "
                        "--output-feedback: auto (default: every route, the best certified), ccl, observer, vk, "
                        "descent (nonsmooth descent on the exact stability test, any order), hinf (BFGS on the "
                        "bounded-real gamma from a stabilising controller, any order)")
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
    y.add_argument("--period", type=positive, default=None,
                   help="sampling period H of the digital controller, in the system's time unit: design until the "
                        "sampled loop is proved mean-square stable at H (smaller gain bounds), write period = H "
                        "into the controller file (default: none, continuous time)")
    y.set_defaults(func=_cmd_synthesize)

