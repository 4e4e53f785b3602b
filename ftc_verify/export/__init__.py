"""Exporting a certified controller: C code, FMI 2.0 / 3.0 co-simulation FMUs, SSP.

* :mod:`ftc_verify.export.ccode` -- the sampled FDI-switched controller as one C99 file;
* :mod:`ftc_verify.export.controller_fmu` -- its co-simulation FMU (model description,
  glue, compiling, archive);
* :mod:`ftc_verify.export.certificate` -- the certificate an export records and the
  refusal of an uncertified controller.
"""

from __future__ import annotations

__all__: list[str] = []
