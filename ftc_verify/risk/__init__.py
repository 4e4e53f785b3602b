"""Stage 6: the probability of leaving the safe envelope (issue 35): a proved upper bound
from the certificates (:mod:`ftc_verify.risk.bound`) and the FDI timing view
(:mod:`ftc_verify.risk.timing`)."""

from __future__ import annotations

__all__ = []  # the names of bound and timing are imported from their modules
