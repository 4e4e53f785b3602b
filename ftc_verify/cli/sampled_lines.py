"""The CLI's handling of a sampling period: ``--period`` against ``--step`` and
``--horizon``, and the lines that report the sampled loop
(:func:`ftc_verify.analysis.moments.sampled.sampled_analysis`).

Nothing here imports numpy at import time (the parser is built without it).
"""

from __future__ import annotations

import argparse
from typing import Any

from ..claimtext import lower_text, upper_text
from .common import EXIT_NEGATIVE, EXIT_OK, EXIT_UNCERTIFIED, EXIT_UNDECIDED, bad
from .export_commands import DEFAULT_STEP  # the simulators' step when no period or step is given

__all__ = ["add_h_max_work_option", "check_period_option", "resolve_step", "sampled_exit", "print_sampled",
           "print_period_design", "warn_short_h_max", "performance_lines"]



def add_h_max_work_option(parser: argparse.ArgumentParser) -> None:
    """``--h-max-work UNITS`` (``analyze`` and ``verify``: the same option, the same checks,
    the same stage, :func:`~ftc_verify.analysis.moments.sampled_refine.refine_result`)."""
    from .common import positive

    parser.add_argument("--h-max-work", type=positive, default=None, metavar="UNITS",
                        help="with a period: refine the proved h_max bracket when it is wider than 1e-3, with "
                             "covers of the rate box by cubic clock-dependent certificates within UNITS work "
                             "units (about a millisecond of one core each; e.g. 200000: a few minutes); refused "
                             "when the program's memory estimate is over 4 GB or the memory limit")


def check_period_option(args: argparse.Namespace) -> None:
    """``--period`` against ``--step`` and ``--horizon``, before any work (exit 2 naming
    ``--period``); the value itself is checked by the argument type (positive, finite)."""
    period = args.period
    if period is None:
        return
    if getattr(args, "step", None) is not None and args.step != period:
        raise bad(f"--period {period:g} and --step {args.step:g} disagree: the simulation samples the controller "
                  "every --step; give one of them")
    horizon = getattr(args, "horizon", None)
    if horizon is not None and period > horizon:
        raise bad(f"--period {period:g}: longer than --horizon {horizon:g} (the controller would not sample again)")


def resolve_step(args: argparse.Namespace, controller: Any) -> float:
    """The simulation step: ``--period``, else ``--step``, else the controller file's
    ``period`` (checked against ``--horizon``), else ``DEFAULT_STEP`` (0.01, ``cli.export_commands``)."""
    if args.period is not None:
        return float(args.period)
    if args.step is not None:
        return float(args.step)
    period = None if controller is None else controller.period
    if period is not None:
        if period > args.horizon:
            raise bad(f"{args.controller}: period {period:g} is longer than --horizon {args.horizon:g} "
                      "(give --period or --step)")
        return float(period)
    return DEFAULT_STEP


def sampled_exit(code: int, sampled: Any) -> int:
    """The exit code with the sampled loop's verdict: a loop certified in continuous time
    whose sampled loop is proved unstable exits 1, undecided 5."""
    if sampled is None or sampled.verdict == "stable" or code not in (EXIT_OK, EXIT_UNCERTIFIED):
        return code
    return EXIT_NEGATIVE if sampled.verdict == "not stable" else EXIT_UNDECIDED


def print_sampled(res: Any) -> None:
    """The sampled loop's lines of ``analyze``."""
    from ..analysis.moments.sampled_refine import period_text, refinement_note

    word = {"stable": "stable", "not stable": "NOT stable", "undecided": "UNDECIDED"}[res.verdict]
    print(f"  sampled loop, period h = {res.period:g} (controller reads x and the FDI report every h, holds u)")
    rho = f"{res.spectral_radius:.6g}" + ("" if res.spectral_radius < float("inf") else " (overflows float64)")
    print(f"    mean-square stability  spectral radius of the one-period map {rho}: {word}")
    print(f"      {'not proved' if res.verdict == 'undecided' else 'proved'}: {res.proof}")
    if res.h_max is not None and res.h_max_unstable is not None:
        print(f"    h_max {period_text(res.h_max, down=True)}: proved stable over the rate box there, proved "
              f"unstable at {period_text(res.h_max_unstable, down=False)}")
        refined = refinement_note(res)  # analyze --h-max-work
        if refined is not None:
            print(f"      {refined}")
    else:
        print(f"    h_max not found: {res.h_max_note}")
    intervals = ", ".join(f"[{a:.4g}, {b:.4g}]" for a, b in res.stability_intervals) or "none"
    print(f"    stable periods in the scan [{res.scan[0]:.3g}, {res.scan[1]:.3g}] (float64): {intervals}")
    verdict = {"stable": "mean-square stable over the rate box (proved)",
               "not stable": "NOT mean-square stable (proved)",
               "undecided": "UNDECIDED (neither stability nor instability proved)"}[res.verdict]
    if res.performance is not None:  # analysis.moments.sampled_gamma
        print("\n".join(performance_lines(res.performance)))
    print(f"  verdict at period h = {res.period:g}: the sampled loop is {verdict}")


