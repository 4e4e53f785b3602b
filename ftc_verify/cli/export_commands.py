"""``ftc-verify export-controller``: the certified controller as an FMI 2.0 / 3.0 FMU or a C99 file.

Exit codes (:mod:`ftc_verify.cli.main`): 0 when the file was written (and, for an FMU,
FMPy's validation found no problem); 2 for bad input -- a controller that does not fit the
system, a full-information controller, an existing output without ``--force``, a
compiler that is missing or fails (its first error line); 1, 3 or 5 when the controller is
not certified (not stable, stable without a certificate, undecided) and
``--allow-uncertified`` was not given: the analysis verdict is printed and nothing is written.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from .common import (EXIT_NEGATIVE, EXIT_OK, EXIT_UNCERTIFIED, EXIT_UNDECIDED, bad, check_output_file, fmt, load,
                     positive)

__all__ = ["add_export_commands"]

#: The default sampling period: the simulators' default ``--step``.
DEFAULT_STEP = 0.01


def _check_output(args: argparse.Namespace) -> None:
    suffix = ".c" if args.c else ".fmu"
    check_output_file(args.output, "-o", (suffix,), inputs=(args.controller, args.system))
    if Path(args.output).exists() and not args.force:
        raise bad(f"-o {args.output}: exists; give --force to replace it")


def _cmd_export_controller(args: argparse.Namespace) -> int:
    from ..export.ccode import controller_c_source, controller_tables
    from ..export.certificate import export_certificate

    if args.c == (args.fmi is not None):
        raise bad("export-controller: give exactly one of --fmi 2.0|3.0 (an FMU) and --c (a C99 file)")
    _check_output(args)
    system, controller = load(args.system, args.controller)
    tables = controller_tables(controller, float(args.step), system.m)
    if not args.c:
        from ..export.controller_fmu import controller_source_dir
        from ..plants.build import find_gcc

        find_gcc(controller_source_dir() / "ctrl_glue.c")  # a missing compiler is refused before the analysis
    cert, rep = export_certificate(system, controller, float(args.step), solver=args.solver)
    print(f"ftc-verify export-controller: {system.name} ({controller.describe(system.m)})")
    gammas = f"nominal gamma {fmt(cert.nominal_gamma)}, robust gamma {fmt(cert.robust_gamma)}" if cert.certified else ""
    print(f"  analysis: {cert.verdict}{'; ' + gammas if gammas else ''}")
    if not cert.certified and not args.allow_uncertified:
        print("  verdict: refused (the controller is not certified; --allow-uncertified exports it anyway, "
              "recording that it is not)")
        if rep.mss.undecided:
            return EXIT_UNDECIDED
        return EXIT_UNCERTIFIED if rep.mss.stable else EXIT_NEGATIVE
    attrs = cert.attributes()
    title = (f"controller {controller.name or args.controller!r} for system {system.name!r}: "
             f"{cert.verdict} ({', '.join(f'{k}={v}' for k, v in attrs.items() if k != 'tool')})")
    source = controller_c_source(tables, title=title)
    out = Path(args.output)
    if args.c:
        from ..model.files import write_atomic

        write_atomic(out, source)
        print(f"  C99 file: {out} (sampling period {args.step!r} s, {tables.modes} FDI modes, order {tables.nc})")
    else:
        _write_fmu(args, system, controller, tables, source, attrs, title)
    print(f"  verdict: exported ({cert.verdict})")
    return EXIT_OK


def _write_fmu(args: argparse.Namespace, system: Any, controller: Any, tables: Any, source: str,
               attrs: dict[str, str], title: str) -> None:
    from ..controllers.files import dump_controller
    from ..errors import FMUError
    from ..export.controller_fmu import build_controller_fmu
    from ..model.files import dump_system
    from ..plants.controller_session import fmu_problems

    import shutil
    import tempfile

    out = Path(args.output)
    folder = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent if str(out.parent) else "."))
    try:  # built and validated beside the output, then renamed: nothing half-written
        tmp = build_controller_fmu(tables, source, folder / out.name, fmi_version=args.fmi, description=title,
                                   certificate=attrs, resources={"controller.toml": dump_controller(controller),
                                                                 "system.toml": dump_system(system)})
        problems = fmu_problems(tmp)
        if problems:
            raise FMUError(f"{out}: FMPy's validation found problems: {'; '.join(problems)}")
        tmp.replace(out)
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    print(f"  FMU (FMI {args.fmi}, co-simulation, sampling period {args.step!r} s): {out} (FMPy validation: no problems)")


def add_export_commands(sub: Any) -> None:
    """Register ``export-controller`` on the CLI's subparsers."""
    e = sub.add_parser("export-controller",
                       help="write a certified controller as an FMI 2.0/3.0 co-simulation FMU or a C99 file")
    e.add_argument("controller", help="controller TOML file ([[gain]] or [[controller]] tables, one per FDI mode)")
    e.add_argument("--system", required=True, help="system TOML file the controller is certified for")
    e.add_argument("--fmi", choices=["2.0", "3.0"], default=None, help="write an FMU of this FMI version")
    e.add_argument("--c", action="store_true", help="write one dependency-free C99 file instead of an FMU")
    e.add_argument("-o", "--output", required=True, help="the file to write (.fmu, or .c with --c)")
    e.add_argument("--step", type=positive, default=DEFAULT_STEP,
                   help="sampling period h in s (default 0.01, the simulators' default --step); the exported "
                        "update is exact for this period and refuses any other step")
    e.add_argument("--force", action="store_true", help="replace an existing output file")
    e.add_argument("--allow-uncertified", action="store_true",
                   help="export a controller the analysis does not certify (the record says so)")
    e.add_argument("--solver", default="auto", choices=["auto", "clarabel", "sdpa", "scs"], help="LMI solver")
    e.set_defaults(func=_cmd_export_controller)


def add_controller_fmu_option(parser: argparse.ArgumentParser) -> None:
    """``--controller-fmu`` of ``simulate`` and ``verify``."""
    parser.add_argument("--controller-fmu", default=None,
                        help="run the loop with this controller FMU (written by export-controller) computing u and "
                             "x_c; its sampling period must be --step; jump times move to its step grid")


def load_loop(args: argparse.Namespace) -> tuple[Any, Any]:
    """The system and controller of ``simulate``/``verify``: from ``--controller`` (or
    none: ``verify`` synthesizes), or the controller an exported FMU carries, bound to it
    (:class:`~ftc_verify.plants.controller_session.ExportedController`); every mismatch
    (dimensions, period, backend) refused before any work."""
    path = getattr(args, "controller_fmu", None)
    if path is None:
        if args.command == "simulate" and args.controller is None:
            raise bad("simulate: give --controller (a controller file) or --controller-fmu (an exported FMU)")
        return load(args.system, args.controller)
    if args.controller is not None:
        raise bad(f"--controller-fmu {path}: give --controller or --controller-fmu, not both")
    if getattr(args, "backend", "fmu") != "fmu":
        raise bad(f"--controller-fmu {path}: an exported controller is co-simulated; it needs --backend fmu")
    if not Path(path).is_file():
        raise bad(f"--controller-fmu {path}: no such file")
    from ..model.files import load_system
    from ..plants.controller_session import ControllerFMU, check_period, controller_of_fmu

    system = load_system(args.system)
    controller = controller_of_fmu(path)
    controller.check(system, source=str(path))
    with ControllerFMU(path) as fmu:
        check_period(fmu, float(args.step))
    return system, controller
