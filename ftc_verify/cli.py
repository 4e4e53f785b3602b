"""Command-line interface: ``ftc-verify COMMAND ...`` (also ``python -m ftc_verify``).

Exit codes: 0 success (e.g. certified stable), 1 a negative answer (not certified),
2 bad input (one line on stderr, no traceback, no output file written).
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from collections.abc import Sequence
from typing import Any

from . import __version__
from .errors import FTCError

__all__ = ["main", "build_parser"]

EXIT_OK, EXIT_NEGATIVE, EXIT_BAD_INPUT = 0, 1, 2


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # one line, exit 2, no usage dump
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message}\n")


def _fmt(x: float | None, digits: int = 6) -> str:
    return "-" if x is None else f"{x:.{digits}g}"


def _print_analysis(rep: Any) -> None:
    d = rep.to_dict()
    mss = d["mss"]
    vert = f"worst of {mss['vertices_evaluated']} beta vertices" + ("" if mss["exhaustive"] else ", greedy search")
    print(f"ftc-verify analyze: {rep.name} ({rep.controller})")
    print(f"  mean-square stability    spectral abscissa {_fmt(mss['spectral_abscissa'])} ({vert}): "
          f"{'stable' if mss['stable'] else 'NOT stable'}")
    for label, res in (("Theorem 3.1 LMI", rep.mes_lmi), ("nominal gamma (Th. 3.2)", rep.nominal),
                       ("robust gamma (Lem. 4.1)", rep.robust)):
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
    verdict = "certified stable" if rep.certified_stable else "NOT certified stable"
    print(f"  verdict: {verdict}; certificates {'all passed' if rep.certificate_ok else 'NOT all passed'}")


def _cmd_analyze(args: argparse.Namespace) -> int:
    from .analysis import analyze
    from .closedloop import state_feedback_loop
    from .problem_files import check_gains, load_gains, load_system

    system = load_system(args.system)
    gains = check_gains(system, load_gains(args.gains), source=str(args.gains))
    loop = state_feedback_loop(system, gains)
    rep = analyze(loop, solver=args.solver, name=system.name)
    if args.json:
        print(json.dumps(rep.to_dict(), indent=2))
    else:
        _print_analysis(rep)
    return EXIT_OK if rep.certified_stable else EXIT_NEGATIVE


def _positive(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not (value > 0 and value < float("inf")):
        raise argparse.ArgumentTypeError(f"must be positive and finite, got {text!r}")
    return value


def _print_synthesis(res: Any) -> None:
    d = res.to_dict()
    print(f"ftc-verify synthesize: method {res.method} ({res.solver}, {res.solver_calls} solver calls, "
          f"{res.solve_seconds:.2f} s solving, {res.wall_seconds:.2f} s wall)")
    print(f"  {res.message}")
    if not res.feasible:
        print("  no gains")
        return
    print(f"  synthesis-side gamma     {_fmt(d['synthesis_gamma'])}")
    print(f"  certified robust gamma   {_fmt(d['gamma_certified'])}")
    print(f"  certified nominal gamma  {_fmt(d['gamma_nominal_certified'])}")
    print(f"  spectral abscissa        {_fmt(d['spectral_abscissa'])}")
    print(f"  max gain norm            {_fmt(d['max_gain_norm'])}" + (f" (bound {res.k_max:g})" if res.k_max else ""))
    if res.history:
        print("  iterate history          " + " -> ".join(f"{g:.6g}" for g in res.history))
    if d["lower_bound"] is not None:
        print(f"  full-information optimum {d['lower_bound']:.6g} (lower bound for FDI-only gains)")
    print(f"  verdict: {'certified' if res.certified else 'NOT certified'}")


def _cmd_synthesize(args: argparse.Namespace) -> int:
    from .problem_files import dump_gains, load_system, write_atomic
    from .synthesis import synthesize

    system = load_system(args.system)
    res = synthesize(system, method=args.method, gamma=args.gamma, k_max=args.k_max, solver=args.solver)
    if res.certified:
        write_atomic(args.output, dump_gains(res.gains, name=f"{system.name} {res.method}"))
    if args.json:
        print(json.dumps(res.to_dict(), indent=2))
    else:
        _print_synthesis(res)
        print(f"  gains {'written to ' + str(args.output) if res.certified else 'not written (not certified)'}")
    return EXIT_OK if res.certified else EXIT_NEGATIVE


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``ftc-verify``."""
    p = _Parser(prog="ftc-verify", description=__doc__.splitlines()[0])
    p.add_argument("--version", action="version", version=f"ftc-verify {__version__}")
    sub = p.add_subparsers(dest="command", required=True, parser_class=_Parser)
    a = sub.add_parser("analyze", help="analyse a closed loop: exact MSS, certified LMIs, cross-validation")
    a.add_argument("system", help="system TOML file")
    a.add_argument("--gains", required=True, help="gains TOML file (one [[gain]] per FDI mode)")
    a.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    a.add_argument("--solver", default="auto", choices=["auto", "clarabel", "sdpa", "scs"],
                   help="LMI solver (default: auto = clarabel for small problems, sdpa above the size threshold)")
    a.set_defaults(func=_cmd_analyze)

    y = sub.add_parser("synthesize", help="synthesize state-feedback gains and certify them")
    y.add_argument("system", help="system TOML file")
    level = y.add_mutually_exclusive_group()
    level.add_argument("--gamma", type=_positive, help="attenuation level to achieve (feasibility)")
    level.add_argument("--minimize", action="store_true", help="make gamma as small as possible (default)")
    y.add_argument("--method", required=True, choices=["two-step", "iterative", "full-info", "common"])
    y.add_argument("--k-max", type=_positive, default=None, help="bound on the spectral norm of every gain")
    y.add_argument("-o", "--output", required=True, help="gains TOML file to write (only when certified)")
    y.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    y.add_argument("--solver", default="auto", choices=["auto", "clarabel", "sdpa", "scs"])
    y.set_defaults(func=_cmd_synthesize)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit code."""
    args = build_parser().parse_args(argv)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # solver chatter; statuses are reported in the results
            return int(args.func(args))
    except FTCError as exc:
        print(f"ftc-verify: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print("ftc-verify: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
