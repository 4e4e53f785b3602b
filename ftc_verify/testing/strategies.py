r"""Hypothesis strategies for FTC plants, fault chains, controllers and disturbances.

Every option is keyword-only and accepts a plain value, a ``(low, high)`` range (inclusive)
or a hypothesis strategy for it. Nothing is drawn or computed at import time.

Drawn plants are small and well scaled, so that every LMI solve stays around 0.1 s:

* the modes are perturbations of a common nominal plant, as faults are in FTC:
  :math:`A_i = A_0 + s U_i`, :math:`B_i = B_0 \operatorname{diag}(e_i) + s V_i`,
  :math:`C_i = C_0 + s W_i`, :math:`D_i = D_0 + s Z_i`, perturbations in ``[-1, 1]``,
  spread :math:`s \in [0, 0.5]`, actuator effectiveness :math:`e_i \in [0.3, 1]`;
* :math:`A_0 = R - 0.2 I` with ``R`` in ``[-1.3, 1.3]`` (the shift keeps the simple
  values hypothesis favours, such as ``A_0 = 0``, stabilizable);
  :math:`B_0 = U \operatorname{diag}(\sigma)` with orthonormal columns ``U`` and
  :math:`\sigma \in [0.5, 1.5]` (full column rank, ``nu <= n``);
  :math:`C_0 = R_C + 0.5 E`, :math:`D_0 = R_D + 0.5 E` with ``R`` in ``[-1, 1]`` and
  ``E`` the rectangular identity, so the disturbance-to-output map does not vanish (a
  vanishing one has :math:`\gamma_{\inf} = 0`, which no LMI can certify); the measured
  output :math:`C_{y,i}` (optional) is drawn like :math:`C_i`;
* with ``stability_margin=a`` every :math:`A_i` is shifted by the same :math:`-cI`,
  :math:`c \ge 0` the least making every nominal :math:`A_i` Hurwitz with
  :math:`\max\operatorname{Re}\lambda(A_i) \le -a`;
* fault rates ``alpha[i][k]`` and detection rates ``beta_min[j][i]`` in ``[0.2, 3]``,
  ``beta_max = beta_min + width`` with width in ``[0, 2]`` (:func:`chains`); on request
  Erlang-``k`` delays (``delay_phases``), false-alarm rates in ``[0, 0.5]`` with widths in
  ``[0, 0.5]`` (``false_alarms``) and ``beta_min = 0`` entries (``missed_detection``);
* uncertainty weights (optional) ``A1, A2`` (``n x n``), ``B1`` (``n x nu``), ``B2``
  (``nu x nu``) with entries in ``[-0.3, 0.3]``, or exact zero matrices.

Controllers (:func:`controllers`): per FDI mode ``j`` the LQR gain
:math:`K_j = -B_j^T X_j` of :math:`(A_j, B_j)` (``Q = qI``, ``R = rI``), optionally scaled;
the dynamic variant is the observer-based controller
:math:`\dot{\hat x} = (A_j + B_j K_j - L_j C_{y,j})\hat x + L_j y_m`, :math:`u = K_j \hat x`,
with the dual LQR gain :math:`L_j`. Neither is guaranteed mean-square stable under the FDI
delay; :func:`ftc_verify.testing.stable_loops` filters on the exact test.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, TypeAlias, TypeVar

import numpy as np
import scipy.linalg
from hypothesis import assume
from hypothesis import strategies as st
from hypothesis.errors import InvalidArgument
from hypothesis.extra.numpy import arrays
from numpy.typing import NDArray

from ..controllers.controller import Controller
from ..model.chain import MAX_DELAY_PHASES
from ..model.system import FTCSystem, JointChain
from .gains import GAIN_BOUND, lqr_gains, observer_gains

__all__ = [
    "GAIN_BOUND",
    "matrices",
    "chains",
    "systems",
    "lqr_gains",
    "observer_gains",
    "state_feedback",
    "controllers",
    "disturbances",
    "similarity_transforms",
    "periods",
]

Matrix = NDArray[np.float64]
#: The type of the value of an :data:`Opt`.
T = TypeVar("T")
#: An option: a value, an inclusive ``(low, high)`` range, or a strategy.
Opt: TypeAlias = T | tuple[T, T] | st.SearchStrategy[T]

#: Bounds of the drawn data (module docstring).
A_BOUND, A_SHIFT = 1.3, 0.2
B_SINGULAR = (0.5, 1.5)
CD_BOUND, CD_FLOOR = 1.0, 0.5
RATE_RANGE = (0.2, 3.0)
WIDTH_MAX = 2.0
#: Largest lower false-alarm rate and largest false-alarm width of :func:`chains`.
FALSE_ALARM_MAX = 0.5
WEIGHT_BOUND = 0.3
#: Poles of the extra controller states of :func:`controllers` beyond ``n_c = n``.
FILTER_POLES = (0.5, 2.0)


def _opt(value: Any, *, floats: bool = False) -> st.SearchStrategy[Any]:
    """``value`` as a strategy: itself, a range, ``None -> booleans()`` or ``just``."""
    if isinstance(value, st.SearchStrategy):
        return value
    if isinstance(value, tuple) and len(value) == 2:
        lo, hi = value
        if floats or isinstance(lo, float) or isinstance(hi, float):
            return st.floats(float(lo), float(hi), allow_nan=False, allow_infinity=False)
        return st.integers(int(lo), int(hi))
    return st.just(value)


def _flag(value: bool | st.SearchStrategy[bool] | None) -> st.SearchStrategy[bool]:
    """A boolean option: ``None`` means either."""
    return st.booleans() if value is None else _opt(value)


def matrices(rows: int, cols: int, *, bound: float = 1.0) -> st.SearchStrategy[Matrix]:
    """Float matrices ``rows x cols`` with entries in ``[-bound, bound]`` (no NaN or inf).

    Examples
    --------
    >>> from hypothesis import given
    >>> @given(matrices(2, 3, bound=0.5))
    ... def test_shape(M):
    ...     assert M.shape == (2, 3) and abs(M).max() <= 0.5
    >>> test_shape()
    """
    return arrays(np.float64, (rows, cols),
                  elements=st.floats(-bound, bound, allow_nan=False, allow_infinity=False, width=64))


def _rates(m: int, low: float, high: float) -> st.SearchStrategy[Matrix]:
    """``m x m`` matrices of rates in ``[low, high]`` (the caller masks the diagonal)."""
    return arrays(np.float64, (m, m), elements=st.floats(low, high, allow_nan=False, allow_infinity=False))


@st.composite
def chains(
    draw: st.DrawFn,
    *,
    m: Opt[int] = (2, 3),
    rate_min: float = RATE_RANGE[0],
    alpha_max: float = RATE_RANGE[1],
    beta_max: float = RATE_RANGE[1],
    beta_width: Opt[float] = WIDTH_MAX,
    fault_during_delay: bool | st.SearchStrategy[bool] | None = False,
    delay_phases: Opt[int] = 1,
    false_alarms: bool | st.SearchStrategy[bool] | None = False,
    false_alarm_max: float = FALSE_ALARM_MAX,
    false_alarm_width: Opt[float] = FALSE_ALARM_MAX,
    missed_detection: bool | st.SearchStrategy[bool] | None = False,
) -> JointChain:
    """Joint (true, FDI) chains: a valid fault generator and a box of detection rates,
    optionally with the FDI models of :mod:`ftc_verify.model.chain` (Erlang delays,
    false alarms, missed detection).

    Parameters
    ----------
    m : int, (low, high) or strategy
        Number of fault modes (at least 2).
    rate_min : float
        Smallest off-diagonal fault rate and smallest lower detection rate (``> 0``).
    alpha_max : float
        Largest off-diagonal fault rate ``alpha[i][k]``; the diagonal makes rows sum to zero.
    beta_max : float
        Largest lower detection rate ``beta_min[j][i]``.
    beta_width : float, (low, high) or strategy
        Largest interval width ``beta_max - beta_min``; each width is drawn in
        ``[0, beta_width]``. ``0`` gives exact rates (``beta_min == beta_max``).
    fault_during_delay : bool, None or strategy
        The chain variant; ``None`` draws either.
    delay_phases : int, (low, high) or strategy
        Erlang phases ``k`` of the detection delay (1 to
        :data:`~ftc_verify.model.chain.MAX_DELAY_PHASES`; 1 is the paper's exponential).
    false_alarms : bool, None or strategy
        Add a box of false-alarm rates: ``false_alarm_min[i][j]`` in
        ``[0, false_alarm_max]``, width in ``[0, false_alarm_width]``; ``None`` draws either.
    false_alarm_max : float
        Largest lower false-alarm rate (``>= 0``).
    false_alarm_width : float, (low, high) or strategy
        Largest false-alarm interval width; ``0`` gives exact false-alarm rates.
    missed_detection : bool, None or strategy
        Set ``beta_min`` to 0 on a drawn, non-empty set of off-diagonal entries (the
        detection may never come); ``None`` draws either.

    Raises
    ------
    hypothesis.errors.InvalidArgument
        For ``m < 2``, ``delay_phases`` outside ``1 .. MAX_DELAY_PHASES``, a negative
        ``false_alarm_max`` (hypothesis's error for a strategy's bad argument).

    Examples
    --------
    >>> from hypothesis import given
    >>> @given(chains(m=3, beta_width=0.0))
    ... def test_generator(chain):
    ...     beta = chain.beta_min
    ...     assert abs(chain.generator(beta).sum(axis=1)).max() < 1e-9
    >>> test_generator()
    """
    m_ = draw(_opt(m))
    if m_ < 2:
        raise InvalidArgument(f"chains: m must be at least 2, got {m_}")
    off = ~np.eye(m_, dtype=bool)
    alpha = np.where(off, draw(_rates(m_, rate_min, alpha_max)), 0.0)
    alpha -= np.diag(alpha.sum(axis=1))
    k = draw(_opt(delay_phases))
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 1 <= k <= MAX_DELAY_PHASES:
        raise InvalidArgument(f"chains: delay_phases must be an integer from 1 to {MAX_DELAY_PHASES}, got {k!r}")
    if not (0.0 <= false_alarm_max < np.inf):
        raise InvalidArgument(f"chains: false_alarm_max must be finite and >= 0, got {false_alarm_max!r}")
    beta_min = np.where(off, draw(_rates(m_, rate_min, beta_max)), 0.0)
    width_max = draw(_opt(beta_width, floats=True))
    width = np.where(off, draw(_rates(m_, 0.0, width_max)), 0.0) if width_max > 0 else np.zeros((m_, m_))
    beta_top = beta_min + width
    if draw(_flag(missed_detection)):
        missed = off & draw(arrays(np.bool_, (m_, m_)))
        if not missed.any():
            missed[0, 1] = True
        beta_min = np.where(missed, 0.0, beta_min)
    fa_min = fa_max = None
    if draw(_flag(false_alarms)):
        fa_min = np.where(off, draw(_rates(m_, 0.0, false_alarm_max)), 0.0)
        fa_width = draw(_opt(false_alarm_width, floats=True))
        fa_max = fa_min + (np.where(off, draw(_rates(m_, 0.0, fa_width)), 0.0) if fa_width > 0 else 0.0)
    return JointChain(alpha, beta_min, beta_top, draw(_flag(fault_during_delay)), delay_phases=int(k),
                      false_alarm_min=fa_min, false_alarm_max=fa_max)


_chains = chains


def _shift_to_margin(modes: list[dict[str, Matrix]], margin: float | None) -> None:
    """Shift every ``A`` by the same ``-cI`` so that each is Hurwitz with ``margin``."""
    if margin is None:
        return
    worst = max(float(np.max(np.linalg.eigvals(md["A"]).real)) for md in modes)
    shift = max(0.0, worst + float(margin))
    for md in modes:
        md["A"] = md["A"] - shift * np.eye(md["A"].shape[0])


def _chain_of(draw: st.DrawFn, chain: Any, m: Any) -> JointChain:
    """The chain option of :func:`systems`: a strategy, a mapping of options, or ``None``."""
    if isinstance(chain, st.SearchStrategy):
        return draw(chain)
    options = dict(chain) if isinstance(chain, Mapping) else {}
    return draw(_chains(m=m, **options))


@st.composite
def systems(
    draw: st.DrawFn,
    *,
    n: Opt[int] = (2, 4),
    m: Opt[int] = (2, 3),
    nu: Opt[int] = (1, 2),
    ny: Opt[int] = (1, 2),
    nw: Opt[int] = (1, 2),
    stability_margin: Opt[float] | None = None,
    uncertain: bool | st.SearchStrategy[bool] | None = False,
    zero_weights: bool | st.SearchStrategy[bool] | None = False,
    measured_outputs: Opt[int] | None = None,
    chains: st.SearchStrategy[JointChain] | Mapping[str, Any] | None = None,
    spread: Opt[float] = (0.0, 0.5),
    name: str = "drawn",
) -> FTCSystem:
    """Small, well-scaled random :class:`~ftc_verify.model.system.FTCSystem` (module docstring).

    Parameters
    ----------
    n, m, nu, ny, nw : int, (low, high) or strategy
        States, fault modes, control inputs (capped at ``n``), performance outputs and
        disturbances.
    stability_margin : float, (low, high), strategy or None
        If given, every open-loop nominal ``A_i`` is Hurwitz with spectral abscissa at
        most ``-stability_margin``.
    uncertain : bool, None or strategy
        Add uncertainty weights ``A1, A2, B1, B2`` to every mode; ``None`` draws either.
    zero_weights : bool, None or strategy
        With ``uncertain``, make every weight an exact zero matrix.
    measured_outputs : int, (low, high), strategy or None
        If given, add a measured output ``Cy`` with that many rows to every mode (output
        feedback then reads ``y_m = Cy x`` instead of ``C x``).
    chains : strategy, mapping or None
        The joint chain: a strategy of :class:`~ftc_verify.model.system.JointChain` (then
        ``m`` is the chain's), or keyword options of :func:`chains` (e.g.
        ``{"beta_width": 0.0}``), default :func:`chains` with ``m``.
    spread : float, (low, high) or strategy
        Size of the differences between the modes.
    name : str
        The system's name.

    Examples
    --------
    >>> from hypothesis import given
    >>> @given(systems(n=2, m=2, stability_margin=0.1, measured_outputs=1))
    ... def test_open_loop(system):
    ...     assert all(max(np.linalg.eigvals(md.A).real) <= -0.1 + 1e-9 for md in system.modes)
    ...     assert system.ny_measured == 1
    >>> test_open_loop()
    """
    chain = _chain_of(draw, chains, m)
    n_, nu_, ny_, nw_ = (draw(_opt(v)) for v in (n, nu, ny, nw))
    for label, value in (("n", n_), ("nu", nu_), ("ny", ny_), ("nw", nw_)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
            raise InvalidArgument(f"systems: {label} must be an integer of at least 1, got {value!r}")
    unc, zero = draw(_flag(uncertain)), draw(_flag(zero_weights))
    ny_m = None if measured_outputs is None else draw(_opt(measured_outputs))
    if ny_m is not None and (isinstance(ny_m, bool) or not isinstance(ny_m, (int, np.integer)) or ny_m < 1):
        raise InvalidArgument(f"systems: measured_outputs must be an integer of at least 1, got {ny_m!r}")
    ny_m = None if ny_m is None else int(ny_m)
    s = draw(_opt(spread, floats=True))
    nu_ = min(nu_, n_)
    A0 = draw(matrices(n_, n_, bound=A_BOUND)) - A_SHIFT * np.eye(n_)
    U, _ = np.linalg.qr(draw(matrices(n_, nu_)))  # orthonormal columns, whatever is drawn
    B0 = U[:, :nu_] * draw(arrays(np.float64, (nu_,), elements=st.floats(*B_SINGULAR)))
    C0 = draw(matrices(ny_, n_, bound=CD_BOUND)) + CD_FLOOR * np.eye(ny_, n_)
    D0 = draw(matrices(n_, nw_, bound=CD_BOUND)) + CD_FLOOR * np.eye(n_, nw_)
    Cy0 = None if ny_m is None else draw(matrices(ny_m, n_, bound=CD_BOUND)) + CD_FLOOR * np.eye(ny_m, n_)
    modes = []
    for _ in range(chain.m):
        eff = draw(arrays(np.float64, (nu_,), elements=st.floats(0.3, 1.0)))
        mode: dict[str, Matrix] = {
            "A": A0 + s * draw(matrices(n_, n_)),
            "B": B0 * eff + s * draw(matrices(n_, nu_)),
            "C": C0 + s * draw(matrices(ny_, n_)),
            "D": D0 + s * draw(matrices(n_, nw_)),
        }
        if Cy0 is not None:
            mode["Cy"] = Cy0 + s * draw(matrices(*Cy0.shape))
        if unc:
            for key, shape in {"A1": (n_, n_), "A2": (n_, n_), "B1": (n_, nu_), "B2": (nu_, nu_)}.items():
                mode[key] = np.zeros(shape) if zero else draw(matrices(*shape, bound=WEIGHT_BOUND))
        modes.append(mode)
    _shift_to_margin(modes, None if stability_margin is None else draw(_opt(stability_margin, floats=True)))
    built = FTCSystem.from_arrays(name=name, modes=modes, alpha=chain.alpha, beta_min=chain.beta_min,
                                  beta_max=chain.beta_max, fault_during_delay=chain.fault_during_delay)
    return FTCSystem(name=name, modes=built.modes, chain=chain)  # the drawn chain whole (phases, false alarms)


@st.composite
def state_feedback(
    draw: st.DrawFn,
    system: FTCSystem,
    *,
    scale: Opt[float] = 1.0,
    q: float = 1.0,
    r: float = 1.0,
    max_gain: float = GAIN_BOUND,
) -> Controller:
    """Static state feedback ``u = scale * K_j x`` with the LQR gains of :func:`lqr_gains`.

    Draws for which :func:`lqr_gains` returns ``None`` are rejected (``assume``).

    Examples
    --------
    >>> from hypothesis import given
    >>> @given(systems(n=2, m=2).flatmap(lambda s: st.tuples(st.just(s), state_feedback(s))))
    ... def test_shapes(pair):
    ...     system, controller = pair
    ...     assert controller.is_state_feedback and controller.entries == system.m
    >>> test_shapes()
    """
    gains = lqr_gains(system, q=q, r=r, max_gain=max_gain)
    assume(gains is not None)
    assert gains is not None
    c = draw(_opt(scale, floats=True))
    return Controller.state_feedback([c * K for K in gains], name="LQR state feedback")


def _observer(draw: st.DrawFn, system: FTCSystem, n_c: int, c: float, q: float, r: float,
              max_gain: float) -> Controller:
    """The observer-based controller of :func:`controllers` with ``n_c - n`` filter states."""
    n = system.dims[0]
    if n_c < n:
        raise InvalidArgument(f"controllers: n_c = {n_c} is below the plant order n = {n} (observer-based)")
    K, L = lqr_gains(system, q=q, r=r, max_gain=max_gain), observer_gains(system, q=q, r=r, max_gain=max_gain)
    assume(K is not None and L is not None)
    assert K is not None and L is not None
    extra, ny_m = n_c - n, system.ny_measured
    poles = draw(arrays(np.float64, (extra,), elements=st.floats(*FILTER_POLES)))
    G = draw(matrices(extra, ny_m))
    Ac, Bc, Cc, Dc = [], [], [], []
    for md, Kj, Lj in zip(system.modes, K, L):
        obs = md.A + c * md.B @ Kj - Lj @ md.measured
        Ac.append(scipy.linalg.block_diag(obs, -np.diag(poles)))
        Bc.append(np.vstack([Lj, G]))
        Cc.append(np.hstack([c * Kj, np.zeros((Kj.shape[0], extra))]))
        Dc.append(np.zeros((Kj.shape[0], ny_m)))
    return Controller.dynamic(Ac, Bc, Cc, Dc, name="observer-based output feedback")


@st.composite
def controllers(
    draw: st.DrawFn,
    system: FTCSystem,
    *,
    dynamic: bool | st.SearchStrategy[bool] | None = False,
    n_c: Opt[int] | None = None,
    extra_states: Opt[int] = 0,
    scale: Opt[float] = 1.0,
    q: float = 1.0,
    r: float = 1.0,
    max_gain: float = GAIN_BOUND,
) -> Controller:
    r"""Controllers for ``system``: LQR state feedback, or dynamic observer-based output feedback.

    The dynamic controller of FDI mode ``j`` reads ``y_m = Cy x`` (default ``C x``):

    .. math::

        \dot{\hat x} = (A_j + B_j K_j - L_j C_{y,j})\hat x + L_j y_m,\quad
        \dot\eta = -\operatorname{diag}(p)\,\eta + G y_m,\quad u = K_j \hat x,

    with ``K_j`` from :func:`lqr_gains` (times ``scale``), ``L_j`` from
    :func:`observer_gains`, and ``n_c - n`` extra stable filter states ``eta`` (poles
    ``p`` in ``[0.5, 2]``, ``G`` in ``[-1, 1]``) that do not feed ``u``.

    Parameters
    ----------
    system : FTCSystem
        The plant.
    dynamic : bool, None or strategy
        Dynamic output feedback instead of state feedback; ``None`` draws either.
    n_c : int, (low, high), strategy or None
        Order of the dynamic controller (at least ``n``); default ``n + extra_states``.
    extra_states : int, (low, high) or strategy
        Filter states beyond the observer's ``n`` when ``n_c`` is not given.
    scale : float, (low, high) or strategy
        Factor on the LQR gains ``K_j``.
    q, r, max_gain : float
        LQR weights ``Q = qI``, ``R = rI`` and the largest accepted gain entry; draws whose
        Riccati equations fail or whose gains exceed ``max_gain`` are rejected.

    Examples
    --------
    >>> from hypothesis import given
    >>> from ftc_verify.analysis import closed_loop
    >>> @given(systems(n=2, m=2, measured_outputs=1).flatmap(
    ...     lambda s: st.tuples(st.just(s), controllers(s, dynamic=True, n_c=3))))
    ... def test_order(pair):
    ...     system, controller = pair
    ...     assert closed_loop(system, controller).n == 2 + 3
    >>> test_order()
    """
    if not draw(_flag(dynamic)):
        return draw(state_feedback(system, scale=scale, q=q, r=r, max_gain=max_gain))
    order = system.dims[0] + draw(_opt(extra_states)) if n_c is None else draw(_opt(n_c))
    return _observer(draw, system, order, draw(_opt(scale, floats=True)), q, r, max_gain)


def periods(*, low: float = 1e-3, high: float = 0.2) -> st.SearchStrategy[float]:
    """A controller's sampling period ``h`` in ``[low, high]``, log-uniform
    (``10 ** u``, ``u`` uniform between the logarithms): short and long periods alike, for
    :mod:`ftc_verify.analysis.moments.sampled`."""
    if not 0 < low <= high:
        raise InvalidArgument(f"periods: need 0 < low <= high, got {low!r}, {high!r}")
    lo, hi = float(np.log10(low)), float(np.log10(high))
    return st.floats(lo, hi).map(lambda e: float(min(max(10.0 ** e, low), high)))


def disturbances(*, exact: bool = False, decaying: bool = False, nonzero: bool = False) -> st.SearchStrategy[str]:
    """Names of disturbance shapes of :data:`ftc_verify.simulation.paths.DISTURBANCES`.

    Parameters
    ----------
    exact : bool
        Only shapes with an exact moment model (:func:`ftc_verify.analysis.moments.energy.exact_energy`).
    decaying : bool
        Only shapes of finite energy on ``[0, inf)`` (implies ``exact``; what an
        infinite-horizon ``exact_energy`` needs).
    nonzero : bool
        Leave out ``"zero"`` (whose energy ratio is undefined).

    Examples
    --------
    >>> from hypothesis import given
    >>> @given(disturbances(decaying=True, nonzero=True))
    ... def test_name(kind):
    ...     assert kind == "paper"
    >>> test_name()
    """
    from ..simulation.paths import DISTURBANCES  # imported here: the simulators are heavy to import
    from ..analysis.moments.energy import EXOSYSTEMS

    names = sorted(DISTURBANCES)
    if exact or decaying:
        names = [k for k in names if k in EXOSYSTEMS]
    if decaying:
        names = [k for k in names if np.max(np.linalg.eigvals(EXOSYSTEMS[k][0]).real) < 0]
    if nonzero:
        names = [k for k in names if k != "zero"]
    if not names:
        raise InvalidArgument("disturbances: no disturbance shape meets the options")
    return st.sampled_from(names)


@st.composite
def similarity_transforms(draw: st.DrawFn, n: int, *, max_condition: float = 10.0) -> Matrix:
    r"""Invertible ``n x n`` matrices with condition number at most ``max_condition``.

    :math:`T = Q_1 \operatorname{diag}(\sigma) Q_2` with orthogonal :math:`Q_1, Q_2` (QR
    factors of drawn matrices, orthogonal whatever is drawn) and singular values
    :math:`\sigma \in [1, \text{max\_condition}]`.

    Examples
    --------
    >>> from hypothesis import given
    >>> @given(similarity_transforms(3, max_condition=4.0))
    ... def test_condition(T):
    ...     assert np.linalg.cond(T) <= 4.0 * (1 + 1e-9)
    >>> test_condition()
    """
    q1, _ = np.linalg.qr(draw(matrices(n, n)))
    q2, _ = np.linalg.qr(draw(matrices(n, n)))
    sigma = draw(arrays(np.float64, (n,), elements=st.floats(1.0, max_condition)))
    return q1 @ np.diag(sigma) @ q2
