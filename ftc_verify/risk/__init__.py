"""The probability of leaving the safe envelope (issue 35): the envelope
(:mod:`~ftc_verify.risk.envelope`), importance sampling of the chain
(:mod:`~ftc_verify.risk.importance`), the estimator (:mod:`~ftc_verify.risk.estimate`)
and the risk run (:mod:`~ftc_verify.risk.run`)."""

from .envelope import Envelope, output_envelope, region_envelope, state_envelope
from .estimate import Estimate, Settings, estimate_probability
from .run import RiskResult, run_risk

__all__ = ["Envelope", "output_envelope", "region_envelope", "state_envelope", "Estimate", "Settings",
           "estimate_probability", "RiskResult", "run_risk"]
