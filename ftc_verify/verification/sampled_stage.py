"""The sampled-loop stage of ``verify``: the loop it simulates, analysed at its period.

``verify --step h`` co-simulates the controller sampled every ``h`` with its output held
(:mod:`ftc_verify.simulation.reference`); this stage proves (or refutes) mean-square
stability of that sampled loop over the rate box at ``h`` and finds the proved ``h_max``
bracket (:func:`ftc_verify.analysis.sampled.sampled_analysis`). The continuous-time
certificates of the other stages are its :math:`h \\to 0` limit.
"""

from __future__ import annotations

from ..analysis.sampled import SampledLoop, SampledResult, sampled_analysis
from ..controllers.controller import Controller
from ..model.system import FTCSystem
from .verify import Check

__all__ = ["SAMPLED_LIMIT", "sampled_stage"]

#: Largest second-moment generator (rows, joint states times ``d (d + 1) / 2`` with
#: ``d = n + n_u + n_c``) the stage analyses; its rigorous exponential is the cost.
SAMPLED_LIMIT = 400


def sampled_stage(system: FTCSystem, controller: Controller, step: float) -> tuple[SampledResult | None, Check]:
    """``(result, check)`` of the sampled loop at period ``step``: the check passes when
    mean-square stability over the whole rate box is proved; a loop above
    :data:`SAMPLED_LIMIT` is not analysed (said in the check, which then passes as
    before this stage existed and names what it does not cover)."""
    loop = SampledLoop.build(system, controller)
    d = loop.d
    rows = loop.states * d * (d + 1) // 2
    name = f"sampled loop (h = {step:g})"
    if rows > SAMPLED_LIMIT:
        return None, Check(name, True, f"NOT analysed: its moment generator has {rows} rows (limit {SAMPLED_LIMIT}); "
                                       "the certificates above are those of the continuous-time loop")
    res = sampled_analysis(system, controller, step)
    if res.h_max is None or res.h_max_unstable is None:
        bracket = "h_max not found: " + res.h_max_note
    else:
        bracket = f"h_max {res.h_max:.6g} (proved stable; unstable at {res.h_max_unstable:.6g})"
    word = {"stable": "mean-square stable", "not stable": "NOT mean-square stable",
            "undecided": "UNDECIDED"}[res.verdict]
    return res, Check(name, res.stable, f"{word}: spectral radius of the one-period map {res.spectral_radius:.6g}; "
                                        f"{res.proof}; {bracket}")
