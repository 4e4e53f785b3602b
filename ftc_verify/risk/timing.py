r"""The FDI timing view: how likely a detection outlasts the fault-tolerant time interval.

After a fault from mode :math:`i` to mode :math:`i'` the joint chain of
:mod:`ftc_verify.model.chain` enters the detection state :math:`(i', i, 0)`: the plant is
in :math:`i'`, the controller still runs the controller of :math:`i`. Let :math:`T` be
the first time the FDI shows the true mode again (the chain reaches a *matched* state
:math:`(r, r)`). The question of the fault-tolerant time interval :math:`\tau` (the time
the plant tolerates a mismatched controller, ISO 26262's FTTI) is :math:`P(T > \tau)`.

**The exact formula.** Let :math:`\mathcal T` be the mismatched states :math:`(r, l, p)`,
:math:`r \ne l`, and :math:`Q_{\mathcal T\mathcal T}` the generator restricted to them.
The chain stopped on leaving :math:`\mathcal T` has the sub-generator
:math:`Q_{\mathcal T\mathcal T}`, so by the Kolmogorov forward equation the probability
of being still in :math:`\mathcal T` at :math:`\tau`, from the state :math:`e` entered
at the fault, is

.. math::

    P(T > \tau) = e^T \exp(Q_{\mathcal T\mathcal T}\,\tau)\,\mathbf 1 ,

the survival function of a phase-type distribution. In the paper's model (one phase, no
fault during the delay) :math:`\mathcal T` reduces to the one state :math:`(i', i)` with
exit rate :math:`\beta_{i i'}`, and :math:`P(T > \tau) = e^{-\beta\tau}`; with an
Erlang-:math:`k` delay (``delay_phases = k``, each phase at rate :math:`k\beta`) it is the
Erlang tail :math:`\sum_{n<k} e^{-k\beta\tau} (k\beta\tau)^n / n!`. With the named
``fault_during_delay`` variant a new fault restarts the detection (phase 0 of the new
pair) or, when it returns the plant to the mode the FDI shows, ends the mismatch: both
are in the formula, since they are transitions of :math:`Q`. A **false alarm** (FDI
reports :math:`j` while the plant stays in :math:`i`) enters the state :math:`(i, j, 0)`
and is withdrawn by the same detection process, so its duration has the same law as the
delay of a fault from :math:`j` to :math:`i`; it is listed as its own event.

**The rate box.** The rows of :math:`\mathcal T` contain the detection rates
:math:`k\beta` and the fault rates (fixed); the false-alarm rates leave matched states
only and do not enter. :math:`P(T > \tau)` is non-increasing in every detection rate:
couple two chains with :math:`\beta \le \beta'` entry-wise on the same fault times
(faults depend on the true mode only, which both share until their exits) and realise
each phase advance of the slower chain as one of the faster (thinning); the faster
chain's phase is then never behind the slower one's in the same pair, both restart at
the same faults, so it exits first. Hence the worst case over the box is exactly the
value at the lower corner :attr:`~ftc_verify.model.chain.JointChain.rate_min` and the
best at the upper corner: both are reported.

**Proof.** :math:`Q_{\mathcal T\mathcal T}` is formed in ball arithmetic from the rates
(:func:`~ftc_verify.analysis.exact.ball_generator`), its exponential is Arb's rigorous
``arb_mat.exp`` (as in :mod:`ftc_verify.analysis.moments.sampled_proof`), so the ball of
each probability contains the exact value for the float rates; the reported number is
the ball's upper end rounded up to a float.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..analysis.exact import ball_generator
from ..analysis.rigorous import precision
from ..errors import ValidationError
from ..model.system import JointChain

__all__ = ["Exceedance", "DelayExceedance", "delay_exceedance", "mismatch_survival"]


def _float_up(value: Any) -> float:
    """The upper end of an ``arb`` as a float that is not below it."""
    return float(np.nextafter(float(value.upper()), math.inf))


def _float_down(value: Any) -> float:
    """The lower end of an ``arb`` as a float that is not above it."""
    return float(np.nextafter(float(value.lower()), -math.inf))


@dataclass(frozen=True)
class Exceedance:
    """One event that puts the loop out of step: a fault or a false alarm.

    Attributes
    ----------
    kind : str
        ``"fault"`` (true mode ``source`` to ``target``, the FDI still shows ``source``)
        or ``"false alarm"`` (true mode ``source``, FDI reports ``target``).
    source, target : int
        Modes, 1-based as in the reports.
    probability : float
        Proved upper bound of :math:`P(T > \\tau)` at the lower corner of the rate box:
        the worst case over the box (module docstring).
    enclosure : (float, float)
        Lower and upper ends of the ball of that probability.
    best : float
        Proved upper bound of the same probability at the upper corner of the box (the
        best case).
    """

    kind: str
    source: int
    target: int
    probability: float
    enclosure: tuple[float, float]
    best: float

    @property
    def label(self) -> str:
        """``"fault 1->2"`` or ``"false alarm 1->2"``."""
        return f"{self.kind} {self.source}->{self.target}"

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {"kind": self.kind, "source": self.source, "target": self.target, "label": self.label,
                "probability": self.probability, "enclosure": list(self.enclosure), "best": self.best}


@dataclass(frozen=True)
class DelayExceedance:
    """The FDI timing view (:func:`delay_exceedance`).

    Attributes
    ----------
    interval : float
        The fault-tolerant time interval :math:`\\tau`.
    events : tuple of Exceedance
        One per possible fault (``alpha[i, i'] > 0``) and false alarm (upper false-alarm
        rate > 0).
    worst : float or None
        The largest ``probability`` over the events (``None`` when the chain has none).
    worst_event : str
        Its label (empty when there is none).
    method : str
        How the numbers were obtained.
    """

    interval: float
    events: tuple[Exceedance, ...]
    worst: float | None
    worst_event: str
    method: str

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {"interval": self.interval, "events": [e.to_dict() for e in self.events], "worst": self.worst,
                "worst_event": self.worst_event, "method": self.method}


def _mismatched(chain: JointChain) -> list[int]:
    """Indices of the mismatched joint states (true != fdi), in state order."""
    return [s for s, (i, j, _) in enumerate(chain.states) if i != j]


def mismatch_survival(chain: JointChain, rates: Any, start: tuple[int, int], interval: float) -> Any:
    r"""The ball (``flint.arb``) of :math:`P(T > \tau)` from the state ``(true, fdi, 0)`` =
    ``start`` (0-based, mismatched) at the rate array ``rates`` (module docstring:
    :math:`e^T \exp(Q_{\mathcal T\mathcal T}\tau) \mathbf 1`), at the working precision of
    the caller (:func:`~ftc_verify.analysis.rigorous.precision`)."""
    import flint

    true, fdi = start
    if true == fdi:
        raise ValidationError(f"start: {start} is a matched state; the mismatch has not begun")
    keep = _mismatched(chain)
    Q = ball_generator(chain, np.asarray(rates, dtype=float))
    sub = flint.arb_mat(len(keep), len(keep))
    for a, s in enumerate(keep):
        for b, t in enumerate(keep):
            sub[a, b] = Q[s][t]
    E = (sub * flint.arb(float(interval))).exp()
    row = keep.index(chain.state_index(true, fdi, 0))
    total = flint.arb(0)
    for b in range(len(keep)):
        total += E[row, b]
    return total


def _check_interval(interval: float) -> float:
    if isinstance(interval, bool) or not isinstance(interval, (int, float, np.floating)) or not (
            math.isfinite(interval) and interval >= 0):
        raise ValidationError(f"interval: the fault-tolerant time interval must be a finite number >= 0, "
                              f"got {interval!r}")
    return float(interval)


def _events(chain: JointChain) -> list[tuple[str, int, int, tuple[int, int]]]:
    """``(kind, source, target, start state (true, fdi))`` of every fault and false alarm."""
    m = chain.m
    out = [("fault", i, k, (k, i)) for i in range(m) for k in range(m) if k != i and chain.alpha[i, k] > 0]
    if chain.false_alarm_max is not None:
        out += [("false alarm", i, j, (i, j)) for i in range(m) for j in range(m)
                if j != i and chain.false_alarm_max[i, j] > 0]
    return out


def delay_exceedance(chain: JointChain, interval: float) -> DelayExceedance:
    r"""For each fault and false alarm, the probability that the FDI has not shown the true
    mode within ``interval`` after it (module docstring), proved in ball arithmetic.

    Parameters
    ----------
    chain : JointChain
        The joint chain (exponential or Erlang-``k`` delays, false alarms, the
        ``fault_during_delay`` variant).
    interval : float
        The fault-tolerant time interval :math:`\tau \ge 0`, in the chain's time unit.

    Returns
    -------
    DelayExceedance
        Per event the worst case over the rate box (at its lower corner; module
        docstring) and the best case, and the worst over the events.

    Raises
    ------
    ValidationError
        ``chain`` is not a :class:`~ftc_verify.model.chain.JointChain`, or ``interval`` is
        not a finite number ``>= 0``.
    """
    if not isinstance(chain, JointChain):
        raise ValidationError(f"chain: expected a JointChain, got {type(chain).__name__}")
    tau = _check_interval(interval)
    events = []
    cache: dict[tuple[int, int], tuple[Any, Any]] = {}
    with precision():
        for kind, source, target, start in _events(chain):
            if start not in cache:
                cache[start] = (mismatch_survival(chain, chain.rate_min, start, tau),
                                mismatch_survival(chain, chain.rate_max, start, tau))
            worst, best = cache[start]
            events.append(Exceedance(kind, source + 1, target + 1, min(1.0, _float_up(worst)),
                                     (max(0.0, _float_down(worst)), min(1.0, _float_up(worst))),
                                     min(1.0, _float_up(best))))
    top = max(events, key=lambda e: e.probability) if events else None
    method = ("exact phase-type survival e' exp(Q_TT tau) 1 of the joint chain, Arb ball arithmetic "
              f"(128 bits); worst case at the lower corner of the rate box ({chain.describe()})")
    return DelayExceedance(tau, tuple(events), None if top is None else top.probability,
                           "" if top is None else top.label, method)
