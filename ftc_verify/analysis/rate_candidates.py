"""The candidate rate vectors of the proved lower bounds (:mod:`~ftc_verify.analysis.lower_bound`)."""

from __future__ import annotations

import numpy as np

from ..model.system import Matrix
from .closedloop import ClosedLoop
from .exact import written_box

__all__ = ["candidate_rates"]


def candidate_rates(loop: ClosedLoop, worst: Matrix | None) -> list[Matrix]:
    """The rate vectors :func:`~ftc_verify.analysis.lower_bound.gain_lower_bound` tries first:
    just inside the box's lowest and highest corners (as written), its centre, and ``worst``
    (the worst spectral-abscissa vertex) clipped into the box; no duplicates."""
    chain = loop.chain
    lo, hi = written_box(chain.rate_min, chain.rate_max)
    inner_lo = np.where(lo < hi, np.nextafter(lo, np.inf), lo)  # strictly inside the box as written
    inner_hi = np.where(lo < hi, np.nextafter(hi, -np.inf), hi)
    points = [inner_lo, 0.5 * (lo + hi), inner_hi]
    if worst is not None:
        points.append(np.clip(np.asarray(worst, dtype=float), inner_lo, inner_hi))
    out: list[Matrix] = []
    for p in points:
        if not any(np.array_equal(p, o) for o in out):
            out.append(p)
    return out
