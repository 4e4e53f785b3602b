r"""The constant uncertainty of the robust lower bound, and the bound at it.

The robust gain is at least the gain of the loop with any one admissible uncertainty;
a constant :math:`\Delta` with :math:`\|\Delta\| \le 1` on every channel (the same in
every joint state) is admissible, and the proved lower bound of
:func:`~ftc_verify.analysis.lower_bound.gain_lower_bound` at it is a lower bound of the
robust gain (:mod:`~ftc_verify.analysis.lower_bound`, module docstring). Which
:math:`\Delta`: on every channel a rectangular diagonal of signs (an extreme point of
the unit ball), found by flipping one sign at a time while the float gain at one rate
vector grows (:func:`worst_constant_delta`).

**The search's cost.** Each flip is first compared with the best loop so far at
:math:`(1 + 10^{-3})` times its gain (:func:`~ftc_verify.analysis.lower_bound.exceeds`:
one policy iteration of the coupled bounded-real Riccati equations, warm-started from the
best loop's worst-case feedback, a failure decided again from :math:`F = 0`); only a flip
found above it gets its gain by bisection, which goes on from that level, first
:data:`CLIMB` up. The policy iterations of the search end as soon as an iterate falls
(:func:`~ftc_verify.analysis.lower_bound.worst_case_feedback`): no stabilising solution.

**The level of the feedback.** :func:`robust_lower_bound` takes the worst-case feedback
at the float gain the search found at the chosen :math:`\Delta` (the upper end of a
bisection bracket of relative width :math:`10^{-3}`), not at the certified robust
:math:`\gamma`: the gain at one constant :math:`\Delta` can be several per cent below the
certified :math:`\gamma` (which bounds every time-varying uncertainty), and the closer the
level to the loop's own gain, the closer the excitation's ratio to it (six random
n = 8, m = 3 loops: 0.1-4 % higher proved bounds, ``benchmarks/results/h37u.md``). The
search needs only the nominal gamma, so :func:`~ftc_verify.analysis.analyze.analyze`
runs it, and the bound, beside Lemma 4.1's program.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ..model.system import Matrix
from .closedloop import ClosedLoop
from .conditioning import conditioning_transform
from .lower_bound import GainLowerBound, exceeds, float_gain, gain_lower_bound, within_solve_limit

__all__ = ["CLIMB", "SEARCH_WIDTH", "worst_constant_delta", "robust_lower_bound"]

#: The first step of the search's gain above the level its comparison found infeasible
#: (one sign flip moved the gain by 0.07-0.4 % on random n = 8, m = 3 loops).
CLIMB = 0.01
#: Relative width of the search's bisections, and the margin a flip must clear.
SEARCH_WIDTH = 1e-3


def _search(loop: ClosedLoop, rates: Matrix, upper: float | None,
            passes: int) -> tuple[dict[str, Matrix], float]:
    """The signs of :func:`worst_constant_delta` as ``{channel: Delta}`` and the float gain
    there (the upper end of its bracket; ``-inf`` when no loop tried was mean-square stable)."""
    shapes = {ch.name: (ch.E.shape[1], ch.F.shape[0]) for chans in loop.channels for ch in chans}
    signs = {name: np.ones(min(shape)) for name, shape in shapes.items()}
    Q = loop.chain.generator(rates)

    def deltas(sg: dict[str, np.ndarray]) -> dict[str, Matrix]:
        out = {}
        for name, (p, q) in shapes.items():
            D = np.zeros((p, q))
            D[np.arange(len(sg[name])), np.arange(len(sg[name]))] = sg[name]
            out[name] = D
        return out

    def gain(sg: dict[str, np.ndarray], start: float | None, above: float | None = None,
             near: Sequence[Matrix] | None = None) -> tuple[float, Sequence[Matrix] | None]:
        found = float_gain(loop.perturbed(deltas(sg)), loop.Bw, loop.Cz, Q, upper=start, rtol=SEARCH_WIDTH,
                           above=above, start=near, climb=CLIMB, converge=False)
        return (-math.inf, None) if found is None else found

    best, F = gain(signs, upper)
    for _ in range(passes):
        improved = False
        for name in signs:
            for k in range(len(signs[name])):
                trial = {key: v.copy() for key, v in signs.items()}
                trial[name][k] = -trial[name][k]
                level = best * (1 + SEARCH_WIDTH)
                if not math.isfinite(best):
                    g, found = gain(trial, upper)
                elif exceeds(loop.perturbed(deltas(trial)), loop.Bw, loop.Cz, Q, level, F):
                    g, found = gain(trial, level, above=level, near=F)  # at least that
                else:
                    continue  # not clearly above the best so far
                if g > best:
                    best, signs, F, improved = g, trial, found, True
        if not improved:
            break
    return deltas(signs), best


def _label(delta: dict[str, Matrix]) -> str:
    return "Delta = " + ", ".join(f"{name}: diag{[int(v) for v in np.diag(D)]}" for name, D in delta.items())


def worst_constant_delta(loop: ClosedLoop, rates: Matrix, *, upper: float | None = None,
                         passes: int = 1) -> tuple[str, dict[str, Matrix]]:
    """A constant uncertainty of norm 1 that makes the float gain at ``rates`` large: on
    every channel a rectangular diagonal of signs, the same in every joint state, found by
    flipping one sign at a time while the coarse float gain grows by more than 0.1 % (at
    most ``passes`` sweeps; a second changed nothing on three random n = 8, m = 3 loops),
    the first gain searched from ``upper`` (module docstring). A search: the bound it leads
    to is proved afterwards. Returns a label and ``{channel name: Delta}``."""
    delta, _ = _search(conditioning_transform(loop).apply(loop), rates, upper, passes)
    return _label(delta), delta


def robust_lower_bound(loop: ClosedLoop, rates: Matrix, *, worst_rates: Matrix | None = None,
                       upper: float | None = None,
                       passes: int = 1) -> tuple[tuple[str, dict[str, Matrix]], GainLowerBound | None]:
    """The constant uncertainty of :func:`worst_constant_delta` at ``rates`` and the proved
    lower bound of :func:`~ftc_verify.analysis.lower_bound.gain_lower_bound` at it (the
    candidate rate vectors with ``worst_rates``), its feedback taken at the gain the search
    found (module docstring); the bound is ``None`` when no loop tried was mean-square
    stable. The search runs in the coordinates of
    :func:`~ftc_verify.analysis.conditioning.conditioning_transform` (a ``Delta``
    maps channels to channels: it does not depend on the state coordinates); above
    :data:`~ftc_verify.analysis.verdict.SOLVE_LIMIT` rows there is none (the bound says why)."""
    if not within_solve_limit(loop):  # no bound would be computed: no search either
        return ("Delta=0", {}), gain_lower_bound(loop, deltas=[("Delta=0", {})], upper=upper)
    delta, gain = _search(conditioning_transform(loop).apply(loop), rates, upper, passes)
    labelled = (_label(delta), delta)
    if not math.isfinite(gain):
        return labelled, None
    return labelled, gain_lower_bound(loop, deltas=[labelled], worst_rates=worst_rates, upper=gain)
