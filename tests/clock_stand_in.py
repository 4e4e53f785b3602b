"""A stand-in for :func:`ftc_verify.analysis.moments.sampled_clock.clock_stable` in the
bracket's tests (``test_bracket_h31p.py``, ``test_bracket_h31n.py``): it proves every
period up to a limit and records the periods asked, so a test can check which distances
the clock rung tries, in which order, without solving a program."""

from __future__ import annotations

from ftc_verify.analysis.moments.sampled import SampledLoop


class ProvedUpTo:
    """Proves every period at most ``limit``; ``asked``: the periods asked, in order."""

    def __init__(self, limit: float) -> None:
        self.limit = limit
        self.asked: list[float] = []

    def __call__(self, loop: SampledLoop, h: float, pieces: int, quadratic: bool) -> object:
        self.asked.append(h)

        class Cert:
            proved = h <= self.limit

        return Cert()