def print_period_design(design: Any, period: float) -> None:
    """The lines of ``synthesize --period``: each gain bound tried and the outcome."""
    print(f"  designed for the sampled loop at period h = {period:g} (gain bounds tried, largest first):")
    for row in design.attempts:
        bound = "none" if row["k_max"] is None else f"{row['k_max']:g}"
        gamma = "not certified" if not row["certified"] else f"certified gamma {upper_text(row['gamma_certified'])}"
        sampled = "" if row["sampled_verdict"] is None else f"; sampled loop {row['sampled_verdict']}"
        h_max = "" if row["h_max"] is None else f" (h_max {lower_text(row['h_max'])})"
        print(f"    k_max {bound:>6}: {gamma}{sampled}{h_max}")
    if design.found and design.sampled is not None:
        print(f"  sampled loop at h = {period:g}: {design.sampled.proof}")
    else:
        print(f"  no certified design whose sampled loop at h = {period:g} is proved mean-square stable")


def warn_short_h_max(system: Any, controller: Any) -> None:
    """Without ``--period``: a warning on stderr when the certified controller's sampled
    loop is not stable at some period up to 10 times ``DEFAULT_STEP`` (0.01,
    ``cli.export_commands``): a float64 screen of the rate vertices and midpoint (of the
    corners, the midpoint and the vertex ascent's worst vertex on a box with more than 16
    vertices and a map of at most ``SCREEN_ASCENT_ROWS`` rows) at the periods ``0.1 / 2^k``, ``k = 7 .. 0``
    (:func:`~ftc_verify.analysis.moments.sampled_scan.octave_verdicts`); its ``h_max`` is
    then below that. The radius printed is the worst of those
    (:func:`~ftc_verify.analysis.moments.sampled_bracket.period_worst`). A warning, not a
    certificate -- ``analyze --period`` proves it."""
    import sys

    from ..analysis.moments.sampled import SampledLoop
    from ..analysis.moments.sampled_bracket import period_worst
    from ..analysis.moments.sampled_scan import octave_verdicts

    limit = 10 * DEFAULT_STEP
    loop = SampledLoop.build(system, controller)
    for h, stable in octave_verdicts(loop, limit, 7):
        if not stable:
            rho = period_worst(loop, h)[0]
            print(f"ftc-verify synthesize: warning: the sampled loop of this controller is not mean-square stable "
                  f"at period {h:.3g} (float64 spectral radius {rho:.9g}): its h_max is below {limit:g}, 10 times "
                  f"the simulator's default step; check the period it will run at with analyze --period, or "
                  f"design for it with synthesize --period", file=sys.stderr)
            return


def performance_lines(perf: Any) -> list[str]:
    """The report lines of ``analyze --period`` for ``perf``
    (:class:`~ftc_verify.analysis.moments.sampled_gamma.SampledPerformance`): each proved gamma
    rounded up, each proved lower bound rounded down (:mod:`ftc_verify.claimtext`)."""
    out = []
    rows = [("nominal", perf.nominal, perf.nominal_lower, perf.nominal_lower_kind)]
    if perf.robust is not None:
        rows.append(("robust", perf.robust, perf.robust_lower, perf.robust_lower_kind))
    for name, cert, lower, kind in rows:
        low = "n/a" if lower is None else (lower_text(lower) if kind == "proved" else f"{lower:.6g}")
        low += " (proved)" if kind == "proved" else " (float64, not proved)"
        if cert.gamma is None:
            out.append(f"    {name} gain (sampled, between samples included)  NOT certified: {cert.note}; "
                       f"lower bound {low}")
        else:
            out.append(f"    {name} gain (sampled, between samples included)  gamma <= {upper_text(cert.gamma)} (proved, "
                       f"N = {cert.pieces} {'affine' if cert.degree == 1 else 'quadratic'}); lower bound {low}")
    return out
