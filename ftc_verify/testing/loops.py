"""Drawn closed loops: a plant and a controller, with a pasteable ``repr``.

:class:`DrawnLoop` pairs a drawn :class:`~ftc_verify.model.system.FTCSystem` with a drawn
:class:`~ftc_verify.controllers.Controller`; its closed loop and exact mean-square
stability test are computed lazily, and its ``repr`` is a ``DrawnLoop.from_spec(...)``
call with every number in full precision, so a falsifying example printed by hypothesis
can be pasted back into a test. :func:`closed_loops`, :func:`stable_loops` and
:func:`unstable_loops` draw them.
"""

from __future__ import annotations

import dataclasses

import functools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from hypothesis import assume
from hypothesis import strategies as st

from ..analysis.closedloop import ClosedLoop, closed_loop
from ..analysis.moments.stability import MSSResult, mean_square_stability
from ..controllers.controller import Controller
from ..model.system import FTCSystem, Matrix
from . import strategies
from .strategies import Opt

__all__ = ["MODE_KEYS", "DrawnLoop", "closed_loops", "stable_loops", "unstable_loops"]

#: Keys of a mode in :meth:`DrawnLoop.spec` (those present in the mode).
MODE_KEYS = ("A", "B", "C", "D", "Cy", "A1", "A2", "B1", "B2")
CONTROLLER_KEYS = ("Ac", "Bc", "Cc", "Dc")


def _plain(value: Any) -> Any:
    """Nested lists of Python floats (exact ``repr``)."""
    return np.asarray(value, dtype=float).tolist()


@dataclass(frozen=True, eq=False)
class DrawnLoop:
    """A plant and a controller; the closed loop (:attr:`loop`) and its stability test
    (:attr:`mss`) are built on first use and kept.

    Attributes
    ----------
    system : FTCSystem
    controller : Controller

    Examples
    --------
    >>> drawn = DrawnLoop.from_spec(
    ...     modes=[{"A": [[1.0]], "B": [[1.0]], "C": [[1.0]], "D": [[1.0]]}] * 2,
    ...     alpha=[[-1.0, 1.0], [1.0, -1.0]], beta_min=[[0.0, 2.0], [2.0, 0.0]],
    ...     beta_max=[[0.0, 2.0], [2.0, 0.0]], gains=[[[-3.0]], [[-3.0]]])
    >>> drawn.mss.stable
    True
    >>> eval(repr(drawn)).controller == drawn.controller
    True
    """

    system: FTCSystem
    controller: Controller

    @classmethod
    def from_spec(
        cls,
        *,
        modes: Sequence[Mapping[str, Any]],
        alpha: Any,
        beta_min: Any,
        beta_max: Any,
        gains: Sequence[Any] | None = None,
        dynamic: Mapping[str, Sequence[Any]] | None = None,
        fault_during_delay: bool = False,
        name: str = "drawn",
        period: float | None = None,
    ) -> DrawnLoop:
        """Build from plain arrays (the inverse of :meth:`spec`): state-feedback ``gains``
        or a ``dynamic`` controller given as lists ``{"Ac": [...], "Bc": [...], ...}``, and the
        controller's sampling ``period`` (``None``: none)."""
        if (gains is None) == (dynamic is None):
            raise TypeError("DrawnLoop.from_spec: give exactly one of gains and dynamic")
        system = FTCSystem.from_arrays(name=name, modes=modes, alpha=alpha, beta_min=beta_min,
                                       beta_max=beta_max, fault_during_delay=fault_during_delay)
        if gains is not None:
            controller = Controller.state_feedback([np.array(K, dtype=float) for K in gains])
        else:
            assert dynamic is not None
            controller = Controller.dynamic(*([np.array(M, dtype=float) for M in dynamic[k]] for k in CONTROLLER_KEYS))
        if period is not None:
            controller = dataclasses.replace(controller, period=period)
        return cls(system, controller)

    def spec(self) -> dict[str, Any]:
        """Keyword arguments of :meth:`from_spec` (numpy copies, safe to modify)."""
        chain = self.system.chain
        out: dict[str, Any] = {
            "modes": [{k: np.array(getattr(md, k)) for k in MODE_KEYS if getattr(md, k) is not None}
                      for md in self.system.modes],
            "alpha": np.array(chain.alpha),
            "beta_min": np.array(chain.beta_min),
            "beta_max": np.array(chain.beta_max),
            "fault_during_delay": chain.fault_during_delay,
            "name": self.system.name,
        }
        if self.controller.is_state_feedback:
            out["gains"] = [np.array(K) for K in self.controller.gains]
        else:
            out["dynamic"] = {k: [np.array(M) for M in getattr(self.controller, k)] for k in CONTROLLER_KEYS}
        if self.controller.period is not None:
            out["period"] = self.controller.period
        return out

    @property
    def gains(self) -> tuple[Matrix, ...]:
        """The gains of a state-feedback controller (raises for a dynamic one)."""
        return self.controller.gains

    @functools.cached_property
    def loop(self) -> ClosedLoop:
        """The closed loop :func:`~ftc_verify.analysis.closed_loop` of the pair."""
        return closed_loop(self.system, self.controller)

    @functools.cached_property
    def mss(self) -> MSSResult:
        """Exact mean-square stability: the verdict proved over the whole rate box and the
        worst spectral abscissa (:func:`~ftc_verify.analysis.moments.stability.mean_square_stability`)."""
        return mean_square_stability(self.loop)

    @functools.cached_property
    def vertex_abscissa(self) -> float:
        """The worst spectral abscissa over the beta vertices, without the box proof
        (``budget_seconds=0``): what :func:`stable_loops` and :func:`unstable_loops` filter
        on. A float estimate; :attr:`mss` holds the proved verdict."""
        return float(mean_square_stability(self.loop, budget_seconds=0.0).spectral_abscissa)

    def _repr_pretty_(self, printer: Any, cycle: bool) -> None:
        """Hypothesis's pretty printer prints the pasteable ``repr``."""
        printer.text(repr(self))

    def __repr__(self) -> str:
        s = self.spec()
        modes = [{k: _plain(v) for k, v in md.items()} for md in s["modes"]]
        if "gains" in s:
            ctrl = f"gains={[_plain(K) for K in s['gains']]!r}"
        else:
            ctrl = f"dynamic={ {k: [_plain(M) for M in v] for k, v in s['dynamic'].items()}!r}"
        return (
            f"DrawnLoop.from_spec(modes={modes!r}, alpha={_plain(s['alpha'])!r}, "
            f"beta_min={_plain(s['beta_min'])!r}, beta_max={_plain(s['beta_max'])!r}, "
            f"{ctrl}, fault_during_delay={s['fault_during_delay']!r}"
            + (f", period={s['period']!r})" if "period" in s else ")")
        )


