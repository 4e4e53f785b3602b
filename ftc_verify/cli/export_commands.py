"""``ftc-verify export-controller`` (an FMI 2.0 / 3.0 FMU or a C99 file) and ``export-loop`` (an SSP archive).

Exit codes (:mod:`ftc_verify.cli.main`): 0 when the file was written (and, for an FMU,
FMPy's validation found no problem); 2 for bad input -- a controller that does not fit the
system, a full-information controller, an existing output without ``--force``, a
compiler that is missing or fails (its first error line); 1, 3 or 5 when the controller is
not certified (not stable, stable without a certificate, undecided) and
``--allow-uncertified`` was not given: the analysis verdict is printed and nothing is written.
``export-loop`` also refuses (exit 2) a mode outside ``1..m``, a plant map that does not fit
the system or the controller, or one with an operating point.
"""

from __future__ import annotations

import argparse
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from .common import (EXIT_NEGATIVE, EXIT_OK, EXIT_UNCERTIFIED, EXIT_UNDECIDED, bad, check_output_file, fmt, load,
                     positive)

__all__ = ["add_export_commands"]

#: The default sampling period: the simulators' default ``--step``.
DEFAULT_STEP = 0.01


def _period(args: argparse.Namespace, controller: Any) -> float:
    """The export's sampling period: ``--step``, else the controller file's ``period``,
    else :data:`DEFAULT_STEP`; a ``--step`` that differs from the file's period is refused."""
    if controller.period is None:
        return float(DEFAULT_STEP if args.step is None else args.step)
    if args.step is not None and float(args.step) != float(controller.period):
        raise bad(f"--step {args.step}: differs from the controller's period {controller.period} "
                  f"({args.controller}); the export runs at the period the controller was certified for")
    return float(controller.period)


def _check_output(args: argparse.Namespace, suffix: str) -> None:
    check_output_file(args.output, "-o", (suffix,), inputs=(args.controller, args.system))
    if Path(args.output).exists() and not args.force:
        raise bad(f"-o {args.output}: exists; give --force to replace it")


def _certify(args: argparse.Namespace, system: Any, controller: Any, command: str) -> tuple[int, dict[str, str], str]:
    """The analysis of the loop, printed: ``(exit code, certificate attributes, title)``;
    the code is 0 unless the controller is refused (not certified, no ``--allow-uncertified``)."""
    from ..export.certificate import export_certificate

    from ..analysis.solvers import interruptible

    cert, rep = interruptible(lambda: export_certificate(system, controller, float(args.step), solver=args.solver),
                              "the analysis")
    print(f"ftc-verify {command}: {system.name} ({controller.describe(system.m)})")
    gammas = f"nominal gamma {fmt(cert.nominal_gamma)}, robust gamma {fmt(cert.robust_gamma)}" if cert.certified else ""
    print(f"  analysis: {cert.verdict}{'; ' + gammas if gammas else ''}")
    attrs = cert.attributes()
    title = (f"controller {controller.name or args.controller!r} for system {system.name!r}: "
             f"{cert.verdict} ({', '.join(f'{k}={v}' for k, v in attrs.items() if k != 'tool')})")
    if cert.certified or args.allow_uncertified:
        return EXIT_OK, attrs, title
    print("  verdict: refused (the controller is not certified; --allow-uncertified exports it anyway, "
          "recording that it is not)")
    if rep.mss.undecided or cert.sampled_verdict == "undecided":
        return EXIT_UNDECIDED, attrs, title
    if cert.sampled_verdict == "not stable":
        return EXIT_NEGATIVE, attrs, title  # the loop as exported is proved unstable at its period
    return (EXIT_UNCERTIFIED if rep.mss.stable else EXIT_NEGATIVE), attrs, title


def _require_gcc() -> None:
    """A missing compiler is refused before the analysis."""
    from ..export.controller_fmu import controller_source_dir
    from ..plants.build import find_gcc

    find_gcc(controller_source_dir() / "ctrl_glue.c")


def _cmd_export_controller(args: argparse.Namespace) -> int:
    from ..export.ccode import controller_c_source, controller_tables

    if args.c == (args.fmi is not None):
        raise bad("export-controller: give exactly one of --fmi 2.0|3.0 (an FMU) and --c (a C99 file)")
    _check_output(args, ".c" if args.c else ".fmu")
    system, controller = load(args.system, args.controller)
    args.step = _period(args, controller)
    tables = controller_tables(controller, float(args.step), system.m)
    if not args.c:
        _require_gcc()
    code, attrs, title = _certify(args, system, controller, "export-controller")
    if code != EXIT_OK:
        return code
    source = controller_c_source(tables, title=title)
    out = Path(args.output)
    if args.c:
        from ..model.files import write_atomic

        write_atomic(out, source)
        print(f"  C99 file: {out} (sampling period {args.step!r} s, {tables.modes} FDI modes, order {tables.nc})")
    else:
        with _staging(out) as folder:
            fmu = _controller_fmu(folder / out.name, args.fmi, system, controller, tables, source, attrs, title)
            fmu.replace(out)
        print(f"  FMU (FMI {args.fmi}, co-simulation, sampling period {args.step!r} s): {out} "
              "(FMPy validation: no problems)")
    print(f"  verdict: exported ({attrs['verdict']})")
    return EXIT_OK


