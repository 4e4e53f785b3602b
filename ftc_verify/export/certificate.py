r"""What an exported controller carries about its certificate, and the refusal of an uncertified one.

:func:`export_certificate` runs the package's own analysis
(:func:`~ftc_verify.analysis.analyze.analyze` on
:func:`~ftc_verify.analysis.closedloop.closed_loop`) of ``(system, controller)``: the
controller is *certified* when the exact spectral test proves mean-square stability at every
rate vertex and the Theorem 3.1 certificate passed (``certified_stable``); the
nominal (Theorem 3.2) and robust (Lemma 4.1) :math:`\gamma` are recorded when certified.
The analysis is of the continuous-time loop; the export samples the controller with period
:math:`h` (:mod:`ftc_verify.export.ccode`), the loop the simulators run. No certificate
for the sampled loop exists yet (the sampled-data analysis, ``h_max``, is future work): the
record says so (``h_max = "not computed"``).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

from .. import __version__
from ..analysis.analyze import AnalysisReport, analyze
from ..analysis.closedloop import closed_loop
from ..controllers.controller import Controller
from ..controllers.files import dump_controller
from ..model.files import dump_system
from ..model.system import FTCSystem

__all__ = ["ExportCertificate", "export_certificate"]


@dataclass(frozen=True)
class ExportCertificate:
    """The record an export writes into its model description and C file.

    Attributes
    ----------
    verdict : str
        ``certified``, ``stable, not certified``, ``not stable`` or ``undecided``.
    certified : bool
        ``certified_stable`` of the analysis.
    nominal_gamma, robust_gamma : float or None
        The certified levels (None when not certified).
    period : float
        The sampling period of the export.
    system_name, system_sha256, controller_name, controller_sha256 : str
        What was certified: names and the SHA-256 of the canonical TOML texts
        (:func:`~ftc_verify.model.files.dump_system`,
        :func:`~ftc_verify.controllers.files.dump_controller`).
    """

    verdict: str
    certified: bool
    nominal_gamma: float | None
    robust_gamma: float | None
    period: float
    system_name: str
    system_sha256: str
    controller_name: str
    controller_sha256: str

    def attributes(self) -> dict[str, str]:
        """The record as XML attributes (numbers with ``repr``; ``none`` for a missing gamma)."""
        def num(x: float | None) -> str:
            return "none" if x is None else repr(float(x))

        return {"verdict": self.verdict, "certified": "true" if self.certified else "false",
                "nominalGamma": num(self.nominal_gamma), "robustGamma": num(self.robust_gamma),
                "period": repr(self.period), "hMax": "not computed", "systemName": self.system_name,
                "systemSha256": self.system_sha256, "controllerName": self.controller_name,
                "controllerSha256": self.controller_sha256, "tool": f"ftc-verify {__version__}"}


def _verdict(rep: AnalysisReport) -> str:
    if rep.certified_stable:
        return "certified"
    if rep.mss.undecided:
        return "undecided"
    return "stable, not certified" if rep.mss.stable else "not stable"


def export_certificate(system: FTCSystem, controller: Controller, period: float, *,
                       solver: str = "auto") -> tuple[ExportCertificate, AnalysisReport]:
    """Analyse ``(system, controller)`` and return the record of an export with ``period``
    and the analysis report (module docstring)."""
    rep = analyze(closed_loop(system, controller), solver=solver, name=system.name)
    ok = rep.certified_stable
    cert = ExportCertificate(
        verdict=_verdict(rep), certified=ok,
        nominal_gamma=rep.nominal.gamma if ok and rep.nominal.certified else None,
        robust_gamma=rep.robust.gamma if ok and rep.robust.certified else None,
        period=float(period), system_name=system.name,
        system_sha256=hashlib.sha256(dump_system(system).encode()).hexdigest(),
        controller_name=controller.name,
        controller_sha256=hashlib.sha256(dump_controller(controller).encode()).hexdigest())
    return cert, rep
