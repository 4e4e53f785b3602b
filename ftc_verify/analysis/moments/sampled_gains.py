r"""The sampled loop's gains at one period: proved lower bounds, then both certificates.

What ``analyze --period`` and ``verify --step`` report as ``sampled.nominal_gamma``,
``sampled.robust_gamma`` and their lower bounds
(:func:`~ftc_verify.analysis.moments.sampled_gamma.sampled_performance` calls
:func:`sampled_gains`). The order is the point:

1. the proved lower bounds of :mod:`~ftc_verify.analysis.moments.sampled_lower`, nominal
   and robust from one float64 search (the nominal candidates, :math:`\Delta = 0`, are
   among the robust ones); the robust bound is raised to the nominal one when that is
   larger (:math:`\Delta = 0` is admissible);
2. the certificates of :func:`~ftc_verify.analysis.moments.sampled_gamma.sampled_gamma`
   with those bounds as ``target`` (more pieces only while the gamma stays far above
   the bound), the robust one in a forked child beside the nominal one
   (:class:`~ftc_verify.analysis.solvers.ForkedCall`: each solve is single-threaded, so
   the two use two cores). The robust certificate covers :math:`\Delta = 0`: when its
   gamma is smaller, it is the nominal one too.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

from ...controllers.controller import Controller
from ...model.system import FTCSystem
from .sampled import SampledLoop
from .sampled_gamma import SampledGamma, SampledPerformance, sampled_gamma
from .sampled_energy import gain_lower_estimate

__all__ = ["sampled_gains"]


def _lowers(system: FTCSystem, controller: Controller, period: float,
            loop: SampledLoop) -> tuple[tuple[float | None, str, str], tuple[float | None, str, str]]:
    """``((value, where, kind) nominal, robust)``: the proved bounds of
    :func:`~ftc_verify.analysis.moments.sampled_lower.sampled_lower_bounds`, each else
    the float64 :func:`gain_lower_estimate` (kind ``"estimate"``); the robust one
    ``(None, "no uncertainty channels", "estimate")`` without uncertainty."""
    from .sampled_lower import sampled_lower_bounds

    def pick(low: Any, robust: bool) -> tuple[float | None, str, str]:
        if low.value is not None:
            return low.value, low.where, "proved"
        est, where = gain_lower_estimate(system, controller, period, robust=robust)
        return est, f"{where} (no proved bound: {low.where})", "estimate"

    nom, rob = sampled_lower_bounds(system, controller, period, loop=loop)
    return pick(nom, False), (pick(rob, True) if rob is not None else (None, "no uncertainty channels", "estimate"))


def _certificates(system: FTCSystem, controller: Controller, period: float, loop: SampledLoop,
                  targets: tuple[float | None, float | None]) -> tuple[SampledGamma, SampledGamma | None]:
    """The nominal and (with uncertainty) robust :func:`sampled_gamma`, the robust one in
    a forked child beside the nominal one where the platform forks
    (:class:`~ftc_verify.analysis.solvers.ForkedCall`: two cores, each solve single-threaded)."""
    import os

    from ..solvers import ForkedCall

    def robust_one() -> SampledGamma:
        return sampled_gamma(system, controller, period, robust=True, loop=loop, target=targets[1])

    forked = ForkedCall(robust_one, "the robust sampled gain") if system.uncertain and hasattr(os, "fork") else None
    try:
        nominal = sampled_gamma(system, controller, period, robust=False, loop=loop, target=targets[0])
        if forked is not None:
            return nominal, forked.result()
    finally:
        if forked is not None:
            forked.cancel()
    return nominal, robust_one() if system.uncertain else None


def sampled_gains(system: FTCSystem, controller: Controller, period: float, *,
                  loop: SampledLoop | None = None) -> SampledPerformance:
    """Both certificates (robust only with uncertainty channels) and their lower bounds
    (proved, else float64 estimates; the robust one at least the nominal: Delta = 0 is
    admissible). The lower bounds come first: proved, they are the certificates'
    ``target`` (:func:`~ftc_verify.analysis.moments.sampled_gamma.sampled_gamma`).
    ``loop``: :meth:`SampledLoop.build` of ``system, controller`` (built here when ``None``)."""
    loop = SampledLoop.of(system, controller, loop)
    (lo_n, where_n, kind_n), (lo_r, where_r, kind_r) = _lowers(system, controller, period, loop)
    if kind_n == kind_r == "proved" and lo_r is not None and lo_n is not None and lo_n > lo_r:
        lo_r, where_r = lo_n, f"Delta = 0 (admissible): {where_n}"
    nominal, robust = _certificates(system, controller, period, loop,
                                    (lo_n if kind_n == "proved" else None, lo_r if kind_r == "proved" else None))
    if robust is not None and robust.gamma is not None and (nominal.gamma is None or robust.gamma < nominal.gamma):
        nominal = replace(nominal, gamma=robust.gamma, pieces=robust.pieces, degree=robust.degree, rows=robust.rows,
                          note=f"the robust certificate (Delta = 0 is admissible): {robust.note}")
    return SampledPerformance(float(period), nominal, robust, lo_n, where_n, lo_r, where_r, kind_n, kind_r)