@contextmanager
def _staging(out: Path) -> Iterator[Path]:
    """A temporary folder beside ``out`` (removed in every case): built and checked there,
    then renamed into place, so nothing is half-written."""
    import shutil
    import tempfile

    folder = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent if str(out.parent) else "."))
    try:
        yield folder
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def _controller_fmu(dest: Path, fmi: str, system: Any, controller: Any, tables: Any, source: str,
                    attrs: dict[str, str], title: str) -> Path:
    """The controller FMU ``dest``, built and checked by FMPy's validation."""
    from ..controllers.files import dump_controller
    from ..errors import FMUError
    from ..export.controller_fmu import build_controller_fmu
    from ..model.files import dump_system
    from ..plants.controller_session import fmu_problems

    fmu = build_controller_fmu(tables, source, dest, fmi_version=fmi, description=title, certificate=attrs,
                               resources={"controller.toml": dump_controller(controller),
                                          "system.toml": dump_system(system)})
    problems = fmu_problems(fmu)
    if problems:
        raise FMUError(f"{dest.name}: FMPy's validation found problems: {'; '.join(problems)}")
    return fmu


def _modes(args: argparse.Namespace, m: int) -> None:
    for option, value in (("--fault-mode", args.fault_mode), ("--fdi-mode", args.fdi_mode)):
        if not 1 <= value <= m:
            raise bad(f"{option} {value}: the system has modes 1..{m}")


def _cmd_export_loop(args: argparse.Namespace) -> int:
    from ..export.ccode import controller_c_source, controller_tables
    from ..export.ssp import loop_spec, write_loop_ssp
    from ..plants.controller_session import fmu_variable_types
    from ..plants.plant_map import check_controller, load_plant_map
    from ..simulation.supervisor import resolve_plant

    _check_output(args, ".ssp")
    system, controller = load(args.system, args.controller)
    args.step = _period(args, controller)
    _modes(args, system.m)
    tables = controller_tables(controller, float(args.step), system.m)
    plant = None if args.plant is None else load_plant_map(args.plant)
    plant = resolve_plant(system, plant)  # default: the LinearJumpPlant FMU of the system (built when missing)
    check_controller(plant, controller, args.controller)
    spec = loop_spec(plant.injection_map(), fmu_variable_types(plant.fmu), controller, fault_mode=args.fault_mode,
                     fdi_mode=args.fdi_mode, x0=args.x0, step=float(args.step), stop_time=args.stop_time,
                     name=system.name)
    _require_gcc()
    code, attrs, title = _certify(args, system, controller, "export-loop")
    if code != EXIT_OK:
        return code
    out = Path(args.output)
    with _staging(out) as folder:
        fmu = _controller_fmu(folder / "controller.fmu", "2.0", system, controller, tables,
                              controller_c_source(tables, title=title), attrs, title)
        write_loop_ssp(spec, plant.fmu, fmu, folder / out.name).replace(out)
    print(f"  SSP 1.0: {out} (plant {Path(plant.fmu).name}, controller FMU FMI 2.0 with period {args.step!r} s; "
          f"fault mode {args.fault_mode}, FDI mode {args.fdi_mode})")
    print(f"  verdict: exported ({attrs['verdict']})")
    return EXIT_OK


def _floats(text: str) -> list[float]:
    """Argument type: comma-separated finite numbers."""
    import math

    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from None
    if not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"expected finite numbers, got {text!r}")
    return values


def _common_options(parser: argparse.ArgumentParser, suffix: str) -> None:
    parser.add_argument("-o", "--output", required=True, help=f"the file to write ({suffix})")
    parser.add_argument("--step", type=positive, default=None,
                        help="sampling period h in s (default: the controller file's period, else 0.01, the "
                             "simulators' default --step); the exported update is exact for this period and "
                             "refuses any other step; a --step that differs from the file's period is refused")
    parser.add_argument("--force", action="store_true", help="replace an existing output file")
    parser.add_argument("--allow-uncertified", action="store_true",
                        help="export a controller the analysis does not certify (the record says so)")
    parser.add_argument("--solver", default="auto", choices=["auto", "clarabel", "sdpa", "scs"],
                        help="LMI solver of the certificate (default: auto = clarabel at every size; sdpa and scs "
                             "on request)")


def add_export_commands(sub: Any) -> None:
    """Register ``export-controller`` and ``export-loop`` on the CLI's subparsers."""
    e = sub.add_parser("export-controller",
                       help="write a certified controller as an FMI 2.0/3.0 co-simulation FMU or a C99 file")
    e.add_argument("controller", help="controller TOML file ([[gain]] or [[controller]] tables, one per FDI mode)")
    e.add_argument("--system", required=True, help="system TOML file the controller is certified for")
    e.add_argument("--fmi", choices=["2.0", "3.0"], default=None, help="write an FMU of this FMI version")
    e.add_argument("--c", action="store_true", help="write one dependency-free C99 file instead of an FMU")
    _common_options(e, ".fmu, or .c with --c")
    e.set_defaults(func=_cmd_export_controller)

    s = sub.add_parser("export-loop", help="write the closed loop (plant FMU + controller FMU) as an SSP 1.0 archive")
    s.add_argument("system", help="system TOML file")
    s.add_argument("--controller", required=True, help="controller TOML file (one table per FDI mode)")
    s.add_argument("--plant", default=None, help="plant map TOML file (default: the LinearJumpPlant of the system)")
    s.add_argument("--fault-mode", type=int, default=1, help="the true fault mode of the loop, 1-based (default 1)")
    s.add_argument("--fdi-mode", type=int, default=1, help="the FDI mode of the loop, 1-based (default 1)")
    s.add_argument("--x0", type=_floats, default=None, help="initial plant state, comma-separated (default: the FMU's)")
    s.add_argument("--stop-time", type=positive, default=10.0, help="the default experiment's stop time (default 10 s)")
    _common_options(s, ".ssp")
    s.set_defaults(func=_cmd_export_loop)


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
