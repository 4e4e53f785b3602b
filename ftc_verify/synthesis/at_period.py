"""Synthesis for the loop that runs: a certified controller whose sampled loop at the
controller's period is proved mean-square stable (``synthesize --period H``).

The synthesis LMIs are those of the continuous-time loop. A controller designed without
regard to the period can be certified there and still make the sampled loop unstable
(the paper's plant at ``h = 0.1``: large gains move the continuous poles far left, where
a period of 0.1 s cannot follow them). :func:`synthesize_at_period` designs with a
sequence of gain bounds, largest first, and returns the first design that is certified
(continuous time: robust gamma, stability) **and** whose sampled loop at the period is
proved mean-square stable over the whole rate box
(:func:`ftc_verify.analysis.moments.sampled.sampled_analysis`). A smaller gain bound trades
continuous-time gamma for a longer ``h_max``. It never returns a controller whose sampled
loop was not proved stable: if no bound gives one, the result says so and carries the
attempts.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from ..analysis.moments.sampled import SampledResult, sampled_analysis
from ..analysis.solvers import interruptible
from ..controllers.controller import Controller
from ..model.system import FTCSystem

__all__ = ["GAIN_BOUNDS", "PeriodDesign", "synthesize_at_period"]

#: Gain bounds tried after the user's own (spectral norm of every gain or controller block).
GAIN_BOUNDS = (30.0, 15.0, 8.0, 4.0, 2.0, 1.0)


@dataclass(frozen=True, eq=False)
class PeriodDesign:
    """The outcome of :func:`synthesize_at_period`.

    ``result`` is the accepted synthesis result (or the last one tried), ``controller``
    the accepted controller with its ``period`` set (``None`` when none was proved stable
    at the period), ``sampled`` its sampled-loop analysis, ``attempts`` one row per gain
    bound tried: ``k_max``, ``certified``, ``gamma_certified``, ``sampled_verdict``,
    ``h_max``."""

    result: Any
    controller: Controller | None
    sampled: SampledResult | None
    attempts: tuple[dict[str, Any], ...]

    @property
    def found(self) -> bool:
        """A certified controller whose sampled loop is proved stable at the period."""
        return self.controller is not None


def synthesize_at_period(system: FTCSystem, period: float, design: Callable[[float | None], Any],
                         controller_of: Callable[[Any], Controller], *, k_max: float | None = None,
                         bounds: Sequence[float] = GAIN_BOUNDS) -> PeriodDesign:
    """Design with ``design(k_max)`` (a synthesis result with ``certified``,
    ``gamma_certified``) for ``k_max`` = the user's bound, then each of ``bounds`` below
    it, until the sampled loop of ``controller_of(result)`` at ``period`` is proved
    mean-square stable (module docstring)."""
    tried: list[float | None] = [k_max]
    tried += [b for b in bounds if k_max is None or b < k_max]
    attempts: list[dict[str, Any]] = []
    last = None
    for bound in tried:
        res = design(bound)
        last = res
        row: dict[str, Any] = {"k_max": bound, "certified": bool(res.certified),
                               "gamma_certified": res.gamma_certified if res.certified else None,
                               "sampled_verdict": None, "h_max": None}
        attempts.append(row)
        if not res.certified:
            continue
        controller = controller_of(res)
        sampled = interruptible(functools.partial(sampled_analysis, system, controller, period),
                                "the sampled-data analysis")
        row["sampled_verdict"], row["h_max"] = sampled.verdict, sampled.h_max
        if sampled.stable:
            return PeriodDesign(res, controller.with_period(period), sampled, tuple(attempts))
    return PeriodDesign(last, None, None, tuple(attempts))
