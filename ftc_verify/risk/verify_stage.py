r"""The risk stage of ``ftc-verify verify``: when the plant map declares ``[risk]``, the
probability of leaving its ``[region]`` within ``[0, T]``, by :func:`~ftc_verify.risk.run.run_risk`.

The stage reuses the risk run as ``ftc-verify risk --region MAP`` runs it: the envelope is
the map's ``[region]`` around its operating point (:func:`~ftc_verify.risk.envelope.region_envelope`),
the loop is verify's (its step, seed, ``x0``, the paper's disturbance, the rates at the
centre of the box), on the map's FMU (``backend = "fmu"``, the default, on verify's Dask
client when there is one) or on the numpy reference of the linearisation
(``backend = "reference"``), with the settings of :class:`~ftc_verify.plants.plant_map.RiskTarget`.

The pass/fail rule with a ``target`` :math:`p^*`: the stage passes when

* the proved upper bound (:mod:`ftc_verify.risk.bound`, of the continuous-time loop) is at
  most :math:`p^*`, or
* the upper end of the estimate's interval is at most :math:`p^*` and that interval is
  informative: the Wilson interval of crude Monte Carlo (informative with any number of
  hits), or the normal interval of importance sampling with at least
  :data:`~ftc_verify.risk.estimate.MIN_HITS` hits (with fewer, the estimated spread says
  nothing; a zero estimate is no proof of zero).

It fails otherwise (the detail says whether the estimate is above the target or
undecided). The statistical half of the rule holds at the interval's confidence: the
claim is :math:`P \le p^*` at that confidence, not a proof. Without a target the stage
reports and adds no check.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..claimtext import upper_text
from ..controllers.controller import Controller
from ..model.system import FTCSystem
from ..simulation.spec import SimulationSpec
from .envelope import region_envelope
from .estimate import MIN_HITS, Settings
from .run import available_stages, run_risk

__all__ = ["verify_risk_stage", "risk_verdict"]


def risk_verdict(result: dict[str, Any], target: float | None) -> tuple[bool | None, str]:
    """The rule of the module docstring on a :meth:`RiskResult.to_dict
    <ftc_verify.risk.run.RiskResult.to_dict>`: ``(ok, detail)``, ``ok`` ``None`` without a
    target."""
    lo, hi = result["ci"]
    bound = (result.get("upper_bound") or {}).get("value")
    informative = result["method"] == "crude" or result["hits"] >= MIN_HITS
    text = (f"P(leave {result['envelope']} within [0, {result['horizon']:g}]) = {result['probability']:.4g}, "
            f"{100 * result['confidence']:g} % interval [{lo:.4g}, {hi:.4g}] ({result['method']}, "
            f"{result['paths']} paths, {result['hits']} left, {result['backend']}); proved upper bound "
            + ("none" if bound is None else upper_text(bound, 4)))
    if target is None:
        return None, text + "; no [risk].target: reported only"
    if bound is not None and bound <= target:
        return True, text + f"; proved bound <= target {target:g}"
    if informative and hi <= target:
        return True, text + f"; interval's upper end <= target {target:g} (at {100 * result['confidence']:g} %)"
    if not informative:
        return False, text + (f"; undecided against target {target:g}: {result['hits']} hits, fewer than "
                              f"{MIN_HITS}, the interval is not informative")
    return False, text + f"; interval's upper end above target {target:g}"


def verify_risk_stage(system: FTCSystem, controller: Controller, plant: Any, spec: SimulationSpec,
                      client: Any = None) -> tuple[dict[str, Any], bool | None, str]:
    """Run the stage of the module docstring for the plant map ``plant`` (its ``risk``
    must be set) on verify's ``spec`` (step, seed, ``x0``, disturbance); returns the risk
    result's JSON dict with ``target``, and :func:`risk_verdict`'s ``(ok, detail)``."""
    rt = plant.risk
    envelope = region_envelope(plant.states_min, plant.states_max, plant.require_states_op("the risk stage"),
                               str(plant.source))
    settings = Settings(method=rt.method, relative_error=rt.relative_error, confidence=rt.confidence,
                        max_paths=rt.max_paths, pilot_paths=rt.pilot_paths, seed=int(spec.seed or 0))
    bound, timing = available_stages()
    res = run_risk(system, controller, envelope, horizon=rt.horizon, step=spec.step, settings=settings,
                   x0=None if spec.x0 is None else [float(v) for v in np.ravel(spec.x0)], disturbance=spec.disturbance, backend=rt.backend,
                   plant=plant if rt.backend == "fmu" else None, bound=bound, timing=timing, interval=rt.ftti,
                   client=client if rt.backend == "fmu" else None)
    d = res.to_dict() | {"target": rt.target}
    ok, detail = risk_verdict(d, rt.target)
    return d, ok, detail
