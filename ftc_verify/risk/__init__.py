"""The probability of leaving the safe envelope (issue 35): the envelope
(:mod:`~ftc_verify.risk.envelope`), importance sampling of the chain
(:mod:`~ftc_verify.risk.importance`), the estimator (:mod:`~ftc_verify.risk.estimate`),
the risk run (:mod:`~ftc_verify.risk.run`) and the estimate against the horizon
(:mod:`~ftc_verify.risk.horizon`); a proved upper bound from the certificates
(:mod:`~ftc_verify.risk.bound`) and the FDI timing view (:mod:`~ftc_verify.risk.timing`),
whose names are imported from their modules."""

from __future__ import annotations

from .envelope import Envelope, output_envelope, region_envelope, state_envelope
from .estimate import Estimate, Settings, estimate_probability
from .run import RiskResult, run_risk

__all__ = ["Envelope", "output_envelope", "region_envelope", "state_envelope", "Estimate", "Settings",
           "estimate_probability", "RiskResult", "run_risk"]