@st.composite
def closed_loops(
    draw: st.DrawFn,
    *,
    systems: st.SearchStrategy[FTCSystem] | None = None,
    gain_scale: Opt[float] = 1.0,
    dynamic: bool | st.SearchStrategy[bool] | None = False,
    n_c: Opt[int] | None = None,
    extra_states: Opt[int] = 0,
    period: Opt[float] | None = None,
    **system_options: Any,
) -> DrawnLoop:
    """A plant and a controller from :func:`~ftc_verify.testing.controllers`.

    Parameters
    ----------
    systems : strategy, optional
        The plants; default :func:`~ftc_verify.testing.systems` with ``system_options``.
    gain_scale : float, (low, high) or strategy
        Factor on the LQR gains.
    dynamic, n_c, extra_states
        As in :func:`~ftc_verify.testing.controllers`.
    period : float, (low, high) or strategy, optional (keyword only)
        A sampling period for the controller (``Controller.period``; the sampled loop of
        :mod:`ftc_verify.analysis.moments.sampled`), a range drawn log-uniformly
        (:func:`~ftc_verify.testing.strategies.periods`); ``None``: no period.
    **system_options
        Options of :func:`~ftc_verify.testing.systems` (not together with ``systems``).

    Examples
    --------
    >>> from hypothesis import given
    >>> @given(closed_loops(n=2, m=2, dynamic=True))
    ... def test_order(drawn):
    ...     assert drawn.loop.n == 4 and drawn.loop.n_plant == 2
    >>> test_order()
    """
    if systems is None:
        systems = strategies.systems(**system_options)
    elif system_options:
        raise TypeError("closed_loops: give either systems or system options, not both")
    system = draw(systems)
    controller = draw(strategies.controllers(system, dynamic=dynamic, n_c=n_c, extra_states=extra_states,
                                               scale=gain_scale))
    if period is not None:
        if isinstance(period, tuple):
            period = strategies.periods(low=float(period[0]), high=float(period[1]))
        h = draw(period) if isinstance(period, st.SearchStrategy) else float(period)
        controller = dataclasses.replace(controller, period=h)
    return DrawnLoop(system, controller)


@st.composite
def stable_loops(draw: st.DrawFn, *, margin: float = 0.05, gain_scale: Opt[float] = 1.0,
                 **options: Any) -> DrawnLoop:
    """Loops mean-square stable with ``margin``: worst spectral abscissa over the beta
    vertices below ``-margin`` (about 85 % of the default LQR draws qualify). Other
    options as :func:`closed_loops`.

    Examples
    --------
    >>> from hypothesis import given
    >>> @given(stable_loops(n=2, m=2, margin=0.1))
    ... def test_stable(drawn):
    ...     assert drawn.vertex_abscissa < -0.1
    >>> test_stable()
    """
    drawn = draw(closed_loops(gain_scale=gain_scale, **options))
    assume(drawn.vertex_abscissa < -margin)
    return drawn


@st.composite
def unstable_loops(draw: st.DrawFn, *, margin: float = 0.05, gain_scale: Opt[float] = (-2.0, 0.0),
                   **options: Any) -> DrawnLoop:
    """Loops mean-square unstable with ``margin``: worst spectral abscissa over the beta
    vertices above ``margin``. The LQR gains are removed or reversed (``gain_scale`` in
    ``[-2, 0]``) so that most draws qualify. Other options as :func:`closed_loops`.

    Examples
    --------
    >>> from hypothesis import given
    >>> @given(unstable_loops(n=2, m=2))
    ... def test_unstable(drawn):
    ...     assert not drawn.mss.stable
    >>> test_unstable()
    """
    drawn = draw(closed_loops(gain_scale=gain_scale, **options))
    assume(drawn.vertex_abscissa > margin)
    return drawn
