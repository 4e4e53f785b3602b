r"""What an exported controller carries about its certificate, and the refusal of an uncertified one.

:func:`export_certificate` runs the package's own analysis
(:func:`~ftc_verify.analysis.analyze.analyze` on
:func:`~ftc_verify.analysis.closedloop.closed_loop`) of ``(system, controller)``: the
controller is *certified* when mean-square stability is proved over the whole rate box and
the Theorem 3.1 certificate passed (``certified_stable``) *and* the loop as exported -- the
controller sampled with period :math:`h` (:mod:`ftc_verify.export.ccode`), its output held
-- is proved mean-square stable over the box at that period
(:func:`~ftc_verify.analysis.moments.sampled.sampled_analysis`); the nominal (Theorem 3.2) and
robust (Lemma 4.1) :math:`\gamma` of the continuous loop (the :math:`h \to 0` limit) are
recorded when certified, with the sampled verdict and the proved ``h_max`` (the largest
period proved stable; ``none`` when no bracket was proved).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

from .. import __version__
from ..analysis.analyze import AnalysisReport, analyze
from ..analysis.closedloop import closed_loop
from ..analysis.moments.sampled import SampledResult, sampled_analysis
from ..analysis.solvers import interruptible
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
    sampled_verdict : str
        Mean-square stability of the sampled loop at ``period`` over the rate box.
    h_max : float or None
        The largest period proved stable (the sampled-data analysis), or None.
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
    sampled_verdict: str
    h_max: float | None
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
                "period": repr(self.period), "sampledVerdict": self.sampled_verdict, "hMax": num(self.h_max),
                "systemName": self.system_name,
                "systemSha256": self.system_sha256, "controllerName": self.controller_name,
                "controllerSha256": self.controller_sha256, "tool": f"ftc-verify {__version__}"}


def _verdict(rep: AnalysisReport, sampled: SampledResult) -> str:
    if rep.certified_stable:
        return "certified" if sampled.stable else f"certified in continuous time, {sampled.verdict} at the period"
    if rep.mss.undecided:
        return "undecided"
    return "stable, not certified" if rep.mss.stable else "not stable"


def export_certificate(system: FTCSystem, controller: Controller, period: float, *,
                       solver: str = "auto") -> tuple[ExportCertificate, AnalysisReport]:
    """Analyse ``(system, controller)`` and return the record of an export with ``period``
    and the analysis report (module docstring)."""
    rep = analyze(closed_loop(system, controller), solver=solver, name=system.name)
    sampled = interruptible(lambda: sampled_analysis(system, controller, float(period), max_seconds=30.0),
                            "the sampled-data analysis")
    ok = rep.certified_stable and sampled.stable
    cert = ExportCertificate(
        verdict=_verdict(rep, sampled), certified=ok,
        nominal_gamma=rep.nominal.gamma if ok and rep.nominal.certified else None,
        robust_gamma=rep.robust.gamma if ok and rep.robust.certified else None,
        period=float(period), sampled_verdict=sampled.verdict, h_max=sampled.h_max, system_name=system.name,
        system_sha256=hashlib.sha256(dump_system(system).encode()).hexdigest(),
        controller_name=controller.name,
        controller_sha256=hashlib.sha256(dump_controller(controller).encode()).hexdigest())
    return cert, rep
