"""Exporting a certified controller: C code, FMI 2.0 / 3.0 co-simulation FMUs, SSP.

* :mod:`ftc_verify.export.ccode` -- the sampled FDI-switched controller as one C99 file;
* :mod:`ftc_verify.export.controller_fmu` -- its co-simulation FMU (model description,
  glue, compiling, archive);
* :mod:`ftc_verify.export.certificate` -- the certificate an export records and the
  refusal of an uncertified controller;
* :mod:`ftc_verify.export.ssp` -- the closed loop (plant FMU and controller FMU) as an
  SSP 1.0 archive.
"""

from __future__ import annotations

from .ccode import ControllerTables, controller_c_source, controller_tables
from .certificate import ExportCertificate, export_certificate
from .controller_fmu import build_controller_fmu
from .ssp import LoopSpec, write_loop_ssp

__all__ = ["ControllerTables", "controller_tables", "controller_c_source", "ExportCertificate", "export_certificate",
           "build_controller_fmu", "LoopSpec", "write_loop_ssp"]
